"""Flood a SocketCAN interface with other nodes' frames, as fast as one Python sender goes.

    python bench/can_flood.py --channel vcan0 --seconds 3 [--ids 0x181-0x1FF] [--rate 0]

Sends 8-byte data frames on the identifiers of ``--ids`` in turn (default 0x181-0x1FF:
other nodes' TPDO1s, never ours) through a raw ``AF_CAN`` socket (the standard library, no
python-can: the fastest a Python sender gets), ``--rate`` frames/s (0: as fast as it can).
A full transmit queue (ENOBUFS) is waited out, not counted. Prints one JSON line:
``{"frames": N, "seconds": S, "rate": N/S}``. Used by bench/can_load.py and
tests/socketcan/test_socketcan_can_load.py; needs Linux with SocketCAN (inside User-Mode Linux here).
"""

from __future__ import annotations

import argparse
import errno
import json
import socket
import struct
import time

FRAME = struct.Struct("=IB3x8s")  # struct can_frame


def parse_ids(text: str) -> list[int]:
    ids: list[int] = []
    for part in text.split(","):
        lo, _, hi = part.partition("-")
        ids.extend(range(int(lo, 0), int(hi or lo, 0) + 1))
    return ids


def flood(channel: str, seconds: float, ids: list[int], rate: float = 0.0) -> dict[str, float]:
    sock = socket.socket(socket.AF_CAN, socket.SOCK_RAW, socket.CAN_RAW)
    sock.setsockopt(socket.SOL_CAN_RAW, socket.CAN_RAW_FILTER, b"")  # receive nothing
    sock.bind((channel,))
    frames = [FRAME.pack(i, 8, bytes([i & 0xFF] * 8)) for i in ids]
    start = time.monotonic()
    end = start + seconds
    sent = 0
    period = 1.0 / rate if rate > 0 else 0.0
    n = len(frames)
    send = sock.send
    while True:
        now = time.monotonic()
        if now >= end:
            break
        if period:
            due = start + sent * period
            if due > now:
                time.sleep(min(due - now, 0.001))
                continue
        try:
            send(frames[sent % n])
            sent += 1
        except OSError as exc:
            if exc.errno != errno.ENOBUFS:
                raise
            time.sleep(0.0002)  # the interface's queue is full: let the receivers catch up
    elapsed = time.monotonic() - start
    sock.close()
    return {"frames": sent, "seconds": round(elapsed, 3), "rate": round(sent / elapsed, 1)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--channel", default="vcan0")
    parser.add_argument("--seconds", type=float, default=3.0)
    parser.add_argument("--ids", default="0x181-0x1FF", help="e.g. 0x181-0x1FF,0x281")
    parser.add_argument("--rate", type=float, default=0.0, help="frames/s; 0 = as fast as it goes")
    args = parser.parse_args()
    print(json.dumps(flood(args.channel, args.seconds, parse_ids(args.ids), args.rate)), flush=True)


if __name__ == "__main__":
    main()
