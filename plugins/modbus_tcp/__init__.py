"""The ``modbus-tcp`` front: the process image served as a Modbus TCP server (docs/modbus-tcp.md)."""
