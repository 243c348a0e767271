"""fieldgate.plugins.canopen"""
