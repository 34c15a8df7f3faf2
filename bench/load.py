"""Query load: client processes asking as fast as they can while the arm moves.

    python bench/load.py [--clients 10] [--seconds 60] [--robot iiwa]

Starts ``jara-arm up`` with one arm, keeps it moving as ``bench/soak.py`` does,
and runs ``--clients`` processes, each with its own Zenoh session, that call
``getState``, ``getFeedbackPosJoint`` and ``getFeedbackPosCartesian`` in turn
with no pause. Reports queries per second, reply time p50/p99/max per
operation, and what the arm noticed: alarms, late servo cycles, underruns.
Exits 1 if an alarm was raised or a motion call was refused.
"""

from __future__ import annotations

import argparse
import multiprocessing
import sys
import threading
import time
from pathlib import Path

import numpy as np
import zenoh

sys.path.insert(0, str(Path(__file__).parent))
from _system import client, launched_system, percentile  # noqa: E402
from soak import ArmTally, drive  # noqa: E402

from jara_arm.client import Arm  # noqa: E402
from jara_arm.schema import messages  # noqa: E402
from jara_arm.schema.keys import ArmKeys  # noqa: E402
from jara_arm.schema.operations import OP, Interface  # noqa: E402
from jara_arm.services.runtime.wire import decode_sample  # noqa: E402
from jara_arm.services.runtime.zenoh_args import zenoh_config  # noqa: E402

OPS = (OP.getState, OP.getFeedbackPosJoint, OP.getFeedbackPosCartesian)


def querier(port: int, arm: str, seconds: float, out: multiprocessing.Queue) -> None:  # pragma: no cover
    """One client process: the three queries in turn for ``seconds``; puts {op: [reply times]}."""
    times: dict[str, list[float]] = {op: [] for op in OPS}
    errors = 0
    with zenoh.open(zenoh_config("client", connect=[f"tcp/127.0.0.1:{port}"])) as session:
        arm_client = Arm(session, arm, timeout=5.0)
        end = time.monotonic() + seconds
        k = 0
        while time.monotonic() < end:
            op = OPS[k % len(OPS)]
            k += 1
            t0 = time.perf_counter()
            try:
                interface = Interface.MIDDLE if op == OP.getFeedbackPosCartesian else Interface.COMMON
                reply = arm_client.call(interface, op)
                if reply.id != 0:
                    errors += 1
            except Exception:
                errors += 1
                continue
            times[op].append(time.perf_counter() - t0)
    out.put((times, errors))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--clients", type=int, default=10)
    ap.add_argument("--seconds", type=float, default=60.0)
    ap.add_argument("--robot", default="iiwa")
    args = ap.parse_args()
    arm = "a0"
    tally = ArmTally()
    alarms: list[str] = []
    ctx = multiprocessing.get_context("spawn")
    with launched_system(arms=[(arm, args.robot)]) as port, client(port) as session:
        def on_alarm(s: zenoh.Sample) -> None:
            ev = decode_sample(messages.ALARM_EVENT, s)
            if ev.event == "raised":
                alarms.append(f"0x{ev.alarm.code:02x} {ev.alarm.type.value}: {ev.alarm.description}")

        def on_health(s: zenoh.Sample) -> None:
            tally.add(decode_sample(messages.LOOP_HEALTH, s), time.monotonic())

        keys = ArmKeys(arm)
        subs = [session.declare_subscriber(keys.alarm, on_alarm),
                session.declare_subscriber(keys.servo_health, on_health)]
        stop = threading.Event()
        # Clients start first; the arm moves for their whole run.
        out: multiprocessing.Queue = ctx.Queue()
        procs = [ctx.Process(target=querier, args=(port, arm, args.seconds, out)) for _ in range(args.clients)]
        for p in procs:
            p.start()
        time.sleep(2.0)  # the clients' imports and sessions (not counted: each measures its own window)
        until = time.monotonic() + args.seconds
        driver = threading.Thread(target=drive, args=(Arm(session, arm), args.robot, until, tally, stop))
        driver.start()
        results = [out.get(timeout=args.seconds + 60) for _ in procs]
        for p in procs:
            p.join()
        driver.join()
        for s in subs:
            s.undeclare()
    total = sum(len(v) for r, _ in results for v in r.values())
    errors = sum(e for _, e in results)
    print(f"load: {args.clients} client processes, {args.seconds:.0f} s, arm {args.robot} moving")
    print(f"queries: {total} in all, {total / args.seconds:.0f} per s, {errors} errors")
    print(f"{'operation':<26} {'count':>7} {'p50 ms':>8} {'p99 ms':>8} {'max ms':>8}")
    for op in OPS:
        t = np.array([x for r, _ in results for x in r[op]])
        if t.size:
            print(f"{op:<26} {t.size:>7} {percentile(t, 50) * 1e3:>8.2f} {percentile(t, 99) * 1e3:>8.2f} "
                  f"{t.max() * 1e3:>8.2f}")
    pct = 100.0 * tally.late / max(1, tally.cycles)
    print(f"servo: {tally.cycles} cycles, {tally.late} late by more than one period ({pct:.3f} %), "
          f"max lateness {tally.lateness_max * 1e3:.2f} ms, {tally.overruns} overruns, {tally.underruns} underruns; "
          f"{tally.motions} motions, {len(tally.refused)} refused")
    for line in tally.refused[:10]:
        print("  refused: " + line)
    print(f"alarms raised: {len(alarms)}")
    for line in alarms:
        print("  " + line)
    return 1 if alarms or tally.refused else 0


if __name__ == "__main__":
    sys.exit(main())
