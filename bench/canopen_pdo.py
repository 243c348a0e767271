"""CANopen PDO engine: SYNC -> last TPDO latency and event-driven TPDO throughput,
against canopen's LocalNode doing the equivalent by hand, in the same run.

Run:  .venv/bin/python bench/canopen_pdo.py   (about 20 s)

Both nodes serve the same object dictionary (fieldgate's generated EDS for the same
topology: 64 DI, 124 AI, node-ID 1) on python-can's in-process ``virtual`` bus; a
master on the same bus sends the SYNCs and counts the frames.

1. SYNC -> last TPDO: all 32 TPDOs valid, transmission type 1, mapped to live data
   (the DI bytes and 124 AI channels, which change between SYNCs). fieldgate: the
   gateway (loopback back, canopen front) on its event loop in a thread; the PDO
   engine samples and sends at SYNC. LocalNode: a SYNC subscription that copies the
   same 188 values into its 32 TPDO maps and calls ``transmit()`` on each (canopen has
   no SYNC consumer). Latency = master sends SYNC -> master has received the 32nd TPDO.
2. Event-driven throughput: TPDO1 (type 255, the DI bytes) for a stream of DI changes.
   fieldgate: process-image writes, each followed by one event-loop turn (the engine
   is driven by image subscriptions). LocalNode: set the map variable, ``transmit()``.
   Frames per second counted at the master.
"""

from __future__ import annotations

import asyncio
import statistics
import sys
import tempfile
import threading
import time
import uuid
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run from a checkout too

import can  # noqa: E402
import canopen  # noqa: E402

from fieldgate import Gateway, load_registry  # noqa: E402
from fieldgate.plugins.canopen.eds import write_eds  # noqa: E402

SYNCS = 400
EVENTS = 3000
TPDOS = 32
EXTRA_COB = 0x1C0  # COB-IDs for TPDO5..32 (0x1C4..0x1DF, free for node 1)


def topology(channel: str, state_dir: str) -> dict:
    return {
        "gateway": {"name": "bench", "state_dir": state_dir},
        "fronts": [
            {
                "name": "can",
                "type": "canopen",
                "interface": "virtual",
                "channel": channel,
                "node_id": 1,
            }
        ],
        "backs": [
            {
                "name": "io",
                "type": "loopback",
                "modules": [{"address": 1, "digital": 64}]
                + [{"address": a, "analog": 31} for a in (2, 3, 4, 5)],
            }
        ],
    }


def tpdo_ids() -> list[int]:
    return [0x181, 0x281, 0x381, 0x481] + [EXTRA_COB + n for n in range(4, TPDOS)]


def percentile(values: list[float], q: float) -> float:
    values = sorted(values)
    return values[min(len(values) - 1, int(q * len(values)))]


def measure_sync(master: can.BusABC, ids: set[int], change) -> list[float]:
    latencies = []
    for k in range(SYNCS):
        change(k)
        while master.recv(timeout=0) is not None:
            pass
        t0 = time.perf_counter()
        master.send(can.Message(arbitration_id=0x80, data=b"", is_extended_id=False))
        seen = 0
        while seen < len(ids):
            msg = master.recv(timeout=1.0)
            if msg is None:
                raise RuntimeError(f"SYNC {k}: only {seen} TPDOs arrived")
            if msg.arbitration_id in ids:
                seen += 1
        latencies.append(time.perf_counter() - t0)
    return latencies


def count_frames(master: can.BusABC, can_id: int, expected: int, timeout: float = 5.0) -> int:
    n = 0
    deadline = time.monotonic() + timeout
    while n < expected and time.monotonic() < deadline:
        msg = master.recv(timeout=0.1)
        if msg is not None and msg.arbitration_id == can_id:
            n += 1
    return n


# -- fieldgate ---------------------------------------------------------------------------
class GatewayThread:
    def __init__(self, topo: dict):
        self.loop = asyncio.new_event_loop()
        self.gw = Gateway.load(topo, registry=load_registry())
        ready = threading.Event()

        def run() -> None:
            asyncio.set_event_loop(self.loop)
            self.loop.run_until_complete(self.gw.start())
            ready.set()
            self.loop.run_forever()
            self.loop.run_until_complete(self.gw.stop())

        self.thread = threading.Thread(target=run, daemon=True)
        self.thread.start()
        ready.wait(10)

    def call(self, fn):
        async def wrapper():
            result = fn()
            if asyncio.iscoroutine(result):
                result = await result
            return result

        return asyncio.run_coroutine_threadsafe(wrapper(), self.loop).result(30)

    def close(self) -> None:
        self.loop.call_soon_threadsafe(self.loop.stop)
        self.thread.join(10)


def sdo(master: can.BusABC, index: int, sub: int, value: int, size: int) -> None:
    cs = {1: 0x2F, 2: 0x2B, 4: 0x23}[size]
    master.send(
        can.Message(
            arbitration_id=0x601,
            data=bytes([cs, index & 0xFF, index >> 8, sub])
            + value.to_bytes(size, "little").ljust(4, b"\0"),
            is_extended_id=False,
        )
    )
    while True:
        msg = master.recv(timeout=2)
        if msg is None:
            raise RuntimeError(f"no SDO answer for 0x{index:04X}:{sub}")
        if msg.arbitration_id == 0x581:
            if msg.data[0] != 0x60:
                raise RuntimeError(f"SDO 0x{index:04X}:{sub} refused: {msg.data.hex()}")
            return


def fieldgate_run(state_dir: str) -> tuple[list[float], float]:
    channel = f"bench-fg-{uuid.uuid4().hex[:8]}"
    dut = GatewayThread(topology(channel, state_dir))
    master = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
    try:
        for n in range(TPDOS):
            if n >= 4:
                sdo(master, 0x1800 + n, 1, EXTRA_COB + n, 4)
            sdo(master, 0x1800 + n, 2, 1, 1)
        master.send(can.Message(arbitration_id=0, data=b"\x01\x01", is_extended_id=False))
        time.sleep(0.2)
        image = dut.gw.image
        ais = [c.id for c in image if c.kind.value == "ai"]

        def change(k: int) -> None:
            def update():
                for i, cid in enumerate(ais):
                    image.update_input(cid, (k * 7 + i) & 0x7FFF)

            dut.call(update)

        latencies = measure_sync(master, set(tpdo_ids()), change)
        for n in range(TPDOS):
            sdo(master, 0x1800 + n, 2, 255, 1)  # back to event-driven for part 2
        while master.recv(timeout=0.05) is not None:
            pass

        async def events():
            for k in range(EVENTS):
                image.update_input("io/m1/di0", not k & 1)
                await asyncio.sleep(0)

        t0 = time.perf_counter()
        dut.call(events)
        got = count_frames(master, 0x181, EVENTS)
        rate = got / (time.perf_counter() - t0)
        if got != EVENTS:
            raise RuntimeError(f"fieldgate: {got} of {EVENTS} event TPDOs arrived")
        return latencies, rate
    finally:
        master.shutdown()
        dut.close()


# -- canopen LocalNode by hand ----------------------------------------------------------------
def localnode_run(eds_path: str) -> tuple[list[float], float]:
    channel = f"bench-co-{uuid.uuid4().hex[:8]}"
    network = canopen.Network()
    network.connect(interface="virtual", channel=channel)
    master = can.Bus(interface="virtual", channel=channel)
    try:
        node = canopen.LocalNode(1, canopen.import_od(eds_path, node_id=1))
        network.add_node(node)
        node.tpdo.read(from_od=True)
        maps = [node.tpdo[n + 1] for n in range(TPDOS)]
        for n, m in enumerate(maps):
            m.cob_id = tpdo_ids()[n]
            m.enabled = True
            m.trans_type = 1
        data = {"k": 0}

        def on_sync(can_id, payload, timestamp):  # what the PDO engine does, written by hand
            k = data["k"]
            i = 0
            for n, m in enumerate(maps):
                for var in m.map:
                    if n == 0:
                        var.raw = 0
                    else:
                        var.raw = (k * 7 + i) & 0x7FFF
                        i += 1
                m.transmit()

        network.subscribe(0x80, on_sync)

        def change(k: int) -> None:
            data["k"] = k

        latencies = measure_sync(master, set(tpdo_ids()), change)
        network.unsubscribe(0x80)
        while master.recv(timeout=0.05) is not None:
            pass
        tpdo1 = maps[0]
        t0 = time.perf_counter()
        for k in range(EVENTS):
            tpdo1.map[0].raw = k & 1
            tpdo1.transmit()
        got = count_frames(master, 0x181, EVENTS)
        rate = got / (time.perf_counter() - t0)
        return latencies, rate
    finally:
        master.shutdown()
        network.disconnect()


def main() -> int:
    with tempfile.TemporaryDirectory() as tmp:
        eds_path = str(Path(tmp) / "bench.eds")
        write_eds(topology("unused", tmp), "can", eds_path)
        t_start = time.perf_counter()
        fg_lat, fg_rate = fieldgate_run(tmp)
        co_lat, co_rate = localnode_run(eds_path)
    ms = 1000.0
    print(
        f"SYNC -> last of {TPDOS} TPDOs (type 1, 188 live values), {SYNCS} SYNCs on the virtual bus:"
    )
    for name, lat in (("fieldgate PDO engine", fg_lat), ("canopen LocalNode by hand", co_lat)):
        print(
            f"  {name:28s} p50 {statistics.median(lat) * ms:7.3f} ms   p99 {percentile(lat, 0.99) * ms:7.3f} ms"
        )
    print(
        f"  ratio fieldgate/LocalNode     p50 {statistics.median(fg_lat) / statistics.median(co_lat):5.2f}    p99 {percentile(fg_lat, 0.99) / percentile(co_lat, 0.99):5.2f}"
    )
    print(f"Event-driven TPDO1 throughput ({EVENTS} DI changes):")
    print(f"  fieldgate (image event -> engine -> bus)  {fg_rate:9.0f} TPDO/s")
    print(f"  canopen LocalNode (raw = v; transmit())   {co_rate:9.0f} TPDO/s")
    print(f"  ratio fieldgate/LocalNode                 {fg_rate / co_rate:9.2f}")
    print(f"(total {time.perf_counter() - t_start:.1f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
