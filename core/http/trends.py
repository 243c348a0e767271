"""The last minutes of every analog input, sampled from the process image for trend plots.

One task samples the AI channels once per ``period`` (default 1 s) into a ring of
``window`` samples each: a page that opens later still shows the last minutes. It reads
the image only (no bus traffic); the cost is one list append per AI per second.
"""

from __future__ import annotations

import asyncio
import time
from collections import deque
from collections.abc import Callable
from typing import Any

from ..image import DataType, Kind, ProcessImage, Quality

PERIOD_S = 1.0
WINDOW = 300  # samples: 5 minutes at 1 s


class TrendRecorder:
    def __init__(
        self,
        image: ProcessImage,
        period: float = PERIOD_S,
        window: int = WINDOW,
        wall: Callable[[], float] = time.time,
    ):
        self.image = image
        self.period = period
        self.window = window
        self.wall = wall
        self.channels = [c for c in image.channels(kind=Kind.AI) if c.dtype is not DataType.STRING]
        self.series: dict[str, deque[tuple[float, float | None]]] = {
            c.id: deque(maxlen=window) for c in self.channels
        }
        self._task: asyncio.Task[None] | None = None

    def sample(self) -> None:
        now = round(self.wall(), 3)
        for ch in self.channels:
            good = ch.quality is Quality.GOOD or ch.quality is Quality.STALE
            value: float | None = None
            if good:
                scaling = ch.spec.scaling
                raw = float(ch.value)
                value = round(scaling.to_engineering(raw), 6) if scaling is not None else raw
            self.series[ch.id].append((now, value))

    async def _run(self) -> None:
        while True:
            self.sample()
            await asyncio.sleep(self.period)

    def start(self) -> None:
        if self.channels and self._task is None:
            self._task = asyncio.get_running_loop().create_task(
                self._run(), name="fieldgate:trends"
            )

    async def stop(self) -> None:
        if self._task is not None:
            self._task.cancel()
            await asyncio.gather(self._task, return_exceptions=True)
            self._task = None

    def as_dict(self) -> dict[str, Any]:
        return {
            "period_s": self.period,
            "window": self.window,
            "series": {
                ch.id: {
                    "unit": ch.spec.scaling.unit if ch.spec.scaling is not None else "",
                    "samples": [list(s) for s in self.series[ch.id]],
                }
                for ch in self.channels
            },
        }
