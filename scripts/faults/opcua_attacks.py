#!/usr/bin/env python3
"""The OPC UA front under a hostile client: issue 29's cases, each a probe with its outcome.

Run:  .venv/bin/python scripts/faults/opcua_attacks.py [--case d2,d7] [--flood-mb 128]
      [--idle 500] [--items 10000] [--lifetime 30]          (about two minutes for all)

A real gateway (``fieldgate run examples/plant-northbound.yaml --simulate``, its listeners
moved to free loopback ports, the status API on) runs as a child process with its log in a
file; this process attacks its OPC UA endpoint from 127.0.0.0/8 and prints one line per
case: what the server answered (ERR and its status, a close, nothing), how long it took,
what it cost the gateway (RSS of its processes, log growth, tracebacks) and whether a
fresh client was still served. Each case has an expectation; the verdict is the last line.
docs/reliability.md ("OPC UA under a hostile client") has the figures before and after.

The cases (issue 29): D1 expired subscriptions with publishing interval 0; D2 chunk floods
(0x7FFFFFFF after Hello, without Hello), a chunk over the negotiated buffer, a message over
MaxMessageSize, over MaxChunkCount; D4 idle sockets, held sessions, another peer's crowd;
D7 Hello buffer sizes 0 and 1; D8 an EndpointUrl length of 0x7FFFFFFF and one over 4096;
D9 refused identity tokens in the counters; the framing cases (not Hello first, Hello
twice, a chunk shorter than its header); the subscription limits (publishing and sampling
intervals, monitored items per subscription and per session, subscriptions per session,
queue size, session timeout).
"""

from __future__ import annotations

import argparse
import asyncio
import json
import logging
import os
import signal
import subprocess
import sys
import tempfile
import time
import urllib.request
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))
import uaraw  # noqa: E402  (scripts/faults)

ROOT = Path(__file__).resolve().parents[2]
sys.path.append(str(ROOT / "tests"))
from netkit import free_port  # noqa: E402  (tests/netkit.py: one helper for tests, benches and scripts)

EXAMPLE = ROOT / "examples" / "plant-northbound.yaml"
NAMESPACE = "urn:fieldgate:line4"
MB = 1024 * 1024


@dataclass
class GatewayProcess:
    """``fieldgate run`` of the example in a child process, its log in a file."""

    proc: subprocess.Popen[bytes]
    ua_port: int
    http_port: int
    log_path: Path
    state: tempfile.TemporaryDirectory[str]
    fresh_user: tuple[str, str] | None = None

    @classmethod
    async def start(
        cls,
        sets: tuple[str, ...] = (),
        example: Path = EXAMPLE,
        fresh_user: tuple[str, str] | None = None,
    ) -> GatewayProcess:
        """Started, and serving a client (``fresh_user``: name and password, when the
        topology has users)."""
        ua_port, http_port, mb_port = free_port(), free_port(), free_port()
        state = tempfile.TemporaryDirectory(prefix="opcua-attacks-")
        log_path = Path(state.name) / "gateway.log"
        args = [
            sys.executable,
            "-m",
            "fieldgate",
            "run",
            str(example),
            "--simulate",
            "--http",
            f"127.0.0.1:{http_port}",
            "--set",
            f"fronts.opcua.listen=127.0.0.1:{ua_port}",
            "--set",
            f"fronts.modbus.listen=127.0.0.1:{mb_port}",
            "--set",
            f"gateway.state_dir={state.name}",
            "--set",
            f"fronts.can.channel=opcua-attacks-{os.getpid()}-{ua_port}",
            "--set",
            f"fronts.plant.brokers=[{{host: 127.0.0.1, port: {free_port()}}}]",
        ]
        for item in sets:
            args += ["--set", item]
        with log_path.open("wb") as log:
            proc = subprocess.Popen(args, stdout=log, stderr=subprocess.STDOUT, cwd=state.name)
        gateway = cls(proc, ua_port, http_port, log_path, state)
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            if proc.poll() is not None:
                raise RuntimeError(f"the gateway exited: {log_path.read_text()[-2000:]}")
            if await fresh_client(ua_port, tries=1, timeout=2, user=fresh_user) == 1:
                gateway.fresh_user = fresh_user
                return gateway
            await asyncio.sleep(0.5)
        gateway.stop()
        raise RuntimeError("the gateway's OPC UA endpoint did not answer within 60 s")

    def stop(self) -> None:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(timeout=20)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self.state.cleanup()

    def pids(self) -> list[int]:
        """The gateway and every process under it (north-facing children included)."""
        found = [self.proc.pid]
        for pid in found:
            try:
                text = Path(f"/proc/{pid}/task/{pid}/children").read_text()
            except OSError:
                continue
            found += [int(p) for p in text.split()]
        return found

    def rss_mb(self) -> float:
        total = 0
        for pid in self.pids():
            try:
                for line in Path(f"/proc/{pid}/status").read_text().splitlines():
                    if line.startswith("VmRSS:"):
                        total += int(line.split()[1])
            except OSError:
                pass
        return total / 1024

    def log_size(self) -> int:
        return self.log_path.stat().st_size

    def log_text(self, since: int = 0) -> str:
        with self.log_path.open("rb") as f:
            f.seek(since)
            return f.read().decode("utf-8", "replace")

    def status(self) -> dict[str, Any]:
        url = f"http://127.0.0.1:{self.http_port}/api/v1/status"
        with urllib.request.urlopen(url, timeout=5) as reply:
            return json.loads(reply.read())  # type: ignore[no-any-return]

    def counters(self) -> dict[str, int]:
        return dict(self.status()["fronts"]["opcua"].get("counters", {}))


async def fresh_client(
    port: int, tries: int = 10, timeout: float = 5.0, user: tuple[str, str] | None = None
) -> int:
    """How many of ``tries`` fresh clients (connect, session, read a point, close) are served."""
    from asyncua import Client

    # the client library's own complaints (not the server's: a test may run both in one process)
    logging.getLogger("asyncua.client").setLevel(logging.CRITICAL)
    served = 0
    for _ in range(tries):
        client = Client(f"opc.tcp://127.0.0.1:{port}/", timeout=timeout)
        if user is not None:
            client.set_user(user[0])
            client.set_password(user[1])
        try:
            async with asyncio.timeout(timeout * 2):
                await client.connect()
                try:
                    idx = await client.get_namespace_index(NAMESPACE)
                    await client.get_node(f"ns={idx};s=rs485/m1/di0").read_value()
                    served += 1
                finally:
                    await client.disconnect()
        except Exception:  # noqa: BLE001  (any failure is "not served")
            pass
    return served


@dataclass
class Outcome:
    case: str
    text: str
    ok: bool
    figures: dict[str, Any] = field(default_factory=dict)

    def line(self) -> str:
        return f"{'ok  ' if self.ok else 'FAIL'} {self.case:24} {self.text}"


@dataclass
class Costs:
    """What a case cost the gateway: RSS peak over the start, log growth, tracebacks."""

    gateway: GatewayProcess
    rss0: float = 0.0
    peak: float = 0.0
    log0: int = 0
    _task: asyncio.Task[None] | None = None

    async def __aenter__(self) -> Costs:
        self.rss0 = self.peak = self.gateway.rss_mb()
        self.log0 = self.gateway.log_size()
        self._task = asyncio.create_task(self._watch())
        return self

    async def _watch(self) -> None:
        while True:
            self.peak = max(self.peak, self.gateway.rss_mb())
            await asyncio.sleep(0.05)

    async def __aexit__(self, *exc: object) -> None:
        if self._task is not None:
            self._task.cancel()
        self.peak = max(self.peak, self.gateway.rss_mb())

    @property
    def rss_growth(self) -> float:
        return self.peak - self.rss0

    @property
    def log_growth(self) -> int:
        return self.gateway.log_size() - self.log0

    @property
    def tracebacks(self) -> int:
        return self.gateway.log_text(self.log0).count("Traceback")

    def text(self) -> str:
        return (
            f"RSS +{self.rss_growth:.1f} MB (peak), log +{self.log_growth / 1024:.0f} KB, "
            f"{self.tracebacks} tracebacks"
        )


Case = Callable[[GatewayProcess, argparse.Namespace], Awaitable[Outcome]]
CASES: dict[str, Case] = {}


def case(name: str) -> Callable[[Case], Case]:
    def register(fn: Case) -> Case:
        CASES[name] = fn
        return fn

    return register


def url(gw: GatewayProcess) -> str:
    return f"opc.tcp://127.0.0.1:{gw.ua_port}/"


async def refused(
    gw: GatewayProcess, name: str, parts: list[bytes], expect: str, wait: float = 3.0
) -> Outcome:
    """One exchange whose expected answer is ERR ``expect`` then the close."""
    async with Costs(gw) as costs:
        answer = await uaraw.exchange("127.0.0.1", gw.ua_port, parts, wait=wait)
    ok = answer.kind == "ERR" and answer.status_name == expect and costs.tracebacks == 0
    return Outcome(
        name,
        f"{answer} after {answer.seconds * 1e3:.1f} ms ({answer.sent:,} bytes sent); "
        f"{costs.text()}; expected ERR {expect}",
        ok,
        {"answer": str(answer), "ms": answer.seconds * 1e3, "tracebacks": costs.tracebacks},
    )


# -- D2: chunk floods and message limits ------------------------------------------------------
async def flood(gw: GatewayProcess, args: argparse.Namespace, with_hello: bool) -> Outcome:
    name = "d2-flood-after-hello" if with_hello else "d2-flood-without-hello"
    block = b"\x00" * MB
    parts = [uaraw.hello(url(gw))] if with_hello else []
    parts += [uaraw.header(b"MSG", b"F", 0x7FFF_FFFF) + block[8:]]
    parts += [block] * (args.flood_mb - 1)
    expect = "Bad_TcpMessageTooLarge" if with_hello else "Bad_TcpMessageTypeInvalid"
    async with Costs(gw) as costs:
        answer = await uaraw.exchange("127.0.0.1", gw.ua_port, parts, wait=5.0)
        await asyncio.sleep(0.3)
    served = await fresh_client(gw.ua_port, tries=3, user=gw.fresh_user)
    ok = (
        answer.kind == "ERR"
        and answer.status_name == expect
        and costs.rss_growth < 16
        and served == 3
    )
    return Outcome(
        name,
        f"{args.flood_mb} MB offered: {answer} after {answer.seconds * 1e3:.1f} ms, "
        f"{answer.sent / MB:.1f} MB taken; {costs.text()}; fresh client {served}/3; "
        f"expected ERR {expect}, RSS < +16 MB",
        ok,
        {"rss_mb": costs.rss_growth, "ms": answer.seconds * 1e3, "sent_mb": answer.sent / MB},
    )


@case("d2-flood-after-hello")
async def d2_flood_hello(gw: GatewayProcess, args: argparse.Namespace) -> Outcome:
    return await flood(gw, args, True)


@case("d2-flood-without-hello")
async def d2_flood_no_hello(gw: GatewayProcess, args: argparse.Namespace) -> Outcome:
    return await flood(gw, args, False)


@case("d2-chunk-over-buffer")
async def d2_chunk_over_buffer(gw: GatewayProcess, args: argparse.Namespace) -> Outcome:
    ack = await uaraw.exchange("127.0.0.1", gw.ua_port, [uaraw.hello(url(gw))], wait=2)
    size = (ack.ack[1] if ack.ack else 65535) + 1
    chunk = uaraw.header(b"MSG", b"F", size) + b"\x00" * (size - 8)
    return await refused(
        gw, "d2-chunk-over-buffer", [uaraw.hello(url(gw)), chunk], "Bad_TcpMessageTooLarge"
    )


async def chunked(gw: GatewayProcess, name: str, body: int, count: int, expect: str) -> Outcome:
    """``count`` intermediate chunks of ``body`` bytes on an open secure channel."""
    try:
        reader, writer, channel, token = await uaraw.open_channel("127.0.0.1", gw.ua_port)
    except (ConnectionError, OSError, TimeoutError) as exc:
        return Outcome(name, f"no secure channel: {exc}", False)
    parts = [
        uaraw.secure_chunk(channel, token, 2 + i, 2, b"\x00" * body, b"C") for i in range(count)
    ]
    async with Costs(gw) as costs:
        answer = await uaraw.exchange_on(reader, writer, parts, wait=3.0)
    ok = answer.kind == "ERR" and answer.status_name == expect and costs.tracebacks == 0
    return Outcome(
        name,
        f"{count} chunks of {body:,} bytes offered: {answer} after {answer.seconds * 1e3:.0f} ms "
        f"({answer.sent / MB:.1f} MB sent); {costs.text()}; expected ERR {expect}",
        ok,
        {"answer": str(answer), "rss_mb": costs.rss_growth},
    )


@case("d2-message-over-max")
async def d2_message_over_max(gw: GatewayProcess, args: argparse.Namespace) -> Outcome:
    return await chunked(gw, "d2-message-over-max", 65_000, 160, "Bad_RequestTooLarge")


@case("d2-too-many-chunks")
async def d2_too_many_chunks(gw: GatewayProcess, args: argparse.Namespace) -> Outcome:
    return await chunked(gw, "d2-too-many-chunks", 16, 2_000, "Bad_RequestTooLarge")


# -- framing ----------------------------------------------------------------------------------
@case("first-not-hello")
async def first_not_hello(gw: GatewayProcess, args: argparse.Namespace) -> Outcome:
    return await refused(
        gw, "first-not-hello", [uaraw.open_secure_channel()], "Bad_TcpMessageTypeInvalid"
    )


@case("http-request")
async def http_request(gw: GatewayProcess, args: argparse.Namespace) -> Outcome:
    return await refused(
        gw,
        "http-request",
        [b"GET / HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n"],
        "Bad_TcpMessageTypeInvalid",
    )


@case("hello-twice")
async def hello_twice(gw: GatewayProcess, args: argparse.Namespace) -> Outcome:
    h = uaraw.hello(url(gw))
    return await refused(gw, "hello-twice", [h, h], "Bad_TcpMessageTypeInvalid")


@case("chunk-shorter-than-header")
async def short_chunk(gw: GatewayProcess, args: argparse.Namespace) -> Outcome:
    return await refused(
        gw,
        "chunk-shorter-than-header",
        [uaraw.hello(url(gw)), uaraw.header(b"MSG", b"F", 10) + b"\x00\x00"],
        "Bad_DecodingError",
    )


# -- D7, D8: Hello fields ---------------------------------------------------------------------
@case("d7-hello-buffers")
async def d7_hello_buffers(gw: GatewayProcess, args: argparse.Namespace) -> Outcome:
    lines, ok = [], True
    for fields in (
        {"receive_buffer": 0},
        {"send_buffer": 0},
        {"receive_buffer": 1, "send_buffer": 1},
        {"receive_buffer": 8191},
        {"max_message": 1},
    ):
        one = await refused(gw, "d7", [uaraw.hello(url(gw), **fields)], "Bad_TcpNotEnoughResources")
        name = ",".join(f"{k}={v}" for k, v in fields.items())
        lines.append(f"{name}: {one.figures.get('answer')}")
        ok = ok and one.ok
    return Outcome("d7-hello-buffers", "; ".join(lines), ok)


@case("d8-endpoint-url")
async def d8_endpoint_url(gw: GatewayProcess, args: argparse.Namespace) -> Outcome:
    lines, ok = [], True
    for label, message in (
        ("length 0x7FFFFFFF", uaraw.hello(url(gw), url_length=0x7FFF_FFFF)),
        ("length -2", uaraw.hello(url(gw), url_length=-2)),
        ("4097 bytes", uaraw.hello("opc.tcp://x/" + "a" * (4097 - 12))),
    ):
        one = await refused(gw, "d8", [message], "Bad_TcpEndpointUrlInvalid")
        lines.append(f"{label}: {one.figures.get('answer')} ({one.figures.get('ms', 0):.1f} ms)")
        ok = ok and one.ok
    return Outcome("d8-endpoint-url", "; ".join(lines), ok)


# -- D4: crowds -------------------------------------------------------------------------------
async def hold_sockets(port: int, count: int, source: str | None = None) -> list[Any]:
    held = []
    for _ in range(count):
        try:
            held.append(await uaraw.open_connection("127.0.0.1", port, source))
        except OSError:
            break
    return held


async def closed_count(held: list[Any]) -> int:
    """How many of the held connections the server has closed (read to their end)."""
    n = 0
    for reader, _ in held:
        try:
            while not reader.at_eof():
                async with asyncio.timeout(0.001):
                    if not await reader.read(65536):
                        break
            n += 1
        except TimeoutError:
            pass
        except (ConnectionError, OSError):
            n += 1
    return n


@case("d4-idle-sockets")
async def d4_idle(gw: GatewayProcess, args: argparse.Namespace) -> Outcome:
    async with Costs(gw) as costs:
        held = await hold_sockets(gw.ua_port, args.idle)
        started = time.monotonic()
        served = await fresh_client(gw.ua_port, tries=10, user=gw.fresh_user)
        during = time.monotonic() - started
        closed_at = None
        while time.monotonic() - started < 45:
            if await closed_count(held) == len(held):
                closed_at = time.monotonic() - started
                break
            await asyncio.sleep(0.5)
        still = len(held) - await closed_count(held)
        for _, writer in held:
            writer.close()
    ok = served >= 9 and still == 0 and closed_at is not None
    return Outcome(
        "d4-idle-sockets",
        f"{len(held)} silent sockets: fresh clients served {served}/10 while they were held "
        f"({during:.1f} s); all closed by the server after "
        f"{'never' if closed_at is None else f'{closed_at:.1f} s'} ({still} still open); "
        f"{costs.text()}",
        ok,
        {"served": served, "closed_s": closed_at},
    )


@case("d4-other-peer-crowd")
async def d4_other_peer(gw: GatewayProcess, args: argparse.Namespace) -> Outcome:
    """Another address (127.0.0.2) fills the server with Hello-ed, silent connections."""
    held = []
    for _ in range(200):
        try:
            reader, writer = await uaraw.open_connection("127.0.0.1", gw.ua_port, "127.0.0.2")
        except OSError:
            break
        writer.write(uaraw.hello(url(gw)))
        held.append((reader, writer))
    await asyncio.sleep(0.5)
    served = await fresh_client(gw.ua_port, tries=10, user=gw.fresh_user)
    open_ = len(held) - await closed_count(held)
    for _, writer in held:
        writer.close()
    return Outcome(
        "d4-other-peer-crowd",
        f"{len(held)} connections from 127.0.0.2 (Hello, then silent): {open_} kept by the "
        f"server, fresh clients from 127.0.0.1 served {served}/10",
        served >= 9,
        {"served": served, "kept": open_},
    )


@case("d4-sessions")
async def d4_sessions(gw: GatewayProcess, args: argparse.Namespace) -> Outcome:
    from asyncua import Client

    clients = []
    revised = []
    async with Costs(gw) as costs:
        for _ in range(args.sessions):
            client = Client(url(gw), timeout=5, watchdog_intervall=30)
            client.session_timeout = 600_000
            try:
                await client.connect()
                revised.append(client.session_timeout)
                clients.append(client)
            except Exception:  # noqa: BLE001  (refused or evicted: counted below)
                pass
        served = await fresh_client(gw.ua_port, tries=10, user=gw.fresh_user)
        alive = 0
        for client in clients:
            try:
                async with asyncio.timeout(3):
                    await client.get_node("i=2258").read_value()  # Server_ServerStatus_CurrentTime
                alive += 1
            except Exception:  # noqa: BLE001
                pass
        for client in clients:
            try:
                async with asyncio.timeout(2):
                    await client.disconnect()
            except Exception:  # noqa: BLE001
                pass
    timeout = max(revised) if revised else 0
    ok = served >= 9 and timeout <= 600_000
    return Outcome(
        "d4-sessions",
        f"{args.sessions} sessions asked for 600,000 ms: {len(clients)} opened, session timeout "
        f"revised to {timeout:,.0f} ms, {alive} still served at the end; fresh clients "
        f"served {served}/10; {costs.text()}",
        ok,
        {"served": served, "revised_ms": timeout, "alive": alive},
    )


# -- D1 and the subscription limits --------------------------------------------------------
async def raw_session(gw: GatewayProcess) -> Any:
    from asyncua import Client

    # (asyncua's client probes the server every second and gives up after 1 s: a server busy
    # creating thousands of items for this very connection answers it later than that)
    client = Client(url(gw), timeout=30, watchdog_intervall=30)
    await client.connect()
    return client


async def request(client: Any, req: Any, response_type: Any) -> Any:
    from asyncua.ua.ua_binary import struct_from_binary

    data = await client.uaclient.protocol.send_request(req)
    return struct_from_binary(response_type, data)


async def create_subscription(
    client: Any, interval: float, lifetime: int, keepalive: int = 10
) -> Any:
    from asyncua import ua

    req = ua.CreateSubscriptionRequest()
    req.Parameters = ua.CreateSubscriptionParameters(
        RequestedPublishingInterval=interval,
        RequestedLifetimeCount=lifetime,
        RequestedMaxKeepAliveCount=keepalive,
        MaxNotificationsPerPublish=0,
        PublishingEnabled=True,
        Priority=0,
    )
    return (await request(client, req, ua.CreateSubscriptionResponse)).Parameters


async def monitor(
    client: Any, sub_id: int, nodes: list[Any], count: int, sampling: float = 0.0, queue: int = 1
) -> list[Any]:
    from asyncua import ua

    results: list[Any] = []
    for start in range(0, count, 1000):
        req = ua.CreateMonitoredItemsRequest()
        req.Parameters.SubscriptionId = sub_id
        req.Parameters.TimestampsToReturn = ua.TimestampsToReturn.Both
        for i in range(start, min(count, start + 1000)):
            item = ua.MonitoredItemCreateRequest()
            item.ItemToMonitor = ua.ReadValueId(NodeId=nodes[i % len(nodes)], AttributeId=13)
            item.MonitoringMode = ua.MonitoringMode.Reporting
            item.RequestedParameters = ua.MonitoringParameters(
                ClientHandle=i, SamplingInterval=sampling, QueueSize=queue, DiscardOldest=True
            )
            req.Parameters.ItemsToCreate.append(item)
        try:
            results += (await request(client, req, ua.CreateMonitoredItemsResponse)).Results
        except ua.UaStatusCodeError as exc:  # the whole call refused: no item of it created
            failed = ua.MonitoredItemCreateResult()
            failed.StatusCode = ua.StatusCode(exc.code)
            results += [failed] * len(req.Parameters.ItemsToCreate)
    return results


async def channel_nodes(client: Any) -> list[Any]:
    from asyncua import ua

    idx = await client.get_namespace_index(NAMESPACE)
    ids = [
        f"rs485/m{m}/{k}{i}"
        for m, k, n in ((1, "di", 8), (5, "ai", 4), (6, "di", 8), (6, "do", 8), (4, "ao", 4))
        for i in range(n)
    ]
    return [ua.NodeId(cid, idx) for cid in ids]


def good(results: list[Any]) -> int:
    return sum(1 for r in results if r.StatusCode.is_good())


async def publish_slowly(client: Any, stop: asyncio.Event) -> None:
    """A slow consumer: one Publish request a second (no acknowledgements), never awaited."""
    from asyncua import ua

    pending: set[asyncio.Task[Any]] = set()
    while not stop.is_set():
        req = ua.PublishRequest()
        req.RequestHeader.TimeoutHint = 10_000
        task = asyncio.create_task(client.uaclient.protocol.send_request(req, timeout=10))
        task.add_done_callback(lambda t: t.cancelled() or t.exception())
        pending.add(task)
        try:
            async with asyncio.timeout(1.0):
                await stop.wait()
        except TimeoutError:
            pass
    for task in pending:
        task.cancel()


async def subscription_gone(client: Any, sub_id: int, nodes: list[Any]) -> bool:
    results = await monitor(client, sub_id, nodes, 1)
    return results[0].StatusCode.value == 0x80280000  # Bad_SubscriptionIdInvalid


@case("d1-expired-subscriptions")
async def d1_expired(gw: GatewayProcess, args: argparse.Namespace) -> Outcome:
    """4 sessions, one subscription each (interval 0, lifetime --lifetime), --items items; a
    Publish request a second for --publish-s, then none until the lifetime ran out, then leave."""
    clients = []
    subs: list[Any] = []
    accepted = 0
    stop = asyncio.Event()
    async with Costs(gw) as costs:
        try:
            for _ in range(4):
                client = await raw_session(gw)
                clients.append(client)
                nodes = await channel_nodes(client)
                sub = await create_subscription(client, 0.0, args.lifetime, keepalive=1)
                subs.append(sub)
                accepted += good(await monitor(client, sub.SubscriptionId, nodes, args.items))
            publishers = [asyncio.create_task(publish_slowly(c, stop)) for c in clients]
            await asyncio.sleep(args.publish_s)
            stop.set()
            await asyncio.gather(*publishers)
            log_publishing = costs.log_growth
            interval = max(s.RevisedPublishingInterval for s in subs)
            await asyncio.sleep(max(3.0, args.lifetime * interval / 1000 * 1.5 + 1))
            gone = [
                await subscription_gone(c, s.SubscriptionId, nodes)
                for c, s in zip(clients, subs, strict=True)
            ]
            log_mark = costs.log_growth
            await asyncio.sleep(args.settle_s)  # image changes after the expiry, still connected
            log_expired = costs.log_growth - log_mark
            served = await fresh_client(gw.ua_port, tries=5, user=gw.fresh_user)
        finally:
            stop.set()
            for client in clients:
                try:
                    async with asyncio.timeout(2):
                        await client.disconnect()
                except Exception:  # noqa: BLE001
                    pass
        log_mark = costs.log_growth
        await asyncio.sleep(args.settle_s)
        log_left = costs.log_growth - log_mark
        recursion = gw.log_text(costs.log0).count("RecursionError")
    ok = (
        recursion == 0
        and costs.tracebacks == 0
        and served == 5
        and all(gone)
        and log_expired + log_left < 64 * 1024
    )
    revised = [s.RevisedPublishingInterval for s in subs]
    return Outcome(
        "d1-expired-subscriptions",
        f"4 subscriptions asked for interval 0, lifetime {args.lifetime} (revised "
        f"{min(revised):g} ms, {subs[0].RevisedLifetimeCount}), {accepted:,} of "
        f"{4 * args.items:,} items; {recursion} RecursionError; log +{log_publishing / 1024:.0f} "
        f"KB in the {args.publish_s:g} s of slow Publish, +{log_expired / 1024:.0f} KB in "
        f"{args.settle_s:g} s after the lifetime ran out ({sum(gone)}/4 subscriptions gone), "
        f"+{log_left / 1024:.0f} KB in {args.settle_s:g} s after the clients left; fresh client {served}/5; {costs.text()}",
        ok,
        {"recursion": recursion, "log_kb": costs.log_growth / 1024, "served": served},
    )


@case("limits")
async def limits(gw: GatewayProcess, args: argparse.Namespace) -> Outcome:
    """What the server revises or refuses of a greedy client's subscriptions."""
    from asyncua import ua

    client = await raw_session(gw)
    parts: list[str] = []
    try:
        nodes = await channel_nodes(client)
        sub = await create_subscription(client, 0.0, 3000, keepalive=10)
        parts.append(f"publishing 0 ms -> {sub.RevisedPublishingInterval:g} ms")
        short = await create_subscription(client, 1000.0, 1, keepalive=10)
        parts.append(f"lifetime 1, keep-alive 10 -> {short.RevisedLifetimeCount}")
        items = await monitor(client, sub.SubscriptionId, nodes, 1, sampling=0.0, queue=1_000_000)
        parts.append(
            f"sampling 0 ms -> {items[0].RevisedSamplingInterval:g} ms, "
            f"queue 1,000,000 -> {items[0].RevisedQueueSize:,}"
        )
        many = await monitor(client, sub.SubscriptionId, nodes, 6_000)
        parts.append(f"6,000 more items in that subscription -> {good(many):,} created")
        second = await create_subscription(client, 1000.0, 3000)
        session = await monitor(client, second.SubscriptionId, nodes, 6_000)
        parts.append(f"6,000 items in a second one -> {good(session):,} created")
        subs = 3
        for _ in range(20):
            try:
                await create_subscription(client, 1000.0, 300)
                subs += 1
            except ua.UaStatusCodeError as exc:
                parts.append(f"subscriptions in a session -> {subs} ({exc.__class__.__name__})")
                break
        else:
            parts.append(f"subscriptions in a session -> {subs} (no limit met)")
        await asyncio.sleep(2.2)  # the child's report and the status API's copy, a second each
        counters = gw.counters()
        parts.append(
            f"refused items counted {counters.get('rejected_too_many_monitored_items', 0):,}"
        )
    finally:
        await client.disconnect()
    ok = (
        sub.RevisedPublishingInterval > 0
        and items[0].RevisedSamplingInterval > 0
        and items[0].RevisedQueueSize < 1_000_000
        and good(many) < 6_000
        and good(session) < 6_000
        and short.RevisedLifetimeCount >= 30
        and subs < 23
    )
    return Outcome("limits", "; ".join(parts), ok)


# -- D9 -------------------------------------------------------------------------------------
async def refusals_counted(gw: GatewayProcess, token: str, tries: int = 20) -> Outcome:
    """Sessions with an identity token the endpoint does not take ("username" where no users
    are configured, "anonymous" where users are): refused, counted, one short line each."""
    from asyncua import Client

    before = gw.counters()
    async with Costs(gw) as costs:
        refusals = 0
        for _ in range(tries):
            client = Client(url(gw), timeout=5)
            if token == "username":
                client.set_user("mallory")
                client.set_password("x")
            try:
                await client.connect()
                await client.disconnect()
            except Exception:  # noqa: BLE001  (refused, as expected)
                refusals += 1
    deadline = time.monotonic() + 5  # the front's child reports once a second, so does the API
    while True:
        after = gw.counters()
        grown = {k: after[k] - before.get(k, 0) for k in after if after[k] != before.get(k, 0)}
        counted = sum(v for k, v in grown.items() if k.startswith("rejected_"))
        if counted >= tries or time.monotonic() > deadline:
            break
        await asyncio.sleep(0.2)
    ok = refusals == tries and counted >= tries and costs.tracebacks == 0
    return Outcome(
        f"d9-{token}-refused",
        f"{tries} sessions with a {token} token the endpoint does not take: {refusals} refused; "
        f"counters grew {grown}; {costs.text()}",
        ok,
        {"grown": grown},
    )


@case("d9-refusals-counted")
async def d9_refusals(gw: GatewayProcess, args: argparse.Namespace) -> Outcome:
    return await refusals_counted(gw, "username")


async def run(args: argparse.Namespace) -> list[Outcome]:
    names = list(CASES) if args.case == "all" else args.case.split(",")
    unknown = [n for n in names if n not in CASES]
    if unknown:
        raise SystemExit(f"unknown case(s) {', '.join(unknown)}; known: {', '.join(CASES)}")
    gw = await GatewayProcess.start()
    print(
        f"gateway pid {gw.proc.pid}: OPC UA on 127.0.0.1:{gw.ua_port}, status API on "
        f"127.0.0.1:{gw.http_port}, RSS {gw.rss_mb():.0f} MB, log {gw.log_path}",
        flush=True,
    )
    outcomes = []
    log0 = gw.log_size()
    rss0 = gw.rss_mb()
    try:
        for name in names:
            try:
                outcome = await CASES[name](gw, args)
            except Exception as exc:  # noqa: BLE001  (a probe that fails is a finding)
                outcome = Outcome(name, f"probe failed: {type(exc).__name__}: {exc}", False)
            print(outcome.line(), flush=True)
            outcomes.append(outcome)
            if gw.proc.poll() is not None:
                print("FAIL the gateway exited", flush=True)
                break
        print(
            f"gateway after all cases: RSS {gw.rss_mb():.0f} MB (started {rss0:.0f}), log "
            f"+{(gw.log_size() - log0) / MB:.2f} MB, "
            f"{gw.log_text(log0).count('Traceback')} tracebacks",
            flush=True,
        )
    finally:
        if args.keep_log:
            Path(args.keep_log).write_bytes(gw.log_path.read_bytes())
        gw.stop()
    return outcomes


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--case", default="all", help=f"all, or some of {', '.join(CASES)}")
    parser.add_argument("--flood-mb", type=int, default=128, help="D2: MB offered per flood")
    parser.add_argument("--idle", type=int, default=500, help="D4: silent sockets held")
    parser.add_argument("--sessions", type=int, default=40, help="D4: sessions opened")
    parser.add_argument("--items", type=int, default=10_000, help="D1: items per subscription")
    parser.add_argument(
        "--lifetime", type=int, default=30, help="D1: RequestedLifetimeCount (the issue: 3000)"
    )
    parser.add_argument(
        "--publish-s", type=float, default=10.0, help="D1: seconds of one Publish request a second"
    )
    parser.add_argument(
        "--settle-s", type=float, default=3.0, help="D1: seconds watched after expiry and after"
    )
    parser.add_argument("--keep-log", help="copy the gateway's log here at the end")
    args = parser.parse_args(argv)
    logging.getLogger("asyncua").setLevel(logging.CRITICAL)  # the attacker's own library
    outcomes = asyncio.run(run(args))
    failed = [o.case for o in outcomes if not o.ok]
    print("verdict:", "PASS" if not failed else f"FAIL ({', '.join(failed)})")
    return 0 if not failed else 1


if __name__ == "__main__":
    sys.exit(main())
