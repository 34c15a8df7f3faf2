"""IK benchmark, TRAC-IK protocol: random reachable poses, random seed configurations.

For each robot: ``--n`` configurations drawn uniformly within the hard joint
limits give the target flange poses (FK); each solve starts from another
uniform random configuration; tolerance 1e-5 m / 1e-5 rad. Prints one line
per robot: success rate, mean / p50 / p99 solve time [ms], mean iterations.

    python bench/ik.py [--robot iiwa] [--n 10000] [--seed 0]

Without ``--robot``, iiwa and panda are run. Reference (C++ TRAC-IK): 99.84 %
in 0.31 ms (iiwa), 99.70 % in 0.38 ms (Panda).
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from jara_arm.robots import ROBOTS
from jara_arm.services.planner.kinematics import Kinematics


def bench(name: str, n: int, seed: int, tol: float = 1e-5) -> str:
    kin = Kinematics(ROBOTS[name])
    lo, hi = kin.lower, kin.upper
    rng = np.random.default_rng(seed)
    goals = lo + (hi - lo) * rng.random((n, kin.axis_num))
    seeds = lo + (hi - lo) * rng.random((n, kin.axis_num))
    targets = [kin.fk(q) for q in goals]
    times = np.empty(n)
    ok = 0
    iters = 0
    outside = 0
    clock = time.perf_counter
    for i in range(n):
        t0 = clock()
        res = kin.ik(targets[i], seeds[i], tol_pos=tol, tol_rot=tol)
        times[i] = clock() - t0
        ok += res.success
        iters += res.iterations
        outside += not kin.within_limits(res.q)
    times *= 1e3
    line = (f"{name:8s} n={n} success {100.0 * ok / n:6.2f} %  mean {times.mean():.3f} ms  "
            f"p50 {np.percentile(times, 50):.3f} ms  p99 {np.percentile(times, 99):.3f} ms  "
            f"max {times.max():.2f} ms  iterations {iters / n:.1f}")
    if outside:
        line += f"  OUTSIDE LIMITS: {outside}"
    return line


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--robot", choices=sorted(ROBOTS), action="append",
                    help="robot to benchmark (repeatable; default iiwa and panda)")
    ap.add_argument("--n", type=int, default=10000, help="number of poses per robot")
    ap.add_argument("--seed", type=int, default=0, help="RNG seed of the poses")
    args = ap.parse_args(argv)
    for name in args.robot or ["iiwa", "panda"]:
        print(bench(name, args.n, args.seed), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
