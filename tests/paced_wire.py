"""A serial wire for the tests that paces every byte at the baud rate (test side, independent
of fieldgate's own PtyPair and of the code under test).

Two pseudo-terminals joined by a relay running in a process of its own (so the code under
test, its event loop and its GIL never delay the wire; as root it also runs at a higher
priority, as a UART does not wait for the CPU). A byte written at one end reaches the other
end one character time after the previous byte left (10 bits a character: 8N1), on an
absolute schedule, so a 255-byte reply at 9600 baud takes 266 ms from its first byte to its
last, as on a real RS-485 line; a reply whose writer hands it over at once still starts
arriving after one character time. ``echo``: what end ``a`` sends comes back to ``a`` as it
goes out (a 2-wire adapter that hears itself). ``corrupt(after, value)``: once, the byte
towards ``a`` that follows ``after`` more bytes arrives as ``value`` (a hit by noise).
"""

from __future__ import annotations

import os
import select
import subprocess
import sys
import time
import tty


def _raw_pty() -> tuple[int, int]:
    master, slave = os.openpty()
    tty.setraw(master)
    tty.setraw(slave)
    return master, slave


class PacedWire:
    def __init__(self, baudrate: int, *, bits: int = 10, echo: bool = False):
        self._a = _raw_pty()
        self._b = _raw_pty()
        self.a = os.ttyname(self._a[1])
        self.b = os.ttyname(self._b[1])
        control_r, self._control = os.pipe()
        ready_r, ready_w = os.pipe()
        self._relay = subprocess.Popen(
            [
                sys.executable,
                __file__,
                str(self._a[0]),
                str(self._b[0]),
                str(control_r),
                str(bits / baudrate),
                "1" if echo else "0",
                str(ready_w),
            ],
            pass_fds=(self._a[0], self._b[0], control_r, ready_w),
        )
        os.close(control_r)
        os.close(ready_w)
        os.read(ready_r, 1)  # the relay runs: no byte waits for it to start
        os.close(ready_r)

    def corrupt(self, after: int, value: int) -> None:
        os.write(self._control, f"{after} {value}\n".encode())
        time.sleep(0.05)  # the relay has read it before the next request goes out

    def close(self) -> None:
        os.close(self._control)  # the relay ends when its control pipe closes
        try:
            self._relay.wait(timeout=2)
        except subprocess.TimeoutExpired:
            self._relay.kill()
            self._relay.wait()
        for fd in (*self._a, *self._b):
            try:
                os.close(fd)
            except OSError:
                pass

    def __enter__(self) -> PacedWire:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _relay(a: int, b: int, control: int, char: float, echo: bool, ready: int) -> None:
    try:
        os.setpriority(os.PRIO_PROCESS, 0, -10)
    except OSError:
        pass  # not root: the normal priority
    os.write(ready, b"!")
    os.close(ready)
    free_at = {a: 0.0, b: 0.0}  # per direction: when the wire is free for the next character
    corrupt: list[int] | None = None
    while True:
        ready, _, _ = select.select([a, b, control], [], [], 0.5)
        if control in ready:
            line = os.read(control, 64)
            if not line:
                return
            after, value = (int(x) for x in line.split())
            corrupt = [after, value]
        for src in (s for s in (a, b) if s in ready):
            try:
                data = os.read(src, 4096)
            except OSError:
                return
            dst = b if src == a else a
            free_at[src] = max(free_at[src], time.perf_counter())
            for byte in data:
                if src == b and corrupt is not None:
                    corrupt[0] -= 1
                    if corrupt[0] < 0:
                        byte = corrupt[1]
                        corrupt = None
                free_at[src] += char
                delay = free_at[src] - time.perf_counter()
                if delay > 0:
                    time.sleep(delay)
                try:
                    os.write(dst, bytes([byte]))
                    if src == a and echo:
                        os.write(a, bytes([byte]))
                except OSError:
                    return


class SimulatorProcess:
    """``fieldgate simulate ARGS...`` in a process of its own (as root at a higher priority: a
    module does not wait for the CPU), so that the gateway under test and its loop never
    delay the module's answers. ``outputs`` collects the ``output <channel> = <value>``
    lines it prints; ``command`` types at its prompt."""

    def __init__(self, *args: str, ready: str = "simulating"):
        import threading

        self.proc = subprocess.Popen(
            [sys.executable, "-m", "fieldgate", "simulate", *args],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
            preexec_fn=_raise_priority,
        )
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            if line.startswith(ready):
                break
        else:
            self.close()
            raise RuntimeError("the simulator did not start")
        self.outputs: list[str] = []
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    @classmethod
    def modbus(
        cls, topology: dict, port: str, folder: str, sets: tuple[str, ...] = ()
    ) -> SimulatorProcess:
        """The modules of ``topology``'s first back (``fieldgate simulate modbus --topology``)."""
        import json

        path = os.path.join(folder, "sim-modbus.json")
        with open(path, "w") as f:
            json.dump(topology, f)
        sets_args = [x for s in sets for x in ("--set", s)]
        return cls("modbus", "--topology", path, "--port", port, *sets_args)

    def command(self, line: str) -> None:
        """A command of the simulator's prompt (``fault 1 delay 1 delay=0.05``, ``set ...``)."""
        assert self.proc.stdin is not None
        self.proc.stdin.write(line + "\n")
        self.proc.stdin.flush()
        time.sleep(0.2)  # read and applied before the next request

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            if line.startswith("output "):
                self.outputs.append(line.strip())

    def close(self) -> None:
        self.proc.terminate()
        try:
            self.proc.wait(timeout=5)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()

    def __enter__(self) -> SimulatorProcess:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _raise_priority() -> None:
    try:
        os.setpriority(os.PRIO_PROCESS, 0, -10)
    except OSError:
        pass


if __name__ == "__main__":
    a_fd, b_fd, control_fd, char_s, echo_on, ready_fd = sys.argv[1:7]
    _relay(int(a_fd), int(b_fd), int(control_fd), float(char_s), echo_on == "1", int(ready_fd))
