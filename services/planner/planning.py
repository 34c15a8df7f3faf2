"""Turn one ``MotionRequest`` and its start joints into a sampled joint trajectory.

Every geometric check of DECISIONS.md "Motion commands" happens here, before a
motion is accepted; a refusal raises :class:`PlanRefused` with the return code
and a comment saying why, and nothing is queued.

Frames (DECISIONS.md "Frames"): Cartesian commands are in the robot frame.
With the base offset ``B`` (robot frame seen from the arm frame) a robot-frame
pose ``T`` is ``B · T`` in the arm frame, where kinematics works; the
controlled pose is ``T_flange · C`` (``C``: control point offset).

Motions, all timed by one profile along one path (``profile.py``):

* PTP (joint, Cartesian, goHome): a joint-space line, speed ``spdRatioJoint``
  x ``maxSpeedJoint`` synchronised to the slowest axis, ``accelTimeJoint``.
  A Cartesian target is solved by IK nearest to the start joints.
* LIN / CIRC: a Cartesian line or arc of the control point, speed
  ``spdRatioCartesian`` x ``maxSpeedCartesian`` (the slowest of translation,
  rotation and, on a 7-axis arm, the arm angle at its own rate limit,
  ``elbow.py``, sets it), ``accelTimeCartesian``; joints from IK at knots of the
  path and a spline in between, every servo sample checked on the path by
  forward kinematics (``sampling.py``). If the joint speeds that this implies
  exceed ``maxSpeedJoint``, the whole profile is slowed down (same accel time)
  until they do not; refused only when even the lowest speed ratio (1 %) is
  too fast (a singularity or a posture change on the path).
* Gripper: the gripper axis alone, at the model's gripper speed with
  ``accelTimeJoint``; the arm holds.

Joint speed limits are ``maxSpeedJoint`` capped at the model's rated speeds
(the servo refuses anything faster as an overspeed fault).

Every motion's sampled path is then checked for contact of the arm's links
with the world's boxes and with each other (``collision.py``); a contact
refuses it with VALUE_ERR, naming the two bodies and where on the path.

Cartesian targets: ``structFlag`` 0 takes the IK solution nearest to the
start joints. On robots with posture bits (``arm6``, ``iiwa``, ``panda``:
``kinematics/posture.py``) a non-zero ``structFlag`` is ``POSTURE_SET | bits``:
a PTP reaches the pose in that posture (VALUE_ERR naming it if the pose has
none within the joint soft limits); a LIN / CIRC must keep the start's posture
(a posture change needs a PTP), and its target's structFlag, if non-zero, must
be that posture; a CIRC's via point's structFlag is only checked for form.
Other robots refuse a non-zero ``structFlag``. A relative target adds its translation in the robot
frame, applies its rotation about the robot frame axes (``R_rel · R_start``)
and, on a 7-axis arm, adds its ``elbow`` to the start arm angle. A 7-axis
LIN / CIRC moves the arm angle linearly along the path from the start's to the
target's. What each family ignores of a pose is in ``families.py``.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from collections.abc import Callable, Sequence

import numpy as np
import pinocchio as pin
from numpy.typing import NDArray

from jara_arm.kinematics import Kinematics, KinematicsError, arm_to_robot, hg_to_se3
from jara_arm.kinematics.posture import BITS, POSTURE_SET, Postures, describe
from jara_arm.robots import Obstacle, RobotModel
from jara_arm.schema import codec
from jara_arm.schema.codes import ReturnCode
from jara_arm.schema.errors import JaraArmError, Refusal, WireError
from jara_arm.schema.operations import MIDDLE
from jara_arm.schema.planner import MotionRequest, MotionSettings
from jara_arm.schema.types import CarPosWithElbow, JointPos
from jara_arm.services.runtime.timing import EARLY_START

from . import families
from .blend import UNBLENDED_OPS, Blend, BlendError, JointLimits, cut_points, joint_blend, state_at
from .collision import DEFAULT_MARGIN, PathChecker
from .elbow import elbow_speed_limit
from .families import CartesianKind, CartesianRule, Orientation
from .paths import CartesianArc, CartesianLine, PathGeometryError
from .profile import (
    PathMotion,
    PathProfile,
    ProfileError,
    ProfileLimits,
    cartesian_path_speed,
    move_profile,
    plan_joint_ptp,
)
from .sampling import BatchFk, PathJoints, Tolerances, Unreachable
from .trajectory import UNQUEUED, Joints, LineMap, PlannedMotion, TableMap

log = logging.getLogger(__name__)

#: IK tolerance at LIN / CIRC knots and for PTP-Cartesian targets [m] and [rad].
IK_TOLERANCE = 1e-7
#: Largest error of any LIN / CIRC sample [m] and [rad] (checked by FK at every servo sample):
#: every planned point lies within 1e-6 m of the ideal path, with margin.
SAMPLE_TOLERANCE = 2e-7
#: Newton iterations per knot: a warm start needs 1-3; more means the path left the workspace.
IK_SAMPLE_ITERATIONS = 60
#: Points of a motion's control point polyline for viewers (``PlannedMotion.preview``, ``Planner/path``).
PREVIEW_POINTS = 200
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
#: Uniform knots solved for a LIN / CIRC's early start (the start and the next): the head's samples.
HEAD_KNOTS = 2

#: The operations whose motions may start early (``MotionPlanner.head``): the LINs and CIRCs.
EARLY_OPS = frozenset({"moveLinearCartesianAbs", "moveLinearCartesianRel", "moveCircularCartesianAbs",
                       "moveCircularCartesianRel"})


@dataclasses.dataclass(frozen=True, eq=False)
class Head:
    """The checked first samples of a LIN / CIRC still being planned: what the servo may run before acceptance.

    ``motion.q``: the samples that may go out (at most the early-start time's);
    ``motion.path``: the joints up to the head's end (the path's first knot interval), every sample on the
    path and within the joint speeds; those of ``motion.q`` clear of collisions too (the servo never runs a
    head past its last sample).
    The whole motion's samples start with ``motion.q`` bit for bit when its profile is ``motion.profile``
    (not slowed down): the same computation, and cubic Hermite pieces are local.
    """

    motion: PlannedMotion
    #: [m] the control point's largest distance from the start up to where braking from the last sample ends
    reach: float


class _HeadDone(Exception):
    """Ends :meth:`MotionPlanner.plan` within :meth:`MotionPlanner.head` once the head is checked."""


class PlanRefused(Refusal):
    """A motion that is not queued: ``code`` and ``comment`` go back to the client."""


@dataclasses.dataclass(frozen=True)
class _Frames:
    """The settings' frames, decoded from the wire once per motion."""

    base: pin.SE3  # B: robot frame seen from the arm frame
    tool: pin.SE3  # C: control point in the flange frame

    def to_robot(self, points: NDArray[np.float64]) -> NDArray[np.float64]:
        """Arm-frame points (N, 3) [m] in the robot frame: inv(B) on a batch, as an array for speed."""
        inv = self.base.inverse()
        return points @ inv.rotation.T + inv.translation


def _frames(settings: MotionSettings, *, planar: bool = False) -> _Frames:
    base = pin.SE3.Identity() if planar else hg_to_se3(settings.baseOffset)
    return _Frames(base, hg_to_se3(settings.controlPointOffset))


def _yaw_only(r_delta: NDArray[np.float64]) -> NDArray[np.float64]:
    """The rotation about Z nearest to ``r_delta`` (3x3)."""
    psi = math.atan2(r_delta[1, 0] - r_delta[0, 1], r_delta[0, 0] + r_delta[1, 1])
    c, s = math.cos(psi), math.sin(psi)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


class MotionPlanner:
    """Plans motions for one robot model. Not thread-safe: one instance per planning thread."""

    def __init__(self, model: RobotModel, kinematics: Kinematics | None = None, *,
                 obstacles: Sequence[Obstacle] = (), collision_margin: float = DEFAULT_MARGIN,
                 early_start: float = EARLY_START) -> None:
        """``obstacles``: the world's boxes (the model's own and the ``--obstacle`` ones, in the world frame);
        ``collision_margin`` [m]: the clearance every link keeps from them (``collision.py``);
        ``early_start`` [s]: how much of a LIN / CIRC its head may run before acceptance (``plan(head=)``)."""
        self.model = model
        self.early_start = early_start
        self._head: list[Head] | None = None  # plan() within head(): where _cartesian puts it
        self.kin = kinematics or Kinematics(model)
        self.postures = Postures(self.kin) if model.posture_joints is not None else None
        self.collisions = PathChecker(model, obstacles, collision_margin)
        self.n = model.axis_num
        self.dt = model.cmd_cycle
        self._rated = np.array(model.rated_speed)
        self._fk = BatchFk(self.kin)
        self._tol = Tolerances(IK_TOLERANCE, IK_TOLERANCE, SAMPLE_TOLERANCE, SAMPLE_TOLERANCE,
                               max_iter=IK_SAMPLE_ITERATIONS)

    # ------------------------------------------------------------------ entry

    def plan(self, req: MotionRequest, start: Joints, previous: PlannedMotion | None = None, *,
             preview: bool = True) -> PlannedMotion:
        """The motion ``req`` from ``start`` (wire joints); raises PlanRefused.

        ``previous``: the queued motion that ends at ``start``, if any: with ``blendDistance`` > 0 the
        motion also carries a blend of that corner (``blend.py``) when one passes every check.
        ``preview``: fill in ``PlannedMotion.preview``; the planning process leaves it out and sends it after
        the motion (a viewer's polyline is no part of the acceptance: it stays off the first command's path).
        """
        op = MIDDLE.get(req.op)
        if op is None or not op.motion:
            raise PlanRefused(ReturnCode.NOT_IMPLEMENTED, f"{req.op!r} is not a motion operation")
        start = np.array(start, dtype=float)
        if start.shape != (self.model.dof,):
            raise PlanRefused(ReturnCode.STATUS_ERR, f"start joints have {start.size} axes, "
                              f"the robot {self.model.dof}")
        try:
            args = codec.decode_args(op, req.args)  # wire form to typed, no second serialisation
            self._check_settings(req.settings)
            motion: Callable[..., PlannedMotion] = getattr(self, op.name)  # one method per IDL motion
            planned = motion(req, start, **args)
            contact = self.collisions.check(planned.q)  # every motion passes here, before it is accepted
            if contact is not None:
                raise PlanRefused(ReturnCode.VALUE_ERR, f"{req.op}: {contact.describe()}")
            if previous is not None and req.settings.blendDistance > 0.0:
                planned = dataclasses.replace(planned, blend=self._blend(previous, planned, req.settings))
            return dataclasses.replace(planned, preview=self.preview(planned.q, req.settings)) if preview else planned
        except WireError as exc:
            raise PlanRefused(ReturnCode.VALUE_ERR, str(exc)) from None
        except (PathGeometryError, ProfileError, KinematicsError) as exc:
            raise PlanRefused(ReturnCode.VALUE_ERR, f"{req.op}: {exc}") from None

    def head(self, req: MotionRequest, start: Joints) -> Head | None:
        """A LIN / CIRC's :class:`Head` from ``start``: its first knot interval planned and checked, the rest
        not (the early start: ``docs/decisions.md``, "First command and acceptance"). None for other motions,
        with ``early_start`` 0, and wherever the head alone cannot tell (a refusal, a joint too fast, a
        contact): :meth:`plan` of the whole then decides and says why."""
        if req.op not in EARLY_OPS or self.early_start <= 0.0:
            return None
        found: list[Head] = []
        self._head = found
        try:
            self.plan(req, start, preview=False)
        except (_HeadDone, PlanRefused):
            pass
        finally:
            self._head = None
        return found[0] if found else None

    def preview(self, q: Joints, settings: MotionSettings) -> NDArray[np.float64]:
        """(K, 3) [m] the control point at up to ``PREVIEW_POINTS`` of the samples ``q``, evenly
        spread, the first and the last included, in the arm frame (a polyline for viewers)."""
        rows = np.unique(np.linspace(0, len(q) - 1, min(len(q), PREVIEW_POINTS)).round().astype(int))
        points: NDArray[np.float64] = self._fk.run(q[rows, :self.n], hg_to_se3(settings.controlPointOffset))[0]
        return points

    # ------------------------------------------------------------------ blending

    def _blend(self, previous: PlannedMotion, planned: PlannedMotion, s: MotionSettings) -> Blend | None:
        """The blend of the corner between ``previous`` and ``planned``, or None (exact stop) when
        there is none that passes every check: never a reason to refuse the motion."""
        d = s.blendDistance
        if previous.op in UNBLENDED_OPS or planned.op in UNBLENDED_OPS:
            return None
        if not np.allclose(previous.end, planned.start, rtol=0.0, atol=1e-12):
            return None  # not the corner this motion starts from
        tool = hg_to_se3(s.controlPointOffset)
        pts_prev = self._fk.run(previous.q[:, :self.n], tool)[0]
        pts_next = self._fk.run(planned.q[:, :self.n], tool)[0]
        corner = pts_prev[-1]
        vmax = self._vmax(s)
        limits = JointLimits.from_accel_time(vmax, s.accelTimeJoint)
        lo, hi = self._soft_limits(s)
        why = ""
        for radius in (d, 0.5 * d):  # a blend that bulges out of d at full radius may fit at half of it
            try:
                cut, rejoin = cut_points(pts_prev, pts_next, radius)
                if previous.blend is not None and cut <= previous.blend.rejoin:
                    cut = previous.blend.rejoin + 1  # leave after the previous corner's blend rejoined
                    if cut > len(previous.q) - 2:
                        raise BlendError("the previous motion's own blend reaches this corner")
                traj = joint_blend(state_at(previous.q, cut, self.dt), state_at(planned.q, rejoin, self.dt),
                                   limits, self.dt)
            except BlendError as exc:
                why = str(exc)
                continue
            q = traj.q
            arm = q[:, :self.n]
            deviation = float(np.max(np.linalg.norm(self._fk.run(arm, tool)[0] - corner, axis=1)))
            if deviation > d * (1.0 + 1e-9):
                why = f"it would leave the path by {deviation * 1e3:.1f} mm"
                continue
            if np.any(arm < lo) or np.any(arm > hi):
                why = "it would leave the joint soft limits"
                continue
            try:
                self._path_box(s, q, _frames(s), "blend")
            except PlanRefused:
                why = "it would leave the Cartesian soft limits"
                continue
            contact = self.collisions.check(q)
            if contact is not None:
                why = contact.describe()
                continue
            s_rejoin = float(planned.profile.sample(self.dt).s[rejoin])
            return Blend(previous.motion, cut, rejoin, s_rejoin, traj, limits, d, deviation)
        log.info("%s: exact stop at the corner after motion %d, no blend of %.1f mm: %s", planned.op,
                 previous.motion, d * 1e3, why)
        return None

    # ------------------------------------------------------------------ the IDL motions, by name

    def movePTPJointAbs(self, req: MotionRequest, start: Joints, jointPoints: JointPos) -> PlannedMotion:
        return self._joint_ptp(req, start, self._joint_arg(jointPoints))

    def movePTPJointRel(self, req: MotionRequest, start: Joints, jointPoints: JointPos) -> PlannedMotion:
        return self._joint_ptp(req, start, start[:self.n] + self._joint_arg(jointPoints))

    def goHome(self, req: MotionRequest, start: Joints) -> PlannedMotion:
        return self._joint_ptp(req, start, np.array(req.settings.home, dtype=float), "home")

    def movePTPCartesianAbs(self, req: MotionRequest, start: Joints, carPoint: CarPosWithElbow) -> PlannedMotion:
        return self._ptp_cartesian(req, start, carPoint, relative=False)

    def movePTPCartesianRel(self, req: MotionRequest, start: Joints, carPoint: CarPosWithElbow) -> PlannedMotion:
        return self._ptp_cartesian(req, start, carPoint, relative=True)

    def moveLinearCartesianAbs(self, req: MotionRequest, start: Joints, carPoint: CarPosWithElbow) -> PlannedMotion:
        return self._linear(req, start, carPoint, relative=False)

    def moveLinearCartesianRel(self, req: MotionRequest, start: Joints, carPoint: CarPosWithElbow) -> PlannedMotion:
        return self._linear(req, start, carPoint, relative=True)

    def moveCircularCartesianAbs(self, req: MotionRequest, start: Joints, carPointR: CarPosWithElbow,
                                 carPointT: CarPosWithElbow) -> PlannedMotion:
        return self._circular(req, start, carPointR, carPointT, relative=False)

    def moveCircularCartesianRel(self, req: MotionRequest, start: Joints, carPointR: CarPosWithElbow,
                                 carPointT: CarPosWithElbow) -> PlannedMotion:
        return self._circular(req, start, carPointR, carPointT, relative=True)

    def moveGripper(self, req: MotionRequest, start: Joints, angleRatio: int) -> PlannedMotion:
        return self._gripper(req, start, angleRatio)

    def openGripper(self, req: MotionRequest, start: Joints) -> PlannedMotion:
        return self._gripper(req, start, 100)

    def closeGripper(self, req: MotionRequest, start: Joints) -> PlannedMotion:
        return self._gripper(req, start, 0)

    # ------------------------------------------------------------------ checks

    def _check_settings(self, s: MotionSettings) -> None:
        n = self.n
        for field, value, size in (("maxSpeedJoint", s.maxSpeedJoint, n),
                                   ("softLimitJoint", s.softLimitJoint, n),
                                   ("softLimitCartesian", s.softLimitCartesian, 3), ("home", s.home, n)):
            if len(value) != size:
                raise WireError(f"settings.{field}", f"expected {size} entries, got {len(value)}")
        if any(v <= 0.0 for v in s.maxSpeedJoint):
            raise WireError("settings.maxSpeedJoint", "every max speed must be positive")
        if s.maxSpeedCartesian.translation <= 0.0 or s.maxSpeedCartesian.rotation <= 0.0:
            raise WireError("settings.maxSpeedCartesian", "max speeds must be positive")
        for field in ("accelTimeJoint", "accelTimeCartesian"):
            if getattr(s, field) <= 0.0:
                raise WireError(f"settings.{field}", "acceleration time must be positive")
        for field in ("spdRatioJoint", "spdRatioCartesian"):
            if getattr(s, field) > 100:
                raise WireError(f"settings.{field}", "speed ratio above 100 %")

    def _joint_arg(self, points: tuple[float, ...]) -> Joints:
        if len(points) != self.n:
            raise WireError("jointPoints", f"expected {self.n} values (one per arm axis, gripper "
                            f"excluded), got {len(points)}")
        return np.array(points, dtype=float)

    def _soft_limits(self, s: MotionSettings) -> tuple[Joints, Joints]:
        """Joint soft limits, clamped into the hard limits (IK insists on that)."""
        lo = np.maximum([lim.lower for lim in s.softLimitJoint], self.kin.lower)
        hi = np.minimum([lim.upper for lim in s.softLimitJoint], self.kin.upper)
        return lo, hi

    def _check_joint_target(self, s: MotionSettings, target: Joints, what: str) -> None:
        for i, (q, lim) in enumerate(zip(target, s.softLimitJoint)):
            if not lim.lower <= q <= lim.upper:
                raise PlanRefused(ReturnCode.VALUE_ERR,
                                  f"{what}: J{i + 1} = {q:.6g} is outside its joint soft limit "
                                  f"[{lim.lower:.6g}, {lim.upper:.6g}]")

    @staticmethod
    def _check_box(s: MotionSettings, positions: NDArray[np.float64], what: str) -> None:
        """Refuse if any control-point position (N, 3) [m, robot frame] leaves the Cartesian soft limits."""
        lo = np.array([lim.lower for lim in s.softLimitCartesian])
        hi = np.array([lim.upper for lim in s.softLimitCartesian])
        bad = np.flatnonzero(np.any((positions < lo) | (positions > hi), axis=1))
        if bad.size:
            k = int(bad[0])
            p = positions[k]
            axis = int(np.flatnonzero((p < lo) | (p > hi))[0])
            last = len(positions) - 1
            where = "target" if k == last else f"path at {100.0 * k / max(1, last):.0f} %"
            raise PlanRefused(ReturnCode.VALUE_ERR,
                              f"{what}: the control point leaves the Cartesian soft limits ({where}): "
                              f"{'xyz'[axis]} = {p[axis]:.6g} m outside [{lo[axis]:.6g}, {hi[axis]:.6g}] "
                              f"(robot frame)")

    def _vmax(self, s: MotionSettings) -> Joints:
        """Joint speed limits of the wire axes [rad/s or m/s]: settings capped at the rated speeds."""
        v = np.minimum(np.array(s.maxSpeedJoint, dtype=float), self._rated)
        if self.model.has_gripper:
            v = np.append(v, self.model.gripper_speed)
        return v

    # ------------------------------------------------------------------ poses

    def control_pose(self, q_arm: Joints, frames: _Frames) -> pin.SE3:
        """Control point pose in the robot frame at arm joints ``q_arm``."""
        return arm_to_robot(self.kin.control_point(q_arm, frames.tool), frames.base)

    def _path_box(self, s: MotionSettings, q: Joints, frames: _Frames, what: str) -> None:
        """Cartesian soft-limit check of a joint-space path, at every sample."""
        if np.all(q[0, :self.n] == q[-1, :self.n]):
            return  # the arm does not move (gripper only, or already there)
        self._check_box(s, frames.to_robot(self._fk.run(q[:, :self.n], frames.tool)[0]), what)

    def _target(self, cp: CarPosWithElbow, start_pose: pin.SE3, relative: bool,
                rule: CartesianRule) -> pin.SE3:
        """The commanded pose (robot frame; arm frame for ``planar``) after the family rule."""
        self._posture_flag(cp)
        cmd = hg_to_se3(cp.carPos)
        r0, p0 = start_pose.rotation, start_pose.translation
        if relative:
            # The command acts in the frame at the start point with the robot frame's axes:
            # its translation along the robot axes, its rotation about them (R_rel · R_start).
            at_start = pin.SE3(np.eye(3), p0)
            T = at_start * cmd * at_start.actInv(start_pose)
        else:
            T = cmd
        if rule.orientation is Orientation.KEEP:
            T = pin.SE3(r0, T.translation)
        elif rule.orientation is Orientation.YAW:
            T = pin.SE3(_yaw_only(T.rotation @ r0.T) @ r0, T.translation)
        if rule.planar:
            T = pin.SE3(T.rotation, np.array([*T.translation[:2], p0[2]]))
        return T

    def _posture_flag(self, cp: CarPosWithElbow) -> int:
        """``cp.structFlag`` checked: 0 (nearest) or, on a robot with posture bits, ``POSTURE_SET | bits``."""
        flag = cp.structFlag
        if flag == 0:
            return 0
        if self.postures is None:
            raise PlanRefused(ReturnCode.VALUE_ERR,
                              f"structFlag {flag}: {self.model.name} defines no posture flags; "
                              "use 0 (the IK solution nearest to the start joints)")
        if flag & ~(POSTURE_SET | BITS) or not flag & POSTURE_SET:
            raise PlanRefused(ReturnCode.VALUE_ERR,
                              f"structFlag {flag:#x}: {self.model.name}'s posture flags are {POSTURE_SET:#x} | "
                              f"bits (0x1 shoulder back, 0x2 elbow down, 0x4 wrist flipped), or 0 (nearest)")
        return flag

    def _elbow_target(self, cp: CarPosWithElbow, start: Joints, relative: bool,
                      rule: CartesianRule) -> tuple[float | None, float | None]:
        """(start, target) arm angle [rad] of a 7-axis arm, (None, None) when not commanded.

        A relative command adds its ``elbow`` to the start arm angle.
        """
        if not (rule.elbow and self.kin.has_elbow):
            return None, None
        e0 = self.kin.elbow_angle(start[:self.n])
        e1 = e0 + cp.elbow if relative else cp.elbow
        return e0, e0 + math.remainder(e1 - e0, 2.0 * math.pi)

    def _rule(self, kind: CartesianKind, op: str) -> CartesianRule:
        r = families.rule(self.model, kind)
        if isinstance(r, families.Refused):
            raise PlanRefused(ReturnCode.NG, f"{op}: {r.why}")
        return r

    # ------------------------------------------------------------------ motions

    def _motion(self, req: MotionRequest, motion: PathMotion) -> PlannedMotion:
        _, q = motion.sample(self.dt)
        return PlannedMotion(UNQUEUED, req.op, LineMap(motion.path), motion.profile, q, self.dt)

    def _joint_ptp(self, req: MotionRequest, start: Joints, target: Joints,
                   what: str = "target") -> PlannedMotion:
        s = req.settings
        self._check_joint_target(s, target, f"{req.op} {what}")
        if s.spdRatioJoint == 0:
            raise PlanRefused(ReturnCode.STATUS_ERR, "joint speed ratio is 0 %: call setSpeedJoint first")
        q1 = start.copy()
        q1[:self.n] = target
        planned = self._motion(req, plan_joint_ptp(start, q1, self._vmax(s), s.spdRatioJoint / 100.0,
                                                   s.accelTimeJoint))
        self._path_box(s, planned.q, _frames(s), req.op)
        return planned

    def _ptp_cartesian(self, req: MotionRequest, start: Joints, cp: CarPosWithElbow,
                       relative: bool) -> PlannedMotion:
        s = req.settings
        rule = self._rule(CartesianKind.LINEAR, req.op)
        frames = _frames(s, planar=rule.planar)
        T1 = self._target(cp, self.control_pose(start[:self.n], frames), relative, rule)
        self._check_box(s, T1.translation[None], req.op)
        _, elbow = self._elbow_target(cp, start, relative, rule)
        lo, hi = self._soft_limits(s)
        target = families.reachable_pose(rule, self.kin, frames.base * T1, frames.tool)
        flag = self._posture_flag(cp)
        if flag and self.postures is not None:
            found = self.postures.ik(flag, target, [start[:self.n]], tool=frames.tool, elbow=elbow, mask=rule.mask,
                                     tol_pos=IK_TOLERANCE, tol_rot=IK_TOLERANCE, lower=lo, upper=hi)
            if found is None:
                raise PlanRefused(ReturnCode.VALUE_ERR,
                                  f"{req.op}: the target pose has no IK solution with posture {describe(flag)}"
                                  + (" at this arm angle" if elbow is not None else "")
                                  + " within the joint soft limits")
            return self._joint_ptp(req, start, found.q)
        res = self.kin.ik(target, start[:self.n], tool=frames.tool, elbow=elbow,
                          mask=rule.mask, tol_pos=IK_TOLERANCE, tol_rot=IK_TOLERANCE, lower=lo, upper=hi)
        if not res.success:
            raise PlanRefused(ReturnCode.VALUE_ERR,
                              f"{req.op}: target pose unreachable within the joint soft limits "
                              f"(best IK residual {res.pos_err:.3g} m, {res.rot_err:.3g} rad"
                              + (f", arm angle {res.elbow_err:.3g} rad)" if elbow is not None else ")"))
        return self._joint_ptp(req, start, res.q)

    def _linear(self, req: MotionRequest, start: Joints, cp: CarPosWithElbow,
                relative: bool) -> PlannedMotion:
        rule = self._rule(CartesianKind.LINEAR, req.op)
        frames = _frames(req.settings, planar=rule.planar)
        T0 = self.control_pose(start[:self.n], frames)
        T1 = self._target(cp, T0, relative, rule)
        elbows = self._elbow_target(cp, start, relative, rule)
        return self._keep_posture(req, start, self._posture_flag(cp),
                                  lambda: self._cartesian(req, start, CartesianLine(T0, T1), rule, frames, elbows))

    def _circular(self, req: MotionRequest, start: Joints, via: CarPosWithElbow, cp: CarPosWithElbow,
                  relative: bool) -> PlannedMotion:
        rule = self._rule(CartesianKind.CIRCULAR, req.op)
        frames = _frames(req.settings, planar=rule.planar)
        T0 = self.control_pose(start[:self.n], frames)
        T1 = self._target(cp, T0, relative, rule)
        Tv = self._target(via, T0, relative, rule)  # its orientation is ignored (DECISIONS.md)
        elbows = self._elbow_target(cp, start, relative, rule)
        try:
            arc = CartesianArc(T0, Tv.translation, T1)
        except PathGeometryError as exc:
            raise PlanRefused(ReturnCode.VALUE_ERR, f"{req.op}: {exc}") from None
        return self._keep_posture(req, start, self._posture_flag(cp),
                                  lambda: self._cartesian(req, start, arc, rule, frames, elbows))

    def _keep_posture(self, req: MotionRequest, start: Joints, flag: int,
                      plan: Callable[[], PlannedMotion]) -> PlannedMotion:
        """A LIN / CIRC ``plan`` whose target posture ``flag`` (0: any) must be the start's, and is at its end."""
        if not flag or self.postures is None:
            return plan()
        at_start = self.postures.of(start[:self.n])
        if flag == at_start:
            planned = plan()
            at_end = self.postures.of(planned.end[:self.n])
            if at_end == flag:
                return planned
            flag = at_end  # the path ends in another posture: no path keeps this one
        raise PlanRefused(ReturnCode.VALUE_ERR,
                          f"{req.op}: the target posture {describe(flag)} differs from the start's "
                          f"{describe(at_start)}: a posture change needs a PTP (movePTPCartesianAbs / Rel)")

    def _cartesian(self, req: MotionRequest, start: Joints, path: CartesianLine | CartesianArc,
                   rule: CartesianRule, frames: _Frames,
                   elbows: tuple[float | None, float | None]) -> PlannedMotion:
        """LIN / CIRC: profile, box check, joints at every sample, joint speed check (slowing down)."""
        s = req.settings
        if s.spdRatioCartesian == 0:
            raise PlanRefused(ReturnCode.STATUS_ERR,
                              "Cartesian speed ratio is 0 %: call setSpeedCartesian first")
        vt, vr = s.maxSpeedCartesian.translation, s.maxSpeedCartesian.rotation
        vmax = self._vmax(s)[:self.n]
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
        lo, hi = self._soft_limits(s)
        checked_box = False
        joints: PathJoints | None = None  # the joint path q(s): solved once, reused when slowing down
        for _ in range(SLOWDOWN_ROUNDS):
            profile = move_profile(path.length, ProfileLimits.from_accel_time(speed, s.accelTimeCartesian))
            samples = profile.sample(self.dt)
            if not checked_box:
                pts = path.positions(samples.s)
                if rule.planar:  # the points are in the arm frame: the limits are in the robot frame
                    pts = frames.to_robot(pts)
                self._check_box(s, pts, req.op)
                checked_box = True
            try:
                if joints is None and self._head is not None:  # head(): the first knot interval only
                    joints = self._path_joints(path, start, frames, rule, elbows, lo, hi, HEAD_KNOTS)
                    self._early_head(req, joints, profile, samples.s, path, start, vmax, frames, rule)
                    raise _HeadDone
                if joints is None:
                    joints = self._path_joints(path, start, frames, rule, elbows, lo, hi)
                poses = path.sample(samples.s)
                q = np.repeat(start[None, :], len(samples.s), axis=0)  # gripper column kept as it is
                q[:, :self.n] = joints.joints(samples.s, self._ik_targets(poses, frames, rule))
            except Unreachable as exc:
                p = frames.base.actInv(exc.position)
                raise PlanRefused(ReturnCode.VALUE_ERR,
                                  f"{req.op}: unreachable at {100.0 * exc.s / path.length:.0f} % of the path "
                                  f"(control point at [{p[0]:.4f}, {p[1]:.4f}, {p[2]:.4f}] m): no IK solution "
                                  f"within the joint soft limits") from None
            over = np.abs(np.diff(q[:, :self.n], axis=0)) / self.dt / vmax  # [-] joint speed / max
            worst = float(over.max()) if over.size else 0.0
            if worst <= 1.0:
                return PlannedMotion(UNQUEUED, req.op, TableMap.build(samples.s, q), profile, q, self.dt)
            new_speed = speed * JOINT_SPEED_MARGIN / worst
            if new_speed < lowest:
                k, i = np.unravel_index(int(over.argmax()), over.shape)
                raise PlanRefused(
                    ReturnCode.VALUE_ERR,
                    f"{req.op}: at {100.0 * samples.s[k] / path.length:.0f} % of the path J{i + 1} would "
                    f"exceed its max speed {vmax[i]:.3g} even at the lowest speed "
                    f"({100 * LOWEST_SPEED_RATIO:.0f} %): a singularity or a posture change lies on the path")
            speed = new_speed
        raise PlanRefused(ReturnCode.VALUE_ERR, f"{req.op}: could not keep the joint speeds within "
                          f"maxSpeedJoint along the path")

    def _early_head(self, req: MotionRequest, joints: PathJoints, profile: PathProfile, s: NDArray[np.float64],
                    path: CartesianLine | CartesianArc, start: Joints, vmax: Joints, frames: _Frames,
                    rule: CartesianRule) -> None:
        """Check the target (IK from the start, contacts) and the samples up to the last knot solved, and keep
        the :class:`Head` for :meth:`head`; none where that is not enough to say: too short, too fast, a contact,
        a target IK from the start does not reach."""
        assert self._head is not None
        try:  # refusals for the target itself come before any motion: unreachable, in contact
            end = start.copy()
            end[:self.n] = joints.end_from_start()
        except Unreachable:
            return
        if self.collisions.check(end[None, :]) is not None:
            return
        m = int(np.searchsorted(s, joints.spline.s[-1], side="right"))  # samples on the solved knots
        poses = path.sample(s[:m])
        early = min(m - 1, int(round(self.early_start / self.dt)) + 1)
        if early < 2:
            return
        q = np.repeat(start[None, :], m, axis=0)
        # Every sample up to the last knot solved, not only those sent: a sample off the path splits its
        # knot interval at the sample nearest its middle, and the whole must split it where the head did.
        q[:, :self.n] = joints.joints(s[:m], self._ik_targets(poses, frames, rule))
        if (np.abs(np.diff(q[:, :self.n], axis=0)) / self.dt > vmax).any():
            return  # the whole plan decides and says why
        while early >= 2 and profile.stop_at((early - 1) * self.dt).s_end > s[m - 1]:
            early //= 2  # braking from the last early sample must end on the head
        # Collisions on the samples sent only: the servo never runs a head past its last sample (it slows
        # the head down instead, and a refusal stops it on them); the whole checks the rest.
        if early < 2 or self.collisions.check(q[:early]) is not None:
            return
        stop = profile.stop_at((early - 1) * self.dt).s_end
        points = path.positions(np.append(s[:m][s[:m] < stop], stop))
        reach = float(np.max(np.linalg.norm(points - points[0], axis=1)))
        self._head.append(Head(PlannedMotion(UNQUEUED, req.op, TableMap.build(s[:m], q), profile,
                                             q[:early].copy(), self.dt), reach))

    def _ik_targets(self, poses: NDArray[np.float64], frames: _Frames,
                    rule: CartesianRule) -> NDArray[np.float64]:
        """Robot-frame path poses (N, 4, 4) as IK must meet them: arm frame, family rule applied."""
        if frames.base != pin.SE3.Identity():  # B · T on the batch, as an array for speed
            poses = np.einsum("ij,njk->nik", frames.base.homogeneous, poses)
        return families.reachable(rule, self.kin, poses, frames.tool)

    def _path_joints(self, path: CartesianLine | CartesianArc, start: Joints, frames: _Frames,
                     rule: CartesianRule, elbows: tuple[float | None, float | None], lo: Joints,
                     hi: Joints, first_knots: int | None = None) -> PathJoints:
        """The joint path along ``path`` (robot frame) from ``start``, ``first_knots`` of its knots solved
        (default all); raises Unreachable."""

        def targets(s: NDArray[np.float64]) -> NDArray[np.float64]:
            return self._ik_targets(path.sample(s), frames, rule)

        e0, e1 = elbows
        turn = 0.0 if e0 is None or e1 is None else abs(e1 - e0)
        intervals = math.ceil(max(path.translation_length / KNOT_TRANSLATION,
                                  path.rotation_angle / KNOT_ROTATION, turn / KNOT_ELBOW, 1.0))
        return PathJoints(self.kin, self._fk, targets, path.length, start[:self.n], frames.tool, rule.mask,
                          elbows, lo, hi, self._tol, intervals, first_knots)

    def _gripper(self, req: MotionRequest, start: Joints, ratio: int) -> PlannedMotion:
        lim = self.model.gripper_limits
        if lim is None:
            raise PlanRefused(ReturnCode.NG, f"{req.op}: this robot has no gripper")
        if ratio > 100:
            raise PlanRefused(ReturnCode.VALUE_ERR, f"{req.op}: angleRatio {ratio} % is above 100 %")
        q1 = start.copy()
        q1[self.n] = lim.lower + ratio / 100.0 * (lim.upper - lim.lower)
        return self._motion(req, plan_joint_ptp(start, q1, self._vmax(req.settings), 1.0,
                                                req.settings.accelTimeJoint))


__all__ = ["IK_TOLERANCE", "MotionPlanner", "PlanRefused"]
