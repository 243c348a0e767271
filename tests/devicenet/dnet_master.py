"""A small DeviceNet master for the end-to-end tests: python-can virtual bus, explicit + I/O."""

from __future__ import annotations

import asyncio

import can

from fieldgate.plugins.devicenet import ids


class Master:
    def __init__(self, channel: str, slave: int, mac: int = 0x0A):
        self.bus = can.Bus(interface="virtual", channel=channel)
        self.slave, self.mac = slave, mac

    def close(self) -> None:
        self.bus.shutdown()

    def send(self, can_id: int, data: bytes = b"") -> None:
        self.bus.send(can.Message(arbitration_id=can_id, data=data, is_extended_id=False))

    async def expect(self, can_id: int, timeout: float = 3.0) -> bytes:
        loop = asyncio.get_running_loop()
        end = loop.time() + timeout
        while loop.time() < end:
            msg = await asyncio.to_thread(self.bus.recv, 0.05)
            if msg is not None and msg.arbitration_id == can_id:
                return bytes(msg.data)
        raise AssertionError(f"no frame {can_id:03X} within {timeout} s")

    async def frames(self, seconds: float) -> list[can.Message]:
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
        for _ in range(2):
            assert (await self.expect(self.g2(ids.G2_DUP_MAC)))[0] == 0x00
        await self.frames(settle)  # the slave goes online one check period after the second request

    async def allocate(self, choice: int) -> bytes:
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
