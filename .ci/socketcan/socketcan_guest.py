"""One boot of a SocketCAN guest: its environment, its console, its end.

The guest runs `guest-init.sh` with a work directory on the host; the host side streams the
guest's console (its own lines to standard error, the command's output to standard output)
and reads the command's exit code from the work directory.
"""

from __future__ import annotations

import os
import re
import shlex
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections import deque
from pathlib import Path

from socketcan_backends import HERE, REPO, Backend, Uml, python, say, venv

TIMED_OUT, CANNOT_RUN = 124, 125
STARTED = "socketcan-guest: started"
FINISHED = "socketcan-guest: finished"
GUEST_SAYS = "socketcan-guest: "


# -- one guest ----------------------------------------------------------------------------------
class Outcome:
    def __init__(self, ran: bool, rc: int, reason: str = "") -> None:
        self.ran, self.rc, self.reason = ran, rc, reason


def guest_env(backend: Backend, work: Path, host_calibration: str) -> dict[str, str]:
    env = {
        "PATH": f"{venv()}/bin:/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin",
        "HOME": "/root",
        "LANG": "C.UTF-8",
        "PYTHONDONTWRITEBYTECODE": "1",
        "PYTHONUNBUFFERED": "1",
        "VIRTUAL_ENV": str(venv()),
        "CI": os.environ.get("CI", ""),
        "PY_COLORS": os.environ.get("PY_COLORS", "0"),
        "TMPDIR": "/dev/shm",
        "FIELDGATE_TEST_CAN": "socketcan:vcan0",
        "FIELDGATE_SOCKETCAN_GUEST": backend.name,
        "SOCKETCAN_HOSTNAME": os.uname().nodename,
        "SOCKETCAN_GUARD": str(
            backend.cache.build(HERE / "vector-guard.c", "vector-guard", "-pthread")
        ),
        "SOCKETCAN_CALIBRATE": str(HERE / "calibrate.py"),
        "SOCKETCAN_HOST_CALIBRATION": host_calibration,
    }
    for key, value in os.environ.items():  # the caller's test settings go through
        if (
            key.startswith(("FIELDGATE_TEST_", "HYPOTHESIS_")) or key == "PYTEST_ADDOPTS"
        ) and key not in env:
            env[key] = value
    env.update(backend.guest_settings(work))
    return env


def uml_memory_dir(mem: str, work: Path) -> str | None:
    """UML keeps the guest's RAM in a host file in TMPDIR, else /dev/shm, else /tmp. Containers
    often have a 64 MB /dev/shm: then use the work directory, so the guest does not die of SIGBUS."""
    if os.environ.get("TMPDIR"):
        return None
    try:
        need = int(float(mem[:-1]) * {"K": 2**10, "M": 2**20, "G": 2**30}[mem[-1].upper()])
        free = shutil.disk_usage("/dev/shm").free
    except (ValueError, KeyError, OSError):
        return str(work)
    return str(work) if free < need else None


def boot(backend: Backend, command: list[str], timeout_s: float, deadline: float) -> Outcome:
    work = Path(tempfile.mkdtemp(prefix="fieldgate-socketcan.", dir=os.environ.get("TMPDIR")))
    process: subprocess.Popen[bytes] | None = None
    try:
        (work / "cmd").write_text(f"cd {shlex.quote(str(REPO))}\nexec {shlex.join(command)}\n")
        calibration = subprocess.run(
            [python(), str(HERE / "calibrate.py")], capture_output=True, text=True
        )
        env = guest_env(backend, work, calibration.stdout.strip() or "0")
        (work / "env").write_text("".join(f"export {k}={shlex.quote(v)}\n" for k, v in env.items()))
        (work / "init").write_text(
            f"#!/bin/sh\nexec /bin/sh {shlex.quote(str(HERE / 'guest-init.sh'))} {shlex.quote(str(work))}\n"
        )
        (work / "init").chmod(0o755)
        mem = os.environ.get("FIELDGATE_SOCKETCAN_MEM", backend.default_mem)
        host_env = dict(os.environ, **backend.host_env())
        if isinstance(backend, Uml):
            memdir = uml_memory_dir(mem, work)
            if memdir:
                host_env["TMPDIR"] = memdir
        say(f"booting {backend.name} ({backend.what}) to run: {shlex.join(command)}")
        started_at = time.monotonic()
        process = subprocess.Popen(
            backend.argv(work, mem),
            stdin=subprocess.DEVNULL,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            env=host_env,
            start_new_session=True,
        )
        console: deque[str] = deque(maxlen=60)
        state = {"started": False, "finished": False}

        def pump() -> None:
            """Guest lines until the `started` marker; then the command's output as it comes
            (chunks, not lines: pytest's progress dots have no newline), up to `finished`."""
            assert process is not None and process.stdout is not None
            fd = process.stdout.fileno()
            pending = b""
            while True:
                chunk = os.read(fd, 65536)
                if not chunk:
                    break
                pending = (pending + chunk).replace(b"\r\n", b"\n")
                while not state["started"] and b"\n" in pending:
                    raw, pending = pending.split(b"\n", 1)
                    line = raw.decode("utf-8", "replace").replace("\r", "")
                    if line.startswith(STARTED):
                        state["started"] = True
                    elif line.startswith(GUEST_SAYS):
                        say(f"{backend.name}: {line[len(GUEST_SAYS) :]}")
                    console.append(line)
                if not state["started"] or state["finished"]:
                    continue
                marker = FINISHED.encode()
                if marker in pending:
                    state["finished"] = True
                    pending = pending[: pending.index(marker)]
                    keep = b""
                else:  # hold back what may be the start of the marker or of a CR LF
                    keep = next(
                        (
                            pending[-n:]
                            for n in range(len(marker) - 1, 0, -1)
                            if marker.startswith(pending[-n:]) or pending[-n:] == b"\r"
                        ),
                        b"",
                    )
                    pending = pending[: len(pending) - len(keep)]
                sys.stdout.buffer.write(pending)
                sys.stdout.flush()
                pending = keep
            if state["started"] and not state["finished"] and pending:
                sys.stdout.buffer.write(pending)
                sys.stdout.flush()

        reader = threading.Thread(target=pump, daemon=True)
        reader.start()
        rc_file = work / "rc"
        rc_seen_at: float | None = None
        while process.poll() is None:
            now = time.monotonic()
            if now > deadline:
                stop(process, work)
                say(
                    f"timed out after {timeout_s:g}s (FIELDGATE_SOCKETCAN_TIMEOUT); the guest was killed"
                )
                return Outcome(True, TIMED_OUT, "timed out")
            if rc_file.exists():
                rc_seen_at = rc_seen_at or now
                if now - rc_seen_at > 15:
                    say("the guest did not power off; stopping it")
                    stop(process, work)
                    break
            time.sleep(0.1)
        reader.join(5)
        stop(process, work)
        elapsed = time.monotonic() - started_at
        if (work / "refused").exists():
            return Outcome(
                False, CANNOT_RUN, f"the guard refused it: {(work / 'refused').read_text().strip()}"
            )
        if not state["started"] or not rc_file.exists():
            return Outcome(False, CANNOT_RUN, console_reason(console, process.returncode))
        rc = int(rc_file.read_text().strip() or CANNOT_RUN)
        slowdown = (work / "slowdown").read_text().strip() if (work / "slowdown").exists() else "?"
        say(
            f"{backend.name}: command exit code {rc}, stage took {elapsed:.0f}s (slowdown {slowdown})"
        )
        return Outcome(True, rc)
    finally:
        if process is not None and process.poll() is None:
            stop(process, work)
        shutil.rmtree(work, ignore_errors=True)


def console_reason(console: deque[str], exit_code: int | None) -> str:
    lines = [line.strip() for line in console if line.strip()]
    for pattern in (
        r"ptrace set fp regs failed.*",
        r"Kernel panic.*",
        r"REFUSED: .*",
        r".*failed.*",
        r"Too few physical memory.*",
        r"qemu-system.*",
    ):
        for line in lines:
            found = re.search(pattern, line)
            if found:
                return f"the guest did not start the command: {found.group(0)[:300]}"
    tail = " | ".join(lines[-3:])[:300]
    return (
        f"the guest did not start the command (exit code {exit_code}){': ' + tail if tail else ''}"
    )


def stop(process: subprocess.Popen[bytes], work: Path) -> None:
    """Kill the guest and everything it started (UML runs one host process per guest process;
    all of them carry the work directory on their command line)."""
    for sig in (signal.SIGTERM, signal.SIGKILL):
        if process.poll() is not None:
            break
        try:
            os.killpg(process.pid, sig)
        except ProcessLookupError:
            break
        try:
            process.wait(3)
        except subprocess.TimeoutExpired:
            pass
    subprocess.run(["pkill", "-KILL", "-f", str(work)], capture_output=True)
    try:
        process.wait(5)
    except subprocess.TimeoutExpired:
        pass
