"""Run the Eclipse Sparkplug TCK's Edge Node profile headless against a fieldgate topology.

    .venv/bin/python bench/sparkplug_tck.py --tck PATH [--topology examples/sparkplug-modbus.yaml]
        [--device rs485-m5] [--tests SendDataTest ReceiveCommandTest ...] [--set PATH=VALUE ...]
        [--work DIR] [--json results.json]

Not run by CI (docs/sparkplug.md, "The Eclipse Sparkplug TCK"). PATH is the TCK extension's
classes: the ``sparkplug-tck-3.0.0.jar`` of the TCK's release (the HiveMQ extension zip), or a
directory of classes built from ``eclipse-sparkplug/sparkplug: tck/`` as its README says.
This script builds none of the TCK; it fetches, with Maven from Maven Central, HiveMQ CE
2022.1 (embedded) and the libraries the TCK needs at run time, compiles the small launcher
``bench/sparkplug_tck/TckBroker.java`` (embedded HiveMQ + the TCK extension + allow-all
authentication, which the TCK's guide installs as hivemq-allow-all-extension), and then
plays the part of the TCK's web console:

* HiveMQ with the TCK on 127.0.0.1:1883 and, for MultipleBrokerTest, Mosquitto on
  127.0.0.1:1884 (both ports are the TCK's own, hard-coded in its HostApplication), in a
  network namespace of their own (``unshare --net``, as root; ``--no-isolate`` to use the
  host's loopback): on a shared machine another program's client on 127.0.0.1:1883 would
  otherwise join the TCK's broker (a test gateway of someone else did, as edge node "line4");
* for each Edge Node test: ``NEW_TEST edge <test> <host> <group> <edge> <device>`` on
  ``SPARKPLUG_TCK/TEST_CONTROL``, ``fieldgate run --simulate`` of the topology with the
  test's ids (only the device under test exposed: the TCK's ``topics-ddata-topic`` assumes
  one device; one state dir for all tests, as one gateway restarted), the steps the console asks of a person (start
  the edge node before or after the test, stop it for SessionTerminationTest), and
  ``END_TEST`` after ``--data-s`` seconds for the data tests, which end by themselves only
  after an NDATA (this topology has no node-level metrics);
* the verdicts from ``SPARKPLUG_TCK/RESULT``, one line per assertion; every message of the
  edge node as seen by a QoS 1 subscriber (so the QoS shown is the one it was published with);
  for a FAIL of ``operational-behavior-data-commands-rebirth-action-1``, the DATA the TCK saw
  after its NCMD, with where fieldgate's own debug log puts them (handed to the MQTT client
  before or after the request arrived).

Logs of each run: ``WORK/<test>/fieldgate.log`` (debug level: every publish), ``WORK/hivemq.log``,
and the TCK's own ``WORK/SparkplugTCKresults.log`` (its ``report.py`` makes a summary of it).
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shlex
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import paho.mqtt.client as mqtt
from paho.mqtt.enums import CallbackAPIVersion
from ruamel.yaml import YAML

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(ROOT))  # the tests' Sparkplug decoder, independent of the front's code
from tests.sparkplug import spb  # noqa: E402

LAUNCHER = HERE / "sparkplug_tck" / "TckBroker.java"
TCK_PORT = 1883  # the TCK's HostApplication and Results connect to tcp://localhost:1883
SECOND_PORT = 1884  # MultipleBrokerTest's default second broker
CONTROL = "SPARKPLUG_TCK/TEST_CONTROL"
RESULT = "SPARKPLUG_TCK/RESULT"
LOG = "SPARKPLUG_TCK/LOG"

# Maven Central artifacts: HiveMQ CE embedded (the broker the TCK extends) and the TCK's
# run-time dependencies (tck/build.gradle.kts and gradle.properties of TCK 3.0.0)
ARTIFACTS = [
    ("com.hivemq", "hivemq-community-edition-embedded", "2022.1"),
    ("com.google.protobuf", "protobuf-java", "3.17.3"),
    ("org.eclipse.paho", "org.eclipse.paho.client.mqttv3", "1.2.5"),
    ("jakarta.annotation", "jakarta.annotation-api", "2.0.0"),
    ("com.fasterxml.jackson.core", "jackson-databind", "2.9.8"),
    ("com.google.guava", "guava", "31.1-jre"),
    ("com.hivemq", "hivemq-mqtt-client", "1.3.0"),
    ("org.jetbrains", "annotations", "21.0.1"),
    ("org.jboss.test-audit", "jboss-test-audit-api", "2.0.0.Final"),
]


@dataclass(frozen=True)
class Plan:
    """What the TCK's console asks of the person running a test."""

    edge_first: bool = False  # start fieldgate before NEW_TEST (it must be waiting for the host)
    stop_edge_after_births: bool = False  # SessionTerminationTest: stop the edge node
    end_after_s: float | None = None  # END_TEST after this long (the test does not end itself)
    second_broker: bool = False  # MultipleBrokerTest: a second broker in the front's list


PLANS: dict[str, Plan] = {
    "SessionEstablishmentTest": Plan(),
    "SessionTerminationTest": Plan(stop_edge_after_births=True),
    "SendDataTest": Plan(end_after_s=0.0),  # --data-s
    "SendComplexDataTest": Plan(end_after_s=0.0),
    "ReceiveCommandTest": Plan(),
    "PrimaryHostTest": Plan(edge_first=True),
    "MultipleBrokerTest": Plan(edge_first=True, second_broker=True),
}


@dataclass
class Seen:
    topic: str
    qos: int
    at: float
    payload: bytes


@dataclass
class Console:
    """The TCK web console's part: test control out, results and the wire in."""

    client_id: str = "fieldgate-tck-console"
    client: Any = None
    results: list[str] = field(default_factory=list)
    wire: list[Seen] = field(default_factory=list)
    lock: threading.Lock = field(default_factory=threading.Lock)

    def start(self) -> None:
        self.client = mqtt.Client(
            CallbackAPIVersion.VERSION2, client_id=self.client_id, protocol=mqtt.MQTTv311
        )
        ready = threading.Event()

        def on_connect(client: Any, userdata: Any, flags: Any, reason: Any, props: Any) -> None:
            client.subscribe([(RESULT, 1), (LOG, 0), ("spBv1.0/#", 1)])
            ready.set()

        def on_message(client: Any, userdata: Any, msg: Any) -> None:
            with self.lock:
                if msg.topic == RESULT:
                    self.results.append(msg.payload.decode("utf-8", "replace"))
                elif msg.topic.startswith("spBv1.0/"):
                    self.wire.append(Seen(msg.topic, msg.qos, time.time(), bytes(msg.payload)))

        self.client.on_connect = on_connect
        self.client.on_message = on_message
        self.client.connect("127.0.0.1", TCK_PORT, 30)
        self.client.loop_start()
        if not ready.wait(20):
            raise SystemExit("cannot connect to the TCK broker on 127.0.0.1:1883")

    def send(self, text: str) -> None:
        self.client.publish(CONTROL, text.encode(), qos=1).wait_for_publish(10)

    def mark(self) -> tuple[int, int]:
        with self.lock:
            return len(self.results), len(self.wire)

    def result_after(self, mark: int) -> str | None:
        with self.lock:
            for text in self.results[mark:]:
                if "OVERALL" in text:
                    return text
        return None

    def wire_after(self, mark: int) -> list[Seen]:
        with self.lock:
            return list(self.wire[mark:])

    def stop(self) -> None:
        self.client.disconnect()
        self.client.loop_stop()


def port_free(port: int) -> bool:
    with socket.socket() as s:
        s.setsockopt(
            socket.SOL_SOCKET, socket.SO_REUSEADDR, 1
        )  # TIME_WAIT of a last run is no user
        try:
            s.bind(("127.0.0.1", port))
        except OSError:
            return False
    return True


def prepare(work: Path, tck: Path) -> str:
    """Maven Central jars and the compiled launcher; the Java class path to run it with."""
    lib = work / "lib"
    if not (lib / "done").exists():
        lib.mkdir(parents=True, exist_ok=True)
        deps = "".join(
            f"<dependency><groupId>{g}</groupId><artifactId>{a}</artifactId><version>{v}</version></dependency>"
            for g, a, v in ARTIFACTS
        )
        (work / "pom.xml").write_text(
            '<project xmlns="http://maven.apache.org/POM/4.0.0"><modelVersion>4.0.0</modelVersion>'
            "<groupId>local</groupId><artifactId>fieldgate-tck-run</artifactId><version>1</version>"
            f"<dependencies>{deps}</dependencies></project>\n"
        )
        print("fetching HiveMQ CE embedded and the TCK's libraries with Maven ...", flush=True)
        subprocess.run(
            ["mvn", "-B", "-q", "-f", str(work / "pom.xml"), "dependency:copy-dependencies",
             f"-DoutputDirectory={lib}"],
            check=True,
        )  # fmt: skip
        (lib / "done").write_text("")
    classes = work / "launcher"
    cp = f"{lib}/*:{tck}"
    if not (classes / "TckBroker.class").exists():
        classes.mkdir(exist_ok=True)
        subprocess.run(
            ["javac", "-nowarn", "-d", str(classes), "-cp", cp, str(LAUNCHER)], check=True
        )
    return f"{classes}:{cp}"


def start_tck_broker(work: Path, classpath: str, host: str) -> tuple[subprocess.Popen[bytes], str]:
    """The broker, and the client id the console must use (see TckBroker.java)."""
    log = (work / "hivemq.log").open("wb")
    proc = subprocess.Popen(
        ["java", "-cp", classpath, "TckBroker", str(work / "hivemq"), str(TCK_PORT), host],
        stdout=log,
        stderr=subprocess.STDOUT,
        cwd=work,  # the TCK writes SparkplugTCKresults.log into its working directory
    )
    end = time.monotonic() + 120
    while time.monotonic() < end:
        if proc.poll() is not None:
            raise SystemExit(f"the TCK broker stopped: see {work / 'hivemq.log'}")
        text = (work / "hivemq.log").read_text(errors="replace")
        if "TCK broker ready" in text:
            return proc, re.findall(r"console client id: (\S+)", text)[0]
        time.sleep(0.2)
    proc.terminate()
    raise SystemExit("the TCK broker did not start within 120 s")


def start_second_broker(work: Path) -> subprocess.Popen[bytes]:
    mosquitto = shutil.which("mosquitto") or "/usr/sbin/mosquitto"
    conf = work / "mosquitto.conf"
    conf.write_text(f"listener {SECOND_PORT} 127.0.0.1\nallow_anonymous true\npersistence false\n")
    proc = subprocess.Popen(
        [mosquitto, "-c", str(conf)],
        stdout=subprocess.DEVNULL,
        stderr=(work / "mosquitto.log").open("wb"),
    )
    end = time.monotonic() + 10
    while port_free(SECOND_PORT):
        if time.monotonic() > end or proc.poll() is not None:
            raise SystemExit("the second broker (mosquitto) did not start")
        time.sleep(0.05)
    return proc


def edge_topology(
    base: Path, dest: Path, device: str, host: str, group: str, edge: str, second: bool
) -> None:
    """The topology under test with the TCK's ids, its brokers, only ``device`` exposed."""
    yaml = YAML()
    topo = yaml.load(base.read_text())
    back, _, address = device.rpartition("-m")
    prefix = f"{back}/m{address}/"
    fronts = [f for f in topo["fronts"] if f.get("type") == "sparkplug"]
    if len(fronts) != 1:
        raise SystemExit(f"{base}: needs exactly one sparkplug front")
    front = fronts[0]
    topo["fronts"] = [front]  # other fronts (a CANopen head) need hardware this run has not
    front["group_id"] = group
    front["edge_node_id"] = edge
    front["primary_host_id"] = host
    front["brokers"] = [{"host": "127.0.0.1", "port": TCK_PORT}]
    if second:
        front["brokers"].append({"host": "127.0.0.1", "port": SECOND_PORT})
    front["expose"] = [prefix + "*"]
    front["writable"] = [w for w in front.get("writable", []) if w.startswith(prefix)]
    # one state dir for every test: the same gateway restarted, its bdSeq persisted (the TCK's
    # Monitor checks the +1 per CONNECT across tests)
    topo["gateway"]["state_dir"] = str(dest.parent.parent / "state")
    with dest.open("w") as f:
        yaml.dump(topo, f)


def start_edge(topology: Path, extra: list[str]) -> subprocess.Popen[bytes]:
    log = (topology.parent / "fieldgate.log").open("ab")
    cmd = [sys.executable, "-m", "fieldgate", "run", str(topology), "--simulate",
           "--log-level", "debug", *extra]  # fmt: skip
    return subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, cwd=ROOT)


def stop_edge(proc: subprocess.Popen[bytes] | None) -> None:
    if proc is not None and proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(20)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


VERDICT = re.compile(r"^\s*(\S+): (.*?);?\s*$")  # keys may be "Monitor:<id>"


def parse(result: str) -> dict[str, str]:
    out: dict[str, str] = {}
    for line in result.splitlines():
        m = VERDICT.match(line)
        if m and "Summary Test Results" not in line:
            out[m.group(1).strip()] = m.group(2).strip()
    return out


def rebirth_race(seen: list[Seen], log_file: Path, group: str, edge: str) -> list[str]:
    """For each DATA the TCK saw after its rebirth NCMD and before the new NBIRTH: was it
    handed to the MQTT client before the gateway received the request (the TCK's race)?"""
    ncmd = next((i for i, m in enumerate(seen) if m.topic == f"spBv1.0/{group}/NCMD/{edge}"), None)
    if ncmd is None:
        return ["no NCMD seen on the wire"]
    late = []
    for m in seen[ncmd + 1 :]:
        kind = m.topic.split("/")[2]
        if kind == "NBIRTH":
            break
        if kind in ("DDATA", "NDATA"):
            late.append(m)
    lines = [f"{len(late)} DATA message(s) between the NCMD and the new NBIRTH on the wire"]
    log = log_file.read_text(errors="replace").splitlines()
    received = next(
        (i for i, line in enumerate(log) if f"received spBv1.0/{group}/NCMD/{edge}" in line), None
    )
    for m in late:
        seq = spb.decode(m.payload).seq
        handed = next(
            (
                i
                for i, line in enumerate(log)
                if f"publish {m.topic} seq={seq} " in line and (received is None or i < received)
            ),
            None,
        )
        where = (
            "handed to the MQTT client before the gateway received the NCMD"
            if handed is not None and received is not None
            else "NOT found before the NCMD in fieldgate's log"
        )
        lines.append(f"  {m.topic} seq={seq} qos={m.qos}: {where}")
    return lines


def run_test(
    name: str, args: argparse.Namespace, console: Console, work: Path
) -> tuple[dict[str, str], list[Seen], list[str]]:
    plan = PLANS[name]
    tdir = work / name
    shutil.rmtree(tdir, ignore_errors=True)
    tdir.mkdir(parents=True)
    topo = tdir / "topology.yaml"
    edge_topology(
        args.topology, topo, args.device, args.host, args.group, args.edge, plan.second_broker
    )
    params = f"{args.host} {args.group} {args.edge} {args.device}"
    if plan.second_broker:
        params += f" tcp://localhost:{SECOND_PORT}"
    extra = [x for s in args.set for x in ("--set", s)]
    results_mark, wire_mark = console.mark()
    edge = None
    try:
        if plan.edge_first:
            edge = start_edge(topo, extra)
            wait_log(tdir / "fieldgate.log", "waiting for primary host", 60)
        console.send(f"NEW_TEST edge {name} {params}")
        if not plan.edge_first:
            time.sleep(1.0)  # the TCK's simulated host application comes online
            edge = start_edge(topo, extra)
        if plan.stop_edge_after_births:
            wait_wire(console, wire_mark, f"spBv1.0/{args.group}/DBIRTH/{args.edge}/", 60)
            time.sleep(1.0)
            stop_edge(edge)
        deadline = time.monotonic() + args.timeout
        if plan.end_after_s is not None:
            wait_wire(console, wire_mark, f"spBv1.0/{args.group}/DBIRTH/{args.edge}/", 60)
            time.sleep(args.data_s)
            console.send("END_TEST")
        while console.result_after(results_mark) is None and time.monotonic() < deadline:
            time.sleep(0.2)
        if console.result_after(results_mark) is None:
            console.send("END_TEST")  # as the console's stop button does
            end = time.monotonic() + 15
            while console.result_after(results_mark) is None and time.monotonic() < end:
                time.sleep(0.2)
    finally:
        stop_edge(edge)
    result = console.result_after(results_mark)
    verdicts = parse(result) if result else {"OVERALL": "NO RESULT (timed out)"}
    seen = console.wire_after(wire_mark)
    notes: list[str] = []
    if verdicts.get("operational-behavior-data-commands-rebirth-action-1", "").startswith("FAIL"):
        notes = rebirth_race(seen, tdir / "fieldgate.log", args.group, args.edge)
    (tdir / "result.txt").write_text(result or "")
    return verdicts, seen, notes


def wait_log(path: Path, text: str, timeout: float) -> None:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if path.exists() and text in path.read_text(errors="replace"):
            return
        time.sleep(0.1)
    raise SystemExit(f"fieldgate did not log {text!r} within {timeout} s: see {path}")


def wait_wire(console: Console, mark: int, prefix: str, timeout: float) -> None:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if any(m.topic.startswith(prefix) for m in console.wire_after(mark)):
            return
        time.sleep(0.1)
    raise SystemExit(f"no {prefix}... within {timeout} s")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--tck", type=Path, required=True, help="the TCK's jar or classes directory")
    ap.add_argument("--topology", type=Path, default=ROOT / "examples" / "sparkplug-modbus.yaml")
    ap.add_argument("--device", default="rs485-m5", help="the device under test (exposed alone)")
    ap.add_argument("--host", default="fieldgate_tck_host", help="primary host application id")
    ap.add_argument("--group", default=None, help="default: the topology's group_id")
    ap.add_argument("--edge", default=None, help="default: the topology's edge node id")
    ap.add_argument("--tests", nargs="*", default=list(PLANS), choices=list(PLANS))
    ap.add_argument("--set", action="append", default=[], help="passed to fieldgate run --set")
    ap.add_argument("--data-s", type=float, default=10.0, help="length of the data tests")
    ap.add_argument("--timeout", type=float, default=90.0, help="per test, then END_TEST")
    ap.add_argument("--work", type=Path, default=None, help="default: a new temporary folder")
    ap.add_argument("--json", type=Path, default=None, help="write every verdict here")
    ap.add_argument(
        "--no-isolate",
        dest="isolate",
        action="store_false",
        help="run on the host's loopback instead of a network namespace of its own",
    )
    ap.add_argument("--inside", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    args.tck = args.tck.resolve()
    args.topology = args.topology.resolve()
    front = next(
        f for f in YAML().load(args.topology.read_text())["fronts"] if f["type"] == "sparkplug"
    )
    args.group = args.group or front["group_id"]
    args.edge = (
        args.edge
        or front.get("edge_node_id")
        or YAML().load(args.topology.read_text())["gateway"]["name"]
    )
    work = (args.work or Path(tempfile.mkdtemp(prefix="fieldgate-tck-"))).resolve()
    work.mkdir(parents=True, exist_ok=True)
    classpath = prepare(work, args.tck)  # before the namespace: Maven needs the network
    if args.isolate and not args.inside:
        if os.geteuid() != 0 or shutil.which("unshare") is None:
            raise SystemExit("--isolate needs root and unshare (or run with --no-isolate)")
        inner = [sys.executable, *sys.argv, "--inside", "--work", str(work)]
        script = "ip link set lo up && exec " + " ".join(shlex.quote(a) for a in inner)
        return subprocess.run(["unshare", "--net", "sh", "-c", script]).returncode
    for port in (TCK_PORT, SECOND_PORT):
        if not port_free(port):
            raise SystemExit(f"127.0.0.1:{port} is in use: the TCK needs it (hard-coded)")
    broker, console_id = start_tck_broker(work, classpath, args.host)
    second = start_second_broker(work) if "MultipleBrokerTest" in args.tests else None
    console = Console(client_id=console_id)
    report: dict[str, Any] = {}
    try:
        console.start()
        for name in args.tests:
            print(f"== {name}", flush=True)
            verdicts, seen, notes = run_test(name, args, console, work)
            ddata = [m for m in seen if m.topic.split("/")[2] == "DDATA"]
            qos1 = sum(1 for m in ddata if m.qos == 1)
            for key, verdict in sorted(verdicts.items(), key=lambda kv: kv[0] != "OVERALL"):
                word = "NOT EXECUTED" if verdict.startswith("NOT EXECUTED") else verdict.split()[0]
                detail = verdict[len(word) :].strip()
                print(f"  {word:<13} {key}" + (f"  ({detail})" if detail else ""))
            print(f"  wire: {len(ddata)} DDATA, {qos1} at QoS 1")
            for line in notes:
                print(f"  {line}")
            report[name] = {"verdicts": verdicts, "ddata": len(ddata), "ddata_qos1": qos1,
                            "notes": notes}  # fmt: skip
    finally:
        console.stop() if console.client is not None else None
        for proc in (second, broker):
            if proc is not None:
                proc.terminate()
                proc.wait(30)
    if args.json:
        args.json.write_text(json.dumps(report, indent=2))
    print(f"logs: {work}")
    failed = [n for n, r in report.items() if r["verdicts"].get("OVERALL", "").startswith("FAIL")]
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
