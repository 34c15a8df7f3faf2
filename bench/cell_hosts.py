"""Soak of the secure cell over three hosts: the arm moving for M minutes on the LAN profile; every alarm is false.

    python bench/cell_hosts.py [--minutes 5]

Builds the topology of ``tests/cell_hosts.py`` (network namespaces; as root):
cell host (router, servo, planner) ── LAN 1 ± 0.5 ms, 0.1 % loss ── controller
host (router, command, alarm monitor) ── 20 ± 10 ms, 2 % loss ── operator host.
From the operator host it runs ``jara-arm demo`` (servo on, PTP, LIN, CIRC,
pause/resume, home, servo off) over and over; on the controller host
``jara-arm alarms`` prints every alarm event. Reports demos run and failed,
alarm events, the servo's late cycles (its ``Servo/health``), and exits 1 on
any alarm or failed demo.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))  # the tests' helpers

from tests.cell_hosts import ARM, CellHosts  # noqa: E402
from tests.hosts import Hosts  # noqa: E402
from tests.support import Proc  # noqa: E402


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--minutes", type=float, default=5.0)
    args = parser.parse_args()
    reason = Hosts.available()
    if reason:
        print(f"cell_hosts: cannot build the hosts here: {reason}", file=sys.stderr)
        return 2
    with tempfile.TemporaryDirectory() as tmp, Hosts() as hosts:
        cell = CellHosts(hosts, Path(tmp) / "cell")
        try:
            alarms = Proc(cell.client_argv(cell.ctrl_host, "alarms", "--arm", ARM, identity="olga"))
            health = Proc(cell.client_argv(cell.cell_host, "echo", "--arm", ARM, "Servo/health", identity="olga"))
            cell.procs += [alarms, health]
            deadline = time.monotonic() + 120
            while cell.call(cell.op_host, "getState", timeout=3).get("id") != 0:
                if time.monotonic() > deadline:
                    print("cell_hosts: the system did not come up\n" + cell.logs(), file=sys.stderr)
                    return 1
                time.sleep(0.5)
            first_health = len(health.lines)
            start = time.monotonic()
            end = start + args.minutes * 60
            demos = failed = 0
            while time.monotonic() < end:
                done = subprocess.run(cell.client_argv(cell.op_host, "demo", "--arm", ARM),
                                      capture_output=True, text=True, timeout=300)
                demos += 1
                if done.returncode != 0 or "demo done" not in done.stdout:
                    failed += 1
                    print(f"demo {demos} failed (exit {done.returncode}):\n{done.stdout[-2000:]}{done.stderr[-2000:]}")
            minutes = (time.monotonic() - start) / 60
            events = [ln for ln in alarms.lines if " RAISED " in ln]
            late = cycles = 0
            for line in health.lines[first_health:]:
                try:
                    h = json.loads(line)
                    late += int(h.get("lateCycles", 0))
                    cycles += int(h.get("cycles", 0))
                except (ValueError, TypeError, AttributeError):
                    continue
            print(f"cell_hosts: {minutes:.1f} min on the LAN profile (poor operator link): {demos} demos, "
                  f"{failed} failed; {len(events)} alarm events")
            if cycles:
                print(f"servo: {cycles} cycles, {late} late by more than one period ({100 * late / cycles:.3f} %)")
            for line in events:
                print(f"  {line}")
            return 1 if events or failed else 0
        finally:
            cell.close()


if __name__ == "__main__":
    sys.exit(main())
