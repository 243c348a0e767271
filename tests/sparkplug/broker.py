"""A real Mosquitto for the tests: its own config, a free loopback port, start/kill/restart.

Mosquitto comes from the distribution (``.ci/mosquitto/install``, run by scripts/test in CI).
Without it the broker tests fail under ``CI=true`` and are skipped elsewhere, with the reason.
"""

from __future__ import annotations

import getpass
import json
import os
import shutil
import signal
import socket
import subprocess
import threading
import time
from collections.abc import Hashable, Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import paho.mqtt.client as mqtt
import pytest
from paho.mqtt.enums import CallbackAPIVersion

from . import spb


def mosquitto_path() -> str | None:
    found = shutil.which("mosquitto")
    if found:
        return found
    return "/usr/sbin/mosquitto" if os.access("/usr/sbin/mosquitto", os.X_OK) else None


def require_mosquitto() -> str:
    path = mosquitto_path()
    if path is None:
        reason = (
            "mosquitto is not installed (run .ci/mosquitto/install, or apt-get install mosquitto)"
        )
        if os.environ.get("CI") == "true":
            pytest.fail(reason)
        pytest.skip(reason)
    return path


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def wait_until(predicate: Any, timeout: float = 10.0, what: str = "condition") -> None:
    """Poll ``predicate`` for a real process or broker to get there (never a timing assert)."""
    end = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > end:
            raise AssertionError(f"timed out after {timeout} s waiting for {what}")
        time.sleep(0.01)


class Mosquitto:
    def __init__(
        self,
        binary: str,
        workdir: Path,
        port: int | None = None,
        listener: str = "",
        persistence: bool = False,
    ):
        """``listener``: extra lines for the listener (TLS files, password_file, ...); without
        it, anonymous clients are allowed (loopback only). ``persistence``: the broker saves
        its sessions and their queued messages in ``workdir`` when it stops (SIGTERM) and
        loads them when it starts again; a SIGKILL still loses what it held in memory."""
        self.binary = binary
        self.port = port or free_port()
        self.workdir = workdir
        self.conf = workdir / "mosquitto.conf"
        self.conf.write_text(
            # run as whoever runs the tests (as root, mosquitto would switch to its own user,
            # which cannot read the test's key files)
            f"user {getpass.getuser()}\nper_listener_settings false\nlistener {self.port} 127.0.0.1\n"
            + (listener or "allow_anonymous true\n")
            + (
                f"persistence true\npersistence_location {workdir}/\n"
                if persistence
                else "persistence false\n"
            )
            + "log_dest none\nmax_queued_messages 100000\nmax_inflight_messages 0\n"
        )
        self.proc: subprocess.Popen[bytes] | None = None

    def start(self) -> None:
        self.proc = subprocess.Popen(
            [self.binary, "-c", str(self.conf)],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )

        def listening() -> bool:
            assert self.proc is not None and self.proc.poll() is None, "mosquitto exited"
            with socket.socket() as s:
                return s.connect_ex(("127.0.0.1", self.port)) == 0

        wait_until(listening, 10, f"mosquitto on port {self.port}")

    def kill(self) -> None:
        """SIGKILL: the broker vanishes without closing anything cleanly."""
        if self.proc is not None and self.proc.poll() is None:
            self.proc.send_signal(signal.SIGKILL)
            self.proc.wait()
        self.proc = None

    def stop(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(5)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self.proc = None


@dataclass
class Message:
    topic: str
    payload: bytes
    qos: int
    retain: bool
    received: float  # time.time()

    @property
    def type(self) -> str:
        parts = self.topic.split("/")
        return parts[1] if parts[1] == "STATE" else parts[2]

    @property
    def device(self) -> str | None:
        parts = self.topic.split("/")
        return parts[4] if len(parts) > 4 else None

    def decode(self) -> spb.Payload:
        return spb.decode(self.payload)


class Subscriber:
    """The checking host application: subscribes to everything Sparkplug, QoS 1.

    With ``host_id`` it is a primary host: after every (re)connect it subscribes, then
    publishes its retained STATE online (its will says offline), as Sparkplug 3.0 hosts do.
    """

    def __init__(self, port: int, host_id: str | None = None, client_id: str = "checker"):
        self.port = port
        self.host_id = host_id
        self.messages: list[Message] = []
        self.lock = threading.Lock()
        self.connected = threading.Event()
        self.client = mqtt.Client(
            CallbackAPIVersion.VERSION2, client_id=client_id, protocol=mqtt.MQTTv311
        )
        self.client.reconnect_delay_set(0.05, 0.2)
        self.client.on_connect = self._on_connect
        self.client.on_disconnect = self._on_disconnect
        self.client.on_message = self._on_message
        if host_id is not None:
            self.client.will_set(
                f"spBv1.0/STATE/{host_id}",
                json.dumps({"online": False, "timestamp": int(time.time() * 1000)}),
                qos=1,
                retain=True,
            )

    def _on_connect(self, client: Any, userdata: Any, flags: Any, reason: Any, props: Any) -> None:
        if reason.is_failure:
            return
        client.subscribe("spBv1.0/#", qos=1)
        if self.host_id is not None:
            self.set_state(True)
        self.connected.set()

    def _on_disconnect(self, *args: Any) -> None:
        self.connected.clear()

    def _on_message(self, client: Any, userdata: Any, msg: Any) -> None:
        with self.lock:
            self.messages.append(
                Message(msg.topic, bytes(msg.payload), msg.qos, bool(msg.retain), time.time())
            )

    def set_state(self, online: bool) -> None:
        self.client.publish(
            f"spBv1.0/STATE/{self.host_id}",
            json.dumps({"online": online, "timestamp": int(time.time() * 1000)}),
            qos=1,
            retain=True,
        )

    def start(self) -> None:
        self.client.connect("127.0.0.1", self.port, keepalive=5)
        self.client.loop_start()
        assert self.connected.wait(10), "the checking subscriber could not connect"

    def stop(self) -> None:
        self.client.disconnect()
        self.client.loop_stop()

    def snapshot(self) -> list[Message]:
        with self.lock:
            return list(self.messages)

    def of(self, kind: str) -> list[Message]:
        return [m for m in self.snapshot() if m.type == kind]

    def publish(self, topic: str, payload: bytes) -> None:
        self.client.publish(topic, payload, qos=1)


def in_flight_repeats(copies: Iterable[tuple[Hashable, float, bool]], restart_at: float) -> int:
    """How many repeated samples are replays of a DDATA in flight when the broker was killed.

    ``copies``: one ``(sample, arrived, historical)`` per copy received, where ``sample``
    identifies a sample (acquisition timestamp and value at least) and ``arrived`` is the
    subscriber's ``time.time()``. A repeat counts when the sample's first copy arrived before
    the broker's restart and every repeat after it, as historical: the broker had read the
    DDATA (and passed it on) when it died, before the gateway's sync or PUBACK came back, so
    the journal replayed it (at-least-once; docs/sparkplug.md, "Delivery to the broker is at
    least once"). Any other repeat is the gateway's fault and is not counted here.
    """
    seen: dict[Hashable, list[tuple[float, bool]]] = {}
    for sample, arrived, historical in copies:
        seen.setdefault(sample, []).append((arrived, historical))
    count = 0
    for arrivals in seen.values():
        arrivals.sort()
        first, repeats = arrivals[0], arrivals[1:]
        if first[0] < restart_at and all(hist and at >= restart_at for at, hist in repeats):
            count += len(repeats)
    return count


class SampleLog:
    """Samples (DDATA metrics) per device and alias, decoded independently of the front."""

    def __init__(self, messages: list[Message]):
        self.aliases: dict[tuple[str, int], tuple[str, int]] = {}  # (device, alias) -> (name, type)
        self.samples: dict[tuple[str, str], list[tuple[int, Any, bool, float]]] = {}
        for msg in messages:
            if msg.type == "DBIRTH":
                for m in msg.decode().metrics:
                    assert m.alias is not None and m.name is not None and m.datatype is not None
                    self.aliases[(msg.device or "", m.alias)] = (m.name, m.datatype)
            elif msg.type == "DDATA":
                for m in msg.decode().metrics:
                    name, dtype = self.aliases[(msg.device or "", m.alias or 0)]
                    self.samples.setdefault((msg.device or "", name), []).append(
                        (m.timestamp or 0, spb.value_of(m, dtype), m.is_historical, msg.received)
                    )

    def values(self, device: str, name: str) -> list[Any]:
        return [v for _, v, _, _ in self.samples.get((device, name), [])]

    def in_flight_repeats(self, device: str, name: str, restart_at: float) -> int:
        """in_flight_repeats() of one metric's samples (a sample: timestamp and value)."""
        samples = self.samples.get((device, name), [])
        return in_flight_repeats((((ts, v), at, h) for ts, v, h, at in samples), restart_at)
