"""CANopen slaves on a busy bus over real SocketCAN: fieldgate against canopen's LocalNode
(and durand where installed), in one User-Mode Linux boot, with one raw client.

    FIELDGATE_SOCKETCAN_TIMEOUT=2400 .ci/socketcan/run python bench/can_load.py            # 60 s per phase
    .ci/socketcan/run python bench/can_load.py --duration 5 --requests 500          # a quick run

Each slave is its own process on its own vcan interface, node-ID 5, serving 0x1000 (device type):
``fieldgate run`` with a canopen front and the in-memory ``loopback`` back (no serial
polling: only the CAN front is billed), ``canopen.LocalNode`` on a ``canopen.Network``,
``durand.Node`` on its ``CANBusNetwork``. The bench process is the client: a raw
``AF_CAN`` socket that hears only the answers (kernel filter). Phases, per slave:

1. **idle**: the slave's CPU with no traffic (``/proc/<pid>/stat``, user + system).
2. **SDO**: ``--requests`` expedited uploads of 0x1000:00 back to back: p50/p99 round
   trip, the slave's CPU per request (idle CPU over the same time subtracted).
   Phases 1 and 2 run for all slaves at once, each on its own vcan interface (vcan0,
   vcan0-1, ...; created here), the reads alternating between them (A B B A ...): the
   machine's noise is shared, not handed to whichever slave ran in a bad minute.
3. **paced SDO**: one read every ``--gap-ms`` for ``--duration`` s on the idle bus: the
   baseline p99 and CPU of the next phase.
4. **flood**: ``bench/can_flood.py`` in its own process sends other nodes' PDOs
   (0x181-0x1FF without 0x185) as fast as it goes for ``--duration`` s, printed beside the
   1 Mbit/s line rate; meanwhile the same paced reads: p50/p99, lost (no answer in 1 s),
   and the slave's CPU per foreign frame (its CPU above the paced phase's, per frame sent).
5. **flood + SYNC + RPDO** (fieldgate): the same flood, and SYNC at ``--sync-hz`` with one
   RPDO per SYNC, both sent by the kernel's CAN broadcast manager (one frame every half
   period: SYNC, RPDO, SYNC, ..., 128 values in turn; no client CPU); RPDO1 synchronous
   (each value is applied at the next SYNC); the loopback
   back wires DO to DI, so each applied value comes back in TPDO1: RPDOs sent, outputs seen
   to follow (in order), lost; and from the front's own counts (printed when it stops):
   frames received, ignored after filtering, reaching the engine, RPDOs received.

Inside UML there is one CPU: the flood sender, the client and the slave share it, so the
flood rate a slave leaves the sender is part of the result. Figures are noisy on a shared
machine: compare the slaves of one run (ratios), not runs. Targets (issue 13): no SDO read
lost during the flood and its p99 <= 3x the idle p99; <= 2 us of slave CPU per foreign
frame; fieldgate's CPU per SDO read <= LocalNode's; no RPDO lost at 1 kHz during the flood.
Results: docs/canopen-bench.md.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import select
import socket
import struct
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from can_flood import FRAME  # noqa: E402

NODE = 5
DEVICE_TYPE = 0x000F0191
REQUEST = FRAME.pack(0x600 + NODE, 8, bytes([0x40, 0x00, 0x10, 0x00, 0, 0, 0, 0]))
FOREIGN = "0x181-0x184,0x186-0x1FF"  # other nodes' TPDO1s; 0x185 is ours
CLK_TCK = os.sysconf("SC_CLK_TCK") if hasattr(os, "sysconf") else 100
LINE_RATE = (7_400, 9_000)  # 8-byte standard frames at 1 Mbit/s: 135 bits (worst stuffing) .. 111


# -- the slaves (each its own process: python bench/can_load.py --serve KIND) -----------------
def serve_localnode(channel: str) -> None:
    import canopen
    from canopen.objectdictionary import ObjectDictionary, ODVariable
    from canopen.objectdictionary import datatypes as dt

    od = ObjectDictionary()  # type: ignore[no-untyped-call]  # canopen has no annotations
    var = ODVariable("Device type", 0x1000)
    var.data_type, var.access_type, var.default = dt.UNSIGNED32, "ro", DEVICE_TYPE
    od.add_object(var)
    network = canopen.Network()
    network.connect(interface="socketcan", channel=channel)
    network.add_node(canopen.LocalNode(NODE, od))
    print("ready", flush=True)
    _wait_for_stdin_eof()
    network.disconnect()


def serve_durand(channel: str) -> None:
    import can
    from durand import CANBusNetwork, Node  # type: ignore[import-untyped]

    bus = can.Bus(interface="socketcan", channel=channel)
    network = CANBusNetwork(bus)
    node = Node(network, NODE)
    node.object_dictionary.write(0x1000, 0, DEVICE_TYPE)
    print("ready", flush=True)
    _wait_for_stdin_eof()
    network.stop()
    bus.shutdown()


def serve_fieldgate(channel: str, raw_path: bool = True) -> None:
    """What ``fieldgate run`` does (Gateway.load, the same event loop), and on stdin EOF one
    JSON line with the front's status (its engine's frame counts) before stopping."""
    import asyncio

    from fieldgate import Gateway, load_registry
    from fieldgate.can import socketcan_raw
    from fieldgate.cli import loop_factory

    socketcan_raw.ENABLED = raw_path

    async def run() -> None:
        with tempfile.TemporaryDirectory() as state:
            gateway = Gateway.load(fieldgate_topology(state, channel), registry=load_registry())
            await gateway.start()
            print("ready", flush=True)
            await asyncio.to_thread(_wait_for_stdin_eof)
            front = gateway.status()["fronts"]["can"]
            pdo = front["services"].get("io", {})
            print(
                json.dumps(
                    {
                        "engine_rx": front["counters"]["rx"],
                        "rx": front["bus"]["rx"],
                        "rx_ignored": front["bus"]["rx_ignored"],
                        "tx_errors": front["bus"].get("tx_errors", 0),
                        "rpdo_received": pdo.get("rpdo_received"),
                        "tpdo_sent": pdo.get("tpdo_sent"),
                        "filters": front["bus"]["filters"],
                        "rx_buffer_bytes": front["bus"].get("rx_buffer_bytes"),
                    }
                ),
                flush=True,
            )
            await gateway.stop()

    with asyncio.Runner(loop_factory=loop_factory("auto")) as runner:
        runner.run(run())


def _wait_for_stdin_eof() -> None:
    while sys.stdin.read(1):
        pass


def fieldgate_topology(state_dir: str, channel: str) -> dict[str, Any]:
    return {
        "gateway": {"name": "can-load", "state_dir": state_dir},
        "fronts": [
            {
                "name": "can",
                "type": "canopen",
                "interface": "socketcan",
                "channel": channel,
                "node_id": NODE,
                "identity": {"device_type": DEVICE_TYPE},
            }
        ],
        "backs": [
            {
                "name": "io",
                "type": "loopback",
                "modules": [{"address": 1, "digital": 8, "analog": 2}],
            }
        ],
    }


@dataclass
class Slave:
    kind: str
    channel: str
    proc: subprocess.Popen[str] | None = None

    @property
    def label(self) -> str:
        return {
            "fieldgate": "fieldgate",
            "fieldgate-python-can": "fieldgate (python-can path)",
            "localnode": "canopen LocalNode",
            "durand": "durand",
        }[self.kind]

    def start(self, client: Client) -> None:
        args = [sys.executable, __file__, "--serve", self.kind, "--channel", self.channel]
        self.proc = subprocess.Popen(
            args,
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.DEVNULL,
            text=True,
        )
        assert self.proc.stdout is not None
        if self.proc.stdout.readline().strip() != "ready":
            raise SystemExit(f"{self.label} did not start (exit code {self.proc.wait()})")
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                raise SystemExit(f"{self.label} exited with code {self.proc.returncode}")
            if client.sdo_read(0.2) is not None:
                time.sleep(0.5)  # let start-up work settle before anything is measured
                client.drain()
                return
        raise SystemExit(f"{self.label} did not answer an SDO read within 30 s")

    def cpu_s(self) -> float:
        assert self.proc is not None
        fields = Path(f"/proc/{self.proc.pid}/stat").read_text().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / CLK_TCK  # utime, stime

    def stop(self) -> dict[str, object]:
        """Stop the slave; fieldgate's last words are its front's counts."""
        if self.proc is None:
            return {}
        try:
            out, _ = self.proc.communicate("", timeout=20)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            out, _ = self.proc.communicate()
        lines = [line for line in out.splitlines() if line.startswith("{")]
        return json.loads(lines[-1]) if lines else {}


# -- the client ------------------------------------------------------------------------------------
class Client:
    """A raw AF_CAN socket hearing only ``ids`` (kernel filter)."""

    def __init__(self, channel: str, ids: tuple[int, ...] = (0x580 + NODE,)):
        self.sock = socket.socket(socket.AF_CAN, socket.SOCK_RAW, socket.CAN_RAW)
        self.sock.setsockopt(
            socket.SOL_CAN_RAW,
            socket.CAN_RAW_FILTER,
            b"".join(struct.pack("=II", i, 0x7FF) for i in ids),
        )
        self.sock.bind((channel,))
        try:  # room for bursts: a starved client must not lose TPDOs it is counting
            self.sock.setsockopt(socket.SOL_SOCKET, 33, 4 * 1024 * 1024)  # SO_RCVBUFFORCE
        except OSError:
            pass
        self.sent = 0  # frames sent (all of them to the slave under test)

    def send(self, can_id: int, data: bytes = b"") -> None:
        self.sent += 1
        frame = FRAME.pack(can_id, len(data), data.ljust(8, b"\0"))
        while True:
            try:
                self.sock.send(frame)
                return
            except OSError:  # ENOBUFS: the flood filled the queue
                time.sleep(0.0001)

    def recv(self, timeout: float) -> tuple[int, bytes] | None:
        ready, _, _ = select.select([self.sock], [], [], timeout)
        if not ready:
            return None
        can_id, dlc, data = FRAME.unpack(self.sock.recv(16))
        return can_id & 0x7FF, data[:dlc]

    def drain(self) -> None:
        while self.recv(0.05) is not None:
            pass

    def sdo_read(self, timeout: float = 1.0) -> float | None:
        """Round trip of one expedited upload in seconds, or None (no answer in ``timeout``)."""
        started = time.perf_counter()
        self.sent += 1
        while True:
            try:
                self.sock.send(REQUEST)
                break
            except OSError:
                time.sleep(0.0001)
        end = started + timeout
        while True:
            got = self.recv(max(0.0, end - time.perf_counter()))
            if got is None:
                return None
            if got[0] == 0x580 + NODE and got[1][:4] == b"\x43\x00\x10\x00":
                return time.perf_counter() - started

    def close(self) -> None:
        self.sock.close()


def start_flood(channel: str, seconds: float, rate: float) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [sys.executable, str(HERE / "can_flood.py"), "--channel", channel]
        + ["--seconds", str(seconds), "--ids", FOREIGN, "--rate", str(rate)],
        stdout=subprocess.PIPE,
        text=True,
    )


def flood_result(proc: subprocess.Popen[str]) -> dict[str, float]:
    out, _ = proc.communicate(timeout=600)
    result: dict[str, float] = json.loads(out.strip().splitlines()[-1])
    return result


def pct(values: list[float], q: float) -> float:
    if not values:
        return float("nan")
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(q * len(ordered)))]


@dataclass
class Result:
    label: str
    idle_cpu: float = 0.0  # share of one CPU
    sdo: list[float] = field(default_factory=list)
    sdo_lost: int = 0
    sdo_cpu_us: float = 0.0
    flood: dict[str, float] = field(default_factory=dict)
    paced_sdo: list[float] = field(default_factory=list)
    paced_lost: int = 0
    flood_sdo: list[float] = field(default_factory=list)
    flood_lost: int = 0
    flood_cpu: float = 0.0  # share of one CPU during the flood
    foreign_us: float = 0.0
    sync: dict[str, float] = field(default_factory=dict)
    floods: list[float] = field(default_factory=list)  # frames each flood sent
    counts: dict[str, object] = field(default_factory=dict)  # fieldgate's front, at the end


def shared_phases(
    slaves: list[Slave], clients: list[Client], args: argparse.Namespace
) -> list[Result]:
    """Idle and back-to-back SDO reads for every slave at once, each on its own bus: the
    reads alternate between the slaves (A B B A ...), so they share the machine's noise."""
    results = [Result(slave.label) for slave in slaves]
    cpu0, t0 = [s.cpu_s() for s in slaves], time.monotonic()
    time.sleep(args.duration)
    for r, s, c in zip(results, slaves, cpu0, strict=True):
        r.idle_cpu = (s.cpu_s() - c) / (time.monotonic() - t0)
    cpu0, t0 = [s.cpu_s() for s in slaves], time.monotonic()
    order = list(range(len(slaves)))
    for n in range(args.requests):
        for i in order if n % 2 == 0 else order[::-1]:
            rtt = clients[i].sdo_read()
            if rtt is None:
                results[i].sdo_lost += 1
                clients[i].drain()
            else:
                results[i].sdo.append(rtt)
    wall = time.monotonic() - t0
    for r, s, c in zip(results, slaves, cpu0, strict=True):
        busy = s.cpu_s() - c - r.idle_cpu * wall
        r.sdo_cpu_us = 1e6 * busy / max(1, len(r.sdo))
        print(
            f"  {r.label}: idle {100 * r.idle_cpu:.2f} % CPU; SDO {len(r.sdo)} reads "
            f"(lost {r.sdo_lost}), p50 {1e6 * pct(r.sdo, 0.5):.0f} us, "
            f"p99 {1e6 * pct(r.sdo, 0.99):.0f} us, {r.sdo_cpu_us:.0f} us CPU each",
            flush=True,
        )
    return results


def flood_phases(slave: Slave, client: Client, result: Result, args: argparse.Namespace) -> None:
    # 3. the same paced reads without, then with the flood
    base_cpu, result.paced_sdo, result.paced_lost = paced_reads(slave, client, args, flood=False)
    print(
        f"  paced SDO (one per {args.gap_ms:g} ms), no flood: {len(result.paced_sdo)} reads, "
        f"lost {result.paced_lost}, p50 {1e6 * pct(result.paced_sdo, 0.5):.0f} us, "
        f"p99 {1e6 * pct(result.paced_sdo, 0.99):.0f} us; slave {100 * base_cpu:.1f} % CPU",
        flush=True,
    )
    result.flood_cpu, result.flood_sdo, result.flood_lost = paced_reads(
        slave, client, args, flood=True, result=result
    )
    frames_per_s = result.flood["frames"] / max(1e-9, result.flood["seconds"])
    result.foreign_us = 1e6 * max(0.0, result.flood_cpu - base_cpu) / max(1.0, frames_per_s)
    print(
        f"  flood: {result.flood['rate']:.0f} frames/s for {result.flood['seconds']:.0f} s; "
        f"{len(result.flood_sdo)} SDO reads, lost {result.flood_lost}, "
        f"p50 {1e6 * pct(result.flood_sdo, 0.5):.0f} us, p99 {1e6 * pct(result.flood_sdo, 0.99):.0f} us; "
        f"slave {100 * result.flood_cpu:.1f} % CPU: {result.foreign_us:.2f} us per foreign frame "
        "above the paced reads alone",
        flush=True,
    )
    client.drain()


def paced_reads(
    slave: Slave,
    client: Client,
    args: argparse.Namespace,
    *,
    flood: bool,
    result: Result | None = None,
) -> tuple[float, list[float], int]:
    """One SDO read every --gap-ms for --duration s (with the flood running, if asked):
    (the slave's CPU share, round trips, reads lost)."""
    rtts: list[float] = []
    lost = 0
    sender = start_flood(slave.channel, args.duration, args.flood_rate) if flood else None
    if sender is not None:
        time.sleep(0.2)  # the sender is up
    cpu0, t0 = slave.cpu_s(), time.monotonic()
    end = t0 + args.duration - (0.4 if flood else 0.0)
    while time.monotonic() < end:
        started = time.monotonic()
        rtt = client.sdo_read()
        if rtt is None:
            lost += 1
            client.drain()
        else:
            rtts.append(rtt)
        time.sleep(max(0.0, args.gap_ms / 1000 - (time.monotonic() - started)))
    cpu = (slave.cpu_s() - cpu0) / (time.monotonic() - t0)
    if sender is not None and result is not None:
        result.flood = flood_result(sender)
        result.floods.append(result.flood["frames"])
    return cpu, rtts, lost


BCM_HEAD = struct.Struct("@3I4l2I0q")  # struct bcm_msg_head (native: longs in the timevals)
BCM_TX_SETUP, BCM_TX_DELETE, BCM_SETTIMER, BCM_STARTTIMER = 1, 2, 0x1, 0x2
SYNC_VALUES = 128  # the broadcast manager cycles through 256 frames: 128 SYNC + RPDO pairs


def bcm_sent(sock: socket.socket) -> int:
    """Frames the broadcast manager sent for this socket's job (/proc/net/can-bcm)."""
    inode = os.fstat(sock.fileno()).st_ino
    text = Path(f"/proc/net/can-bcm/{inode}").read_text()
    return int(text.rsplit("# sent", 1)[1].split()[0])


def calibrate_bcm(channel: str, hz: float) -> int:
    """The broadcast manager's interval (us) that gives ``hz`` SYNCs here: UML's timers run
    late under load, so measure 1 s of SYNCs alone (to a CAN-ID nobody reads) and scale."""
    interval = 1e6 / hz / 2
    for _ in range(3):
        bcm = socket.socket(socket.AF_CAN, socket.SOCK_DGRAM, socket.CAN_BCM)
        bcm.connect((channel,))
        probe = FRAME.pack(0x7F0, 0, b"")
        head = BCM_HEAD.pack(
            BCM_TX_SETUP, BCM_SETTIMER | BCM_STARTTIMER, 0, 0, 0, 0, round(interval), 0x7F0, 1
        )
        started = time.monotonic()
        bcm.send(head + probe)
        time.sleep(1.0)
        rate = bcm_sent(bcm) / (time.monotonic() - started) / 2
        bcm.close()
        if rate >= 0.97 * hz:
            break
        interval = max(20.0, interval * rate / hz)
    return round(interval)


def sync_phase(slave: Slave, channel: str, args: argparse.Namespace) -> dict[str, float]:
    """Flood + SYNC at --sync-hz + one RPDO per SYNC, sent by the kernel's CAN broadcast
    manager (like a master's hardware timer: no client CPU); TPDO1 shows each output."""
    io = Client(channel, (0x580 + NODE, 0x180 + NODE))
    sdo = bytes([0x2F, 0x00, 0x14, 0x02, 0x01, 0, 0, 0])  # 0x1400:2 = 1: RPDO1 synchronous
    io.send(0x600 + NODE, sdo)
    got = io.recv(1.0)
    while got is not None and got[0] != 0x580 + NODE:
        got = io.recv(1.0)
    assert got is not None and got[1][0] == 0x60, got
    io.send(0x000, bytes([0x01, NODE]))  # Operational: TPDO1 goes out once
    time.sleep(0.3)
    io.drain()
    frames = b"".join(
        FRAME.pack(0x080, 0, b"") + FRAME.pack(0x200 + NODE, 1, bytes([k + 1]))
        for k in range(SYNC_VALUES)
    )
    interval_us = calibrate_bcm(channel, args.sync_hz)
    bcm = socket.socket(socket.AF_CAN, socket.SOCK_DGRAM, socket.CAN_BCM)
    bcm.connect((channel,))
    seen: list[int] = []
    cpu0, t0 = slave.cpu_s(), time.monotonic()
    flood = start_flood(channel, args.duration, args.flood_rate)
    time.sleep(0.2)
    start = time.monotonic()
    setup = BCM_HEAD.pack(
        BCM_TX_SETUP, BCM_SETTIMER | BCM_STARTTIMER, 0, 0, 0, 0, interval_us, 0x080, 2 * SYNC_VALUES
    )
    bcm.send(setup + frames)
    end = start + args.duration - 0.4
    while time.monotonic() < end:
        got = io.recv(0.1)
        if got is not None and got[0] == 0x180 + NODE:
            seen.append(got[1][0])
    sent_frames = bcm_sent(bcm)
    bcm.send(BCM_HEAD.pack(BCM_TX_DELETE, 0, 0, 0, 0, 0, 0, 0x080, 0))
    stopped = time.monotonic()
    rpdos = sent_frames // 2
    if sent_frames % 2 == 0:
        io.send(0x080)  # the last RPDO is applied at the next SYNC
    quiet_until, give_up = time.monotonic() + 1.0, time.monotonic() + 15.0
    while time.monotonic() < min(quiet_until, give_up):  # late TPDOs count, lost ones not
        got = io.recv(0.05)
        if got is not None and got[0] == 0x180 + NODE:
            seen.append(got[1][0])
            quiet_until = time.monotonic() + 1.0
    flood_info = flood_result(flood)
    wall = time.monotonic() - t0
    cpu = slave.cpu_s() - cpu0
    bcm.close()
    followed = 0  # RPDO values seen in TPDO1, in order
    it = iter(seen)
    for k in range(rpdos):
        value = k % SYNC_VALUES + 1
        for observed in it:
            if observed == value:
                followed += 1
                break
    io.close()
    result = {
        "flood_frames": flood_info["frames"],
        "sent_to_slave": io.sent + sent_frames,
        "sync_rate": (sent_frames - sent_frames // 2) / (stopped - start),
        "rpdos": rpdos,
        "followed": followed,
        "lost": rpdos - followed,
        "tpdos": len(seen),
        "flood_rate": flood_info["rate"],
        "cpu": cpu / wall,
    }
    print(
        f"  SYNC+RPDO (kernel broadcast manager): {result['sync_rate']:.0f} Hz reached, "
        f"{rpdos} RPDOs, {followed} outputs followed in order (TPDO1), {result['lost']} not; "
        f"flood {flood_info['rate']:.0f} frames/s; slave {100 * result['cpu']:.1f} % CPU",
        flush=True,
    )
    return result


def summary(results: list[Result], args: argparse.Namespace) -> None:
    print("\n== summary (same boot; ratios are what to compare) ==")
    print(
        f"flood line: 1 Mbit/s carries {LINE_RATE[0]:,}-{LINE_RATE[1]:,} 8-byte frames/s; "
        "the sender reached: "
        + ", ".join(f"{r.label} {r.flood.get('rate', 0):,.0f}/s" for r in results)
    )
    head = (
        f"{'slave':<18} {'idle CPU':>8} {'SDO p50':>8} {'SDO p99':>8} {'CPU/SDO':>8} "
        f"{'paced p99':>9} {'flood p50':>9} {'flood p99':>9} {'lost':>5} {'us/foreign':>10} "
        f"{'flood CPU':>9}"
    )
    print(head)
    for r in results:
        print(
            f"{r.label:<18} {100 * r.idle_cpu:7.2f}% {1e6 * pct(r.sdo, 0.5):7.0f}u "
            f"{1e6 * pct(r.sdo, 0.99):7.0f}u {r.sdo_cpu_us:7.0f}u "
            f"{1e6 * pct(r.paced_sdo, 0.99):8.0f}u {1e6 * pct(r.flood_sdo, 0.5):8.0f}u {1e6 * pct(r.flood_sdo, 0.99):8.0f}u "
            f"{r.flood_lost:5d} {r.foreign_us:10.2f} {100 * r.flood_cpu:8.1f}%"
        )
    ours = results[0]
    peer = next((r for r in results if r.label == "canopen LocalNode"), None)
    checks = [
        ("no SDO read lost during the flood", ours.flood_lost == 0 and ours.sdo_lost == 0),
        (
            "flood SDO p99 <= 3x its p99 on the idle bus (same pace; "
            f"{pct(ours.flood_sdo, 0.99) / pct(ours.paced_sdo, 0.99):.2f}x)",
            pct(ours.flood_sdo, 0.99) <= 3 * pct(ours.paced_sdo, 0.99),
        ),
        (f"<= 2 us CPU per foreign frame ({ours.foreign_us:.2f} us)", ours.foreign_us <= 2.0),
    ]
    if peer is not None:
        ratio = ours.sdo_cpu_us / peer.sdo_cpu_us if peer.sdo_cpu_us else float("nan")
        checks.append(
            (f"CPU per SDO read <= LocalNode's (ratio ours/LocalNode {ratio:.2f})", ratio <= 1.0)
        )
    if ours.sync and ours.counts.get("rpdo_received") is not None:
        got = int(str(ours.counts["rpdo_received"]))
        checks.append(
            (
                f"every RPDO reached the engine ({got} of {ours.sync['rpdos']:.0f})",
                got >= ours.sync["rpdos"],
            )
        )
    if ours.sync:
        checks.append(
            (
                f"no RPDO lost at {ours.sync['sync_rate']:.0f} Hz SYNC during the flood "
                f"({ours.sync['lost']:.0f} of {ours.sync['rpdos']:.0f})",
                ours.sync["lost"] == 0,
            )
        )
    for text, ok in checks:
        print(f"  [{'met' if ok else 'NOT met'}] {text}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--duration", type=float, default=60.0, help="seconds per timed phase")
    parser.add_argument("--requests", type=int, default=2000, help="SDO reads back to back")
    parser.add_argument("--gap-ms", type=float, default=20.0, help="between SDO reads in the flood")
    parser.add_argument("--flood-rate", type=float, default=0.0, help="frames/s, 0 = max")
    parser.add_argument("--sync-hz", type=float, default=1000.0)
    parser.add_argument(
        "--slaves",
        default="fieldgate,localnode,durand",
        help="which slaves (durand only where installed; fieldgate-python-can: fieldgate "
        "without the raw SocketCAN path, for an A/B run)",
    )
    parser.add_argument("--channel", default="vcan0")
    parser.add_argument(
        "--serve",
        choices=("fieldgate", "fieldgate-python-can", "localnode", "durand"),
        help=argparse.SUPPRESS,
    )
    args = parser.parse_args()
    if args.serve in ("fieldgate", "fieldgate-python-can"):
        return serve_fieldgate(args.channel, raw_path=args.serve == "fieldgate")
    if args.serve == "localnode":
        return serve_localnode(args.channel)
    if args.serve == "durand":
        return serve_durand(args.channel)
    if not Path(f"/sys/class/net/{args.channel}").exists():
        raise SystemExit(
            f"no {args.channel}: run inside User-Mode Linux: .ci/socketcan/run python bench/can_load.py"
        )
    kinds = [k.strip() for k in args.slaves.split(",") if k.strip()]
    if "durand" in kinds:
        try:
            import durand  # noqa: F401
        except ImportError:
            print("durand not installed: skipped (pip install durand)")
            kinds.remove("durand")
    print(
        f"can_load: {platform.python_implementation()} {platform.python_version()}, "
        f"kernel {platform.release()}, {os.cpu_count()} CPU, {args.duration:g} s per phase, "
        f"{args.requests} SDO reads, flood ids {FOREIGN}",
        flush=True,
    )
    channels = [args.channel] + [f"{args.channel}-{n}" for n in range(1, len(kinds))]
    for name in channels[1:]:  # one bus per slave: none hears another's traffic
        if not Path(f"/sys/class/net/{name}").exists():
            subprocess.run(["ip", "link", "add", name, "type", "vcan"], check=True)
            subprocess.run(["ip", "link", "set", name, "up"], check=True)
    slaves = [Slave(kind, channel) for kind, channel in zip(kinds, channels, strict=True)]
    clients = [Client(channel) for channel in channels]
    try:
        for slave, client in zip(slaves, clients, strict=True):
            slave.start(client)
        print("\n-- idle and SDO reads, all slaves at once (reads alternate)", flush=True)
        results = shared_phases(slaves, clients, args)
        for slave, client, result in zip(slaves, clients, results, strict=True):
            print(f"\n-- {slave.label} on {slave.channel}: the flood", flush=True)
            flood_phases(slave, client, result, args)
            if slave.kind.startswith("fieldgate"):
                result.sync = sync_phase(slave, slave.channel, args)
                result.floods.append(result.sync["flood_frames"])
    finally:
        counts = [slave.stop() for slave in slaves]
        for client in clients:
            client.close()
    for result, client, count in zip(results, clients, counts, strict=True):
        if count:
            result.counts = count
            own = client.sent + int(result.sync.get("sent_to_slave", 0))
            filters = count.get("filters") or []
            assert isinstance(filters, list)
            print(
                f"\n{result.label}'s front counted {count['rx']} frames received in all phases, "
                f"{count['rx_ignored']} ignored after filtering, {count['engine_rx']} reached the "
                f"engine; the client sent it {own}, the floods {sum(result.floods):.0f} foreign; "
                f"RPDOs {count['rpdo_received']}, TPDOs {count['tpdo_sent']}, "
                f"send errors {count['tx_errors']}; filters {' '.join(map(str, filters))}; "
                f"receive buffer {count.get('rx_buffer_bytes')} bytes",
                flush=True,
            )
    summary(results, args)
    stats = {
        r.label: {
            "idle_cpu": r.idle_cpu,
            "paced_p99_us": 1e6 * pct(r.paced_sdo, 0.99),
            "sdo_p50_us": 1e6 * pct(r.sdo, 0.5),
            "sdo_p99_us": 1e6 * pct(r.sdo, 0.99),
            "sdo_cpu_us": r.sdo_cpu_us,
            "flood_rate": r.flood.get("rate"),
            "flood_p50_us": 1e6 * pct(r.flood_sdo, 0.5),
            "flood_p99_us": 1e6 * pct(r.flood_sdo, 0.99),
            "flood_lost": r.flood_lost,
            "foreign_us": r.foreign_us,
            **({"sync": r.sync} if r.sync else {}),
        }
        for r in results
    }
    print(
        "json: " + json.dumps(stats, default=lambda x: round(x, 2) if isinstance(x, float) else x)
    )


if __name__ == "__main__":
    main()
