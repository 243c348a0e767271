"""DeviceNet Group 2 Only slave front (``type: devicenet``)."""
