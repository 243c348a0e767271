"""Secure by default: loopback unless configured, a token for anything exposed, read-only."""

from __future__ import annotations

import logging

import pytest
from httpkit import load_gateway, start

from fieldgate import load_registry
from fieldgate.runtime import GatewayStartError
from fieldgate.topology import TopologyError, load_topology

TOKEN = "s3cret-token-0123456789"
REGISTRY = load_registry()


def topology(http: dict) -> dict:
    return {
        "gateway": {"name": "gw", "http": http},
        "fronts": [{"name": "plc", "type": "memory"}],
        "backs": [{"name": "io", "type": "loopback", "modules": [{"address": 1, "digital": 1}]}],
    }


def errors(http: dict) -> list[str]:
    with pytest.raises(TopologyError) as info:
        load_topology(topology(http), REGISTRY)
    return [str(i) for i in info.value.issues]


@pytest.mark.parametrize(
    "listen", ["0.0.0.0:8400", "192.168.1.10:8400", "[::]:8400", "plc-gw:8400"]
)
def test_a_non_loopback_listen_without_a_token_is_a_validation_error(listen):
    (issue,) = errors({"listen": listen})
    assert "gateway.http" in issue
    assert f"listen {listen} is not a loopback address" in issue
    assert "token_file" in issue


@pytest.mark.parametrize(
    "http",
    [
        {"listen": "0.0.0.0:8400", "token_file": "token.txt"},
        {"listen": "0.0.0.0:8400", "token_env": "FIELDGATE_HTTP_TOKEN"},
        {"listen": "127.0.0.1:8400"},
        {"listen": "[::1]:0"},
        {"listen": "localhost:8400"},
        {},
    ],
)
def test_loopback_or_a_token_source_validates(http):
    topo = load_topology(topology(http), REGISTRY)
    assert topo.gateway.http is not None


def test_the_http_section_is_off_unless_given():
    assert load_topology(topology({}) | {"gateway": {"name": "gw"}}, REGISTRY).gateway.http is None


@pytest.mark.parametrize(
    ("http", "message"),
    [
        ({"listen": "8400"}, "expected HOST:PORT"),
        ({"listen": "127.0.0.1:99999"}, "port must be 0..65535"),
        ({"listen": "127.0.0.1:x"}, "port must be 0..65535"),
        ({"auth_token": TOKEN, "token_env": "X"}, "not several"),
        ({"listn": "127.0.0.1:1"}, "did you mean 'listen'"),
    ],
)
def test_bad_http_settings_are_reported(http, message):
    assert any(message in issue for issue in errors(http))


def test_a_token_in_the_yaml_never_shows_in_its_repr():
    topo = load_topology(topology({"auth_token": TOKEN}), REGISTRY)
    assert TOKEN not in repr(topo.gateway) and TOKEN not in str(topo.gateway.http)


async def test_with_a_token_every_request_but_healthz_needs_it(tmp_path, caplog):
    caplog.set_level(logging.DEBUG)
    (tmp_path / "token").write_text(TOKEN + "\n")
    gw = load_gateway(tmp_path, token_file=str(tmp_path / "token"))
    running = await start(gw)
    try:
        assert (await running.get("/healthz")).status == 200
        for path in (
            "/readyz",
            "/api/v1/status",
            "/api/v1/points",
            "/metrics",
            "/",
            "/api/v1/events",
        ):
            reply = await running.get(path)
            assert reply.status == 401, path
            assert reply.headers["www-authenticate"] == 'Bearer realm="fieldgate"'
        bad = await running.get(
            "/api/v1/status", {"Authorization": "Bearer wrong-token-0123456789"}
        )
        assert bad.status == 401
        good = await running.get("/api/v1/status", {"Authorization": f"Bearer {TOKEN}"})
        assert good.status == 200 and TOKEN not in good.text
        # a browser: /?token=... once, then the cookie (HttpOnly, SameSite=Strict), address cleaned
        first = await running.get(f"/?token={TOKEN}")
        assert first.status == 303 and first.headers["location"] == "/"
        cookie = first.headers["set-cookie"]
        assert "HttpOnly" in cookie and "SameSite=Strict" in cookie
        page = await running.get("/", {"Cookie": cookie.split(";")[0]})
        assert page.status == 200
        assert (await running.get("/?token=wrong-token-0123456789")).status == 401
        # read-only: writes are refused before any token check
        assert (await running.get("/api/v1/points/rs485/m3/do0", method="PUT")).status == 405
    finally:
        await gw.stop()
    assert TOKEN not in caplog.text  # never logged


@pytest.mark.parametrize(
    ("settings", "message"),
    [
        ({"token_file": "missing-token"}, "cannot read it"),
        ({"token_env": "FIELDGATE_TEST_NO_SUCH_VAR"}, "is not set or empty"),
        ({"auth_token": "short"}, "shorter than 16 characters"),
    ],
)
async def test_unusable_tokens_stop_the_start_with_one_line(tmp_path, settings, message):
    gw = load_gateway(tmp_path, **settings)
    with pytest.raises(GatewayStartError, match=message) as info:
        await gw.start()
    assert "\n" not in str(info.value)
    assert gw.http is None and not gw.running


async def test_a_port_in_use_is_a_start_error(running, tmp_path):
    gw = load_gateway(tmp_path, listen=f"127.0.0.1:{running.port}")
    with pytest.raises(
        GatewayStartError, match=r"gateway.http.listen 127.0.0.1:\d+: cannot listen there"
    ):
        await gw.start()


async def test_without_a_token_only_loopback_host_names_are_answered(tmp_path):
    """A DNS-rebinding page (its own name resolving to 127.0.0.1) cannot read the gateway."""
    gw = load_gateway(tmp_path, allowed_hosts=["gw.plant.example"])
    running = await start(gw)
    try:
        from httpkit import send_raw

        async def with_host(host: str, path: str = "/api/v1/status"):
            data = f"GET {path} HTTP/1.1\r\nHost: {host}\r\nConnection: close\r\n\r\n".encode()
            return await send_raw(running.port, data)

        for host in (
            f"127.0.0.1:{running.port}",
            "localhost",
            f"[::1]:{running.port}",
            "gw.plant.example:8400",
        ):
            assert (await with_host(host)).status == 200, host
        reply = await with_host("evil.example:8400")
        assert reply.status == 421 and "allowed_hosts" in reply.text
        assert (await with_host("evil.example", "/healthz")).status == 200  # liveness stays open
    finally:
        await gw.stop()
