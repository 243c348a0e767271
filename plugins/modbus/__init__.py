"""fieldgate.plugins.modbus"""
