#!/usr/bin/env python3
"""Draw a soak's CSV (scripts/faults/soak.py) as an SVG: resident memory, CPU and the journal
and log sizes over time, broker outages shaded. No plotting library: the SVG is written here.

Run:  .venv/bin/python scripts/faults/soak_plot.py soak-run/soak.csv docs/soak.svg
"""

from __future__ import annotations

import argparse
import csv
import math
from html import escape
from pathlib import Path

PROCESSES = [
    ("fieldbus", "fieldbus process", "#1f77b4"),
    ("ua", "OPC UA child", "#d62728"),
    ("mb", "Modbus TCP child", "#2ca02c"),
    ("spb", "Sparkplug child", "#9467bd"),
    ("http", "HTTP child", "#ff7f0e"),
]
WIDTH, PANEL_H, LEFT, RIGHT, TOP, GAP = 900, 210, 70, 190, 60, 60


def number(text: str) -> float | None:
    try:
        return float(text)
    except (TypeError, ValueError):
        return None


def smooth(values: list[float | None], window: int) -> list[float | None]:
    out: list[float | None] = []
    for i in range(len(values)):
        chunk = [v for v in values[max(0, i - window + 1) : i + 1] if v is not None]
        out.append(sum(chunk) / len(chunk) if chunk else None)
    return out


def nice_max(value: float) -> float:
    if value <= 0:
        return 1.0
    exp = 10 ** math.floor(math.log10(value))
    for step in (1, 2, 2.5, 5, 10):
        if step * exp >= value:
            return step * exp
    return 10 * exp


class Panel:
    def __init__(self, index: int, title: str, unit: str, t_max: float, y_max: float):
        self.y0 = TOP + index * (PANEL_H + GAP)
        self.title, self.unit = title, unit
        self.t_max, self.y_max = t_max, y_max
        self.parts: list[str] = []

    def x(self, t: float) -> float:
        return LEFT + (WIDTH - LEFT - RIGHT) * t / self.t_max

    def y(self, v: float) -> float:
        return self.y0 + PANEL_H - PANEL_H * min(v, self.y_max) / self.y_max

    def frame(self, outages: list[tuple[float, float]]) -> None:
        p = self.parts
        for start, end in outages:
            p.append(
                f'<rect x="{self.x(start):.1f}" y="{self.y0}" width="{max(1.0, self.x(end) - self.x(start)):.1f}" '
                f'height="{PANEL_H}" fill="#eee"/>'
            )
        p.append(
            f'<rect x="{LEFT}" y="{self.y0}" width="{WIDTH - LEFT - RIGHT}" height="{PANEL_H}" '
            'fill="none" stroke="#888"/>'
        )
        p.append(
            f'<text x="{LEFT}" y="{self.y0 - 8}" font-size="14" font-weight="bold">{escape(self.title)}</text>'
        )
        for i in range(5):
            v = self.y_max * i / 4
            y = self.y(v)
            p.append(
                f'<line x1="{LEFT - 4}" y1="{y:.1f}" x2="{WIDTH - RIGHT}" y2="{y:.1f}" stroke="#ddd"/>'
            )
            p.append(
                f'<text x="{LEFT - 8}" y="{y + 4:.1f}" font-size="11" text-anchor="end">{v:g}</text>'
            )
        p.append(
            f'<text x="16" y="{self.y0 + PANEL_H / 2:.1f}" font-size="11" '
            f'transform="rotate(-90 16 {self.y0 + PANEL_H / 2:.1f})" text-anchor="middle">{escape(self.unit)}</text>'
        )
        hours = self.t_max / 3600
        step = 0.25 if hours <= 2.5 else 1.0 if hours <= 12 else 6.0
        if hours < 0.5:
            step = 0.05
        t = 0.0
        while t <= hours + 1e-9:
            x = self.x(t * 3600)
            p.append(
                f'<line x1="{x:.1f}" y1="{self.y0 + PANEL_H}" x2="{x:.1f}" y2="{self.y0 + PANEL_H + 4}" stroke="#888"/>'
            )
            p.append(
                f'<text x="{x:.1f}" y="{self.y0 + PANEL_H + 16}" font-size="11" text-anchor="middle">{t:g} h</text>'
            )
            t += step

    def line(self, times: list[float], values: list[float | None], color: str) -> None:
        points, runs = [], []
        for t, v in zip(times, values, strict=True):
            if v is None:
                if points:
                    runs.append(points)
                points = []
                continue
            points.append(f"{self.x(t):.1f},{self.y(v):.1f}")
        if points:
            runs.append(points)
        for run in runs:
            self.parts.append(
                f'<polyline fill="none" stroke="{color}" stroke-width="1.5" points="{" ".join(run)}"/>'
            )

    def legend(self, entries: list[tuple[str, str]]) -> None:
        for i, (label, color) in enumerate(entries):
            y = self.y0 + 14 + 18 * i
            x = WIDTH - RIGHT + 14
            self.parts.append(
                f'<line x1="{x}" y1="{y - 4}" x2="{x + 18}" y2="{y - 4}" stroke="{color}" stroke-width="2"/>'
            )
            self.parts.append(f'<text x="{x + 24}" y="{y}" font-size="11">{escape(label)}</text>')


def draw(rows: list[dict[str, str]], title: str) -> str:
    times = [float(r["t_s"]) for r in rows]
    t_max = max(times[-1], 1.0)
    outages: list[tuple[float, float]] = []
    start = None
    for t, r in zip(times, rows, strict=True):
        down = r.get("broker_up") == "0"
        if down and start is None:
            start = t
        elif not down and start is not None:
            outages.append((start, t))
            start = None
    if start is not None:
        outages.append((start, times[-1]))
    series = {key: [number(r.get(f"{key}_rss_mb", "")) for r in rows] for key, _, _ in PROCESSES}
    rss_max = nice_max(max(v for vs in series.values() for v in vs if v is not None) * 1.1)
    window = max(1, int(60 / max(times[1] - times[0], 1e-3))) if len(times) > 1 else 1
    cpu = {
        key: smooth([number(r.get(f"{key}_cpu_pct", "")) for r in rows], window)
        for key, _, _ in PROCESSES
    }
    cpu_max = nice_max(
        max((v for vs in cpu.values() for v in vs if v is not None), default=1) * 1.1
    )
    journal = [(number(r.get("journal_kb", "")) or 0) / 1024 for r in rows]
    log = [(number(r.get("log_kb", "")) or 0) / 1024 for r in rows]
    size_max = nice_max(max(journal + log) * 1.1)
    panels = [
        Panel(0, "resident memory (RSS)", "MB", t_max, rss_max),
        Panel(1, "CPU (1-minute mean)", "% of one core", t_max, cpu_max),
        Panel(2, "Sparkplug journal and gateway log on disk", "MB", t_max, size_max),
    ]
    for panel in panels:
        panel.frame(outages)
    for key, _label, color in PROCESSES:
        panels[0].line(times, series[key], color)
        panels[1].line(times, cpu[key], color)
    panels[0].legend([(label, color) for _, label, color in PROCESSES] + [("broker down", "#ccc")])
    panels[1].legend([(label, color) for _, label, color in PROCESSES])
    panels[2].line(times, journal, "#8c564b")
    panels[2].line(times, log, "#17becf")
    panels[2].legend([("journal (SQLite, WAL)", "#8c564b"), ("gateway log", "#17becf")])
    height = TOP + 3 * (PANEL_H + GAP)
    body = "".join(part for panel in panels for part in panel.parts)
    return (
        f'<svg xmlns="http://www.w3.org/2000/svg" width="{WIDTH}" height="{height}" '
        f'viewBox="0 0 {WIDTH} {height}" font-family="sans-serif">'
        f'<rect width="{WIDTH}" height="{height}" fill="white"/>'
        f'<text x="{LEFT}" y="22" font-size="15">{escape(title)}</text>{body}</svg>\n'
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("csv")
    parser.add_argument("svg")
    parser.add_argument("--title", default="fieldgate soak: every front busy, faults on both sides")
    args = parser.parse_args()
    with open(args.csv, newline="") as f:
        rows = list(csv.DictReader(f))
    Path(args.svg).write_text(draw(rows, args.title))


if __name__ == "__main__":
    main()
