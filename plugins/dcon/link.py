"""One DCON transaction at a time over an asyncio serial port."""

from __future__ import annotations

import asyncio
from typing import Protocol

from fieldgate.health import ErrorKind
from fieldgate.polling import CommError

from .codec import CR, frame, unframe


class SerialPort(Protocol):
    """What the link needs of a port (:class:`fieldgate.serial_link.AsyncSerial` is one)."""

    async def write(self, data: bytes) -> None: ...

    async def read_until(self, terminator: bytes, timeout: float) -> bytes: ...

    def reset_input(self) -> None: ...

    @property
    def pending(self) -> int: ...


class DconLink:
    """Sends a command, waits for the CR-ended reply, verifies and strips the checksum.

    ``serial`` is a :class:`fieldgate.serial_link.AsyncSerial` (or anything with
    ``write``, ``read_until``, ``reset_input`` and ``pending``).
    """

    def __init__(
        self,
        serial: SerialPort,
        use_checksum: bool,
        timeout: float,
        *,
        settle_after_timeout: bool = True,
    ):
        self.serial = serial
        self.settle_after_timeout = settle_after_timeout
        self.use_checksum = use_checksum
        self.timeout = timeout
        self.transactions = 0
        self._after_timeout = False

    async def _settle(self) -> None:
        """After a timeout, let a late reply arrive and drop it: ``>`` replies carry no address,
        so a late one would otherwise be taken for the answer to the next command."""
        if self._after_timeout:
            self._after_timeout = False
            if self.settle_after_timeout:
                await asyncio.sleep(self.timeout)
        self.serial.reset_input()

    async def transact(self, text: str, timeout: float | None = None) -> str:
        await self._settle()
        await self.serial.write(frame(text, self.use_checksum))
        self.transactions += 1
        try:
            raw = await self.serial.read_until(CR, self.timeout if timeout is None else timeout)
        except TimeoutError:
            self._after_timeout = True
            if self.serial.pending:
                raise CommError(ErrorKind.GARBAGE, f"truncated reply to {text!r} (no CR)") from None
            raise CommError(ErrorKind.TIMEOUT, f"no reply to {text!r}") from None
        return unframe(raw, self.use_checksum)

    async def broadcast(self, text: str) -> None:
        """A command nobody answers (``~**``)."""
        await self._settle()
        await self.serial.write(frame(text, self.use_checksum))
        self.transactions += 1
