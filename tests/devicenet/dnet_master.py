"""A small DeviceNet master for the end-to-end tests: explicit messaging, poll, bit-strobe,
change of state and cyclic both ways, path selection.

Independent of the code under test: identifiers, fragmentation and the frames are written
here from the DeviceNet rules (seed-003 §2), not imported from the front. The bus is
python-can's ``virtual`` one (``VcanMaster`` in the SocketCAN tests gives it a socketcan bus).
"""

from __future__ import annotations

import asyncio

import can

# Group 1 (slave -> master) and Group 2 message ids of the Predefined Master/Slave set
G1_COS_CYCLIC, G1_STROBE, G1_POLL = 0xD, 0xE, 0xF
G2_STROBE, G2_COS_ACK, G2_RESPONSE, G2_REQUEST, G2_POLL, G2_UNCONNECTED, G2_DUP_MAC = (
    0,
    2,
    3,
    4,
    5,
    6,
    7,
)


def assembly_path(instance: int) -> bytes:
    """A logical path to an Assembly instance's data: class 4, the instance, attribute 3."""
    return bytes([0x20, 0x04, 0x24, instance, 0x30, 0x03])


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

    def g1(self, message: int) -> int:
        """A Group 1 identifier of the slave: ``0 mmmm ssssss``."""
        return (message & 0xF) << 6 | self.slave

    def g2(self, message: int) -> int:
        """A Group 2 identifier of the slave's MAC: ``10 ssssss mmm``."""
        return 0x400 | self.slave << 3 | message

    async def wait_online(self, settle: float = 0.15) -> None:
        for _ in range(2):
            assert (await self.expect(self.g2(G2_DUP_MAC)))[0] == 0x00
        await self.frames(settle)  # the slave goes online one check period after the second request

    async def allocate(self, choice: int) -> bytes:
        self.send(self.g2(G2_UNCONNECTED), bytes([self.mac, 0x4B, 0x03, 0x01, choice, self.mac]))
        return await self.expect(self.g2(G2_RESPONSE))

    async def release(self, choice: int) -> bytes:
        self.send(self.g2(G2_UNCONNECTED), bytes([self.mac, 0x4C, 0x03, 0x01, choice]))
        return await self.expect(self.g2(G2_RESPONSE))

    async def request(self, body: bytes) -> bytes:
        """An explicit request (body = service, class, instance, ...) -> response body; a request
        longer than a frame goes in acknowledged fragments, a fragmented response is put together."""
        if len(body) <= 7:
            self.send(self.g2(G2_REQUEST), bytes([self.mac]) + body)
        else:
            chunks = [body[i : i + 6] for i in range(0, len(body), 6)]
            for n, chunk in enumerate(chunks):
                kind = 0x00 if n == 0 else 0x80 if n == len(chunks) - 1 else 0x40
                self.send(self.g2(G2_REQUEST), bytes([self.mac | 0x80, kind | n]) + chunk)
                ack = await self.expect(self.g2(G2_RESPONSE))
                assert ack == bytes([self.mac | 0x80, 0xC0 | n, 0x00]), ack.hex(" ")
        payload = b""
        while True:
            reply = await self.expect(self.g2(G2_RESPONSE))
            if not reply[0] & 0x80:
                return reply[1:]
            frag = reply[1]
            self.send(self.g2(G2_REQUEST), bytes([self.mac | 0x80, 0xC0 | frag & 0x3F, 0x00]))
            payload += reply[2:]
            if frag & 0xC0 == 0x80:
                return payload

    async def get(self, class_id: int, instance: int, attribute: int) -> bytes:
        """Get_Attribute_Single that must succeed: the attribute's data."""
        reply = await self.request(bytes([0x0E, class_id, instance, attribute]))
        assert reply[:1] == b"\x8e", f"Get {class_id}/{instance}/{attribute}: {reply.hex(' ')}"
        return reply[1:]

    async def set(self, class_id: int, instance: int, attribute: int, value: bytes) -> bytes:
        """Set_Attribute_Single: the whole response (``90 ...`` or ``94 <general> <additional>``)."""
        return await self.request(bytes([0x10, class_id, instance, attribute]) + value)

    async def number(self, class_id: int, instance: int, attribute: int) -> int:
        return int.from_bytes(await self.get(class_id, instance, attribute), "little")

    # -- I/O -----------------------------------------------------------------------------
    def send_io(self, can_id: int, data: bytes) -> None:
        """An I/O message: one frame up to 8 bytes, else unacknowledged fragments of 7."""
        if len(data) <= 8:
            self.send(can_id, data)
            return
        chunks = [data[i : i + 7] for i in range(0, len(data), 7)]
        for n, chunk in enumerate(chunks):
            kind = 0x00 if n == 0 else 0x80 if n == len(chunks) - 1 else 0x40
            self.send(can_id, bytes([kind | n]) + chunk)

    async def io_message(self, can_id: int, size: int, timeout: float = 3.0) -> bytes:
        """A produced I/O message of ``size`` bytes, its fragments put together."""
        first = await self.expect(can_id, timeout)
        if size <= 8:
            return first
        data, count = first[1:], 1
        assert first[0] & 0xC0 == 0x00, f"not a first fragment: {first.hex(' ')}"
        while len(data) < size:
            fragment = await self.expect(can_id)
            assert fragment[0] & 0x3F == count & 0x3F, f"fragment {count}: {fragment.hex(' ')}"
            data += fragment[1:]
            count += 1
        return data

    async def poll(self, outputs: bytes) -> bytes:
        self.send_io(self.g2(G2_POLL), outputs)
        return await self.expect(self.g1(G1_POLL))

    async def poll_fragmented_reply(self, outputs: bytes, size: int) -> bytes:
        """Poll and reassemble an I/O-fragmented response of ``size`` bytes."""
        self.send_io(self.g2(G2_POLL), outputs)
        return await self.io_message(self.g1(G1_POLL), size)

    async def produced(self, size: int, ack: bool = True, timeout: float = 3.0) -> bytes:
        """The slave's next change-of-state / cyclic message, acknowledged (G2/2) unless ``ack``
        is false (ack suppression)."""
        data = await self.io_message(self.g1(G1_COS_CYCLIC), size, timeout)
        if ack:
            self.send(self.g2(G2_COS_ACK))
        return data

    async def master_data(self, data: bytes, acked: bool = True) -> None:
        """The master's change-of-state / cyclic data (G2/5); with acknowledgement the slave
        answers an empty G1/15 message."""
        self.send_io(self.g2(G2_POLL), data)
        if acked:
            assert await self.expect(self.g1(G1_POLL)) == b""
