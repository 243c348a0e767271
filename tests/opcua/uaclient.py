"""The independent OPC UA client, driven from the tests: node-opcua (tests/opcua/node/client.js).

It runs as a child process that takes one JSON command a line and answers one JSON line;
monitored-item notifications arrive as ``{"event": "change", ...}`` lines in between. node-opcua
comes from the npm registry (``.ci/node-opcua/install``); without it the tests that need it
fail under ``CI=true`` and are skipped elsewhere, with the reason.
"""

from __future__ import annotations

import asyncio
import json
import os
import shutil
from pathlib import Path
from typing import Any

import pytest

NODE_DIR = Path(__file__).parent / "node"
SCRIPT = NODE_DIR / "client.js"


def require_node_opcua() -> str:
    node = shutil.which("node")
    reason = ""
    if node is None:
        reason = "node is not installed (apt-get install nodejs)"
    elif not (NODE_DIR / "node_modules" / "node-opcua-client").is_dir():
        reason = "node-opcua-client is not installed: run .ci/node-opcua/install"
    if reason:
        if os.environ.get("CI") == "true":
            pytest.fail(reason)
        pytest.skip(reason)
    assert node is not None
    return node


class UaClient:
    """One node-opcua client process (one connection, one session)."""

    def __init__(self, proc: asyncio.subprocess.Process):
        self.proc = proc
        self.changes: list[dict[str, Any]] = []
        self._answers: asyncio.Queue[dict[str, Any]] = asyncio.Queue()
        self._changed = asyncio.Event()
        self._next = 0
        self._reader = asyncio.ensure_future(self._read())

    @classmethod
    async def start(cls) -> UaClient:
        node = require_node_opcua()
        proc = await asyncio.create_subprocess_exec(
            node,
            str(SCRIPT),
            stdin=asyncio.subprocess.PIPE,
            stdout=asyncio.subprocess.PIPE,
            cwd=str(NODE_DIR),
            limit=16 * 1024 * 1024,
        )
        return cls(proc)

    async def _read(self) -> None:
        assert self.proc.stdout is not None
        while True:
            line = await self.proc.stdout.readline()
            if not line:
                return
            try:
                msg = json.loads(line)
            except ValueError:
                continue  # node-opcua's own console output
            if msg.get("event"):
                self.changes.append(msg)
                self._changed.set()
            else:
                await self._answers.put(msg)

    async def call(self, cmd: str, timeout: float = 30.0, **args: Any) -> dict[str, Any]:
        assert self.proc.stdin is not None
        self._next += 1
        self.proc.stdin.write((json.dumps({"id": self._next, "cmd": cmd, **args}) + "\n").encode())
        await self.proc.stdin.drain()
        answer = await asyncio.wait_for(self._answers.get(), timeout)
        assert answer["id"] == self._next, answer
        return answer

    async def ok(self, cmd: str, **args: Any) -> dict[str, Any]:
        answer = await self.call(cmd, **args)
        assert answer["ok"], f"{cmd}: {answer.get('error')}"
        return answer

    async def wait_for(self, predicate: Any, timeout: float = 10.0) -> dict[str, Any]:
        """The first change (already received or coming) for which ``predicate`` is true."""
        seen = 0
        loop = asyncio.get_running_loop()
        deadline = loop.time() + timeout
        while True:
            for change in self.changes[seen:]:
                if predicate(change):
                    return change
            seen = len(self.changes)
            self._changed.clear()
            left = deadline - loop.time()
            if left <= 0:
                raise AssertionError(
                    f"no matching change within {timeout} s; last: {self.changes[-3:]}"
                )
            try:
                await asyncio.wait_for(self._changed.wait(), left)
            except TimeoutError:
                pass

    async def close(self) -> None:
        """Ends the client process (node-opcua's graceful close takes seconds; the server sees
        the connection drop, as it would for a client that crashed)."""
        if self.proc.returncode is None:
            self.proc.kill()
            await self.proc.wait()
        self._reader.cancel()
