"""The recorder's cost: late servo cycles of N moving arms without, then with, ``jara-arm record``.

    python bench/record.py [--arms 4] [--minutes 2] [--robot iiwa] [--timing same-host]

One system (``jara-arm up`` with N arms, as bench/soak.py starts it); every arm
driven back and forth without pause (soak.py's ``drive``) for two phases of M
minutes each: first with no recorder, then with ``jara-arm record`` (every key
of every arm, the 1 kHz streams included) writing to a temporary file. Per
phase and arm: servo cycles, cycles late by more than one period, the worst
lateness, overruns, underruns (from the servo's own ``Servo/health``); then
what the recorder wrote and its exit status. Exits 1 if the recorder failed or
dropped samples, or a call was refused.
"""

from __future__ import annotations

import argparse
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import zenoh

sys.path.insert(0, str(Path(__file__).parent))
from _system import client, launched_system  # noqa: E402
from soak import ArmTally, drive  # noqa: E402

from jara_arm.launcher.record.recording import info  # noqa: E402
from jara_arm.client import Arm  # noqa: E402
from jara_arm.schema import messages  # noqa: E402
from jara_arm.schema.keys import ArmKeys, arm_of  # noqa: E402
from jara_arm.services.runtime.wire import decode_sample  # noqa: E402


def phase(session: zenoh.Session, arm_ids: list[str], robot: str, minutes: float) -> dict[str, ArmTally]:
    """Drive every arm for ``minutes``; each arm's servo health over that time."""
    tallies = {a: ArmTally() for a in arm_ids}
    t0 = time.monotonic()
    healths: list[zenoh.Sample] = []
    # The callback only appends: no work on Zenoh's thread.
    subs = [session.declare_subscriber(ArmKeys(a).servo_health, healths.append) for a in arm_ids]
    until = time.monotonic() + minutes * 60.0
    stop = threading.Event()
    drivers = [threading.Thread(target=drive, args=(Arm(session, a), robot, until, tallies[a], stop))
               for a in arm_ids]
    for d in drivers:
        d.start()
    for d in drivers:
        d.join()
    for sub in subs:
        sub.undeclare()
    for s in healths:
        tallies[arm_of(str(s.key_expr))].add(decode_sample(messages.LOOP_HEALTH, s), time.monotonic() - t0)
    return tallies


def table(title: str, tallies: dict[str, ArmTally]) -> None:
    print(title)
    print(f"  {'arm':<5} {'cycles':>8} {'late>1T':>8} {'late %':>8} {'max ms':>7} {'overrun':>8} {'underrun':>8} "
          f"{'motions':>8} {'refused':>8}")
    for a, t in tallies.items():
        pct = 100.0 * t.late / max(1, t.cycles)
        print(f"  {a:<5} {t.cycles:>8} {t.late:>8} {pct:>8.3f} {t.lateness_max * 1e3:>7.2f} {t.overruns:>8} "
              f"{t.underruns:>8} {t.motions:>8} {len(t.refused):>8}")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--arms", type=int, default=4)
    ap.add_argument("--minutes", type=float, default=2.0, help="per phase")
    ap.add_argument("--robot", default="iiwa")
    ap.add_argument("--timing", default="same-host")
    args = ap.parse_args()
    arm_ids = [f"a{i}" for i in range(args.arms)]
    with tempfile.TemporaryDirectory() as tmp, \
            launched_system(arms=[(a, args.robot) for a in arm_ids], extra=["--timing", args.timing],
                            timeout=120.0) as port, client(port) as session:
        without = phase(session, arm_ids, args.robot, args.minutes)
        path = Path(tmp) / "bench.mcap"
        recorder = subprocess.Popen([sys.executable, "-m", "jara_arm.launcher", "record", "--connect",
                                     f"tcp/127.0.0.1:{port}", "-o", str(path)],
                                    stderr=subprocess.PIPE, text=True)
        time.sleep(2.0)  # subscribed, and the trace publishers told
        t0 = time.monotonic()
        with_recorder = phase(session, arm_ids, args.robot, args.minutes)
        recorded_for = time.monotonic() - t0
        recorder.send_signal(signal.SIGINT)
        _, err = recorder.communicate(timeout=120)
        lines = [line for line in err.splitlines() if line.strip()]
        held = info(path) if recorder.returncode in (0, 1) and path.exists() else None
        size = path.stat().st_size if path.exists() else 0
    print(f"recorder cost: {args.arms} arm(s) of {args.robot}, {args.minutes:g} min per phase, timing {args.timing}")
    table("without the recorder:", without)
    table("with jara-arm record:", with_recorder)
    late = (sum(t.late for t in without.values()), sum(t.late for t in with_recorder.values()))
    print(f"late cycles: {late[0]} without, {late[1]} with the recorder")
    print(f"recorder: exit {recorder.returncode}; {lines[-1] if lines else 'no output'}")
    if held is not None:
        rate = held.messages / max(recorded_for, 1e-9)
        print(f"recording: {held.messages} messages on {len(held.counts)} keys, {size / 1e6:.1f} MB, "
              f"{rate:.0f} msg/s over the phase")
    refused = any(t.refused for t in list(without.values()) + list(with_recorder.values()))
    return 1 if recorder.returncode != 0 or refused else 0


if __name__ == "__main__":
    sys.exit(main())
