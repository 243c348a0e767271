"""fieldgate.plugins.dcon"""
