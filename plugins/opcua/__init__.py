"""The ``opcua`` front: the process image served by an OPC UA server (asyncua; docs/opcua.md)."""
