"""Servo loop timing at 1 kHz over 30 s, with the launcher's full system up.

    python bench/servo_loop.py [--robot iiwa] [--seconds 30]

The arm is servoed on and kept moving (a slow sine on every joint streamed by
this script 20 ms ahead of the servo), so the loop does its full work:
FIFO, PyBullet step, feedback and status publishing. Lateness is how long after
its deadline a cycle started; the figures come from the servo's own
``Servo/health`` reports (histogram per one-second window) and are merged here.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
import zenoh

sys.path.insert(0, str(Path(__file__).parent))
from _system import client, launched_system  # noqa: E402

from jara_arm.schema import codec, messages  # noqa: E402
from jara_arm.schema import wire_types as w  # noqa: E402
from jara_arm.schema.keys import ArmKeys  # noqa: E402
from jara_arm.schema.operations import COMMON, OP  # noqa: E402
from jara_arm.schema.types import Time, TimedJointPos  # noqa: E402
from jara_arm.services.runtime.wire import decode_sample  # noqa: E402


def call(session: zenoh.Session, keys: ArmKeys, name: str):
    op = COMMON[name]
    reply = next(iter(session.get(keys.servo_common(name), payload=codec.encode_request(op), timeout=10)))
    return codec.decode_reply(op, reply.ok.payload.to_bytes())


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--robot", default="iiwa")
    ap.add_argument("--seconds", type=float, default=30.0)
    args = ap.parse_args()
    keys = ArmKeys("arm0")
    with launched_system(args.robot) as port, client(port) as session:
        health = session.declare_subscriber(keys.servo_health, zenoh.handlers.FifoChannel(1000))
        pub = session.declare_publisher(keys.pos_cmd)
        assert call(session, keys, OP.servoON).id == 0
        q0 = np.array(call(session, keys, OP.getFeedbackPosJoint)["pos"])
        period = 1e-3
        lead = 20
        t0 = time.monotonic()
        k = 0
        while_first = True
        while time.monotonic() - t0 < args.seconds:
            # A slow sine, 0.1 rad amplitude, 4 s period, starting at rest: never jumps.
            t = k * period
            q = q0 + 0.1 * (1 - np.cos(2 * np.pi * t / 4.0)) / 2
            pub.put(codec.encode_message(w.TIMED_JOINT_POS, TimedJointPos(Time.now(), tuple(q.tolist()))))
            k += 1
            if k > lead:
                delay = t0 + (k - lead) * period - time.monotonic()
                if delay > 0:
                    time.sleep(delay)
            if while_first:
                while health.try_recv() is not None:  # drop the start-up window
                    pass
                while_first = False
        time.sleep(1.2)
        call(session, keys, OP.servoOFF)
        reports = []
        while (s := health.try_recv()) is not None:
            reports.append(decode_sample(messages.LOOP_HEALTH, s))
    reports = reports[1:]  # the first window may include the start of streaming
    cycles = sum(r.cycles for r in reports)
    hist = np.sum([r.latenessHist for r in reports], axis=0)
    edges = list(messages.LATENESS_BIN_EDGES)
    late = sum(r.lateCycles for r in reports)
    overruns = sum(r.overruns for r in reports)
    underruns = sum(r.underruns for r in reports)
    cum = np.cumsum(hist) / max(1, cycles)

    def upper_edge(q: float) -> str:
        i = int(np.searchsorted(cum, q))
        return f"< {edges[i + 1] * 1e6:.0f} us" if i + 1 < len(edges) else f">= {edges[-1] * 1e3:.0f} ms"

    p50 = float(np.median([r.latenessP50 for r in reports]))
    p99 = float(np.max([r.latenessP99 for r in reports]))
    mx = float(np.max([r.latenessMax for r in reports]))
    print(f"servo loop, {args.robot}, 1 kHz, {len(reports)} windows, {cycles} cycles")
    print(f"lateness p50 {p50 * 1e6:.0f} us (median of windows; histogram: {upper_edge(0.5)}), "
          f"p99 {p99 * 1e6:.0f} us (worst window; histogram: {upper_edge(0.99)}), max {mx * 1e3:.2f} ms")
    print(f"late by more than one cycle: {late} ({100 * late / max(1, cycles):.3f} %), "
          f"overruns: {overruns} ({100 * overruns / max(1, cycles):.3f} %), FIFO underruns: {underruns}")
    print("histogram (lower edge [us]: cycles): " + ", ".join(
        f"{e * 1e6:.0f}: {int(c)}" for e, c in zip(edges, hist)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
