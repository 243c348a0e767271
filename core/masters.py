"""Whether each front's fieldbus master is present.

A front reports ``lost`` (life guarding, heartbeat-consumer timeout, bus-off, DeviceNet
connection timeout) and ``ok``. On *lost*, the outputs the front serves go to their
error modes in the process image, and backs write them to the modules. Backs that
keep a module-side watchdog alive (DCON ``~**``) subscribe to know when to stop.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterable

from .image import ProcessImage

log = logging.getLogger("fieldgate.masters")

Listener = Callable[[str, bool, str], None]  # (front name, master ok, reason)


class MasterMonitor:
    def __init__(self, image: ProcessImage):
        self._image = image
        self._ok: dict[str, bool] = {}
        self._listeners: list[Listener] = []

    def register(self, front: str) -> None:
        self._ok.setdefault(front, True)

    def lost(self, front: str, reason: str, outputs: Iterable[str] | None = None) -> list[str]:
        """Front ``front`` lost its master. Applies error modes to ``outputs`` (all if None).

        Returns the output ids whose value changed. Repeated reports while already lost
        re-apply nothing and notify nobody.
        """
        if self._ok.get(front) is False:
            return []
        self._ok[front] = False
        log.warning("front %s lost its master: %s", front, reason)
        changed = self._image.apply_error_modes(outputs, origin=f"{front}:master-lost")
        self._notify(front, False, reason)
        return changed

    def ok(self, front: str, reason: str = "master present") -> None:
        if self._ok.get(front) is True:
            return
        self._ok[front] = True
        log.info("front %s: %s", front, reason)
        self._notify(front, True, reason)

    def mirror(self, front: str, ok: bool, reason: str) -> None:
        """Take a front's master state as another process reports it: listeners hear the
        change, and no error mode is applied here (the fieldbus process applied them)."""
        if self._ok.get(front) is ok:
            return
        self._ok[front] = ok
        self._notify(front, ok, reason)

    def is_ok(self, front: str) -> bool:
        return self._ok.get(front, True)

    @property
    def all_ok(self) -> bool:
        return all(self._ok.values())

    def subscribe(self, listener: Listener) -> None:
        self._listeners.append(listener)

    def _notify(self, front: str, ok: bool, reason: str) -> None:
        for listener in list(self._listeners):
            try:
                listener(front, ok, reason)
            except Exception:
                log.exception("master-state listener failed")
