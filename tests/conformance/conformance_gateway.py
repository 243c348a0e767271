"""fieldgate's canopen front as a device under test: a gateway on its own event loop in a
thread, a loopback back behind it (DO n → DI n, AO n → AI n), and its EDS from ``fieldgate eds``."""

from __future__ import annotations

import asyncio
import json
import subprocess
import sys
import threading
from pathlib import Path

NODE_ID = 5

# the na9161 cases of conformance/cases/profiles.py that need the FnBus register 0x4500
NA9161_PROFILE_CASES = (
    "defaults",
    "heartbeat_loss_outputs",
    "sync_loss_outputs",
    "analog_change_tpdo",
    "emcy_queue_overflow",
    "short_expedited_write",
)
# issue 32's rows (conformance/cases/na9161.py): an NA-9161-style head only
NA9161_ROW_CASES = (
    "field_power_bit",
    "slot_memory_not_io",
    "hw_config_emcy",
    "stored_cob_ids_kept",
)


def patch_out(monkeypatch, target: str, attribute: str, broken) -> None:
    """Break the front on purpose: ``target`` (module.Class) gets ``broken`` as ``attribute``."""
    module_name, class_name = target.rsplit(".", 1)
    module = __import__(module_name, fromlist=[class_name])
    monkeypatch.setattr(getattr(module, class_name), attribute, broken)


# case id -> what the front does wrong (reported to the front's authors; docs/conformance.md)
# (the three findings of the first runs were fixed in the front: see docs/conformance.md)
KNOWN_FINDINGS: dict[str, str] = {}
# case id -> why it cannot apply to this gateway (a substring of the SKIP reason)
DOCUMENTED_SKIPS = {
    "od.read_write_only": "no write-only entry",
    "sync-pdo.bit_mapping": "byte granularity",  # bit_mapping is off in this topology
    "na9161.fnbus_register": "EDS lists no 0x4500",  # the icpdas style has no FnBus register
    "na9161.slot_flags": "EDS lists no 0x4500",
    "na9161.data_mode_layout": "EDS lists no 0x4500",
    "na9161.bit_counts": "EDS lists neither 0x2020:1 nor 0x2220:1",
    "na9161.special_areas": "no special modules",  # the loopback module has none here
    "na9161.special_tpdo": "no special modules",
    **{f"na9161.{name}": "EDS lists no 0x4500" for name in NA9161_PROFILE_CASES},
    **{f"na9161.{name}": "EDS lists no 0x4500" for name in NA9161_ROW_CASES},
    "na9161.slot_objects": "EDS lists no 0x4503",
    # master delta-as300 adds heartbeat to the guarding-only icpdas style
    "icpdas.guarding_only": "heartbeat added",
    "icpdas.no_tpdo_at_start": "a master profile added heartbeat",  # and TPDOs at Start (E2)
    "icpdas.store_write_emcy": "the store could be written",  # its failure: the store tests
}


def topology(state_dir: Path, channel: str) -> dict:
    return {
        "gateway": {"name": "conformance", "state_dir": str(state_dir)},
        "fronts": [
            {
                "name": "plc",
                "type": "canopen",
                "interface": "virtual",
                "channel": channel,
                "node_id": NODE_ID,
                "sdo_timeout_ms": 300,
                # a Delta AS300 as the master (the delta-as300 cases): 0x1016 watches its
                # heartbeat (node 1); the icpdas style guards only, so the profile adds 0x1017
                # (here 0, as CiA 301's default) and the suite grades all of error control
                "master": "delta-as300",
                "heartbeat_ms": 0,
                # the AS300 profile gives the analog TPDO an event timer (REQ-AS-15); 0 here
                # keeps icpdas.analog_change_no_tpdo gradable (changes alone, no timer)
                "tpdos": {2: {"event_timer_ms": 0}},
                "identity": {
                    "vendor_id": 0x0000ABCD,
                    "product_code": 0x7232,
                    "revision": 0x00010000,
                    "serial": 42,
                    "device_name": "fieldgate conformance",
                },
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


def front_unavailable() -> str | None:
    """Why the gateway cannot be tested yet, or None."""
    from fieldgate import load_registry

    registry = load_registry()
    if registry.lookup("front", "canopen") is None:
        return "fieldgate's canopen front is not registered yet"
    if "canopen" not in registry.eds_writers:
        return "`fieldgate eds` cannot describe a canopen front yet"
    return None


def write_eds(topo: dict, workdir: Path) -> Path:
    source = workdir / "topology.yaml"
    source.write_text(json.dumps(topo))  # JSON is YAML
    eds = workdir / "gateway.eds"
    done = subprocess.run(
        [sys.executable, "-m", "fieldgate", "eds", str(source), "-o", str(eds)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    if done.returncode != 0:
        raise RuntimeError(f"fieldgate eds failed: {done.stderr.strip()}")
    return eds


class GatewayThread:
    def __init__(self, topo: dict):
        self.topo = topo
        self.gateway = None
        self._loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self._run, name="gateway-under-test", daemon=True)
        self._ready = threading.Event()
        self._error: BaseException | None = None

    def _run(self) -> None:
        from fieldgate import Gateway

        asyncio.set_event_loop(self._loop)
        try:
            self.gateway = Gateway.load(self.topo)
            self._loop.run_until_complete(self.gateway.start())
        except BaseException as exc:  # reported by __enter__
            self._error = exc
            self._ready.set()
            return
        self._ready.set()
        self._loop.run_forever()
        self._loop.run_until_complete(self.gateway.stop())

    def __enter__(self) -> GatewayThread:
        self._thread.start()
        self._ready.wait(20)
        if self._error is not None:
            raise self._error
        return self

    def __exit__(self, *exc) -> None:
        self._loop.call_soon_threadsafe(self._loop.stop)
        self._thread.join(20)
