"""The ``devicenet_scanner`` fixture (pytest plugin, entry point ``pytest11``): a small
DeviceNet master on a python-can bus (``virtual`` in tests): duplicate MAC check, Allocate,
explicit requests with fragmentation, polled I/O.

For tests that drive a gateway as a scanner would::

    async def test_poll(fieldgate_gateway, devicenet_scanner):
        async with fieldgate_gateway("i7241d.yaml", {"fronts.dnet.channel": "t1"}) as gw:
            scanner = devicenet_scanner("t1", slave=gw.topology.fronts[0].mac_id)
            await scanner.wait_online()
            await scanner.allocate(CHOICE_POLL)
            inputs = await scanner.poll(b"\\x00")
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable, Iterator
from typing import TYPE_CHECKING

import pytest

from . import ids

if TYPE_CHECKING:  # loaded by every pytest run where fieldgate is installed: imports stay lazy
    import can


class DeviceNetScanner:
    """A DeviceNet master (MAC ``mac``) talking to the slave at ``slave`` on ``channel``."""

    def __init__(self, channel: str, slave: int, mac: int = 0x0A, interface: str = "virtual"):
        import can

        self.bus = can.Bus(interface=interface, channel=channel)
        self.slave, self.mac = slave, mac

    def close(self) -> None:
        self.bus.shutdown()

    def send(self, can_id: int, data: bytes = b"") -> None:
        import can

        self.bus.send(can.Message(arbitration_id=can_id, data=data, is_extended_id=False))

    async def expect(self, can_id: int, timeout: float = 3.0) -> bytes:
        """The data of the next frame with ``can_id`` (others are skipped)."""
        loop = asyncio.get_running_loop()
        end = loop.time() + timeout
        while loop.time() < end:
            msg = await asyncio.to_thread(self.bus.recv, 0.05)
            if msg is not None and msg.arbitration_id == can_id:
                return bytes(msg.data)
        raise AssertionError(f"no frame {can_id:03X} within {timeout} s")

    async def frames(self, seconds: float) -> list[can.Message]:
        """Every frame seen during ``seconds``."""
        loop = asyncio.get_running_loop()
        end, got = loop.time() + seconds, []
        while loop.time() < end:
            msg = await asyncio.to_thread(self.bus.recv, 0.02)
            if msg is not None:
                got.append(msg)
        return got

    def g2(self, message: int) -> int:
        return ids.group2_id(self.slave, message)

    async def wait_online(self, settle: float = 0.15) -> None:
        """The slave's two duplicate MAC ID requests, then one check period: it is online."""
        for _ in range(2):
            assert (await self.expect(self.g2(ids.G2_DUP_MAC)))[0] == 0x00
        await self.frames(settle)

    async def allocate(self, choice: int) -> bytes:
        """Allocate_Master/Slave_Connection_Set (``choice``: explicit, poll, strobe, COS bits)."""
        self.send(
            self.g2(ids.G2_UNCONNECTED_REQUEST),
            bytes([self.mac, 0x4B, 0x03, 0x01, choice, self.mac]),
        )
        return await self.expect(self.g2(ids.G2_EXPLICIT_RESPONSE))

    async def request(self, body: bytes) -> bytes:
        """An explicit request (body = service, class, instance, ...) -> response body, reassembling fragments."""
        self.send(self.g2(ids.G2_EXPLICIT_REQUEST), bytes([self.mac]) + body)
        payload = b""
        while True:
            reply = await self.expect(self.g2(ids.G2_EXPLICIT_RESPONSE))
            if not reply[0] & 0x80:
                return reply[1:]
            frag = reply[1]
            self.send(
                self.g2(ids.G2_EXPLICIT_REQUEST), bytes([self.mac | 0x80, 0xC0 | frag & 0x3F, 0x00])
            )
            payload += reply[2:]
            if frag & 0xC0 == 0x80:
                return payload

    async def poll(self, outputs: bytes) -> bytes:
        """One poll with ``outputs`` (fragmented above 8 bytes) -> the first response frame."""
        if len(outputs) <= 8:
            self.send(self.g2(ids.G2_POLL), outputs)
        else:
            chunks = [outputs[i : i + 7] for i in range(0, len(outputs), 7)]
            for n, chunk in enumerate(chunks):
                kind = 0x00 if n == 0 else 0x80 if n == len(chunks) - 1 else 0x40
                self.send(self.g2(ids.G2_POLL), bytes([kind | n]) + chunk)
        return await self.expect(ids.group1_id(ids.G1_POLL_RESPONSE, self.slave))

    async def poll_fragmented_reply(self, outputs: bytes, size: int) -> bytes:
        """Poll and reassemble an I/O-fragmented response of ``size`` bytes."""
        first = await self.poll(outputs)
        if size <= 8:
            return first
        data = first[1:]
        while len(data) < size:
            data += (await self.expect(ids.group1_id(ids.G1_POLL_RESPONSE, self.slave)))[1:]
        return data


@pytest.fixture
def devicenet_scanner() -> Iterator[Callable[..., DeviceNetScanner]]:
    """``scanner(channel, slave, mac=0x0A, interface="virtual")``: a DeviceNet master on the
    bus; closed when the test ends."""
    made: list[DeviceNetScanner] = []

    def make(
        channel: str, slave: int, mac: int = 0x0A, interface: str = "virtual"
    ) -> DeviceNetScanner:
        made.append(DeviceNetScanner(channel, slave, mac, interface))
        return made[-1]

    yield make
    for scanner in made:
        scanner.close()
