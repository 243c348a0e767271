"""Serial ports over pseudo-terminal pairs: the real pyserial code path."""

import asyncio
import os

import pytest

from fieldgate import PluginStartError
from fieldgate.serial_link import AsyncSerial, PtyPair


async def test_read_until_across_a_pty_pair_and_timeout():
    with PtyPair() as pair:
        a = await AsyncSerial.open(pair.a, 115200)
        b = await AsyncSerial.open(pair.b, 115200)
        try:
            await b.write(b"$012\r")
            assert await a.read_until(b"\r", 1.0) == b"$012\r"
            await b.write(b"!01")
            with pytest.raises(TimeoutError):
                await a.read_until(b"\r", 0.05)
            await b.write(b"4000600\r")
            assert await a.read_until(b"\r", 1.0) == b"!014000600\r"  # partial data is kept
        finally:
            await a.close()
            await b.close()


async def test_read_frame_ends_at_a_silent_gap():
    with PtyPair() as pair:
        a = await AsyncSerial.open(pair.a)
        b = await AsyncSerial.open(pair.b)
        try:
            await b.write(b"\x01\x03\x02")
            await asyncio.sleep(0.001)
            await b.write(b"\x00\x07")
            assert await a.read_frame(1.0, gap=0.03) == b"\x01\x03\x02\x00\x07"
        finally:
            await a.close()
            await b.close()


async def test_fault_hook_and_baud_pacing():
    with PtyPair(baudrate=9600) as pair:
        pair.fault = lambda data: data.replace(b"A", b"B")
        a = await AsyncSerial.open(pair.a)
        b = await AsyncSerial.open(pair.b)
        try:
            loop = asyncio.get_running_loop()
            started = loop.time()
            await b.write(b"A" * 48 + b"\r")
            assert await a.read_until(b"\r", 2.0) == b"B" * 48 + b"\r"
            assert loop.time() - started >= 49 * 10 / 9600 * 0.9  # paced like a 9600 baud wire
        finally:
            await a.close()
            await b.close()


async def test_open_errors_are_one_line_causes(tmp_path):
    with pytest.raises(
        PluginStartError, match=r"cannot open serial port /nonexistent/ttyX: no such device"
    ):
        await AsyncSerial.open("/nonexistent/ttyX")
    with pytest.raises(PluginStartError, match="invalid serial settings"):
        await AsyncSerial.open("/dev/null", bytesize=9)


def test_keep_silence_is_never_shorter_than_the_gap_on_uvloop():
    """The Modbus t3.5 before a request is kept on the real clock: on uvloop (the default
    loop of `fieldgate run`) a 1.75 ms asyncio.sleep ended after 1.18 ms, its timers and
    loop.time() being whole milliseconds (issue 33). A lower bound: load can only lengthen."""
    import time

    import uvloop

    from fieldgate.serial_link import AsyncSerial, PtyPair

    async def run() -> list[float]:
        with PtyPair() as pair:
            port = await AsyncSerial.open(pair.a, 115200)
            far = os.open(pair.b, os.O_RDWR | os.O_NOCTTY)
            kept = []
            try:
                for i in range(150):
                    os.write(far, b"\x01")
                    await port.read_until(b"\x01", 1.0)
                    sum(range(500 * (i % 7)))  # land anywhere in a millisecond of the loop
                    await port.keep_silence(0.00175)
                    kept.append(time.monotonic() - port.last_rx_at)
                    since = time.monotonic()
                    await port.keep_silence(0.00175, since=since)
                    kept.append(time.monotonic() - since)
            finally:
                os.close(far)
                await port.close()
            return kept

    assert min(uvloop.run(run())) >= 0.00175
