"""One DCON transaction at a time over an asyncio serial port."""

from __future__ import annotations

from fieldgate.health import ErrorKind
from fieldgate.polling import CommError

from .codec import CR, frame, unframe


class DconLink:
    """Sends a command, waits for the CR-ended reply, verifies and strips the checksum.

    ``serial`` is a :class:`fieldgate.serial_link.AsyncSerial` (or anything with
    ``write``, ``read_until``, ``reset_input`` and ``pending``).
    """

    def __init__(self, serial, use_checksum: bool, timeout: float):
        self.serial = serial
        self.use_checksum = use_checksum
        self.timeout = timeout
        self.transactions = 0

    async def transact(self, text: str, timeout: float | None = None) -> str:
        self.serial.reset_input()  # a late reply to an earlier command must not be taken for this one
        await self.serial.write(frame(text, self.use_checksum))
        self.transactions += 1
        try:
            raw = await self.serial.read_until(CR, self.timeout if timeout is None else timeout)
        except TimeoutError:
            if self.serial.pending:
                raise CommError(ErrorKind.GARBAGE, f"truncated reply to {text!r} (no CR)") from None
            raise CommError(ErrorKind.TIMEOUT, f"no reply to {text!r}") from None
        return unframe(raw, self.use_checksum)

    async def broadcast(self, text: str) -> None:
        """A command nobody answers (``~**``)."""
        await self.serial.write(frame(text, self.use_checksum))
        self.transactions += 1
