"""The machine's floor for the servo's "late cycles": an empty 1 kHz loop, real-time as the servo's clock is.

    python bench/floor.py [--seconds 30] [--priority 40] [--runs 2]

One thread, SCHED_FIFO at ``--priority`` (none without the permission: said) and a
1 µs timer slack, sleeps to each 1 ms deadline and does nothing else; a cycle is
late when it starts more than one period after its deadline, as the servo counts
it (``Servo/health``). No service, no Zenoh, no PyBullet: what this loop misses,
the servo cannot make, so a figure here bounds every soak's (``bench/soak.py``).
Run it with nothing else running; the VM's steal time (``vmstat``) is worth
reading beside it.
"""

from __future__ import annotations

import argparse
import ctypes
import os
import time

PERIOD_NS = 1_000_000
_PR_SET_TIMERSLACK = 29


def run(seconds: float) -> tuple[int, int, float]:
    """(cycles, late cycles, max lateness [ms]) of ``seconds`` of the empty loop."""
    n = int(seconds * 1e9 / PERIOD_NS)
    t0 = time.monotonic_ns()
    late, worst = 0, 0
    for k in range(1, n + 1):
        due = t0 + k * PERIOD_NS
        ahead = due - time.monotonic_ns()
        if ahead > 0:
            time.sleep(ahead / 1e9)
        lateness = time.monotonic_ns() - due
        worst = max(worst, lateness)
        late += lateness > PERIOD_NS
    return n, late, worst / 1e6


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seconds", type=float, default=30.0, help="length of one run [s]")
    ap.add_argument("--priority", type=int, default=40, help="SCHED_FIFO priority (the servo's clock: 40)")
    ap.add_argument("--runs", type=int, default=2)
    args = ap.parse_args()
    ctypes.CDLL(None).prctl(_PR_SET_TIMERSLACK, 1, 0, 0, 0)
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(args.priority))
    except OSError as exc:
        print(f"without real-time priority ({exc}): the figures are the normal scheduler's")
    for r in range(args.runs):
        n, late, worst = run(args.seconds)
        print(f"run {r + 1}: {late} of {n} cycles late by more than 1 ms ({100 * late / n:.2f} %), "
              f"max lateness {worst:.2f} ms")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
