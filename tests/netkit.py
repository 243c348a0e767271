"""Small helpers the network-facing tests share (OPC UA, Modbus TCP, Sparkplug, the HTTP page)."""

from __future__ import annotations

import asyncio
import contextlib
import socket
from collections.abc import Callable, Iterator


def free_port() -> int:
    """A TCP port on 127.0.0.1 that was free a moment ago."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


async def wait_until(condition: Callable[[], object], timeout: float = 5.0) -> None:
    """Poll ``condition`` on the loop until it holds; fail the test after ``timeout`` seconds."""
    loop = asyncio.get_running_loop()
    deadline = loop.time() + timeout
    while not condition():
        assert loop.time() < deadline, "condition not met in time"
        await asyncio.sleep(0.01)


@contextlib.contextmanager
def blackhole_port() -> Iterator[int | None]:
    """A loopback port whose SYNs go unanswered, as a host that is switched off: a listener
    with a backlog of 0 that never accepts, its one queue place taken (Linux drops further
    SYNs, so a connect hangs). None where this kernel answers them anyway."""
    with socket.socket() as listener:
        listener.bind(("127.0.0.1", 0))
        listener.listen(0)
        port = int(listener.getsockname()[1])
        with socket.create_connection(("127.0.0.1", port), timeout=2), socket.socket() as probe:
            probe.settimeout(0.3)
            try:
                probe.connect(("127.0.0.1", port))
            except OSError:  # TimeoutError too: the blackhole holds
                yield port
                return
            yield None
