"""``fieldgate status [URL]``: a running gateway's status as a table, from its HTTP API.

Exit status: 0 ready, 1 reachable but not ready, 2 not reachable or not a fieldgate
(so scripts and health checks can use it). The token comes from ``--token-file`` or the
environment variable ``FIELDGATE_HTTP_TOKEN``, never from the command line (it would
show in ``ps``).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import urllib.error
import urllib.request
from pathlib import Path
from typing import Any

from .exitcodes import ExitCode

DEFAULT_URL = "http://127.0.0.1:8400/"
TOKEN_ENV = "FIELDGATE_HTTP_TOKEN"
TIMEOUT_S = 5.0


def configure_status(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "url",
        nargs="?",
        default=DEFAULT_URL,
        help=f"the gateway's HTTP address (default {DEFAULT_URL}); HOST:PORT works too",
    )
    p.add_argument(
        "--token-file",
        metavar="FILE",
        help=f"file holding the gateway's token (default: ${TOKEN_ENV}, if set)",
    )
    p.add_argument("--json", action="store_true", help="print the status JSON instead of a table")


class StatusError(Exception):
    pass


def _base(url: str) -> str:
    if "://" not in url:
        url = "http://" + url
    return url if url.endswith("/") else url + "/"


def fetch_status(url: str, token: str | None) -> dict[str, Any]:
    request = urllib.request.Request(_base(url) + "api/v1/status")
    if token:
        request.add_header("Authorization", f"Bearer {token}")
    try:
        with urllib.request.urlopen(request, timeout=TIMEOUT_S) as response:
            body = json.loads(response.read())
    except urllib.error.HTTPError as exc:
        detail = exc.read().decode("utf-8", "replace").strip()
        raise StatusError(f"{_base(url)}: HTTP {exc.code}: {detail}") from None
    except (urllib.error.URLError, OSError, TimeoutError) as exc:
        reason = getattr(exc, "reason", exc)
        raise StatusError(f"{_base(url)}: cannot reach the gateway ({reason})") from None
    except ValueError:
        raise StatusError(
            f"{_base(url)}: the answer is not a fieldgate status (not JSON)"
        ) from None
    if not isinstance(body, dict) or "gateway" not in body or "ready" not in body:
        raise StatusError(f"{_base(url)}: the answer is not a fieldgate status")
    return body


def _table(rows: list[list[str]]) -> list[str]:
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    return [
        "  ".join(cell.ljust(w) for cell, w in zip(row, widths, strict=True)).rstrip()
        for row in rows
    ]


def format_status(st: dict[str, Any]) -> str:
    lines = [
        f"gateway {st['gateway']}  {'READY' if st['ready'] else 'NOT READY'}  "
        f"up {st.get('uptime_s', 0):.0f} s  fieldgate {st.get('version', '?')}"
    ]
    for reason in st.get("not_ready", []):
        lines.append(f"  not ready: {reason}")
    rows = [["front", "state", "master", "bus", "restarts"]]
    for name, f in st.get("fronts", {}).items():
        state = f.get("nmt_state") or f.get("state") or "-"
        bus = f.get("bus") or {}
        bus_text = (
            "-"
            if not bus
            else (
                "BUS-OFF" if bus.get("bus_off") else f"rx {bus.get('rx', 0)} tx {bus.get('tx', 0)}"
            )
        )
        rows.append(
            [
                name,
                str(state),
                "ok" if f.get("master_ok") else "LOST",
                bus_text,
                str(f.get("restarts", 0)),
            ]
        )
    if len(rows) > 1:
        lines += ["", *_table(rows)]
    rows = [["module", "model", "health", "requests", "errors", "rtt ms", "last error"]]
    down = st.get("down", {})
    for m in st.get("modules", []):
        health = "DOWN" if m["back"] in down else "online" if m["online"] else "OFFLINE"
        rtt = "-" if m.get("last_rtt_ms") is None else f"{m['last_rtt_ms']:.1f}"
        errors = sum(m.get("errors", {}).values())
        rows.append(
            [
                f"{m['back']}/m{m['address']}",
                m.get("model") or "-",
                health,
                str(m["requests"]),
                str(errors),
                rtt,
                m.get("last_error", ""),
            ]
        )
    if len(rows) > 1:
        lines += ["", *_table(rows)]
    rows = [["process", "pid", "state", "rss MB", "limit MB", "cpu s", "resyncs", "kills"]]
    for name, c in st.get("children", {}).items():
        kills = c.get("kills") or {}
        rows.append(
            [
                name,
                str(c.get("pid") or "-"),
                str(c.get("state", "-")),
                f"{c.get('rss_mb', 0):.0f}",
                str(c.get("memory_limit_mb", "-")),
                f"{c.get('cpu_s', 0):.1f}",
                str(c.get("resyncs", 0)),
                ", ".join(f"{k} {n}" for k, n in kills.items()) or "-",
            ]
        )
    if len(rows) > 1:
        lines += ["", *_table(rows)]
    points = st.get("points", {})
    if points:
        lines += ["", "points: " + ", ".join(f"{n} {q}" for q, n in points.items() if n)]
    return "\n".join(lines)


def run_status(args: argparse.Namespace) -> int:
    token = None
    if args.token_file:
        try:
            token = Path(args.token_file).read_text(encoding="utf-8").strip()
        except OSError as exc:
            print(
                f"fieldgate status: --token-file {args.token_file}: {exc.strerror}", file=sys.stderr
            )
            return ExitCode.CANNOT_RUN
    else:
        token = os.environ.get(TOKEN_ENV) or None
    try:
        st = fetch_status(args.url, token)
    except StatusError as exc:
        print(f"fieldgate status: {exc}", file=sys.stderr)
        return ExitCode.CANNOT_RUN
    print(json.dumps(st, indent=2) if args.json else format_status(st))
    return ExitCode.OK if st["ready"] else ExitCode.FAILED
