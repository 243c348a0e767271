"""One DCON transaction at a time over an asyncio serial port, timed as core's serial model says.

``timeout`` is the response timeout (until the first byte of the reply); a reply ends at
its CR, or, broken, at the inter-byte timeout; after a failure the next command waits for
line silence; an echo of the command (``echo: true|auto``) is compared and dropped
(``fieldgate.serial_timing``).
"""

from __future__ import annotations

import asyncio
import dataclasses
import logging
from typing import Any

from fieldgate.health import ErrorKind
from fieldgate.polling import CommError
from fieldgate.serial_timing import EchoSetting, EchoState, Exchange, LineTiming, Result

from .codec import CR, frame, unframe

log = logging.getLogger("fieldgate.dcon")


def _cr_end(data: bytes) -> int | None:
    end = data.find(CR)
    return end + 1 if end >= 0 else None


class DconLink:
    """Sends a command, waits for the CR-ended reply, verifies and strips the checksum.

    ``serial`` is a :class:`fieldgate.serial_link.AsyncSerial` (or anything with
    ``exchange``, ``write``, ``wait_silence`` and ``reset_input``). ``timing`` comes from the
    back's config (``SerialBackConfig.timing()``); without it, 9600 baud and ``timeout``.
    """

    def __init__(
        self,
        serial: Any,
        use_checksum: bool,
        timeout: float,
        *,
        settle_after_timeout: bool = True,
        timing: LineTiming | None = None,
        echo: EchoSetting = "auto",
    ):
        self.serial = serial
        self.settle_after_timeout = settle_after_timeout
        self.use_checksum = use_checksum
        self.timeout = timeout
        self.timing = timing or LineTiming.of(9600, timeout * 1000, bits=10)
        self.echo = EchoState(echo)
        self.transactions = 0
        self._after_timeout = False
        self._after_failure = False
        self._after_broadcast = False

    async def _settle(self) -> None:
        """Before a command: after a timeout, let a late reply arrive and drop it (``>``
        replies carry no address, so a late one would otherwise be taken for the answer to
        the next command); after any failure (or a broadcast's echo), line silence."""
        if self._after_timeout:
            self._after_timeout = False
            if self.settle_after_timeout:
                await asyncio.sleep(self.timing.response)
        if self._after_failure or (self._after_broadcast and self.echo.setting is not False):
            await self.serial.wait_silence(self.timing.silence, self.timing.silence_limit)
        self._after_failure = self._after_broadcast = False
        self.serial.reset_input()

    async def transact(self, text: str, timeout: float | None = None) -> str:
        await self._settle()
        request = frame(text, self.use_checksum)
        timing = (
            self.timing if timeout is None else dataclasses.replace(self.timing, response=timeout)
        )
        exchange = Exchange(
            request, timing, _cr_end, echo=self.echo.expect, assume=self.echo.assume
        )
        self.transactions += 1
        outcome = await self.serial.exchange(request, exchange)
        if self.echo.learn(outcome):
            log.info("DCON line: %s", self.echo.describe())
        if outcome.result is Result.REPLY:
            self._after_failure = bool(outcome.rest)
            try:
                return unframe(outcome.frame, self.use_checksum)
            except CommError:
                self._after_failure = True
                raise
        self._after_failure = True
        if outcome.result is Result.TIMEOUT:
            self._after_timeout = True
            raise CommError(ErrorKind.TIMEOUT, f"no reply to {text!r}")
        if outcome.result is Result.TRUNCATED:
            raise CommError(ErrorKind.GARBAGE, f"truncated reply to {text!r} (no CR)")
        raise CommError(ErrorKind.GARBAGE, f"{text!r}: {outcome.describe()}")

    async def broadcast(self, text: str) -> None:
        """A command nobody answers (``~**``)."""
        await self._settle()
        await self.serial.write(frame(text, self.use_checksum))
        self.transactions += 1
        self._after_broadcast = True  # its echo, if the adapter echoes, is still on its way
