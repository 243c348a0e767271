"""The device under test for the CANopen integration tests, started through one fixture.

The bus comes from ``FIELDGATE_TEST_CAN`` (``interface:channel``, e.g.
``socketcan:vcan0`` inside User-Mode Linux). Unset: python-can's in-process
``virtual`` interface with a unique channel, and the gateway runs in a thread of this
process. Set: the gateway is started from the CLI as its own process
(``fieldgate run topology.yaml --set fronts.plc.interface=... --set fronts.plc.channel=...``).
The master side is always plain python-can / canopen, so the tests do not change.
"""

from __future__ import annotations

import asyncio
import json
import os
import subprocess
import sys
import uuid
from pathlib import Path

from socketcan_guest import scaled

from fieldgate.testing import GatewayThread

FRONT = "plc"
# How long a started gateway may take to send its boot-up. A `fieldgate run` process in the
# SocketCAN guest, beside the host suite on a 2-core host, took over 10 s once.
BOOT_TIMEOUT = scaled(30.0)
# Every DUT make_dut gave out; tests/canopen/conftest.py stops what a test left running (a
# fixture that fails before its yield has no teardown, and a gateway left on vcan0 answers
# as node 5 in every later test).
MADE: list = []


def bus_under_test() -> tuple[str, str, bool]:
    """(interface, channel, external) for this run."""
    spec = os.environ.get("FIELDGATE_TEST_CAN", "")
    if spec:
        interface, _, channel = spec.partition(":")
        return interface, channel, True
    return "virtual", f"fieldgate-co-{uuid.uuid4().hex[:10]}", False


def topology(state_dir: Path, node_id: int = 5, **front) -> dict:
    return {
        "gateway": {"name": "canopen-test", "state_dir": str(state_dir)},
        "fronts": [
            {
                "name": FRONT,
                "type": "canopen",
                "interface": "virtual",
                "channel": "unused",
                "node_id": node_id,
                "identity": {
                    "vendor_id": 0x0000ABCD,
                    "product_code": 0x7232,
                    "revision": 0x00010000,
                    "serial": 42,
                    "device_name": "fieldgate test node",
                },
                **front,
            }
        ],
        "backs": [
            {
                "name": "io",
                "type": "loopback",
                "modules": [{"address": 3, "digital": 8, "analog": 2, "error_mode": {"value": 0}}],
            }
        ],
    }


class InProcessDut(GatewayThread):
    """The gateway on its own event loop in a thread of the test process (the test fixtures'
    :class:`fieldgate.testing.GatewayThread`), its canopen front on ``interface``/``channel``."""

    def __init__(
        self,
        topo: dict,
        interface: str,
        channel: str,
        loop_factory=asyncio.new_event_loop,
        *,
        simulate: bool = False,
        animate: bool = False,
    ):
        from fieldgate import load_registry

        topo = {
            **topo,
            "fronts": [{**topo["fronts"][0], "interface": interface, "channel": channel}],
        }
        # loop_factory: what ``fieldgate run --loop`` would run; simulate/animate: as
        # ``fieldgate run --simulate`` (simulated modules, moving inputs, outputs wired to inputs)
        super().__init__(
            topo,
            registry=load_registry(),
            simulate=simulate,
            animate=animate,
            loop_factory=loop_factory,
        )


class ProcessDut:
    """``fieldgate run`` as its own process (real SocketCAN inside User-Mode Linux)."""

    gateway = None

    def __init__(
        self, topo: dict, interface: str, channel: str, workdir: Path, *, simulate: bool = False
    ):
        self.path = workdir / "topology.yaml"
        self.path.write_text(json.dumps(topo, indent=1))  # JSON is YAML
        self.interface, self.channel = interface, channel
        self.simulate = simulate  # --simulate: animated simulated modules behind the front
        # what the gateway printed: a file, not a pipe nobody reads (a full pipe stalls it)
        self.log_path = workdir / "gateway.log"
        self.proc: subprocess.Popen | None = None

    def output(self) -> str:
        return self.log_path.read_text(errors="replace") if self.log_path.exists() else ""

    def start(self) -> None:
        cmd = [
            sys.executable,
            "-m",
            "fieldgate",
            "run",
            str(self.path),
            "--set",
            f"fronts.{FRONT}.interface={self.interface}",
            "--set",
            f"fronts.{FRONT}.channel={self.channel}",
            *(["--simulate"] if self.simulate else []),
        ]
        with self.log_path.open("a") as log:
            self.proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT)

    def call(self, fn):
        raise NotImplementedError("the gateway runs in another process")

    def stop(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self.proc = None


def write_eds(topo: dict, workdir: Path, name: str = "dut.eds") -> Path:
    """The EDS of the topology's canopen front, written by ``fieldgate eds`` in a subprocess."""
    source = workdir / "eds-topology.yaml"
    source.write_text(json.dumps(topo))  # JSON is YAML
    eds = workdir / name
    done = subprocess.run(
        [sys.executable, "-m", "fieldgate", "eds", str(source), "-o", str(eds)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert done.returncode == 0, done.stderr
    return eds


def make_dut(
    topo: dict,
    interface: str,
    channel: str,
    external: bool,
    workdir: Path,
    *,
    simulate: bool = False,
):
    """The gateway under test; ``simulate``: its backs served by animated simulated modules,
    as ``fieldgate run --simulate`` does."""
    dut = (
        ProcessDut(topo, interface, channel, workdir, simulate=simulate)
        if external
        else InProcessDut(topo, interface, channel, simulate=simulate, animate=simulate)
    )
    MADE.append(dut)
    return dut


def stop_all_made() -> None:
    """Stop every DUT given out so far (a second stop does nothing)."""
    while MADE:
        MADE.pop().stop()
