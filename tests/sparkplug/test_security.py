"""TLS (the broker certificate is verified), username + password from a file or the
environment, and a missing secret stops the front at start with one line."""

from __future__ import annotations

import asyncio
import subprocess
import time
from pathlib import Path
from typing import Any

import pytest

from fieldgate.plugin import load_registry
from fieldgate.runtime import Gateway, GatewayStartError
from fieldgate.testing import in_this_process

from .broker import Mosquitto, require_mosquitto

# settle() reads the front's session: the front is built in this process (every gateway runs
# it in a child process of its own; tests/sparkplug/test_broker.py covers that way)
INLINE = in_this_process(load_registry(), "sparkplug")


def openssl(*args: str, cwd: Path) -> None:
    subprocess.run(["openssl", *args], cwd=cwd, check=True, capture_output=True)


def make_ca(cwd: Path, name: str) -> None:
    openssl(
        "req", "-x509", "-newkey", "rsa:2048", "-nodes", "-days", "2",
        "-keyout", f"{name}.key", "-out", f"{name}.pem", "-subj", f"/CN={name}",
        cwd=cwd,
    )  # fmt: skip


@pytest.fixture
def pki(tmp_path: Path) -> Path:
    make_ca(tmp_path, "ca")
    make_ca(tmp_path, "other-ca")
    openssl(
        "req", "-newkey", "rsa:2048", "-nodes", "-keyout", "server.key", "-out", "server.csr",
        "-subj", "/CN=127.0.0.1", cwd=tmp_path,
    )  # fmt: skip
    (tmp_path / "san.ext").write_text("subjectAltName=IP:127.0.0.1\n")
    openssl(
        "x509", "-req", "-in", "server.csr", "-CA", "ca.pem", "-CAkey", "ca.key",
        "-CAcreateserial", "-days", "2", "-out", "server.pem", "-extfile", "san.ext",
        cwd=tmp_path,
    )  # fmt: skip
    subprocess.run(
        ["mosquitto_passwd", "-b", "-c", str(tmp_path / "passwd"), "line3", "s3cret"], check=True
    )
    return tmp_path


@pytest.fixture
def tls_broker(pki: Path):
    mosq = Mosquitto(
        require_mosquitto(),
        pki,
        listener=(
            f"cafile {pki / 'ca.pem'}\ncertfile {pki / 'server.pem'}\nkeyfile {pki / 'server.key'}\n"
            f"allow_anonymous false\npassword_file {pki / 'passwd'}\n"
        ),
    )
    mosq.start()
    yield mosq
    mosq.stop()


def topology(port: int, state_dir: Path, broker: dict[str, Any]) -> dict[str, Any]:
    return {
        "gateway": {"name": "gw1", "state_dir": str(state_dir)},
        "fronts": [
            {
                "name": "spb",
                "type": "sparkplug",
                "group_id": "plant",
                "brokers": [{"host": "127.0.0.1", "port": port, **broker}],
                "reconnect_min_s": 0.2,
                "reconnect_max_s": 0.5,
            }
        ],
        "backs": [{"name": "io", "type": "loopback", "modules": [{"address": 1, "digital": 1}]}],
    }


async def settle(gw: Gateway, want_online: bool) -> dict[str, Any]:
    """Wait until the front is online, or (want_online False) has tried a few times."""
    front = gw.component("spb")
    end = time.monotonic() + 15
    while time.monotonic() < end:
        status = front.status()
        if want_online and status["state"] == "online":
            return status
        if not want_online and front.session._attempt >= 3:
            return status
        await asyncio.sleep(0.02)
    raise AssertionError(f"front status stayed {front.status()['state']}")


async def test_tls_with_a_password_file_connects(tls_broker, pki, tmp_path):
    (tmp_path / "pw").write_text("s3cret\n")
    broker = {
        "tls": {"ca_file": str(pki / "ca.pem")},
        "username": "line3",
        "password_file": str(tmp_path / "pw"),
    }
    async with Gateway.load(
        topology(tls_broker.port, tmp_path / "state", broker), registry=INLINE
    ) as gw:
        status = await settle(gw, True)
    assert (
        status["sent"]["nbirth"] == 1
        and status["broker_url"] == f"mqtts://127.0.0.1:{tls_broker.port}"
    )


async def test_a_broker_certificate_from_another_ca_is_refused(
    tls_broker, pki, tmp_path, monkeypatch
):
    monkeypatch.setenv("FG_TEST_PW", "s3cret")
    broker = {
        "tls": {"ca_file": str(pki / "other-ca.pem")},
        "username": "line3",
        "password_env": "FG_TEST_PW",
    }
    async with Gateway.load(
        topology(tls_broker.port, tmp_path / "state", broker), registry=INLINE
    ) as gw:
        status = await settle(gw, False)
    assert status["connects"] == 0 and status["state"] != "online"


async def test_a_wrong_password_is_refused_and_retried(
    tls_broker, pki, tmp_path, monkeypatch, caplog
):
    monkeypatch.setenv("FG_TEST_PW", "wrong-secret")
    broker = {
        "tls": {"ca_file": str(pki / "ca.pem")},
        "username": "line3",
        "password_env": "FG_TEST_PW",
    }
    async with Gateway.load(
        topology(tls_broker.port, tmp_path / "state", broker), registry=INLINE
    ) as gw:
        status = await settle(gw, False)
    assert status["connects"] == 0
    assert "wrong-secret" not in caplog.text


async def test_a_missing_password_stops_the_front_at_start_with_one_line(tmp_path, monkeypatch):
    monkeypatch.delenv("FG_NO_SUCH_PW", raising=False)
    broker = {"username": "u", "password_env": "FG_NO_SUCH_PW"}
    gw = Gateway.load(topology(1883, tmp_path / "state", broker), registry=INLINE)
    with pytest.raises(GatewayStartError) as info:
        await gw.start()
    assert str(info.value) == (
        "front spb (sparkplug): broker mqtt://127.0.0.1:1883: environment variable FG_NO_SUCH_PW is not set"
    )
