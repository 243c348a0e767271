"""Hooks of the example battery pack (examples/canopen-device/battery.eds).

The pack's measurements are computed when a master reads them (0x2000), the charge
limit cannot change while the contactor is closed (abort 0800 0022), closing the
contactor raises the load current and sends TPDO2 at once, and a pack above 45 C
raises EMCY 0x4210 (temperature) until it cools down.
"""

import time

DEVICE_STATE = 0x08000022  # SDO abort: "not in the present device state"
HOT = 450  # 0.1 C


def setup(device):
    start = time.monotonic()

    @device.on_read(0x2000)
    def measure(index, sub):
        hours = (time.monotonic() - start) / 3600
        closed = device.get(0x2101, 0)
        soc = max(0, 80 - int(hours * 10 * closed))
        temperature = 250 + 30 * closed
        if temperature > HOT:
            device.raise_emcy(0x4210, 0x09)
        return {1: 44000 + 60 * soc, 2: -12000 * closed, 3: soc, 4: temperature}[sub]

    @device.on_write(0x2100)
    def charge_limit(index, sub, value):
        if device.get(0x2101, 0):
            raise device.Refuse(DEVICE_STATE, "open the contactor first")

    @device.on_write(0x2101)
    def contactor(index, sub, value):
        device.set(0x2000, 2, -12000 if value else 0)  # TPDO1 carries it at the next SYNC
        device.trigger(0x2101, 0)  # TPDO2 (event-driven) maps 0x2101: sent now
        if not value:
            device.clear_emcy(0x4210)
