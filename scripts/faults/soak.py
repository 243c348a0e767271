#!/usr/bin/env python3
"""A soak: one gateway for hours with every north-facing front busy and faults on both sides,
its memory, CPU, journal and log sampled over time.

Run:  nice -n 10 .venv/bin/python scripts/faults/soak.py --duration 7200 --out soak-run
      (the figure in docs/reliability.md: 2 h; CI runs a short version with growth checks,
      tests/faults/test_soak.py; scripts/faults/soak_plot.py draws the figure from the CSV)

What runs, each in its own process, as a plant would have it:

* ``fieldgate run`` (the gateway under test) on a generated topology: a Modbus RTU line (an
  I-7232D-style set of modules and a meter with byte-swapped floats, 64-bit counters, text
  and scaled values) on a pseudo-terminal, a modbus-tcp-client back with four meters on two
  simulated hosts, and the OPC UA, Modbus TCP and Sparkplug fronts and the HTTP status server;
* ``fieldgate simulate modbus`` on the other end of the pty, ``fieldgate simulate
  modbus-tcp-client`` for the meters: their faults come from this script (stdin commands);
* Mosquitto, stopped for ``--outage-s`` every ``--outage-every-s`` (the Sparkplug front
  journals on disk and replays when it is back);
* a client process: OPC UA clients that connect, subscribe to every input (500 ms), write a
  setpoint and leave (half of them cleanly, half by dropping the connection, so their
  session expires), two at a time; Modbus TCP clients that connect, read every table, write,
  disconnect, 4 a second, plus idle connections left for the idle timeout; an MQTT host
  subscribed to everything.

Faults, in turn every ``--fault-every-s``: an RS-485 module silent for 20 s, 5 CRC errors, a
module answering exceptions, garbage; a TCP meter silent, a TCP host down for 20 s.

Every ``--sample-s`` seconds one CSV row: time, the fieldbus process's RSS and CPU (from
/proc), each child's RSS and CPU (``/api/v1/status`` "children"), the Sparkplug journal's
size on disk, the gateway log's size, and what the clients did. At the end a verdict on
growth (exit 0 when every check holds): each process's RSS in the last fifth of the run
against the fifth after the warm-up, the journal back to its size after a replay, the log
growing by less than ``--log-mb-per-hour``.
"""

from __future__ import annotations

import argparse
import asyncio
import csv
import getpass
import json
import os
import random
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
import urllib.request
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[2]
sys.path.append(str(ROOT / "tests"))
from netkit import free_port  # noqa: E402  (tests/netkit.py: one helper for tests, benches and scripts)

PAGE = os.sysconf("SC_PAGE_SIZE")
TICKS = os.sysconf("SC_CLK_TCK")
MB = 2**20


METER_MAP = """\
# a power meter's register map (PDU addresses), as a vendor lists it
kind,table,address,type,order,divider,decimals,unit,low,high,length,label
ai,input_registers,0,float32,BADC,,,V,0,500,,Voltage L1-N
ai,input_registers,2,int32,CDAB,1000,3,A,,,,Current L1
ai,input_registers,4,uint64,ABCD,,,Wh,,,,Energy import
ai,input_registers,8,string,,,,,,,16,Serial number
ai,input_registers,16,int16,,10,1,°C,-40,125,,Temperature
ao,holding_registers,0,uint32,CDAB,100,2,A,0,100,,Current limit
"""


def topology(ports: dict[str, int]) -> str:
    return f"""\
gateway:
  name: soak
  http: {{listen: "127.0.0.1:{ports["http"]}"}}
models:
  meter: {{type: modbus, map: meter.csv}}
fronts:
  - {{name: ua, type: opcua, listen: "127.0.0.1:{ports["opcua"]}", writable: ["rs485/m4/ao0", "plant/*/ao0"]}}
  - {{name: mb, type: modbus-tcp, listen: "127.0.0.1:{ports["modbus"]}", writable: ["rs485/m4/ao[123]", "rs485/m3/do*"], idle_timeout_s: 30}}
  - name: spb
    type: sparkplug
    group_id: soak
    brokers: [{{host: 127.0.0.1, port: {ports["mqtt"]}}}]
backs:
  - name: rs485
    type: modbus
    port: /dev/null
    baudrate: 115200
    poll_ms: 100
    modules:
      - {{address: 1, model: M-7052D}}
      - {{address: 3, model: M-7055D, counts: {{di: 0}}}}
      - {{address: 4, model: M-7024}}
      - {{address: 5, model: M-7017R}}
      - {{address: 7, model: meter, poll_ms: 500}}
  - name: plant
    type: modbus-tcp-client
    poll_ms: 500
    timeout_ms: 300
    offline_probe_ms: 2000
    hosts: {{"127.0.0.1:{ports["tcp_a"]}": {{pipeline: 2}}}}
    modules:
      - {{address: 1, host: "127.0.0.1:{ports["tcp_a"]}", model: meter}}
      - {{address: 2, host: "127.0.0.1:{ports["tcp_a"]}", model: meter}}
      - {{address: 3, host: "127.0.0.1:{ports["tcp_b"]}", model: meter}}
      - {{address: 4, host: "127.0.0.1:{ports["tcp_b"]}", model: meter}}
"""


class Broker:
    def __init__(self, workdir: Path, port: int):
        self.binary = shutil.which("mosquitto") or "/usr/sbin/mosquitto"
        self.port = port
        self.conf = workdir / "mosquitto.conf"
        self.conf.write_text(
            f"user {getpass.getuser()}\nlistener {port} 127.0.0.1\nallow_anonymous true\n"
            "persistence false\nlog_dest none\nmax_queued_messages 100000\n"
        )
        self.proc: subprocess.Popen[bytes] | None = None

    def start(self) -> None:
        self.proc = subprocess.Popen([self.binary, "-c", str(self.conf)])
        end = time.monotonic() + 10
        while time.monotonic() < end:
            with socket.socket() as s:
                if s.connect_ex(("127.0.0.1", self.port)) == 0:
                    return
            time.sleep(0.05)
        raise SystemExit("mosquitto did not start")

    def stop(self) -> None:
        if self.proc is not None:
            self.proc.terminate()
            self.proc.wait(10)
            self.proc = None


class Sim:
    """A ``fieldgate simulate`` process; ``command`` writes to its stdin."""

    def __init__(self, args: list[str], log: Path):
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "fieldgate", "simulate", *args],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=open(log, "ab"),  # noqa: SIM115  (the process keeps it)
            text=True,
        )
        assert self.proc.stdout is not None
        self.banner = ""
        for line in self.proc.stdout:
            if line.startswith("simulating"):
                self.banner = line
                break
        else:
            raise SystemExit(f"fieldgate simulate {args[0]} did not start")
        # the rest of its output (output changes, answers) is read and dropped
        self._drain = subprocess.Popen(["cat"], stdin=self.proc.stdout, stdout=subprocess.DEVNULL)

    def command(self, text: str) -> None:
        assert self.proc.stdin is not None
        self.proc.stdin.write(text + "\n")
        self.proc.stdin.flush()

    def stop(self) -> None:
        self.proc.terminate()
        self.proc.wait(10)
        self._drain.wait(10)


def proc_stat(pid: int) -> tuple[int, float]:
    """(RSS bytes, CPU seconds) of a process."""
    with open(f"/proc/{pid}/statm", "rb") as f:
        rss = int(f.read().split()[1]) * PAGE
    with open(f"/proc/{pid}/stat", "rb") as f:
        fields = f.read().rsplit(b")", 1)[1].split()
    return rss, (int(fields[11]) + int(fields[12])) / TICKS


def status(port: int) -> dict[str, Any]:
    with urllib.request.urlopen(f"http://127.0.0.1:{port}/api/v1/status", timeout=5) as r:
        return json.loads(r.read())  # type: ignore[no-any-return]


NUMERIC = {"t_s", "journal_kb", "log_kb"}  # what the verdict computes with, read from a CSV

FAULTS = [
    ("rs485", "fault 5 no_answer", 20.0, "clear 5"),
    ("rs485", "fault 1 crc 5", 0.0, None),
    ("rs485", "fault 7 exception 3 code=4", 0.0, None),
    ("rs485", "fault 4 garbage 2", 0.0, None),
    ("plant", "fault 3 no_answer", 20.0, "clear 3"),
    ("plant", "host 3 down", 20.0, "host 3 up"),
]


def run(args: argparse.Namespace) -> int:
    out = Path(args.out).resolve()
    out.mkdir(parents=True, exist_ok=True)
    work = Path(tempfile.mkdtemp(prefix="fieldgate-soak-"))
    ports = {p: free_port() for p in ("http", "opcua", "modbus", "mqtt", "tcp_a", "tcp_b")}
    (work / "meter.csv").write_text(METER_MAP)
    topo = work / "soak.yaml"
    topo.write_text(topology(ports))
    log_path = out / "gateway.log"
    broker = Broker(work, ports["mqtt"])
    broker.start()
    rtu = Sim(["modbus", "--pty", "--topology", str(topo), "--back", "rs485"], out / "sim.log")
    pty = rtu.banner.split("point the gateway at ")[1].split()[0]
    tcp = Sim(["modbus-tcp-client", "--topology", str(topo), "--back", "plant"], out / "sim.log")
    gateway = subprocess.Popen(
        [sys.executable, "-m", "fieldgate", "run", str(topo), "--set", f"backs.rs485.port={pty}"],
        stdout=subprocess.DEVNULL,
        stderr=open(log_path, "ab"),  # noqa: SIM115
    )
    clients = None
    rows: list[dict[str, Any]] = []
    try:
        end = time.monotonic() + 60
        while True:
            try:
                if status(ports["http"]).get("ready"):
                    break
            except OSError:
                pass
            if time.monotonic() > end or gateway.poll() is not None:
                raise SystemExit(f"the gateway did not get ready (log: {log_path})")
            time.sleep(0.5)
        clients = subprocess.Popen(
            [sys.executable, __file__, "--clients", json.dumps(ports), "--out", str(out)],
            stdout=subprocess.DEVNULL,
            stderr=open(out / "clients.log", "ab"),  # noqa: SIM115
        )
        rows = sample_loop(
            args, gateway.pid, ports, broker, {"rs485": rtu, "plant": tcp}, out, log_path, work
        )
    finally:
        if clients is not None:
            clients.send_signal(signal.SIGINT)
            try:
                clients.wait(20)
            except subprocess.TimeoutExpired:
                clients.kill()
        gateway.send_signal(signal.SIGTERM)
        try:
            gateway.wait(30)
        except subprocess.TimeoutExpired:
            gateway.kill()
        rtu.stop()
        tcp.stop()
        broker.stop()
        shutil.rmtree(work, ignore_errors=True)
    return verdict(args, rows, out)


def sample_loop(
    args: argparse.Namespace,
    pid: int,
    ports: dict[str, int],
    broker: Broker,
    sims: dict[str, Sim],
    out: Path,
    log_path: Path,
    work: Path,
) -> list[dict[str, Any]]:
    rows: list[dict[str, Any]] = []
    started = time.monotonic()
    next_sample = started
    next_fault, fault_index, undo = started + args.fault_every_s, 0, None
    next_outage, outage_end = started + args.outage_every_s, None
    last_cpu: dict[str, tuple[float, float]] = {}
    with open(out / "soak.csv", "w", newline="") as f:
        writer: csv.DictWriter[str] | None = None
        while (now := time.monotonic()) - started < args.duration:
            if undo is not None and now >= undo[0]:
                sims[undo[1]].command(undo[2])
                undo = None
            if now >= next_fault and undo is None:
                sim, command, hold, back = FAULTS[fault_index % len(FAULTS)]
                sims[sim].command(command)
                if back:
                    undo = (now + hold, sim, back)
                fault_index += 1
                next_fault = now + args.fault_every_s
            if outage_end is None and now >= next_outage:
                broker.stop()
                outage_end = now + args.outage_s
            elif outage_end is not None and now >= outage_end:
                broker.start()
                outage_end = None
                next_outage = now + args.outage_every_s
            if now >= next_sample:
                row = sample(pid, ports, last_cpu, now - started, log_path, work, out)
                row["broker_up"] = int(outage_end is None)
                rows.append(row)
                if writer is None:
                    writer = csv.DictWriter(f, fieldnames=list(row))
                    writer.writeheader()
                writer.writerow({k: row.get(k, "") for k in writer.fieldnames})
                f.flush()
                next_sample += args.sample_s
            time.sleep(0.2)
    return rows


def sample(
    pid: int,
    ports: dict[str, int],
    last_cpu: dict[str, tuple[float, float]],
    t: float,
    log_path: Path,
    work: Path,
    out: Path,
) -> dict[str, Any]:
    row: dict[str, Any] = {"t_s": round(t, 1)}
    now = time.monotonic()

    def cpu_percent(name: str, cpu_s: float) -> float:
        before = last_cpu.get(name)
        last_cpu[name] = (now, cpu_s)
        if before is None or now <= before[0]:
            return 0.0
        return round(100 * (cpu_s - before[1]) / (now - before[0]), 2)

    rss, cpu_s = proc_stat(pid)
    row["fieldbus_rss_mb"] = round(rss / MB, 2)
    row["fieldbus_cpu_pct"] = cpu_percent("fieldbus", cpu_s)
    try:
        st = status(ports["http"])
    except OSError:
        st = {}
    for name in ("ua", "mb", "spb", "http"):
        child = st.get("children", {}).get(name, {})
        row[f"{name}_rss_mb"] = child.get("rss_mb", "")
        row[f"{name}_cpu_pct"] = cpu_percent(name, float(child.get("cpu_s") or 0.0))
        row[f"{name}_pid"] = child.get("pid", "")
    journal = sum(
        p.stat().st_size for p in (work / "fieldgate-state").glob("spb.journal*") if p.is_file()
    )
    row["journal_kb"] = round(journal / 1024, 1)
    row["log_kb"] = round(log_path.stat().st_size / 1024, 1)
    spb = st.get("fronts", {}).get("spb", {})
    row["spb_backlog"] = spb.get(
        "backlog_messages", spb.get("session", {}).get("backlog_messages", "")
    )
    mb = st.get("fronts", {}).get("mb", {}).get("counters", {})
    row["mb_connections"] = mb.get("connections", "")
    ua = st.get("fronts", {}).get("ua", {}).get("counters", {})
    row["ua_expired"] = ua.get("subscriptions_expired", "")
    row["modules_offline"] = sum(1 for m in st.get("modules", []) if not m.get("online", True))
    try:
        done = json.loads((out / "clients.json").read_text())
    except (OSError, ValueError):
        done = {}
    for key in ("ua_sessions", "ua_notifications", "mb_requests", "mb_errors", "mqtt_messages"):
        row[key] = done.get(key, 0)
    return row


def verdict(args: argparse.Namespace, rows: list[dict[str, Any]], out: Path) -> int:
    if len(rows) < 10:
        print(f"soak: {len(rows)} samples: too few for a verdict")
        return 1
    warm = [r for r in rows if r["t_s"] >= args.warmup_s] or rows
    fifth = max(1, len(warm) // 5)
    early, late = warm[:fifth], warm[-fifth:]
    checks = []
    for name in ("fieldbus", "ua", "mb", "spb", "http"):
        key = f"{name}_rss_mb"
        values_early = [float(r[key]) for r in early if r.get(key) not in ("", None)]
        values_late = [float(r[key]) for r in late if r.get(key) not in ("", None)]
        if not values_early or not values_late:
            checks.append((False, f"{name}: no RSS samples"))
            continue
        pids = {r.get(f"{name}_pid") for r in warm} - {"", None}
        before, after = median(values_early), median(values_late)
        limit = before * (1 + args.rss_growth) + args.rss_slack_mb
        checks.append(
            (
                after <= limit,
                f"{name}: RSS {before:.1f} -> {after:.1f} MB (limit {limit:.1f}; max "
                f"{max(float(r[key]) for r in warm if r.get(key) not in ('', None)):.1f})"
                + (f"; {len(pids) - 1} restart(s)" if name != "fieldbus" and len(pids) > 1 else ""),
            )
        )
    hours = max((rows[-1]["t_s"] - rows[0]["t_s"]) / 3600, 1e-6)
    log_rate = (rows[-1]["log_kb"] - rows[0]["log_kb"]) / 1024 / hours
    checks.append(
        (
            log_rate <= args.log_mb_per_hour,
            f"log: {log_rate:.2f} MB/h (limit {args.log_mb_per_hour})",
        )
    )
    peaks = outage_peaks(rows)
    if len(peaks) >= 2:  # the journal's file reuses its pages: no growth from outage to outage
        checks.append(
            (
                peaks[-1] <= peaks[0] * 1.25 + 256,
                f"journal: {len(peaks)} outages, its file at most {peaks[0]:.0f} KB after the "
                f"first, {peaks[-1]:.0f} KB after the last (limit +25 %)",
            )
        )
    else:
        journal = [float(r["journal_kb"]) for r in rows]
        checks.append(
            (
                max(journal) < 64 * 1024,
                f"journal: at most {max(journal):.0f} KB over {len(peaks)} outage(s) (limit 64 MB)",
            )
        )
    cpu = {
        n: mean([float(r[f"{n}_cpu_pct"]) for r in warm])
        for n in ("fieldbus", "ua", "mb", "spb", "http")
    }
    last = rows[-1]
    summary = {
        "duration_s": rows[-1]["t_s"],
        "samples": len(rows),
        "cpu_pct_mean": {k: round(v, 2) for k, v in cpu.items()},
        "clients": {
            k: last.get(k)
            for k in (
                "ua_sessions",
                "ua_notifications",
                "mb_requests",
                "mb_errors",
                "mqtt_messages",
            )
        },
        "checks": [{"ok": ok, "text": text} for ok, text in checks],
    }
    (out / "summary.json").write_text(json.dumps(summary, indent=2))
    print(f"soak: {rows[-1]['t_s'] / 60:.1f} min, {len(rows)} samples (CSV: {out / 'soak.csv'})")
    print(f"  mean CPU %: {summary['cpu_pct_mean']}")
    print(f"  clients: {summary['clients']}")
    for ok, text in checks:
        print(f"  {'ok  ' if ok else 'FAIL'} {text}")
    passed = all(ok for ok, _ in checks)
    print(f"verdict: {'PASS' if passed else 'FAIL'}")
    return 0 if passed else 1


def outage_peaks(rows: list[dict[str, Any]]) -> list[float]:
    """The journal file's largest size in each broker outage and the replay after it (until
    the next outage)."""
    peaks: list[float] = []
    down_before = False
    for r in rows:
        down = str(r.get("broker_up")) == "0"
        if down and not down_before:
            peaks.append(0.0)
        if peaks:
            peaks[-1] = max(peaks[-1], float(r["journal_kb"]))
        down_before = down
    return peaks


def median(values: list[float]) -> float:
    ordered = sorted(values)
    return ordered[len(ordered) // 2]


def mean(values: list[float]) -> float:
    return sum(values) / len(values) if values else 0.0


# == the client process ========================================================================
def clients(ports: dict[str, int], out: Path) -> None:
    import logging

    logging.basicConfig(level=logging.CRITICAL)  # the clients' own libraries: counted, not logged
    counts = {
        k: 0
        for k in (
            "ua_sessions",
            "ua_notifications",
            "ua_errors",
            "mb_requests",
            "mb_errors",
            "mqtt_messages",
        )
    }

    async def main() -> None:
        tasks = [asyncio.ensure_future(opcua_client(ports["opcua"], counts, i)) for i in range(2)]
        tasks.append(asyncio.ensure_future(modbus_churn(ports["modbus"], counts)))
        tasks.append(asyncio.ensure_future(modbus_idle(ports["modbus"], counts)))
        tasks.append(asyncio.ensure_future(report(counts, out)))
        mqtt_host(ports["mqtt"], counts)
        await asyncio.gather(*tasks)

    try:
        asyncio.run(main())
    except KeyboardInterrupt:
        pass


async def report(counts: dict[str, int], out: Path) -> None:
    while True:
        (out / "clients.json.tmp").write_text(json.dumps(counts))
        os.replace(out / "clients.json.tmp", out / "clients.json")
        await asyncio.sleep(1.0)


async def opcua_client(port: int, counts: dict[str, int], n: int) -> None:
    from asyncua import Client, ua

    await asyncio.sleep(3 * n)
    url = f"opc.tcp://127.0.0.1:{port}/"
    rng = random.Random(n)

    class Handler:
        def datachange_notification(self, node: Any, value: Any, data: Any) -> None:
            counts["ua_notifications"] += 1

    while True:
        client = Client(url, timeout=10)
        client.session_timeout = 30_000
        try:
            await client.connect()
            counts["ua_sessions"] += 1
            idx = await client.get_namespace_index("urn:fieldgate:soak")
            nodes = [
                client.get_node(f"ns={idx};s={cid}")
                for cid in [f"rs485/m5/ai{i}" for i in range(8)]
                + [f"rs485/m1/di{i}" for i in range(8)]
                + [f"rs485/m7/ai{i}" for i in range(5)]
                + [f"plant/m{m}/ai{i}" for m in (1, 2, 3, 4) for i in range(5)]
            ]
            sub = await client.create_subscription(500, Handler())
            await sub.subscribe_data_change(nodes)
            setpoint = client.get_node(f"ns={idx};s=rs485/m4/ao0")
            await setpoint.write_value(
                ua.DataValue(ua.Variant(rng.randint(0, 1000), ua.VariantType.Int16))
            )
            await asyncio.sleep(rng.uniform(10, 40))
            if rng.random() < 0.5:
                await client.disconnect()
            else:  # gone without a goodbye: the session and its subscription expire
                client.uaclient.protocol.transport.abort()  # type: ignore[union-attr]
                try:  # (this client's own tasks: its CloseSession cannot reach the server)
                    await asyncio.wait_for(client.disconnect(), 2)
                except Exception:
                    pass
        except Exception:
            counts["ua_errors"] += 1
            try:
                await client.disconnect()
            except Exception:
                pass
        await asyncio.sleep(rng.uniform(1, 5))


async def modbus_churn(port: int, counts: dict[str, int]) -> None:
    from pymodbus.client import AsyncModbusTcpClient

    rng = random.Random(7)
    while True:
        client = AsyncModbusTcpClient("127.0.0.1", port=port, timeout=3, retries=0)
        try:
            await client.connect()
            for fc in range(4):
                if fc == 0:
                    r = await client.read_coils(0, count=8)
                elif fc == 1:
                    r = await client.read_discrete_inputs(0, count=8)
                elif fc == 2:
                    r = await client.read_holding_registers(0, count=4)
                else:
                    r = await client.read_input_registers(0, count=20)
                counts["mb_requests"] += 1
                if r.isError():
                    counts["mb_errors"] += 1
            await client.write_register(1, rng.randint(0, 1000))
            await client.write_coil(rng.randint(0, 7), rng.random() < 0.5)
            counts["mb_requests"] += 2
        except Exception:
            counts["mb_errors"] += 1
        finally:
            client.close()
        await asyncio.sleep(0.25)


async def modbus_idle(port: int, counts: dict[str, int]) -> None:
    """Connections that say nothing: the front's idle timeout closes them."""
    held: list[asyncio.StreamWriter] = []
    while True:
        try:
            _, writer = await asyncio.open_connection("127.0.0.1", port)
            held.append(writer)
        except OSError:
            pass
        held = [w for w in held if not w.is_closing()][-8:]
        await asyncio.sleep(5)


def mqtt_host(port: int, counts: dict[str, int]) -> None:
    import paho.mqtt.client as mqtt
    from paho.mqtt.enums import CallbackAPIVersion

    client = mqtt.Client(CallbackAPIVersion.VERSION2, client_id="soak-host")
    client.reconnect_delay_set(1, 5)

    def on_connect(c: Any, *rest: Any) -> None:
        c.subscribe("spBv1.0/#", qos=0)

    def on_message(c: Any, userdata: Any, msg: Any) -> None:
        counts["mqtt_messages"] += 1

    client.on_connect = on_connect
    client.on_message = on_message
    client.connect_async("127.0.0.1", port)
    client.loop_start()


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=7200.0, help="seconds (default 2 h)")
    parser.add_argument("--sample-s", type=float, default=10.0)
    parser.add_argument("--warmup-s", type=float, default=300.0)
    parser.add_argument("--fault-every-s", type=float, default=120.0)
    parser.add_argument("--outage-every-s", type=float, default=1200.0)
    parser.add_argument("--outage-s", type=float, default=120.0)
    parser.add_argument("--rss-growth", type=float, default=0.05, help="allowed RSS growth (share)")
    parser.add_argument("--rss-slack-mb", type=float, default=2.0)
    parser.add_argument("--log-mb-per-hour", type=float, default=10.0)
    parser.add_argument("--out", default="soak-run", help="folder for soak.csv, summary.json, logs")
    parser.add_argument("--clients", help=argparse.SUPPRESS)
    parser.add_argument(
        "--from-csv", metavar="CSV", help="no run: the verdict on an earlier run's soak.csv"
    )
    args = parser.parse_args()
    if args.from_csv:
        with open(args.from_csv, newline="") as f:
            rows = [
                {k: (float(v) if k in NUMERIC else v) for k, v in row.items()}
                for row in csv.DictReader(f)
            ]
        return verdict(args, rows, Path(args.from_csv).parent)
    if args.clients:
        clients(json.loads(args.clients), Path(args.out))
        return 0
    return run(args)


if __name__ == "__main__":
    sys.exit(main())
