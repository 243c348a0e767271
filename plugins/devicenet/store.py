"""MAC ID and baud rate set over the network, kept across gateway restarts (the I-7241D's EEPROM).

The file also records the configured values it was written against: when the topology
file changes ``mac_id`` or ``bitrate``, the topology wins and the stored values are
dropped. Writes are atomic; a corrupt file is reported and ignored.
"""

from __future__ import annotations

import logging
from pathlib import Path

from fieldgate.persist import CorruptStore, read_json, write_json_atomic

log = logging.getLogger("fieldgate.devicenet.store")


class NetworkStore:
    def __init__(self, path: Path, configured: tuple[int, int]):
        self.path = path
        self.configured = list(configured)

    def load(self) -> tuple[int, int] | None:
        """``(mac_id, baud_code)`` stored for the current configuration, or None."""
        try:
            data = read_json(self.path)
        except CorruptStore as exc:
            log.warning("ignoring the DeviceNet store: %s", exc)
            return None
        if not isinstance(data, dict) or data.get("configured") != self.configured:
            return None
        mac, baud = data.get("mac_id"), data.get("baud_code")
        if not (
            isinstance(mac, int) and 0 <= mac <= 63 and isinstance(baud, int) and 0 <= baud <= 2
        ):
            log.warning("ignoring the DeviceNet store %s: values out of range", self.path)
            return None
        return mac, baud

    def save(self, mac_id: int, baud_code: int) -> None:
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            write_json_atomic(
                self.path, {"configured": self.configured, "mac_id": mac_id, "baud_code": baud_code}
            )
        except OSError as exc:
            log.error("cannot store the DeviceNet MAC ID / baud rate in %s: %s", self.path, exc)
