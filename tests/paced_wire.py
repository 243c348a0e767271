"""A serial wire for the tests that paces every byte at the baud rate (test side, independent
of fieldgate's own PtyPair and of the code under test).

Two pseudo-terminals joined by two relay threads. A byte written at one end reaches the
other end one character time after the previous byte left (10 bits a character: 8N1), on
an absolute schedule, so a 255-byte reply at 9600 baud takes 266 ms from its first byte to
its last, as on a real RS-485 line; a reply whose writer hands it over at once still starts
arriving after one character time. ``echo``: what end ``a`` sends comes back to ``a`` as it
goes out (a 2-wire adapter that hears itself). ``corrupt(after, value)``: once, the byte
towards ``a`` that follows ``after`` more bytes arrives as ``value`` (a hit by noise).
"""

from __future__ import annotations

import os
import select
import threading
import time
import tty


def _raw_pty() -> tuple[int, int]:
    master, slave = os.openpty()
    tty.setraw(master)
    tty.setraw(slave)
    return master, slave


class PacedWire:
    def __init__(self, baudrate: int, *, bits: int = 10, echo: bool = False):
        self.char = bits / baudrate
        self.echo = echo
        self._a = _raw_pty()
        self._b = _raw_pty()
        self.a = os.ttyname(self._a[1])
        self.b = os.ttyname(self._b[1])
        self._corrupt: list[int] | None = None  # [bytes left before the hit, the value]
        self._stop = threading.Event()
        self._threads = [
            threading.Thread(target=self._relay, args=(self._a[0], self._b[0], True), daemon=True),
            threading.Thread(target=self._relay, args=(self._b[0], self._a[0], False), daemon=True),
        ]
        for t in self._threads:
            t.start()

    def corrupt(self, after: int, value: int) -> None:
        self._corrupt = [after, value]

    def _relay(self, src: int, dst: int, from_a: bool) -> None:
        free_at = 0.0  # when the wire is free for the next character
        while not self._stop.is_set():
            try:
                ready, _, _ = select.select([src], [], [], 0.02)
                if not ready:
                    continue
                data = os.read(src, 4096)
            except OSError:
                return
            free_at = max(free_at, time.perf_counter())
            for byte in data:
                if not from_a and self._corrupt is not None:
                    self._corrupt[0] -= 1
                    if self._corrupt[0] < 0:
                        byte = self._corrupt[1]
                        self._corrupt = None
                free_at += self.char
                delay = free_at - time.perf_counter()
                if delay > 0:
                    time.sleep(delay)
                try:
                    os.write(dst, bytes([byte]))
                    if from_a and self.echo:
                        os.write(self._a[0], bytes([byte]))
                except OSError:
                    return

    def close(self) -> None:
        self._stop.set()
        for t in self._threads:
            t.join(timeout=1)
        for fd in (*self._a, *self._b):
            try:
                os.close(fd)
            except OSError:
                pass

    def __enter__(self) -> PacedWire:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
