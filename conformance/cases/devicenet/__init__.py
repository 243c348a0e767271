"""DeviceNet Group 2 Only slave: duplicate MAC ID check, Predefined Master/Slave Connection Set
(Allocate / Release), explicit messaging with CIP errors and fragmentation, poll, change of
state and cyclic I/O, expected packet rate and inactivity timeout, I/O connection paths, the
I-7241D's Application object (anchors-gateways §2, seed-003: the key to seed citations is
docs/sources.md).

One module per service of the engine (plugins/devicenet), imported in the order the cases
run (their registration order).
"""

from importlib import import_module

# importing a module registers its cases: this order is the order they run in
SERVICES = (
    "netaccess",
    "allocation",
    "objects",
    "explicit",
    "poll",
    "connection_set",
    "paths",
    "cos_cyclic",
    "application",
)
for _service in SERVICES:
    import_module(f"{__name__}.{_service}")
