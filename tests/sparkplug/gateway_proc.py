"""A gateway process for the kill -9 tests: loopback back, Sparkplug front, a 10 Hz driver.

    python tests/sparkplug/gateway_proc.py TOPOLOGY.json START

The driver writes START, START+1, ... to io/m1/ao0 every 100 ms (the loopback back copies
it to io/m1/ai0) and prints ``wrote N`` 100 ms after the write (the front, in its child
process, has taken the change by then: journal or broker), so the test knows which samples
existed before it killed the process.
"""

from __future__ import annotations

import asyncio
import json
import signal
import sys

from fieldgate.runtime import Gateway


async def main(path: str, start: int) -> None:
    with open(path) as f:
        topology = json.load(f)
    gw = Gateway.load(topology)
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    loop.add_signal_handler(signal.SIGTERM, stop.set)
    async with gw:
        print("running", flush=True)
        value = start
        while not stop.is_set():
            gw.write("io/m1/ao0", value)
            try:
                await asyncio.wait_for(stop.wait(), 0.1)
            except TimeoutError:
                pass
            # the front runs in a child process: a change reaches it (and its journal) within
            # a few milliseconds, so the value written 100 ms ago is the one it has taken
            print(f"wrote {value}", flush=True)
            value += 1


if __name__ == "__main__":
    asyncio.run(main(sys.argv[1], int(sys.argv[2])))
