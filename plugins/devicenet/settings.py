"""The slave's settings: what the front configures and the CIP objects report.

Below the engine and the objects (both read it), so neither imports the other for it.
"""

from __future__ import annotations

from dataclasses import dataclass, field

BAUD_RATES = (125_000, 250_000, 500_000)
DUP_MAC_INTERVAL_S = 1.0


@dataclass
class Settings:
    mac_id: int = 1
    baud_code: int = 0
    vendor_id: int = 803
    device_type: int = 0
    product_code: int = 1
    major_revision: int = 2
    minor_revision: int = 1
    serial: int = 1
    product_name: str = "fieldgate"
    tolerate_trailing_bytes: bool = (
        True  # the seed's Set requests carry a stray byte (extract §9.2)
    )
    dup_mac_interval_s: float = DUP_MAC_INTERVAL_S
    # connection type (poll, strobe, cos, cyclic) -> (produce, consume) assembly selectors
    # (fieldgate.plugins.devicenet.paths); missing types keep the defaults
    io_paths: dict[str, tuple[str | int, str | int]] = field(default_factory=dict)
