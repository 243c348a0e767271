"""durand (PyPI, a CANopen responder library we did not write) as a device under test.

A ``MinimalNode`` (1 SDO server, 4 RPDOs, 4 TPDOs, LSS, EMCY, heartbeat, SYNC consumer) with
a small application area, on a python-can bus; its EDS is the one durand writes itself
(``node.eds.content``). Run as a script it serves on SocketCAN until stopped (the SocketCAN
stage starts it as its own process)::

    python tests/conformance/conformance_durand.py --channel vcan0 --eds durand.eds
"""

from __future__ import annotations

import argparse
import asyncio
import signal
import threading
from pathlib import Path

import can

NODE_ID = 9


class DurandDevice:
    """A durand MinimalNode on ``bus``, run as durand means it to run: its receive callbacks and
    its timers on one asyncio loop (``AsyncScheduler``), in a thread of its own.

    durand's ``SyncScheduler`` fires timers in a second thread while the notifier's thread
    serves SDO, with no lock between them: a write of 0 to 0x1017 racing the heartbeat timer
    could leave the producer running (seen once in the SocketCAN stage, under load). One loop
    serialises both, so every verdict is about durand and none about the harness's threads.
    """

    def __init__(self, bus: can.BusABC, node_id: int = NODE_ID):
        self.loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self.loop.run_forever, daemon=True)
        self._thread.start()
        asyncio.run_coroutine_threadsafe(self._build(bus, node_id), self.loop).result(10)

    async def _build(self, bus: can.BusABC, node_id: int) -> None:
        import durand
        from durand.scheduler import AsyncScheduler

        durand.set_scheduler(AsyncScheduler(self.loop))
        self.network = durand.CANBusNetwork(bus, loop=self.loop)
        self.node = durand.MinimalNode(self.network, node_id)
        od = self.node.object_dictionary
        dt = durand.DatatypeEnum
        od[0x1008].value = b"durand MinimalNode"
        ident = od[0x1018]
        ident[1].value, ident[2].value, ident[3].value, ident[4].value = 0x4E, 0x1234, 1, 77
        od[0x2000] = durand.Variable(dt.UNSIGNED16, "rw", 100, name="Setpoint")
        od[0x2001] = durand.Variable(dt.UNSIGNED32, "rw", 0, name="Parameter")
        out = durand.Record(name="Outputs")
        out[1] = durand.Variable(dt.UNSIGNED8, "rw", 0, name="Output 1")
        out[2] = durand.Variable(dt.UNSIGNED16, "rw", 0, name="Output 2")
        od[0x2100] = out
        inp = durand.Record(name="Inputs")
        inp[1] = durand.Variable(dt.UNSIGNED8, "ro", 0, name="Input 1")
        inp[2] = durand.Variable(dt.UNSIGNED16, "ro", 0, name="Input 2")
        od[0x2200] = inp

    def eds(self) -> str:
        return self.node.eds.content

    def write_eds(self, path: Path) -> Path:
        path.write_text(self.eds())
        return path

    def close(self) -> None:
        async def stop() -> None:
            self.network.stop()

        asyncio.run_coroutine_threadsafe(stop(), self.loop).result(5)
        self.loop.call_soon_threadsafe(self.loop.stop)
        self._thread.join(2)
        self.loop.close()


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--interface", default="socketcan")
    p.add_argument("--channel", default="vcan0")
    p.add_argument("--node-id", type=int, default=NODE_ID)
    p.add_argument("--eds", type=Path, required=True, help="write the node's EDS here first")
    args = p.parse_args()
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    with can.Bus(interface=args.interface, channel=args.channel) as bus:
        device = DurandDevice(bus, args.node_id)
        device.write_eds(args.eds)
        print("durand node up", flush=True)
        try:
            stop.wait()
        except KeyboardInterrupt:
            pass
        device.close()


if __name__ == "__main__":
    main()
