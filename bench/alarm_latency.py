"""Alarm detection latency: each fault provoked for real, repeatedly, with the full system up.

    python bench/alarm_latency.py [--repeat 5] [--only estop,jump,...]

Runs the scenarios of ``tests/test_alarms_motion.py`` and ``tests/test_alarms_services.py``
(the same system, ``tests/alarm_system.py``, the same checks) ``--repeat`` times each and
prints, per scenario, the time from the cause to the alarm event received by this client
[ms]: the e-stop put, the cycle the servo takes a command that jumps or could not stop
before a joint soft limit, the servo's timestamp of the first feedback beyond the Cartesian
box or of the first effort above the rating, the SIGKILL or SIGSTOP of a service.
Hung-service figures include the hung bound ``Health.hung_after`` (1.5 s with the
``same-host`` timing profile; ``services/runtime/timing.py``).
"""

from __future__ import annotations

import argparse
import functools
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))  # the tests' helpers
from tests import alarm_system  # noqa: E402
from tests import test_alarms_motion as motion  # noqa: E402
from tests import test_alarms_services as services  # noqa: E402

SCENARIOS = {
    "estop": motion.test_estop_during_a_lin,
    "overload": motion.test_driven_into_an_obstacle,
    "jump": motion.test_position_stream_that_jumps,
    "joint-limit": motion.test_position_stream_that_leaves_the_joint_soft_limits,
    "cartesian-limit": motion.test_control_point_crosses_the_cartesian_soft_limits,
    **{f"{service.value}-{'kill' if how == 'kill' else 'stop'}": functools.partial(
        services.test_a_service_killed_or_hung_mid_motion_is_a_fault, service=service, how=how, code=code)
       for service, how, code in (p.values for p in services.FAULTS)},
    "monitor-kill": services.test_monitor_killed_in_the_middle_of_a_motion,
    "monitor-stop": services.test_monitor_hung_by_sigstop,
}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=5, help="runs of each scenario (default: 5)")
    ap.add_argument("--only", default=",".join(SCENARIOS),
                    help=f"comma-separated scenarios (default: all of {', '.join(SCENARIOS)})")
    args = ap.parse_args()
    chosen = [name.strip() for name in args.only.split(",") if name.strip()]
    unknown = set(chosen) - set(SCENARIOS)
    if unknown:
        ap.error(f"unknown scenarios {sorted(unknown)}; choose from {', '.join(SCENARIOS)}")
    failures = 0
    with alarm_system.started_system() as arm:
        for name in chosen:
            for _ in range(args.repeat):
                arm.reset()
                try:
                    SCENARIOS[name](arm)
                except AssertionError as exc:  # report and go on: the figures of the others still count
                    failures += 1
                    print(f"{name}: FAILED: {str(exc).splitlines()[0]}\n{arm.log_tail(40)}", file=sys.stderr)
    print(f"\nalarm detection latency, cause -> alarm event received [ms] ({args.repeat} runs each):")
    print(f"  {'scenario':<40} {'n':>3} {'min':>7} {'median':>7} {'p95':>7} {'max':>7}")
    for label, values in alarm_system.LATENCIES.items():
        v = np.array(values)
        print(f"  {label:<40} {len(v):>3} {v.min():7.1f} {np.median(v):7.1f} "
              f"{np.percentile(v, 95):7.1f} {v.max():7.1f}")
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
