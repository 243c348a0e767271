"""Output writes of the CiA 401 objects, one process-image batch per message.

Writes made inside :meth:`OutputWrites.batch` (the PDO engine applies an RPDO, or the RPDOs
of one SYNC, in one: :class:`~..cia301.entries.Directory`'s ``batch``) are collected and
written to the image as one batch when the outermost batch ends, so subscribers (a back's
write-on-change, a loopback, Sparkplug) hear of a message once, not once per bit; outside
a batch (an SDO download) each object write is its own batch.
"""

from __future__ import annotations

from typing import Any

from fieldgate.image import ProcessImage, Value


class OutputWrites:
    def __init__(self, image: ProcessImage, origin: str):
        self.image = image
        self.origin = origin  # labels the writes (the front's name)
        self.depth = 0
        self._staged: dict[str, Value] | None = None  # the writes of the open batch

    def write(self, values: dict[str, Value]) -> None:
        if self._staged is not None:
            self._staged.update(values)
        elif values:
            self.image.write_outputs(values, self.origin)

    def batch(self) -> OutputWrites:
        """A context: the writes made inside it reach the image as one batch."""
        return self

    def __enter__(self) -> None:
        if self.depth == 0:
            self._staged = {}
        self.depth += 1

    def __exit__(self, *exc: Any) -> None:
        self.depth -= 1
        if self.depth == 0:
            staged, self._staged = self._staged, None
            if staged:
                self.image.write_outputs(staged, self.origin)
