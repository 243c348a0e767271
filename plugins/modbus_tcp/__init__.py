"""The ``modbus-tcp`` front: the process image served as a Modbus TCP server (pymodbus; docs/modbus-tcp.md)."""
