"""The guest's slowdown against the host, for tests that wait on the clock.

`python3 calibrate.py` prints the seconds a fixed pure-Python workload takes here (best of
five); `python3 calibrate.py HOST_SECONDS` prints this machine's factor against that figure
(one decimal, at least 1.0; below 1.5 it prints 1.0: native speed, noise aside).
"""

import sys
import time


def workload() -> int:
    total = 0
    table: dict[int, int] = {}
    for i in range(60_000):
        table[i % 977] = table.get(i % 977, 0) + i
        total += len(str(i)) * (i & 7)
    return total + len(table)


def best_of(runs: int) -> float:
    best = float("inf")
    for _ in range(runs):
        start = time.perf_counter()
        workload()
        best = min(best, time.perf_counter() - start)
    return best


if __name__ == "__main__":
    here = best_of(5)
    if len(sys.argv) < 2:
        print(f"{here:.6f}")
    else:
        factor = here / float(sys.argv[1])
        print("1.0" if factor < 1.5 else f"{factor:.1f}")
