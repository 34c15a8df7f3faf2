"""Jog latencies on the live system: how soon a held jog moves the arm, and how soon it holds again.

    python bench/jog.py [--tries 20] [--robot iiwa] [--ratio 20] [--lease-ms 200]

Each try jogs J1 (alternately forward and back) as a pendant would: ``Ext/jogJoint`` renewed every 50 ms
for 0.5 s, then ended once by ``Ext/jogStop`` and once by letting the lease lapse. Times come from the
servo's own feedback stamps (``Servo/posFeedback``, every sample, the same host's clock as this client):

* start: from sending the first call to the first sample that moved (more than 1e-6 rad);
* jogStop, braking: from sending ``jogStop`` to the first 20 ms window whose speed fell below 95 % of the
  cruise speed; at rest: to the last sample that still moved (more than 1e-3 rad/s over 20 ms);
* lapse, at rest: from the lease's end (the last renewal sent plus ``leaseMs``) to the last sample that
  still moved.

Prints the median and the max of each [ms]. Run it alone: a test run or another benchmark beside it
changes the figures.
"""

from __future__ import annotations

import argparse
import sys
import threading
import time
from pathlib import Path

import numpy as np
import zenoh

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _system import launched_system  # noqa: E402

from jara_arm.client import Arm  # noqa: E402
from jara_arm.schema import codec  # noqa: E402
from jara_arm.schema import wire_types as w  # noqa: E402

WINDOW = 0.02  # [s] speeds over this many seconds of samples


class Feedback:
    """Every ``Servo/posFeedback`` sample, stamped by the servo: (t [s], J1 [rad])."""

    def __init__(self, session: zenoh.Session, key: str) -> None:
        self._sub = session.declare_subscriber(key, zenoh.handlers.FifoChannel(1 << 17))
        self._lock = threading.Lock()
        self._t: list[float] = []
        self._q: list[float] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            sample = self._sub.try_recv()  # not recv(): it would hold the subscriber while close() undeclares it
            if sample is None:
                time.sleep(0.002)
                continue
            msg = codec.decode_message(w.TIMED_JOINT_POS, sample.payload.to_bytes())
            with self._lock:
                self._t.append(msg.tm.to_seconds())
                self._q.append(msg.pos[0])

    def since(self, t0: float) -> tuple[np.ndarray, np.ndarray]:
        with self._lock:
            t, q = np.array(self._t), np.array(self._q)
        keep = t >= t0
        return t[keep], q[keep]

    def close(self) -> None:
        self._stop.set()
        self._thread.join(1.0)
        self._sub.undeclare()


def speed(t: np.ndarray, q: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """(window end times, |speed| [rad/s]) over windows of ``WINDOW`` [s] of samples ``dt`` apart."""
    n = max(1, int(round(WINDOW / dt)))
    return t[n:], np.abs(q[n:] - q[:-n]) / (t[n:] - t[:-n])


def hold(arm: Arm, ratio: float, lease_ms: int, seconds: float) -> float:
    """Renew the jog every 50 ms for ``seconds``; the wall time the last renewal was sent."""
    end, last = time.monotonic() + seconds, time.time()
    while time.monotonic() < end:
        last = time.time()
        arm.jogJoint(1, ratio, lease_ms)
        time.sleep(0.05)
    return last


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--tries", type=int, default=20)
    ap.add_argument("--robot", default="iiwa")
    ap.add_argument("--ratio", type=float, default=20.0, help="speedRatio [%%] (default: 20)")
    ap.add_argument("--lease-ms", type=int, default=200)
    args = ap.parse_args()
    starts, braking, stopped, lapsed = [], [], [], []
    with launched_system(robot=args.robot) as port, Arm.connect(f"tcp/127.0.0.1:{port}", timeout=20) as arm:
        arm.wait_alive()
        arm.servoON()
        fb = Feedback(arm.session, arm.keys.pos_feedback)
        dt = arm.getManipInfo().cmdCycle * 1e-3  # [ms] -> [s]
        try:
            for k in range(args.tries):
                sign = 1.0 if k % 2 == 0 else -1.0
                for ending in ("jogStop", "lapse"):
                    arm.wait_idle()
                    time.sleep(0.1)  # the world at rest, held
                    t0 = time.time()
                    last = hold(arm, sign * args.ratio, args.lease_ms, 0.5)
                    if ending == "jogStop":
                        asked = time.time()
                        arm.jogStop()
                    else:
                        asked = last + args.lease_ms / 1e3
                    arm.wait_idle()
                    time.sleep(0.05)
                    t, q = fb.since(t0 - 0.05)
                    moved = t[np.abs(q - q[0]) > 1e-6]
                    ts, v = speed(t, q, dt)
                    still = ts[v > 1e-3]
                    if ending == "jogStop":
                        starts.append(moved[0] - t0)
                        cruise = np.median(v[(ts > asked - 0.2) & (ts < asked)])
                        after = ts > asked
                        braking.append(ts[after][v[after] < 0.95 * cruise][0] - asked)
                        stopped.append(still[-1] - asked)
                    else:
                        lapsed.append(still[-1] - asked)
                print(f"try {k + 1}: start {starts[-1] * 1e3:.1f} ms, jogStop braking {braking[-1] * 1e3:.1f} ms, "
                      f"at rest {stopped[-1] * 1e3:.1f} ms, lapse at rest {lapsed[-1] * 1e3:.1f} ms", flush=True)
        finally:
            fb.close()
    print(f"\n{args.robot} J1 at {args.ratio:g} %, lease {args.lease_ms} ms, {args.tries} tries [ms]: median / max")
    for name, values in (("start (first call -> first moved sample)", starts),
                         ("jogStop -> braking", braking), ("jogStop -> at rest", stopped),
                         ("lease end -> at rest", lapsed)):
        a = np.array(values) * 1e3
        print(f"  {name:42s} {np.median(a):7.1f} / {a.max():7.1f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
