"""LIN and CIRC: a Cartesian line or arc of the control point, planned in two stages.

Speed ``spdRatioCartesian`` x ``maxSpeedCartesian`` (the slowest of
translation, rotation and, on a 7-axis arm, the arm angle at its own rate
limit, ``elbow.py``, sets it), ``accelTimeCartesian``; joints from IK at knots
of the path and a spline in between, every servo sample checked on the path by
forward kinematics (``sampling.py``). If the joint speeds that this implies
exceed ``maxSpeedJoint``, the whole profile is slowed down (same accel time)
until they do not; refused only when even the lowest speed ratio (1 %) is too
fast (a singularity or a posture change on the path). A 7-axis LIN / CIRC moves
the arm angle linearly along the path from the start's to the target's.

The stages:

1. :meth:`CartesianPlanner.linear` / :meth:`~CartesianPlanner.circular` set
   the motion up as a :class:`CartesianMotion`: its targets (``frames.py``),
   the start's posture (``postures.py``), its speed, its first profile, and the
   Cartesian soft limits along its path, checked. A target that is the start
   is planned there and then (one sample).
2. :meth:`CartesianPlanner.whole` solves its joints along all of the path
   (slowing down if need be) and checks its end's posture. The early start's
   head (``early.py``) solves the first knot interval of the same
   :class:`CartesianMotion` instead; both take their samples with
   :meth:`CartesianPlanner.samples`, so that the head's are the whole's first
   ones bit for bit.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from numpy.typing import NDArray

from jara_arm.kinematics import Kinematics
from jara_arm.robots import RobotModel
from jara_arm.schema.codes import ReturnCode
from jara_arm.schema.types import CarPosWithElbow

from .checks import IK_TOLERANCE, Checks
from .elbow import elbow_speed_limit, elbow_targets
from .families import CartesianKind, CartesianRule
from .frames import Frames, commanded_pose, control_pose, ik_targets
from .paths import CartesianArc, CartesianLine, PathGeometryError
from .postures import PostureRule
from .profile import PathProfile, ProfileLimits, cartesian_path_speed, move_profile
from .request import PlanRefused, PlanRequest
from .sampling import BatchFk, PathJoints, Tolerances, Unreachable
from .trajectory import UNQUEUED, Joints, PlannedMotion, TableMap

#: Largest error of any LIN / CIRC sample [m] and [rad] (checked by FK at every servo sample):
#: every planned point lies within 1e-6 m of the ideal path, with margin.
SAMPLE_TOLERANCE = 2e-7
#: Newton iterations per knot: a warm start needs 1-3; more means the path left the workspace.
IK_SAMPLE_ITERATIONS = 60
#: Initial knots of a LIN / CIRC: at most this much translation [m] and rotation [rad] apart.
KNOT_TRANSLATION = 0.02
KNOT_ROTATION = 0.1
#: ... and at most this much arm angle [rad] (7 axes): the joints turn by up to a few times as much.
KNOT_ELBOW = 0.05
#: Lowest speed ratio a LIN / CIRC may be slowed down to for the joint speed limits [-].
LOWEST_SPEED_RATIO = 0.01
#: Slowing down for joint speed aims this far below the limit [-].
JOINT_SPEED_MARGIN = 0.97
#: Rounds of slowing down before giving up (each one re-solves IK along the path).
SLOWDOWN_ROUNDS = 4

#: (start, target) arm angle [rad] of a 7-axis LIN / CIRC, (None, None) when not commanded.
Elbows = tuple[float | None, float | None]


@dataclasses.dataclass(frozen=True, eq=False)
class CartesianMotion:
    """A LIN / CIRC set up and checked up to its joints: what its whole and its head are planned from."""

    req: PlanRequest
    start: Joints  # [rad or m] wire joints (arm axes, then the gripper, which holds)
    path: CartesianLine | CartesianArc  # of the control point, robot frame (arm frame for a planar family)
    rule: CartesianRule  # what the family keeps of each pose
    frames: Frames
    elbows: Elbows
    posture: int  # the posture the path must keep, start to end; 0: any
    vmax: Joints  # [rad/s or m/s] joint speed limits of the arm axes
    lo: Joints  # [rad or m] joint soft limits, clamped into the hard limits
    hi: Joints
    speed: float  # [path units/s] of the first profile
    lowest: float  # [path units/s] the slowest it may be slowed down to (LOWEST_SPEED_RATIO)
    profile: PathProfile  # the first profile, at ``speed``
    s: NDArray[np.float64]  # the first profile's path parameter at every servo sample


class CartesianPlanner:
    """Plans the LINs and CIRCs of one robot model (module docstring)."""

    def __init__(self, model: RobotModel, kin: Kinematics, fk: BatchFk, checks: Checks,
                 postures: PostureRule) -> None:
        self.model = model
        self.kin = kin
        self.checks = checks
        self.postures = postures
        self.n = model.axis_num
        self.dt = model.cmd_cycle
        self._fk = fk
        self._tol = Tolerances(IK_TOLERANCE, IK_TOLERANCE, SAMPLE_TOLERANCE, SAMPLE_TOLERANCE,
                               max_iter=IK_SAMPLE_ITERATIONS)

    # ------------------------------------------------------------------ stage 1: set up

    def linear(self, req: PlanRequest, start: Joints, cp: CarPosWithElbow,
               relative: bool) -> CartesianMotion | PlannedMotion:
        """A LIN to the pose ``cp`` commands (``relative``: from the start pose), set up."""
        rule = self.checks.rule(CartesianKind.LINEAR, req.op)
        frames = Frames.of(req.settings, planar=rule.planar)
        T0 = control_pose(self.kin, start[:self.n], frames)
        posture = self.postures.flag(cp)
        T1 = commanded_pose(cp, T0, relative, rule)
        elbows = elbow_targets(self.kin, cp, start[:self.n], relative, rule)
        self.postures.keep_at_start(req.op, posture, start[:self.n])
        return self._set_up(req, start, CartesianLine(T0, T1), rule, frames, elbows, posture)

    def circular(self, req: PlanRequest, start: Joints, via: CarPosWithElbow, cp: CarPosWithElbow,
                 relative: bool) -> CartesianMotion | PlannedMotion:
        """A CIRC through the position of ``via`` to the pose ``cp`` commands, set up."""
        rule = self.checks.rule(CartesianKind.CIRCULAR, req.op)
        frames = Frames.of(req.settings, planar=rule.planar)
        T0 = control_pose(self.kin, start[:self.n], frames)
        posture = self.postures.flag(cp)
        T1 = commanded_pose(cp, T0, relative, rule)
        self.postures.flag(via)  # checked for form only
        Tv = commanded_pose(via, T0, relative, rule)  # its orientation is ignored (DECISIONS.md)
        elbows = elbow_targets(self.kin, cp, start[:self.n], relative, rule)
        try:
            arc = CartesianArc(T0, Tv.translation, T1)
        except PathGeometryError as exc:
            raise PlanRefused(ReturnCode.VALUE_ERR, f"{req.op}: {exc}") from None
        self.postures.keep_at_start(req.op, posture, start[:self.n])
        return self._set_up(req, start, arc, rule, frames, elbows, posture)

    def _set_up(self, req: PlanRequest, start: Joints, path: CartesianLine | CartesianArc, rule: CartesianRule,
                frames: Frames, elbows: Elbows, posture: int) -> CartesianMotion | PlannedMotion:
        """Speed, first profile and the Cartesian soft limits along ``path``; a path of no length planned whole."""
        s = req.settings
        if s.spdRatioCartesian == 0:
            raise PlanRefused(ReturnCode.STATUS_ERR,
                              "Cartesian speed ratio is 0 %: call setSpeedCartesian first")
        vt, vr = s.maxSpeedCartesian.translation, s.maxSpeedCartesian.rotation
        vmax = self.checks.vmax(s)[:self.n]
        e0, e1 = elbows
        elbow = {} if e0 is None or e1 is None or e0 == e1 else {
            "elbow_change": e1 - e0,
            "max_elbow_speed": elbow_speed_limit(self.kin, start[:self.n], frames.tool, rule.mask, vmax, vr)}
        speed = cartesian_path_speed(path, vt, vr, s.spdRatioCartesian / 100.0, **elbow)
        if math.isinf(speed):  # the target is the start pose and arm angle: nothing to do
            profile = move_profile(path.length, ProfileLimits(math.inf, math.inf, math.inf), path.length)
            return PlannedMotion(UNQUEUED, req.op, TableMap.build(np.zeros(1), start[None, :]),
                                 profile, start[None, :].copy(), self.dt)
        lowest = cartesian_path_speed(path, vt, vr, LOWEST_SPEED_RATIO, **elbow)
        lo, hi = self.checks.soft_limits(s)
        profile = move_profile(path.length, ProfileLimits.from_accel_time(speed, s.accelTimeCartesian))
        samples = profile.sample(self.dt)
        pts = path.positions(samples.s)
        if rule.planar:  # the points are in the arm frame: the limits are in the robot frame
            pts = frames.to_robot(pts)
        self.checks.box(s, pts, req.op)
        return CartesianMotion(req, start, path, rule, frames, elbows, posture, vmax, lo, hi, speed, lowest,
                               profile, samples.s)

    # ------------------------------------------------------------------ stage 2: the joints

    def whole(self, m: CartesianMotion) -> PlannedMotion:
        """Joints at every sample of the whole path, within the joint speed limits (slowing the profile down)."""
        op, path, settings = m.req.op, m.path, m.req.settings
        speed, profile, s = m.speed, m.profile, m.s
        joints: PathJoints | None = None  # the joint path q(s): solved once, reused when slowing down
        for round_ in range(SLOWDOWN_ROUNDS):
            if round_:
                profile = move_profile(path.length, ProfileLimits.from_accel_time(speed, settings.accelTimeCartesian))
                s = profile.sample(self.dt).s
            try:
                if joints is None:
                    joints = self.path_joints(m)
                q = self.samples(m, joints, s)
            except Unreachable as exc:
                p = m.frames.base.actInv(exc.position)
                raise PlanRefused(ReturnCode.VALUE_ERR,
                                  f"{op}: unreachable at {100.0 * exc.s / path.length:.0f} % of the path "
                                  f"(control point at [{p[0]:.4f}, {p[1]:.4f}, {p[2]:.4f}] m): no IK solution "
                                  f"within the joint soft limits") from None
            over = np.abs(np.diff(q[:, :self.n], axis=0)) / self.dt / m.vmax  # [-] joint speed / max
            worst = float(over.max()) if over.size else 0.0
            if worst <= 1.0:
                planned = PlannedMotion(UNQUEUED, op, TableMap.build(s, q), profile, q, self.dt)
                self.postures.keep_at_end(op, m.posture, planned.end[:self.n])
                return planned
            new_speed = speed * JOINT_SPEED_MARGIN / worst
            if new_speed < m.lowest:
                k, i = np.unravel_index(int(over.argmax()), over.shape)
                raise PlanRefused(
                    ReturnCode.VALUE_ERR,
                    f"{op}: at {100.0 * s[k] / path.length:.0f} % of the path J{i + 1} would "
                    f"exceed its max speed {m.vmax[i]:.3g} even at the lowest speed "
                    f"({100 * LOWEST_SPEED_RATIO:.0f} %): a singularity or a posture change lies on the path")
            speed = new_speed
        raise PlanRefused(ReturnCode.VALUE_ERR, f"{op}: could not keep the joint speeds within "
                          f"maxSpeedJoint along the path")

    def path_joints(self, m: CartesianMotion, first_knots: int | None = None) -> PathJoints:
        """The joint path along ``m.path`` from its start, ``first_knots`` of its knots solved (default all);
        raises Unreachable."""
        path, frames, rule = m.path, m.frames, m.rule

        def targets(s: NDArray[np.float64]) -> NDArray[np.float64]:
            return ik_targets(self.kin, path.sample(s), frames, rule)

        e0, e1 = m.elbows
        turn = 0.0 if e0 is None or e1 is None else abs(e1 - e0)
        intervals = math.ceil(max(path.translation_length / KNOT_TRANSLATION,
                                  path.rotation_angle / KNOT_ROTATION, turn / KNOT_ELBOW, 1.0))
        return PathJoints(self.kin, self._fk, targets, path.length, m.start[:self.n], frames.tool, rule.mask,
                          m.elbows, m.lo, m.hi, self._tol, intervals, first_knots)

    def samples(self, m: CartesianMotion, joints: PathJoints, s: NDArray[np.float64]) -> Joints:
        """Wire joints (N, dof) at path parameters ``s`` on ``joints`` (the gripper holds); raises Unreachable
        for a sample off the path. The whole motion and its head both take theirs here."""
        poses = m.path.sample(s)
        q = np.repeat(m.start[None, :], len(s), axis=0)  # gripper column kept as it is
        q[:, :self.n] = joints.joints(s, ik_targets(self.kin, poses, m.frames, m.rule))
        return q


__all__ = ["CartesianMotion", "CartesianPlanner", "SAMPLE_TOLERANCE"]
