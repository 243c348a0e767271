"""``fieldgate run --http``, ``fieldgate status`` and ``--log-format json`` from the command line."""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import socket
import subprocess
import sys

from httpkit import EXAMPLES, ROOT

from fieldgate.statuscmd import format_status, run_status

FIELDGATE = [sys.executable, "-m", "fieldgate"]


def status_args(url: str, **kw) -> argparse.Namespace:
    return argparse.Namespace(url=url, token_file=kw.get("token_file"), json=kw.get("json", False))


async def test_status_prints_a_table_and_exits_by_readiness(running, capsys):
    url = f"127.0.0.1:{running.port}"
    assert await asyncio.to_thread(run_status, status_args(url)) == 0
    out = capsys.readouterr().out
    lines = out.splitlines()
    assert lines[0].startswith("gateway i7232d  READY")
    assert any(line.split()[:3] == ["can", "PRE-OPERATIONAL", "ok"] for line in lines)
    rows = [line.split()[:3] for line in lines if line.startswith("rs485/m")]
    assert rows == [
        ["rs485/m1", "M-7052D", "online"],
        ["rs485/m3", "M-7055D", "online"],
        ["rs485/m4", "M-7024", "online"],
        ["rs485/m5", "M-7017R", "online"],
    ]
    running.gateway.down["rs485"] = "SerialException: gone"
    assert await asyncio.to_thread(run_status, status_args(f"http://{url}/", json=True)) == 1
    body = json.loads(capsys.readouterr().out)
    assert body["ready"] is False and "back rs485 down: SerialException: gone" in body["not_ready"]


async def test_status_of_nothing_listening_exits_2(capsys):
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    assert await asyncio.to_thread(run_status, status_args(f"127.0.0.1:{port}")) == 2
    assert "cannot reach the gateway" in capsys.readouterr().err


def test_format_status_shows_offline_modules_and_reasons():
    text = format_status(
        {
            "gateway": "g",
            "ready": False,
            "not_ready": ["front can not started"],
            "uptime_s": 3,
            "version": "0.1.0",
            "fronts": {},
            "modules": [
                {
                    "back": "b",
                    "address": 2,
                    "model": "",
                    "online": False,
                    "requests": 9,
                    "errors": {"timeout": 9},
                    "last_rtt_ms": None,
                    "last_error": "no answer",
                }
            ],
            "down": {},
            "points": {"good": 0, "comm-fault": 4},
        }
    )
    assert "NOT READY" in text and "not ready: front can not started" in text
    assert "b/m2    -      OFFLINE  9         9       -       no answer" in text
    assert text.endswith("points: 4 comm-fault")


def test_run_with_http_and_json_logs_then_status_from_another_process(tmp_path):
    cmd = FIELDGATE + [
        "--log-format",
        "json",
        "run",
        str(EXAMPLES / "i7232d-style.yaml"),
        "--simulate",
        "--http",
        "127.0.0.1:0",
        "--duration",
        "6",
        "--set",
        f"gateway.state_dir={tmp_path}",
        "--set",
        "fronts.can.channel=fieldgate-http-cli",
    ]
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    proc = subprocess.Popen(cmd, cwd=ROOT, stderr=subprocess.PIPE, text=True, env=env)
    records, url = [], None
    try:
        assert proc.stderr is not None
        for line in proc.stderr:
            records.append(json.loads(line))  # every line is one JSON object
            if "running:" in records[-1]["message"] and url:
                break
            if records[-1]["message"].startswith("HTTP status page and API on "):
                url = records[-1]["message"].split(" on ")[1]
        assert url and url.startswith("http://127.0.0.1:")
        status = subprocess.run(
            FIELDGATE + ["status", url], capture_output=True, text=True, timeout=30
        )
        assert status.returncode == 0, status.stderr
        assert status.stdout.startswith("gateway i7232d  READY")
        records += [json.loads(line) for line in proc.stderr]
    finally:
        proc.wait(timeout=30)
    assert proc.returncode == 0
    assert {"time", "level", "logger", "message"} <= set(records[0])
    assert any(r["logger"] == "fieldgate.http" and r["level"] == "info" for r in records)
    assert records[-1]["message"].startswith("gateway i7232d stopped")


async def test_status_reads_the_token_from_a_file_or_the_environment(tmp_path, capsys, monkeypatch):
    from httpkit import load_gateway, start

    token = "status-token-0123456789"
    (tmp_path / "token").write_text(token)
    gw = load_gateway(tmp_path, token_env="FIELDGATE_TEST_TOKEN")
    monkeypatch.setenv("FIELDGATE_TEST_TOKEN", token)
    running = await start(gw)
    try:
        url = f"127.0.0.1:{running.port}"
        monkeypatch.delenv("FIELDGATE_HTTP_TOKEN", raising=False)
        assert await asyncio.to_thread(run_status, status_args(url)) == 2
        assert "HTTP 401" in capsys.readouterr().err
        args = status_args(url, token_file=str(tmp_path / "token"))
        assert await asyncio.to_thread(run_status, args) == 0
        monkeypatch.setenv("FIELDGATE_HTTP_TOKEN", token)
        assert await asyncio.to_thread(run_status, status_args(url)) == 0
        assert token not in capsys.readouterr().out
    finally:
        await gw.stop()
