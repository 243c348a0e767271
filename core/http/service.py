"""The gateway's read-only HTTP service: routes, authentication, readiness, static page.

Endpoints (all GET/HEAD; docs/observability.md):

=========================  ===============================================================
``/healthz``               process alive and its event loop responsive (no auth)
``/readyz``                200 when every front and back is started, else 503 with reasons
``/api/v1/status``         gateway, fronts, backs, modules, recent events (JSON)
``/api/v1/points[/{id}]``  points explained: value, quality and cause, age, source, served at
``/api/v1/events``         Server-Sent Events: point changes and gateway events
``/api/v1/trends``         the last minutes of every analog input
``/metrics``               Prometheus text exposition
``/``                      the live page (package files, no CDN)
=========================  ===============================================================

With a token configured, every request but ``/healthz`` needs it: ``Authorization:
Bearer <token>``, or the ``fieldgate_token`` cookie a browser gets after opening
``/?token=<token>`` once (the page then works without the token in its address).
"""

from __future__ import annotations

import asyncio
import hmac
import json
import logging
import os
import ssl
import time
from importlib import resources
from pathlib import Path
from typing import TYPE_CHECKING, Any
from urllib.parse import quote

from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily, Metric

from ..image import Kind
from ..topology.model import HttpSettings, is_loopback, split_listen
from . import explain
from .metrics import CONTENT_TYPE, GatewayMetrics
from .server import Handler, HttpServer, Request, Response, Stream, text_response
from .sse import EventStreams
from .trends import TrendRecorder

if TYPE_CHECKING:
    from collections.abc import Iterator

    from .view import GatewayView

log = logging.getLogger("fieldgate.http")

COOKIE = "fieldgate_token"
LAG_PERIOD_S = 0.25
LAG_UNHEALTHY_S = 1.0
SLICE_S = 0.0002  # longest stretch of work for one request before the loop serves others
PLACES_TTL_S = 2.0
STATIC = {
    "index.html": "text/html; charset=utf-8",
    "app.js": "text/javascript; charset=utf-8",
    "style.css": "text/css; charset=utf-8",
    "icon.svg": "image/svg+xml",
}
PAGE_HEADERS = [
    ("Cache-Control", "no-cache"),
    ("X-Frame-Options", "DENY"),
    ("Referrer-Policy", "no-referrer"),
    (
        "Content-Security-Policy",
        "default-src 'self'; img-src 'self'; style-src 'self'; script-src 'self'; "
        "connect-src 'self'; frame-ancestors 'none'",
    ),
]
JSON_HEADERS = [("Cache-Control", "no-store")]


class HttpConfigError(Exception):
    """The HTTP settings cannot be used (token file unreadable, address in use); one line."""


def resolve_token(settings: HttpSettings, base_dir: Path) -> str | None:
    """The configured token, read from its file or environment variable; never logged."""
    if settings.auth_token is not None:
        token = settings.auth_token.get_secret_value().strip()
        where = "gateway.http.auth_token"
    elif settings.token_file is not None:
        path = Path(settings.token_file)
        path = path if path.is_absolute() else base_dir / path
        try:
            token = path.read_text(encoding="utf-8").strip()
        except (OSError, UnicodeDecodeError) as exc:
            raise HttpConfigError(
                f"gateway.http.token_file {path}: cannot read it ({type(exc).__name__}: {exc.args[-1] if exc.args else exc})"
            ) from None
        where = f"gateway.http.token_file {path}"
    elif settings.token_env is not None:
        token = os.environ.get(settings.token_env, "").strip()
        where = f"environment variable {settings.token_env} (gateway.http.token_env)"
        if not token:
            raise HttpConfigError(f"{where} is not set or empty")
    else:
        return None
    if len(token) < 16:
        raise HttpConfigError(f"the token in {where} is shorter than 16 characters")
    return token


def tls_context(settings: HttpSettings, base_dir: Path) -> ssl.SSLContext | None:
    """The server's TLS context from ``tls_cert_file``/``tls_key_file`` (PEM), or None."""
    if settings.tls_cert_file is None or settings.tls_key_file is None:
        return None
    cert, key = (
        p if p.is_absolute() else base_dir / p
        for p in (Path(settings.tls_cert_file), Path(settings.tls_key_file))
    )
    context = ssl.create_default_context(ssl.Purpose.CLIENT_AUTH)
    context.minimum_version = ssl.TLSVersion.TLSv1_2
    try:
        context.load_cert_chain(cert, key)
    except (OSError, ssl.SSLError) as exc:
        raise HttpConfigError(
            f"gateway.http.tls_cert_file {cert} / tls_key_file {key}: cannot use them "
            f"({type(exc).__name__}: {exc.args[-1] if exc.args else exc})"
        ) from None
    return context


class LoopMonitor:
    """How late the event loop wakes a task that sleeps ``LAG_PERIOD_S`` (for /healthz)."""

    def __init__(self) -> None:
        self.lag = 0.0
        self.max_lag = 0.0
        self._task: asyncio.Task[None] | None = None

    async def _run(self) -> None:
        loop = asyncio.get_running_loop()
        while True:
            started = loop.time()
            await asyncio.sleep(LAG_PERIOD_S)
            self.lag = max(0.0, loop.time() - started - LAG_PERIOD_S)
            self.max_lag = max(self.max_lag, self.lag)

    def start(self) -> None:
        self._task = asyncio.get_running_loop().create_task(self._run(), name="fieldgate:loop-lag")

    async def stop(self) -> None:
        if self._task is not None:
            self._task.cancel()
            await asyncio.gather(self._task, return_exceptions=True)
            self._task = None


class HttpService:
    def __init__(self, gateway: GatewayView, settings: HttpSettings):
        self.gateway = gateway
        self.settings = settings
        self.token = resolve_token(settings, gateway.topology.base_dir)
        host, port = split_listen(settings.listen)
        self._hosts = {host.lower(), *(h.lower() for h in settings.allowed_hosts)}
        self.server = HttpServer(
            self.handle, host, port, ssl_context=tls_context(settings, gateway.topology.base_dir)
        )
        self.metrics = GatewayMetrics(gateway, point_metrics=settings.point_metrics, extra=self)
        self.streams = EventStreams(
            gateway, max_clients=settings.sse_max_clients, rate_hz=settings.sse_point_rate_hz
        )
        self.trends = TrendRecorder(gateway.image)
        self.loop_monitor = LoopMonitor()
        self.started_at = time.monotonic()
        self.unauthorized = 0
        self._static: dict[str, bytes] = {}
        self._places_cache: tuple[float, dict[str, list[dict[str, str]]]] | None = None
        self._metrics_cache: tuple[float, bytes] | None = None
        self._metrics_render: asyncio.Future[bytes] | None = None
        self._routes: dict[str, Handler] = {
            "/healthz": self._healthz,
            "/readyz": self._readyz,
            "/api/v1/status": self._status,
            "/api/v1/points": self._points,
            "/api/v1/events": self._events,
            "/api/v1/trends": self._trends,
            "/metrics": self._metrics,
            "/": self._page,
        }

    @property
    def url(self) -> str:
        return self.server.url

    async def start(self) -> None:
        folder = resources.files("fieldgate.http") / "static"
        self._static = {name: (folder / name).read_bytes() for name in STATIC}
        try:
            await self.server.start()
        except OSError as exc:
            raise HttpConfigError(
                f"gateway.http.listen {self.settings.listen}: cannot listen there ({exc.strerror or exc})"
            ) from None
        self.loop_monitor.start()
        self.trends.start()
        log.info(
            "HTTP status page and API on %s%s",
            self.url,
            " (token required)" if self.token else "",
        )

    async def stop(self) -> None:
        await self.server.stop()
        await self.trends.stop()
        await self.loop_monitor.stop()

    # -- dispatch ------------------------------------------------------------------------
    async def handle(self, request: Request) -> Response | Stream:
        path = request.path
        route: Handler
        if path.startswith("/api/v1/points/"):
            route = self._point
        elif path.startswith("/static/"):
            route = self._static_file
        else:
            found = self._routes.get(path)
            if found is None:
                return text_response(404, f"no such page {path!r}; the API is under /api/v1/")
            route = found
        if request.method not in ("GET", "HEAD"):
            return text_response(405, "this API is read-only", [("Allow", "GET, HEAD")])
        if path != "/healthz":
            denied = (
                self._authorize(request) if self.token is not None else self._check_host(request)
            )
            if denied is not None:
                return denied
        if route == self._events and request.method == "HEAD":
            return Response(200, b"", "text/event-stream; charset=utf-8")
        return await route(request)

    def _check_host(self, request: Request) -> Response | None:
        """Without a token, only requests addressed to a loopback name (or an allowed host).

        A web page elsewhere can make the browser resolve its own name to 127.0.0.1 (DNS
        rebinding) and then read a token-less gateway as "same origin"; its requests still
        carry that page's name in Host, and are refused here.
        """
        host = request.headers.get("host", "")
        name = host.rsplit(":", 1)[0] if not host.endswith("]") else host
        name = name.strip("[]").lower()
        if name and (is_loopback(name) or name in self._hosts):
            return None  # an empty or missing Host (HTTP/1.0) names no loopback host
        self.unauthorized += 1
        return text_response(
            421,
            f"this gateway answers requests for loopback names only, not {host!r} "
            "(add it to gateway.http.allowed_hosts, or configure a token)",
        )

    def _authorize(self, request: Request) -> Response | None:
        assert self.token is not None
        offered = ""
        auth = request.headers.get("authorization", "")
        if auth[:7].lower() == "bearer ":
            offered = auth[7:].strip()
        elif "token" in request.query and request.path == "/":
            offered = request.query["token"]
            if hmac.compare_digest(offered.encode(), self.token.encode()):
                # the browser keeps the token in a cookie; the address loses it
                return Response(
                    303,
                    b"",
                    headers=[
                        ("Location", "/"),
                        (
                            "Set-Cookie",
                            f"{COOKIE}={quote(self.token)}; HttpOnly; SameSite=Strict; Path=/",
                        ),
                    ],
                )
        else:
            for part in request.headers.get("cookie", "").split(";"):
                name, _, value = part.strip().partition("=")
                if name == COOKIE:
                    from urllib.parse import unquote

                    offered = unquote(value)
        if offered and hmac.compare_digest(offered.encode(), self.token.encode()):
            return None
        self.unauthorized += 1
        return text_response(
            401,
            "this gateway needs its token: Authorization: Bearer <token>, or open /?token=<token> in a browser",
            [("WWW-Authenticate", 'Bearer realm="fieldgate"')],
        )

    # -- endpoints -----------------------------------------------------------------------
    async def _healthz(self, request: Request) -> Response:
        fieldbus = getattr(self.gateway, "fieldbus_health", None)
        ahead = ""
        if fieldbus is not None:  # served from a child process: the fieldbus process's health
            ok, text = fieldbus()
            if not ok:
                return text_response(503, text)
            ahead = f"{text}; this server's "
        lag = self.loop_monitor.lag
        if lag > LAG_UNHEALTHY_S:
            return text_response(503, f"{ahead}event loop {lag * 1000:.0f} ms late")
        return Response(200, f"ok: {ahead}event loop {lag * 1000:.1f} ms late\n".encode())

    async def _readyz(self, request: Request) -> Response:
        ready, reasons = explain.readiness(self.gateway)
        if ready:
            return Response(200, b"ready\n")
        return text_response(503, "not ready: " + "; ".join(reasons))

    async def _status(self, request: Request) -> Response:
        body = explain.status(self.gateway, self.started_at)
        body["http"] = self.stats()
        return self._json(body)

    async def _points(self, request: Request) -> Response:
        image = self.gateway.image
        channels = list(image)
        kind = request.query.get("kind")
        if kind is not None:
            if kind not in {k.value for k in Kind}:
                return text_response(400, f"kind must be one of di, do, ai, ao, got {kind!r}")
            channels = [c for c in channels if c.kind.value == kind]
        back = request.query.get("back")
        if back is not None:
            channels = [c for c in channels if c.source.back == back]
        places = self._places()
        now = image.clock()
        points, started = [], time.perf_counter()
        for channel in channels:
            points.append(explain.point(self.gateway, channel, places, now))
            if time.perf_counter() - started >= SLICE_S:  # a big image: let frames through
                await asyncio.sleep(0)
                started = time.perf_counter()
        return self._json({"points": points})

    async def _point(self, request: Request) -> Response:
        cid = request.path[len("/api/v1/points/") :]
        if cid not in self.gateway.image:
            return text_response(404, f"no point {cid!r} (ids look like rs485/m3/do0)")
        return self._json(explain.point(self.gateway, self.gateway.image[cid], self._places()))

    async def _events(self, request: Request) -> Response | Stream:
        ids: list[str] | None = None
        wanted = request.query.get("points")
        if wanted is not None:
            ids = (
                []
                if wanted == "none"
                else [c.id for c in self.gateway.image.match(p for p in wanted.split(",") if p)]
            )
        rate: float | None = None
        if "rate" in request.query:
            try:
                rate = float(request.query["rate"])
            except ValueError:
                rate = None
            if rate is None or not 0 < rate <= 1000:
                return text_response(400, "rate must be a number of batches per second above 0")
        stream = self.streams.open(ids, rate)  # no await between the check and the slot
        if stream is None:
            return text_response(503, f"{self.settings.sse_max_clients} event streams open already")
        return stream

    async def _trends(self, request: Request) -> Response:
        return self._json(self.trends.as_dict())

    async def _metrics(self, request: Request) -> Response:
        return Response(200, await self._metrics_text(), CONTENT_TYPE, list(JSON_HEADERS))

    async def _metrics_text(self) -> bytes:
        """The exposition, rendered at most once per ``metrics_max_age_ms`` (scrapes in between,
        and scrapes arriving while one renders, share it): a render costs the loop
        milliseconds in slices, and ten scrapers a second need not pay it ten times."""
        now = time.monotonic()
        cached = self._metrics_cache
        if cached is not None and now - cached[0] < self.settings.metrics_max_age_ms / 1000:
            return cached[1]
        if self._metrics_render is None:
            self._metrics_render = asyncio.ensure_future(self.metrics.render_async(SLICE_S))
        render = self._metrics_render
        try:
            body = await asyncio.shield(render)
        finally:
            if render.done() and self._metrics_render is render:
                self._metrics_render = None
        self._metrics_cache = (time.monotonic(), body)
        return body

    async def _page(self, request: Request) -> Response:
        return Response(200, self._static["index.html"], STATIC["index.html"], list(PAGE_HEADERS))

    async def _static_file(self, request: Request) -> Response:
        name = request.path[len("/static/") :]
        if name not in STATIC or name == "index.html":
            return text_response(404, f"no such file {name!r}")
        return Response(200, self._static[name], STATIC[name], list(PAGE_HEADERS))

    # -- helpers -------------------------------------------------------------------------
    def _places(self) -> dict[str, list[dict[str, str]]]:
        """Every component's point locations, reused for ``PLACES_TTL_S`` (a mapping a master
        changes shows up that much later; hovering the page's grid asks for one point at a time)."""
        now = time.monotonic()
        if self._places_cache is None or now - self._places_cache[0] > PLACES_TTL_S:
            self._places_cache = (now, explain.locations(self.gateway.backs + self.gateway.fronts))
        return self._places_cache[1]

    @staticmethod
    def _json(body: Any) -> Response:
        data = json.dumps(body, separators=(",", ":"), allow_nan=False).encode()
        return Response(200, data, "application/json", list(JSON_HEADERS))

    def stats(self) -> dict[str, Any]:
        return {
            "url": self.url,
            "connections": self.server.connections,
            "evicted": self.server.evicted,
            "timed_out": self.server.timed_out,
            "responses": {str(k): v for k, v in sorted(self.server.responses.items())},
            "unauthorized": self.unauthorized,
            "event_streams": len(self.streams.clients),
            "event_stream_batches": self.streams.batches,
            "events_dropped": self.streams.dropped_events,
            "slow_clients_closed": self.streams.closed_slow,
            "loop_lag_ms": round(self.loop_monitor.lag * 1000, 3),
            "loop_lag_max_ms": round(self.loop_monitor.max_lag * 1000, 3),
        }

    def metrics_families(self) -> Iterator[Metric]:
        """The HTTP service's own series (the metrics collector asks for them)."""
        responses = CounterMetricFamily(
            "fieldgate_http_responses", "HTTP responses by status code", labels=["code"]
        )
        for code, n in sorted(self.server.responses.items()):
            responses.add_metric([str(code)], float(n))
        yield responses
        yield GaugeMetricFamily(
            "fieldgate_http_event_streams",
            "open event-stream clients",
            value=len(self.streams.clients),
        )
        yield CounterMetricFamily(
            "fieldgate_sse_dropped",
            "gateway events dropped for event-stream clients that did not keep up",
            value=self.streams.dropped_events,
        )
        yield CounterMetricFamily(
            "fieldgate_sse_slow_clients_closed",
            "event-stream clients disconnected because they stopped reading",
            value=self.streams.closed_slow,
        )
        yield GaugeMetricFamily(
            "fieldgate_event_loop_lag_seconds",
            "how late the event loop woke the last 250 ms timer",
            value=self.loop_monitor.lag,
        )
