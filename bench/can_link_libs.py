"""Which netlink client reads and configures SocketCAN interfaces: the measured comparison
behind fieldgate.can.link (docs/can-link.md, "Choosing the netlink client").

    python bench/can_link_libs.py [IFACE]                 # on the host: IFACE=lo (reads only)
    .ci/socketcan/run --can-controllers python bench/can_link_libs.py can0   # writes too

Candidates: fieldgate's own rtnetlink (core/can/rtnetlink.py, standard library), pyroute2
(`pip install pyroute2`; skipped when absent), and iproute2's `ip -details -json link` /
`ip link set` as a subprocess. For each: import time and resident memory added in a fresh
interpreter that has already imported asyncio (as a gateway has), time per read, time per
bit-rate change (down, set, up) on a CAN controller, and the checks that decided: a read
from inside a running asyncio and uvloop event loop, and the restart request the kernel
accepts. Figures are same-run ratios against the own client.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time

IFACE = sys.argv[1] if len(sys.argv) > 1 else "lo"
N = int(os.environ.get("BENCH_READS", "200"))

MEASURE = r"""
import asyncio, os, sys, time
import fieldgate, fieldgate.can.frame  # what a gateway has loaded before it touches the link
def rss_kb():
    return int(open("/proc/self/statm").read().split()[1]) * os.sysconf("SC_PAGE_SIZE") // 1024
rss0 = rss_kb()
t0 = time.perf_counter()
{imp}
t1 = time.perf_counter()
print((t1 - t0) * 1000, rss_kb() - rss0)
"""
IMPORTS = {
    "own": "from fieldgate.can import link",
    "pyroute2": "from pyroute2 import IPRoute",
    "ip": "import json, subprocess",
}


def fresh(imp: str) -> tuple[float, int]:
    best = (1e9, 0)
    for _ in range(3):
        out = subprocess.run(
            [sys.executable, "-c", MEASURE.format(imp=imp)], capture_output=True, text=True
        )
        if out.returncode != 0:
            raise RuntimeError(out.stderr.strip().splitlines()[-1])
        ms, kb = out.stdout.split()
        best = min(best, (float(ms), int(kb)))
    return best


def own_read() -> object:
    from fieldgate.can.link import read_link

    return read_link(IFACE)


_IPROUTE: list[object] = []


def pyroute2_read() -> object:
    """On one IPRoute kept open (its best case: opening one costs about 0.7 ms more)."""
    from pyroute2 import IPRoute

    if not _IPROUTE:
        _IPROUTE.append(IPRoute())
    return _IPROUTE[0].link("get", ifname=IFACE)  # type: ignore[attr-defined]


def pyroute2_read_in_loop() -> object:
    from pyroute2 import IPRoute

    with IPRoute() as ip:
        return ip.link("get", ifname=IFACE)


def ip_read() -> object:
    out = subprocess.run(
        ["ip", "-details", "-json", "link", "show", IFACE], capture_output=True, text=True
    )
    return json.loads(out.stdout)


def per_op(fn) -> float:
    fn()
    t = time.perf_counter()
    for _ in range(N):
        fn()
    return (time.perf_counter() - t) / N * 1e6


def in_loop(fn, loop_kind: str) -> str:
    import asyncio

    async def main() -> object:
        return fn()

    try:
        if loop_kind == "uvloop":
            import uvloop

            uvloop.run(main())
        else:
            asyncio.run(main())
        return "ok"
    except Exception as exc:  # what the library raises is the finding
        return f"{type(exc).__name__}: {str(exc)[:60]}"


def pyroute2_async_under(loop_kind: str) -> str:
    import asyncio

    try:
        from pyroute2 import AsyncIPRoute
    except ImportError:
        return "n/a"

    async def main() -> None:
        async with AsyncIPRoute() as ip:
            await ip.link("get", ifname=IFACE)

    try:
        if loop_kind == "uvloop":
            import uvloop

            uvloop.run(main())
        else:
            asyncio.run(main())
        return "ok"
    except Exception as exc:
        return f"{type(exc).__name__}: {str(exc)[:60]}"


def set_rate(kind: str, rate: int) -> None:
    if kind == "own":
        from fieldgate.can.link import LinkSettings, apply_settings

        apply_settings(IFACE, LinkSettings(rate))
    elif kind == "pyroute2":
        from pyroute2 import IPRoute

        with IPRoute() as ip:
            idx = ip.link_lookup(ifname=IFACE)[0]
            ip.link("set", index=idx, state="down")
            ip.link("set", index=idx, kind="can", can_bittiming={"bitrate": rate})
            ip.link("set", index=idx, state="up")
    else:
        for args in (
            ["down"],
            ["type", "can", "bitrate", str(rate)],
            ["up"],
        ):
            subprocess.run(["ip", "link", "set", IFACE, *args], check=True)


def restart_check(kind: str) -> str:
    """What the kernel answers to a restart of a running controller that is not bus-off:
    EBUSY (or EINVAL with restart-ms) means the request was understood."""
    if kind == "own":
        from fieldgate.can.link import LinkError, restart

        try:
            restart(IFACE)
            return "restarted"
        except LinkError as exc:
            return f"understood ({exc})"[:70]
    if kind == "pyroute2":
        from pyroute2 import IPRoute

        try:
            with IPRoute() as ip:
                idx = ip.link_lookup(ifname=IFACE)[0]
                ip.link("set", index=idx, kind="can", can_restart=True)
            return "restarted"
        except Exception as exc:
            return f"{exc}"[:70]
    out = subprocess.run(
        ["ip", "link", "set", IFACE, "type", "can", "restart"], capture_output=True, text=True
    )
    return out.stderr.strip()[:70] or "restarted"


def main() -> None:
    try:
        import pyroute2  # noqa: F401

        kinds = ["own", "pyroute2", "ip"]
    except ImportError:
        print("pyroute2 not installed: pip install pyroute2 to compare it", file=sys.stderr)
        kinds = ["own", "ip"]
    reads = {"own": own_read, "pyroute2": pyroute2_read, "ip": ip_read}
    loop_reads = {"pyroute2": pyroute2_read_in_loop}
    is_can = IFACE != "lo"
    rows = []
    for kind in kinds:
        ms, kb = fresh(IMPORTS[kind])
        read_us = per_op(reads[kind])
        row = {
            "client": kind,
            "import_ms": round(ms, 1),
            "rss_kb": kb,
            "read_us": round(read_us),
            "read in asyncio loop": in_loop(loop_reads.get(kind, reads[kind]), "asyncio"),
            "read in uvloop loop": in_loop(loop_reads.get(kind, reads[kind]), "uvloop"),
        }
        if kind == "pyroute2":
            row["AsyncIPRoute asyncio"] = pyroute2_async_under("asyncio")
            row["AsyncIPRoute uvloop"] = pyroute2_async_under("uvloop")
        if is_can:
            t = time.perf_counter()
            for rate in (125000, 250000) * 5:
                set_rate(kind, rate)
            row["rate_change_ms"] = round((time.perf_counter() - t) / 10 * 1000, 1)
            row["restart"] = restart_check(kind)
        rows.append(row)
    base = rows[0]
    for row in rows:
        ratio = row["read_us"] / max(1, base["read_us"])
        print(json.dumps({**row, "read_vs_own": round(ratio, 1)}))


if __name__ == "__main__":
    main()
