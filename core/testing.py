"""Test fixtures for gateways and plugins: a pytest plugin (entry point ``pytest11``).

Installed with fieldgate, so a plugin's tests use them without a conftest of their own
(docs/plugins.md, "Testing your plugin"). Protocol-neutral; the protocol-specific fixtures
come with their plugins (``canopen_master`` from ``fieldgate.plugins.canopen.testing``,
``devicenet_scanner`` from ``fieldgate.plugins.devicenet.testing``).

Fixtures (each a factory; whatever they made is closed when the test ends):

* ``fieldgate_registry``: the installed plugins (``load_registry()``, once per session);
* ``fieldgate_gateway(topology, overrides=None, simulate=True)``: a :class:`Gateway` for
  ``async with`` in an async test, backs served by their simulators by default;
* ``fieldgate_thread(topology, ...)``: the same gateway started on its own event loop in a
  thread (:class:`GatewayThread`), for synchronous tests and synchronous masters;
* ``fieldgate_pty(baudrate=None)``: a pseudo-terminal pair (:class:`PtyPair`), a serial
  line for a back and its simulator;
* ``fieldgate_http(gateway_or_url, token=None)``: a small HTTP/1.1 client of the status API
  (:class:`StatusClient`), written here, not the server's code.

Helpers: :func:`assert_channel` (value and quality now, one clear message),
:func:`wait_for_channel` (until they hold: event-driven through the image's subscription,
with a deadline, no polling), :func:`wait_for_report` (a component's status once it holds
what the test waits for: a north-facing front reports from its child once a second), and
:func:`in_this_process` (a north-facing front built in the test's own process, for tests
that reach into it).
"""

from __future__ import annotations

import asyncio
import json
import threading
import urllib.parse
from collections.abc import Awaitable, Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar

import pytest

from .image import Channel, ProcessImage, Quality
from .plugin import Registry, Simulator, load_registry
from .runtime import Gateway
from .serial_link import PtyPair

T = TypeVar("T")
Value = bool | int | float | str
Topology = str | Path | dict[str, Any]


class _Anything:
    def __repr__(self) -> str:
        return "any value"


ANY: Any = _Anything()  # wait_for_channel(..., value=ANY): the quality alone


def _matches(channel: Channel, value: object, quality: Quality | str | None) -> bool:
    return (value is ANY or channel.value == value) and (
        quality is None or channel.quality == Quality(quality)
    )


def _describe(channel: Channel) -> str:
    return f"{channel.id} is {channel.value!r} ({channel.quality.value})"


def _wanted(value: object, quality: Quality | str | None) -> str:
    parts = [] if value is ANY else [repr(value)]
    if quality is not None:
        parts.append(f"({Quality(quality).value})")
    return " ".join(parts) or "anything"


def assert_channel(
    image: ProcessImage,
    channel_id: str,
    value: object = ANY,
    quality: Quality | str | None = Quality.GOOD,
) -> Channel:
    """The channel holds ``value`` with ``quality`` now (None: any quality); the channel."""
    channel = image[channel_id]
    assert _matches(channel, value, quality), (
        f"{_describe(channel)}; expected {_wanted(value, quality)}"
    )
    return channel


async def wait_for_channel(
    image: ProcessImage,
    channel_id: str,
    value: object = ANY,
    quality: Quality | str | None = Quality.GOOD,
    timeout: float = 5.0,
) -> Channel:
    """Wait until the channel holds ``value`` with ``quality``; AssertionError after ``timeout``
    seconds, naming what it held. Woken by the image's change notification, not by polling."""
    channel = image[channel_id]
    if _matches(channel, value, quality):
        return channel
    changed = asyncio.Event()
    subscription = image.subscribe(lambda change: changed.set(), ids=[channel_id])
    loop = asyncio.get_running_loop()
    deadline = loop.time() + timeout
    try:
        while not _matches(channel, value, quality):
            left = deadline - loop.time()
            if left <= 0:
                raise AssertionError(
                    f"{_describe(channel)} after {timeout} s; expected {_wanted(value, quality)}"
                )
            changed.clear()
            try:
                await asyncio.wait_for(changed.wait(), left)
            except TimeoutError:
                pass
    finally:
        subscription.cancel()
    return channel


async def wait_until(predicate: Callable[[], bool], timeout: float = 5.0, what: str = "") -> None:
    """Wait until ``predicate()`` holds (checked every 10 ms); AssertionError after ``timeout``."""
    loop = asyncio.get_running_loop()
    deadline = loop.time() + timeout
    while not predicate():
        if loop.time() > deadline:
            raise AssertionError(f"{what or 'condition'} not reached within {timeout} s")
        await asyncio.sleep(0.01)


class GatewayThread:
    """A gateway on its own event loop in a thread of the test process.

    For synchronous tests (and synchronous masters such as canopen's): every access to the
    gateway goes through :meth:`call`, which runs on the gateway's loop, the one thread
    that may touch the process image.
    """

    def __init__(
        self,
        topology: Topology,
        overrides: dict[str, Any] | None = None,
        registry: Registry | None = None,
        *,
        simulate: bool = True,
        animate: bool = False,
        loop_factory: Callable[[], asyncio.AbstractEventLoop] = asyncio.new_event_loop,
    ):
        def load() -> Gateway:
            return Gateway.load(topology, overrides, registry, simulate=simulate, animate=animate)

        self._load = load
        self.gateway = self._load()  # an invalid topology is raised here
        self._loop_factory = loop_factory
        self._loop = loop_factory()
        self._thread: threading.Thread | None = None
        self._started = False

    def start(self, timeout: float = 10.0) -> GatewayThread:
        """Start the gateway (backs, then fronts); its start error is raised here.

        A start after :meth:`stop` is a power cycle: a new gateway of the same topology on a
        new loop, with what the first one persisted in its ``state_dir``.
        """
        if self._started:
            self.gateway = self._load()
            self._loop = self._loop_factory()
        self._started = True
        ready = threading.Event()
        errors: list[BaseException] = []

        def run() -> None:
            asyncio.set_event_loop(self._loop)
            try:
                self._loop.run_until_complete(self.gateway.start())
            except BaseException as exc:
                errors.append(exc)
                ready.set()
                return
            ready.set()
            self._loop.run_forever()
            self._loop.run_until_complete(self.gateway.stop())

        self._thread = threading.Thread(target=run, name="fieldgate-gateway", daemon=True)
        self._thread.start()
        if not ready.wait(timeout):
            raise AssertionError(f"the gateway did not start within {timeout} s")
        if errors:
            self._thread.join()
            self._thread = None
            raise errors[0]
        return self

    def call(self, fn: Callable[[], T], timeout: float = 5.0) -> T:
        """``fn()`` run on the gateway's loop; its result."""

        async def call() -> T:
            return fn()

        return asyncio.run_coroutine_threadsafe(call(), self._loop).result(timeout)

    def run(self, coroutine: Callable[[], Awaitable[T]], timeout: float = 10.0) -> T:
        """``await coroutine()`` on the gateway's loop; its result."""

        async def run() -> T:
            return await coroutine()

        return asyncio.run_coroutine_threadsafe(run(), self._loop).result(timeout)

    def read(self, channel_id: str) -> Value:
        return self.call(lambda: self.gateway.read(channel_id))

    def write(self, channel_id: str, value: Value) -> None:
        self.call(lambda: self.gateway.write(channel_id, value))

    def channel(self, channel_id: str) -> tuple[Value, Quality]:
        """(value, quality) of a channel now."""
        return self.call(
            lambda: (self.gateway.image[channel_id].value, self.gateway.image[channel_id].quality)
        )

    def wait_for_channel(
        self,
        channel_id: str,
        value: object = ANY,
        quality: Quality | str | None = Quality.GOOD,
        timeout: float = 5.0,
    ) -> tuple[Value, Quality]:
        """As :func:`wait_for_channel`, from the test's thread; (value, quality) reached."""
        channel = self.run(
            lambda: wait_for_channel(self.gateway.image, channel_id, value, quality, timeout),
            timeout + 5,
        )
        return channel.value, channel.quality

    def simulator(self, back: str) -> Simulator:
        """The simulator serving ``back`` (its set_input/get_output are thread-safe to call
        through :meth:`call`)."""
        assert self.gateway.bench is not None, "the gateway runs without simulate=True"
        return self.gateway.bench.simulator(back)

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def stop(self, timeout: float = 10.0) -> None:
        """Stop the gateway (fronts, shutdown values, backs) and its loop."""
        if self._thread is not None and self._thread.is_alive():
            self._loop.call_soon_threadsafe(self._loop.stop)
            self._thread.join(timeout)
        self._thread = None
        if not self._loop.is_closed() and not self._loop.is_running():
            self._loop.close()

    def __enter__(self) -> GatewayThread:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()


@dataclass
class HttpReply:
    status: int
    headers: dict[str, str]
    body: bytes

    @property
    def text(self) -> str:
        return self.body.decode()

    def json(self) -> Any:
        return json.loads(self.body)


@dataclass
class StatusClient:
    """GET requests to a gateway's status API (HTTP/1.1, one connection a request)."""

    url: str  # http://127.0.0.1:8400/
    token: str | None = None
    timeout: float = 10.0
    headers: dict[str, str] = field(default_factory=dict)

    async def get(self, path: str) -> HttpReply:
        parts = urllib.parse.urlsplit(self.url)
        host, port = parts.hostname or "127.0.0.1", parts.port or 80
        lines = [f"GET {path} HTTP/1.1", f"Host: {parts.netloc}", "Connection: close"]
        if self.token:
            lines.append(f"Authorization: Bearer {self.token}")
        lines += [f"{k}: {v}" for k, v in self.headers.items()]
        async with asyncio.timeout(self.timeout):
            reader, writer = await asyncio.open_connection(host, port)
            try:
                writer.write(("\r\n".join(lines) + "\r\n\r\n").encode())
                await writer.drain()
                raw = await reader.read()
            finally:
                writer.close()
        head, _, body = raw.partition(b"\r\n\r\n")
        status_line, *header_lines = head.decode("latin-1").split("\r\n")
        headers = {}
        for line in header_lines:
            name, _, value = line.partition(":")
            headers[name.strip().lower()] = value.strip()
        return HttpReply(int(status_line.split(" ")[1]), headers, body)

    async def status(self) -> Any:
        """``/api/v1/status`` as JSON (AssertionError unless 200)."""
        reply = await self.get("/api/v1/status")
        assert reply.status == 200, f"GET /api/v1/status: {reply.status} {reply.text[:200]}"
        return reply.json()


# -- fixtures ------------------------------------------------------------------------------------
async def wait_for_report(
    gateway: Gateway,
    component: str,
    holds: Callable[[dict[str, Any]], bool] = lambda status: bool(status),
    timeout: float = 15.0,
) -> dict[str, Any]:
    """A component's ``status()`` once ``holds(status)``: a north-facing front runs in a child
    process that reports its status once a second (a front in the gateway's own process
    answers at once). AssertionError with the last status after ``timeout`` seconds."""
    comp = gateway.component(component)
    loop = asyncio.get_running_loop()
    deadline = loop.time() + timeout
    while True:
        status = comp.status()
        try:
            if holds(status):
                return status
        except (KeyError, IndexError, TypeError):
            pass  # not reported yet
        if loop.time() > deadline:
            raise AssertionError(f"{component}'s status did not get there in {timeout} s: {status}")
        await asyncio.sleep(0.05)


def in_this_process(registry: Registry, *front_types: str) -> Registry:
    """A copy of ``registry`` whose fronts of ``front_types`` run in the gateway's own
    process instead of a child process of their own.

    A north-facing front (``registry.add_front(..., north=True)``) runs in a child process
    against a mirror of the gateway (docs/architecture.md, "Process layout"): its status and
    metrics reach the gateway once a second, and nothing of it is reachable from the test.
    A test that must reach into the front itself (its session, its socket) builds it here
    with this registry; the front's code is the same, only where it runs differs. Test the
    front in its child too: that is how every gateway runs it."""
    import copy
    import dataclasses

    inline = copy.copy(registry)
    inline.types = dict(registry.types)
    for name in front_types:
        ctype = registry.lookup("front", name)
        if ctype is None:
            raise KeyError(f"no front type {name!r} in the registry")
        inline.types[("front", name)] = dataclasses.replace(ctype, north=False)
    return inline


@pytest.fixture(scope="session")
def fieldgate_registry() -> Registry:
    """The installed plugins, loaded once per test session."""
    return load_registry()


@pytest.fixture
def fieldgate_gateway(
    fieldgate_registry: Registry,
) -> Iterator[Callable[..., Gateway]]:
    """``gateway(topology, overrides=None, simulate=True, animate=False)``: a Gateway for
    ``async with``; the test fails if one is still running at its end."""
    made: list[Gateway] = []

    def make(
        topology: Topology,
        overrides: dict[str, Any] | None = None,
        *,
        simulate: bool = True,
        animate: bool = False,
        registry: Registry | None = None,
    ) -> Gateway:
        gateway = Gateway.load(
            topology,
            overrides,
            registry or fieldgate_registry,
            simulate=simulate,
            animate=animate,
        )
        made.append(gateway)
        return gateway

    yield make
    left = [g.topology.gateway.name for g in made if g.running]
    assert not left, f"gateway(s) {', '.join(left)} still running: use async with gateway: ..."


@pytest.fixture
def fieldgate_thread(fieldgate_registry: Registry) -> Iterator[Callable[..., GatewayThread]]:
    """``thread(topology, overrides=None, simulate=True, animate=False)``: a started
    :class:`GatewayThread`, stopped when the test ends."""
    made: list[GatewayThread] = []

    def make(
        topology: Topology,
        overrides: dict[str, Any] | None = None,
        *,
        simulate: bool = True,
        animate: bool = False,
        registry: Registry | None = None,
    ) -> GatewayThread:
        thread = GatewayThread(
            topology, overrides, registry or fieldgate_registry, simulate=simulate, animate=animate
        )
        made.append(thread)
        return thread.start()

    yield make
    for thread in made:
        thread.stop()


@pytest.fixture
def fieldgate_pty() -> Iterator[Callable[..., PtyPair]]:
    """``pty(baudrate=None)``: a pseudo-terminal pair (``.a`` for the back, ``.b`` for its
    simulator; paced at ``baudrate`` when given), closed when the test ends."""
    made: list[PtyPair] = []

    def make(baudrate: int | None = None) -> PtyPair:
        made.append(PtyPair(baudrate))
        return made[-1]

    yield make
    for pair in made:
        pair.close()


@pytest.fixture
def fieldgate_http() -> Callable[..., StatusClient]:
    """``http(gateway_or_url, token=None)``: a :class:`StatusClient` of a running gateway's
    status API (``gateway.http`` must be configured, e.g. ``listen: 127.0.0.1:0``)."""

    def make(target: Gateway | str, token: str | None = None) -> StatusClient:
        if isinstance(target, Gateway):
            assert target.http is not None, "the gateway serves no HTTP (gateway.http)"
            return StatusClient(str(target.http.url), token)
        return StatusClient(target, token)

    return make
