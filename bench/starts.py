"""Start-up: ``jara-arm up --demo`` started again and again; no start may raise an alarm.

    python bench/starts.py [--runs 20] [--robot iiwa]

Each run starts the launcher on a free port with ``--demo`` (what ``make up``
does), waits for the demo's last line, and stops it with SIGINT. Reports per
run the time to the ready line and to the demo's end, and every alarm, stall,
failed demo step, stutter (an early start's head held at its last sample, a
stream that ran dry, a clock that waited for commands) or late-cycle warning it
printed. Exits 1 if any run raised an alarm, had a failed step or stuttered.
"""

from __future__ import annotations

import argparse
import os
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
from _system import end, free_port  # noqa: E402

STUTTER = ("held at its last sample", "ran dry", "mid-motion for late commands")
ALARM = re.compile(r"alarm 0x[0-9a-f]+ (FAULT|WARNING)|raised")


def one_run(robot: str, timeout: float) -> dict:
    port = free_port()
    t0 = time.monotonic()
    proc = subprocess.Popen(
        [sys.executable, "-m", "jara_arm.launcher", "up", "--demo", "--arm", f"arm0:{robot}",
         "--listen", f"tcp/127.0.0.1:{port}"],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, start_new_session=True,
        env={**os.environ, "PYTHONUNBUFFERED": "1"})
    lines: list[str] = []
    ready_at: list[float] = []
    done = threading.Event()

    def read() -> None:
        assert proc.stdout is not None
        for line in proc.stdout:
            lines.append(line)
            if "jara-arm: ready" in line:
                ready_at.append(time.monotonic() - t0)
            if line.startswith("demo done") or line.startswith("demo:") or line.startswith("demo stopped"):
                done.set()

    threading.Thread(target=read, daemon=True).start()
    finished = done.wait(timeout)
    demo_s = time.monotonic() - t0
    time.sleep(1.0)  # anything raised right after the demo's end
    end(proc, signal.SIGINT, 20.0, group=False)
    text = "".join(lines)
    return {
        "ready_s": ready_at[0] if ready_at else None,
        "demo_s": demo_s if finished else None,
        "alarms": [l.strip() for l in lines if ALARM.search(l)],
        "failed": [l.strip() for l in lines if "FAILED" in l or "step(s) failed" in l],
        "stalls": [l.strip() for l in lines if "was silent for" in l],
        "late": [l.strip() for l in lines if "cycles late by more than one period" in l],
        # a stutter: a head that ran out before its rest (braked, then went on), a dry stream, a stopped clock
        "stutters": [l.strip() for l in lines if any(k in l for k in STUTTER)],
        "clean_stop": "Traceback" not in text,
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=20)
    ap.add_argument("--robot", default="iiwa")
    ap.add_argument("--timeout", type=float, default=120.0, help="per run, to the demo's end [s]")
    args = ap.parse_args()
    bad = 0
    for i in range(args.runs):
        r = one_run(args.robot, args.timeout)
        ok = (r["demo_s"] is not None and not r["alarms"] and not r["failed"] and not r["stutters"]
              and r["clean_stop"])
        bad += not ok
        ready = f"{r['ready_s']:.1f}" if r["ready_s"] is not None else "never"
        demo = f"{r['demo_s']:.1f}" if r["demo_s"] is not None else "never"
        print(f"run {i + 1:>2}: {'ok    ' if ok else 'FAILED'} ready {ready} s, demo done {demo} s, "
              f"{len(r['alarms'])} alarms, {len(r['failed'])} failed steps, {len(r['stalls'])} stalls, "
              f"{len(r['stutters'])} stutters, {len(r['late'])} late-cycle warnings", flush=True)
        for line in r["alarms"] + r["failed"] + r["stutters"] + r["stalls"] + r["late"]:
            print("        " + line)
    print(f"{args.runs - bad} of {args.runs} starts clean")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
