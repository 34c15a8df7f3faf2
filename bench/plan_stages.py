"""Where a LIN's and a CIRC's time to the first position command goes, stage by stage, in process (no services).

For a 0.5 m LIN and a half circle (radius 0.15 m) at 0.25 m/s on iiwa and panda
(the motions of ``bench/motion.py``), median over ``--n`` plans of each stage:

* profile: the Ruckig profile and its samples (``move_profile``, ``PathProfile.sample``);
* poses: the Cartesian path's poses at the samples and at the knots' stencils, as IK must meet them;
* IK at knots and tangents: ``PathJoints._solve`` and ``PathJoints._tangent``;
* spline: the Hermite spline at every sample; check: batched FK of every sample (``PathJoints._bad``);
* speed: the joint speed check on the dense samples; table: ``TableMap.build``;
* collision: ``PathChecker.check``; preview: the viewers' polyline;
* plan: ``MotionPlanner.plan`` as a whole (other = plan minus the stages above);
* pipe: ``PlanningProcess.plan`` (the child plans the same motion) minus the plan: pickling both ways,
  the pipe, the profile rebuilt in the parent, less the preview (the child sends it after the motion);
* hand-over: the CPU the hand-over of the motion to the servo costs, without the network: the ``Trajectory``
  message encoded (the planner), decoded and made ready for the interpolator (the servo, ``prepare``).

    python bench/plan_stages.py [--n 15] [--robots iiwa,panda]

The machine's other load shows in the figures: medians, and compare runs made side by side.
"""

from __future__ import annotations

import argparse
import collections
import contextlib
import functools
import sys
import time
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np

from jara_arm.robots import RobotModel, robot
from jara_arm.schema import codec
from jara_arm.schema import wire_types as w
from jara_arm.schema.motion import TRAJECTORY, Trajectory
from jara_arm.schema.operations import OP
from jara_arm.schema.planner import MotionRequest, MotionSettings
from jara_arm.schema.types import CarPosWithElbow, CartesianSpeed, LimitValue
from jara_arm.services.planner import cartesian, collision, paths, profile, sampling, trajectory
from jara_arm.services.planner.planning import MotionPlanner
from jara_arm.services.planner.request import PlanRequest
from jara_arm.services.planner.worker import PlanningProcess
from jara_arm.services.servo.interpolator import prepare

#: (stage, owner, attribute): every call of ``owner.attribute`` counts towards the stage.
_STAGES: tuple[tuple[str, Any, str], ...] = (
    ("profile", cartesian, "move_profile"),
    ("profile", profile.PathProfile, "sample"),
    ("poses", paths.CartesianLine, "sample"),
    ("poses", paths.CartesianArc, "sample"),
    ("poses", cartesian, "ik_targets"),
    ("IK at knots", sampling.PathJoints, "_solve"),
    ("tangents", sampling.PathJoints, "_tangent"),
    ("spline", sampling.HermiteSpline, "__call__"),
    ("check (FK)", sampling.PathJoints, "_bad"),
    ("table", trajectory.TableMap, "build"),
    ("collision", collision.PathChecker, "check"),
    ("preview", MotionPlanner, "preview"),
)


def car(p: np.ndarray, R: np.ndarray) -> dict:
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, p
    return w.CAR_POS_WITH_ELBOW.encode(CarPosWithElbow(T[:3], 0.0, 0))


def settings(model: RobotModel) -> MotionSettings:
    return MotionSettings(spdRatioJoint=50, spdRatioCartesian=100, maxSpeedJoint=model.rated_speed,
                          maxSpeedCartesian=CartesianSpeed(0.25, 1.0), accelTimeJoint=model.min_accel_time,
                          accelTimeCartesian=model.min_accel_time_cartesian, softLimitJoint=model.hard_limits,
                          softLimitCartesian=(LimitValue(2.0, -2.0),) * 3, baseOffset=np.eye(4)[:3],
                          controlPointOffset=np.eye(4)[:3], home=model.ready_pose)


def request(op: str, args: dict, s: MotionSettings) -> PlanRequest:
    """``op`` with ``args`` in wire form, decoded as the planner's plan worker decodes it."""
    return PlanRequest.decode(MotionRequest(op, args, s))


def motions(planner: MotionPlanner) -> list[tuple[str, PlanRequest, np.ndarray]]:
    """The 0.5 m LIN and the half-circle CIRC of ``bench/motion.py``, each with its start joints."""
    model = planner.model
    s = settings(model)
    start = np.array(list(model.ready_pose) + ([model.gripper_limits.upper] if model.has_gripper else []))
    T = planner.kin.control_point(np.array(model.ready_pose))
    a = T.translation + [-0.1, -0.25, 0.0]
    b = a + [0.0, 0.5, 0.0]
    q_a = planner.plan(request(OP.moveLinearCartesianAbs, {"carPoint": car(a, T.rotation)}, s), start).end
    lin = request(OP.moveLinearCartesianAbs, {"carPoint": car(b, T.rotation)}, s)
    q_b = planner.plan(lin, q_a).end
    r = 0.15
    c = b + [0.0, -r, 0.0]
    circ = request(OP.moveCircularCartesianAbs, {"carPointR": car(c + [r, 0.0, 0.0], T.rotation),
                                                "carPointT": car(c + [0.0, -r, 0.0], T.rotation)}, s)
    return [("LIN 0.5 m", lin, q_a), ("CIRC half", circ, q_b)]


@contextlib.contextmanager
def timed_stages() -> Iterator[dict[str, float]]:
    """Accumulated seconds per stage while inside; nested calls of one stage count once."""
    spent: dict[str, float] = collections.defaultdict(float)
    depth: dict[str, int] = collections.defaultdict(int)
    saved = []

    def wrap(stage: str, fn: Callable[..., Any]) -> Callable[..., Any]:
        @functools.wraps(fn)
        def timed(*a: Any, **k: Any) -> Any:
            depth[stage] += 1
            t = time.perf_counter()
            try:
                return fn(*a, **k)
            finally:
                depth[stage] -= 1
                if not depth[stage]:
                    spent[stage] += time.perf_counter() - t
        return timed

    for stage, owner, name in _STAGES:
        raw = owner.__dict__[name]
        saved.append((owner, name, raw))
        fn = raw.__func__ if isinstance(raw, (classmethod, staticmethod)) else raw
        new = wrap(stage, fn)
        setattr(owner, name, type(raw)(new) if isinstance(raw, (classmethod, staticmethod)) else new)
    try:
        yield spent
    finally:
        for owner, name, raw in reversed(saved):
            setattr(owner, name, raw)


def speed_check(planner: MotionPlanner, q: np.ndarray, s: MotionSettings) -> float:
    """[s] the joint speed check of ``CartesianPlanner.whole`` on ``q`` alone."""
    vmax = planner.checks.vmax(s)[:planner.n]
    t = time.perf_counter()
    over = np.abs(np.diff(q[:, :planner.n], axis=0)) / planner.dt / vmax
    float(over.max())
    return time.perf_counter() - t


def hand_over(model: RobotModel, motion: trajectory.PlannedMotion, n: int) -> list[float]:
    """[s] encoding the motion's ``Trajectory``, decoding it and ``prepare`` (no network)."""
    out = []
    for _ in range(n):
        t = time.perf_counter()
        payload = codec.encode_message(TRAJECTORY, Trajectory(1, 1, 0, -1, True, model.dof, motion.q.reshape(-1)))
        traj = codec.decode_message(TRAJECTORY, payload)
        prepare(traj.motion, traj.rows(), traj.final, model.cmd_cycle, np.ones(model.dof))
        out.append(time.perf_counter() - t)
    return out


def run(name: str, n: int) -> list[str]:
    model = robot(name)
    planner = MotionPlanner(model)
    child = PlanningProcess(model, "WARNING")
    lines = []
    try:
        for what, req, start in motions(planner):
            planner.plan(req, start)  # warm
            rows: dict[str, list[float]] = collections.defaultdict(list)
            motion = None
            for _ in range(n):
                with timed_stages() as spent:
                    t = time.perf_counter()
                    motion = planner.plan(req, start)
                    total = time.perf_counter() - t
                for stage, _, _ in _STAGES:
                    rows[stage].append(spent.get(stage, 0.0))
                rows["speed"].append(speed_check(planner, motion.q, req.settings))
                rows["plan"].append(total)
                rows["other"].append(total - sum(spent.values()))
                t = time.perf_counter()
                child.plan(req, start)
                rows["child plan + pipe"].append(time.perf_counter() - t)
            assert motion is not None
            rows["hand-over"] = hand_over(model, motion, n)
            med = {k: 1e3 * float(np.median(v)) for k, v in rows.items()}
            med["pipe"] = med["child plan + pipe"] - med["plan"]
            order = list(dict.fromkeys(s for s, _, _ in _STAGES)) + ["speed", "other", "plan", "pipe",
                                                                     "child plan + pipe", "hand-over"]
            lines.append(f"{name} {what} ({len(motion.q)} samples), median of {n} [ms]: "
                         + ", ".join(f"{k} {med[k]:.2f}" for k in order))
    finally:
        child.close()
    return lines


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n", type=int, default=15, help="plans per motion (medians)")
    ap.add_argument("--robots", default="iiwa,panda", help="comma-separated robot names")
    args = ap.parse_args()
    for name in args.robots.split(","):
        for line in run(name, args.n):
            print(line)
    return 0


if __name__ == "__main__":
    sys.exit(main())
