"""Fuzz targets of the serial wires: Modbus RTU and DCON replies into the backs' real link
and module code, the simulators' valid replies distorted the way a line distorts them."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from fuzz_base import Bytes, InvariantBroken, Target, run_sync

from fieldgate.polling import CommError


def mutate(b: Bytes, valid: bytes) -> bytes:
    """A reply the way a line distorts one: flipped, cut, extended, spliced or random bytes."""
    kind = b.u8() % 6
    out = bytearray(valid)
    if kind == 0 and out:
        for _ in range(1 + b.u8() % 3):
            out[b.u8() % len(out)] ^= 1 << (b.u8() % 8)
    elif kind == 1:
        del out[b.u8() % (len(out) + 1) :]
    elif kind == 2:
        out += b.take(b.u8() % 12)
    elif kind == 3 and out:
        at = b.u8() % len(out)
        out[at : at + 1 + b.u8() % 4] = b.take(b.u8() % 6)
    elif kind == 4:
        out = bytearray(b.take(b.u8() % 24))
    return bytes(out)


def output_values(image: Any, outputs: list[str], b: Bytes) -> dict[str, Any]:
    """Output values as a front sets them: through the image, which refuses what a channel's
    type cannot hold (such a value never reaches a back)."""
    for cid in outputs:
        value = bool(b.u8() & 1) if image[cid].spec.kind.is_digital else b.u16() - b.u8() * 128
        try:
            image.write_output(cid, value, origin="fuzz")
        except ValueError:
            pass
    return {cid: image.value(cid) for cid in outputs}


def distorted(
    b: Bytes, valid: bytes, repair: Callable[[Bytes, bytes], bytes], valid_only: bool
) -> bytes:
    """The reply a fuzzed line gives: the valid one (always while ``valid_only``, else one
    time in four) or a mutation of it that ``repair`` makes plausible enough to be parsed."""
    if valid_only or b.chance(4):
        return valid
    return repair(b, mutate(b, valid))


def _end_line(b: Bytes, out: bytes) -> bytes:
    if b.chance(2) and out and out[-1:] != b"\r":
        out += b"\r"  # mostly a complete line: the mutation reaches the parsers
    return out


class FakeSerial:
    """AsyncSerial's surface for the backs' links: the request goes to ``answer`` (the
    simulator's module, its reply distorted from the fuzz buffer) and the reply is fed to
    the link's real :class:`~fieldgate.serial_timing.Exchange`, all at once, on a clock
    that stands still (deadlines are reached at once)."""

    now = 0.0
    last_rx = 0.0
    last_rx_at = 0.0

    def __init__(self, answer: Callable[[bytes], bytes]):
        self.answer = answer

    def reset_input(self) -> None:
        pass

    async def sleep(self, seconds: float) -> None:
        pass

    async def wait_silence(self, silence: float, limit: float) -> bool:
        return True

    async def keep_silence(self, gap: float, since: float = 0.0) -> None:
        pass  # the Modbus t3.5 before a request: the clock stands still here

    async def write(self, data: bytes) -> None:
        self.answer(data)

    async def exchange(self, request: bytes, exchange: Any) -> Any:
        exchange.sent(0.0)
        outcome = exchange.feed(self.answer(request), 0.0)
        while outcome is None:
            outcome = exchange.check(exchange.deadline())
        return outcome


class ModbusTarget(Target):
    """Modbus RTU replies into the back's real link and module code (DI, DO, AI, AO models)."""

    name = "modbus"
    MODULES = [
        {"address": 1, "model": "M-7052D"},
        {"address": 3, "model": "M-7055D"},
        {"address": 4, "model": "M-7024"},
        {"address": 5, "model": "M-7017R"},
    ]

    def setup(self) -> None:
        from fieldgate import ProcessImage
        from fieldgate.plugins.modbus import codec
        from fieldgate.plugins.modbus.back import ModbusModule
        from fieldgate.plugins.modbus.client import ModbusLink
        from fieldgate.plugins.modbus.config import ModbusBackConfig
        from fieldgate.plugins.modbus.simulator import SimModule

        self.codec = codec
        config = ModbusBackConfig(name="rs485", port="unused", modules=self.MODULES)
        self.image = ProcessImage(lambda: 0.0)
        for spec in config.channel_specs():
            self.image.add(spec)
        points = config.points()
        self.sim_modules = {
            m.address: SimModule(m.address, points[m.address]) for m in config.modules
        }
        self.sim = self.sim_modules
        self.link = ModbusLink("fuzz", inter_frame=0, echo=False)
        self.link.serial = FakeSerial(self._answer)
        self.modules = [
            ModbusModule(
                m,
                [c.spec for c in self.image.channels(module=m.address)],
                self.link,
                points[m.address],
                retry_period=0.0,
                clock=lambda: 0.0,
            )
            for m in config.modules
        ]
        self.b = Bytes(b"")
        self.valid_only = False

    def _answer(self, request: bytes) -> bytes:
        """The simulator's valid reply to ``request`` (none for an unknown unit), distorted."""
        module = self.sim.get(request[0])
        valid = module.handle(self.codec.parse_request(request)) if module else b""
        return self.reply(valid)

    def reply(self, valid: bytes) -> bytes:
        return distorted(self.b, valid, self._fix_crc, self.valid_only)

    def _fix_crc(self, b: Bytes, out: bytes) -> bytes:
        if len(out) > 2 and not b.chance(4):  # fix the CRC: the mutation reaches the decoders
            out = self.codec.frame(out[0], out[1:-2])
        return out

    def transactions(self, b: Bytes) -> None:
        module = b.pick(self.modules)
        action = b.u8() % 4
        try:
            if action == 0:
                run_sync(module.probe())
            elif action == 3 and module.outputs:
                run_sync(module.send_outputs(output_values(self.image, module.outputs, b)))
            else:
                run_sync(module.read_inputs())
        except CommError:
            pass  # the wire's own error: counted by the scheduler

    def run(self, data: bytes) -> None:
        self.b = Bytes(data)
        while self.b.more():
            self.transactions(self.b)

    def check(self) -> None:
        self.valid_only = True
        try:
            for module in self.modules:
                readings = run_sync(module.read_inputs())
                if module.inputs and not isinstance(readings, dict):
                    raise InvariantBroken(f"module {module.unit}: {readings!r}")
        except CommError as exc:
            raise InvariantBroken(f"a valid reply refused: {exc}") from exc
        finally:
            self.valid_only = False


class DconTarget(Target):
    """DCON replies into the back's real link and module code (DIO, AI, AO, counters)."""

    name = "dcon"
    MODULES = [
        {"address": 1, "model": "I-7055"},
        {"address": 2, "model": "I-7017", "data_format": "engineering"},
        {"address": 3, "model": "I-7024"},
        {"address": 4, "model": "I-7012"},
        {"address": 5, "model": "I-7060", "watchdog": {"enabled": True, "timeout_ms": 500}},
    ]

    def setup(self) -> None:
        from fieldgate import ProcessImage
        from fieldgate.plugins.dcon.config import DconBackConfig
        from fieldgate.plugins.dcon.link import DconLink
        from fieldgate.plugins.dcon.module import DconModule
        from fieldgate.plugins.dcon.simulated import SimBus, SimModule

        config = DconBackConfig(name="rs485", port="unused", modules=self.MODULES)
        self.image = ProcessImage(lambda: 0.0)
        for spec in config.channel_specs():
            self.image.add(spec)
        self.bus = SimBus(checksum=False)
        for m in config.modules:
            self.bus.add(SimModule(m.profile, m.address))
        self.serial = FakeSerial(self._answer)
        self.link = DconLink(self.serial, False, 0.1, settle_after_timeout=False, echo=False)
        self.modules = [
            DconModule(
                m, [c.spec for c in self.image.channels(module=m.address)], self.image, self.link
            )
            for m in config.modules
        ]
        self.b = Bytes(b"")
        self.valid_only = False
        for module in self.modules:  # learn the modules as the back does when they come online
            self.valid_only = True
            run_sync(module.on_online())
        self.valid_only = False

    def _answer(self, request: bytes) -> bytes:
        answers = self.bus.feed(request, 0.0)
        return self.wire(answers[0][0] if answers else b"")

    def wire(self, valid: bytes) -> bytes:
        return distorted(self.b, valid, _end_line, self.valid_only)

    def run(self, data: bytes) -> None:
        self.b = b = Bytes(data)
        while b.more():
            module = b.pick(self.modules)
            action = b.u8() % 6
            try:
                if action == 0:
                    run_sync(module.probe())
                elif action == 1:
                    run_sync(module.on_online())
                elif action == 2 and module.outputs:
                    run_sync(module.send_outputs(output_values(self.image, module.outputs, b)))
                elif action == 3:
                    run_sync(module.read_status())
                else:
                    run_sync(module.read_inputs())
            except CommError:
                pass

    def check(self) -> None:
        """Every module reads good data within two polls of a clean line: without a checksum
        a distorted $AA2 reply can set a wrong data format; the read that does not fit it
        makes the next poll read $AA2 again (tests/faults/test_fuzz_findings.py)."""
        self.valid_only = True
        try:
            for module in self.modules:
                try:
                    run_sync(module.read_inputs())
                except CommError:
                    run_sync(module.read_inputs())
        except CommError as exc:
            raise InvariantBroken(f"a valid reply refused twice: {exc}") from exc
        finally:
            self.valid_only = False
