"""The kinematic model of one arm on Pinocchio: joints and limits, forward kinematics, Jacobians, IK.

Frames as in :mod:`.frames`: everything works in the arm base frame, and every
pose taken or returned is a ``pin.SE3`` (wire values go through
:func:`.frames.as_se3` / :func:`.frames.hg_to_se3` first). Joint
values are [rad] (revolute) or [m] (prismatic), always in the order J1..Jn =
``RobotModel.arm_joints``; Pinocchio's own coordinate order may differ, and
stays inside this class.

A :class:`Kinematics` owns one Pinocchio ``Data`` work area: use one instance
per thread.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Final

import numpy as np
import numpy.typing as npt
import pinocchio as pin

from jara_arm.robots.model import RobotModel

from .arm_angle import DEFAULT_ELBOW_JOINTS, ArmAngleChain
from .errors import KinematicsError
from .ik import FULL_MASK, IkResult, IkSolver, Mask, check_mask, nearest_turn

__all__ = ["Kinematics"]

_LIMIT_SLACK = 1e-12  # [rad or m] narrower limits may exceed the hard ones by float error only


def _se3(pose: pin.SE3, what: str) -> pin.SE3:
    """``pose`` itself; a clear error for anything else (a wire array goes through ``as_se3`` first)."""
    if not isinstance(pose, pin.SE3):
        raise KinematicsError(f"{what}: expected a pin.SE3 (convert a wire value with as_se3 or hg_to_se3), "
                              f"got {type(pose).__name__}")
    return pose


class Kinematics:
    """Forward and inverse kinematics of one :class:`RobotModel`, on Pinocchio.

    The Pinocchio model is built from the robot's URDF and reduced to the arm
    joints: gripper joints are locked at their lower limit (closed), any other
    non-arm joint at zero (clamped into its limits). Arm joints must be 1-DoF
    revolute or prismatic joints.

    ``elbow_joints`` (7-axis arms only): the zero-based arm axes whose joint
    origins are the shoulder, elbow and wrist points of the arm angle; default
    ``robot.elbow_joints`` if the model defines it, else (1, 3, 5) -- J2, J4, J6.

    ``seed_table`` configurations, drawn uniformly within the hard limits with
    the RNG ``seed``, are stored with their flange poses; IK restarts from the
    ones nearest to the target (0 disables the table: uniform random restarts).
    """

    def __init__(
        self,
        robot: RobotModel,
        *,
        elbow_joints: Sequence[int] | None = None,
        seed_table: int = 4096,
        seed: int = 0,
    ) -> None:
        self.robot: Final = robot
        full = pin.buildModelFromUrdf(str(robot.urdf))
        arm = set(robot.arm_joints)
        for name in robot.arm_joints:
            if not full.existJointName(name):
                raise KinematicsError(f"{robot.name}: joint {name!r} not in {robot.urdf}; "
                                      f"its joints: {', '.join(list(full.names)[1:])}")
            j = full.joints[full.getJointId(name)]
            if j.nq != 1 or j.nv != 1:
                raise KinematicsError(
                    f"{robot.name}: joint {name!r} is {j.shortname()}; arm joints must be "
                    "1-DoF revolute or prismatic joints")
        q_lock = pin.neutral(full)
        lock = []
        for jid in range(1, full.njoints):
            name = full.names[jid]
            if name in arm:
                continue
            lock.append(jid)
            j = full.joints[jid]
            if j.nq == 1:
                lo_, hi_ = full.lowerPositionLimit[j.idx_q], full.upperPositionLimit[j.idx_q]
                v = lo_ if name in robot.gripper_joints else 0.0
                if lo_ <= hi_:
                    v = min(max(v, lo_), hi_)
                q_lock[j.idx_q] = v
        model = pin.buildReducedModel(full, lock, q_lock) if lock else full
        n = robot.axis_num
        if model.nq != n:  # pragma: no cover - guarded by the checks above
            raise KinematicsError(f"{robot.name}: reduced model has {model.nq} coordinates, not {n}")
        if not model.existFrame(robot.flange_frame):
            bodies = [f.name for f in model.frames if f.type == pin.FrameType.BODY]
            raise KinematicsError(f"{robot.name}: flange frame {robot.flange_frame!r} not in the URDF; "
                                  f"its links: {', '.join(bodies)}")

        self._model = model
        self._n = n
        # Pinocchio's coordinate index of arm axis i (identity for a serial URDF in order).
        jids = [model.getJointId(name) for name in robot.arm_joints]
        idx = np.array([model.joints[j].idx_q for j in jids])
        self._perm: np.ndarray | None = None if (idx == np.arange(n)).all() else idx
        lim = robot.hard_limits
        self._lower = np.array([x.lower for x in lim])  # [rad or m], J1..Jn
        self._upper = np.array([x.upper for x in lim])
        self._revolute = ~np.array(robot.prismatic)
        self._plo, self._phi = self._pin_limits(None, None)
        self._limits_cache: tuple[tuple[bytes, bytes], tuple[np.ndarray, np.ndarray, bool]] | None = None
        self._wrap_default = self._wraps(self._plo, self._phi)

        if model.existFrame(robot.flange_frame, pin.FrameType.BODY):
            self._fid = model.getFrameId(robot.flange_frame, pin.FrameType.BODY)
        else:
            self._fid = model.getFrameId(robot.flange_frame)
        flange = model.frames[self._fid]
        self._flange_placement = flange.placement.copy()
        # One extra frame, re-placed per call: the control point flange · C.
        self._cp_fid = model.addFrame(pin.Frame("jara_arm_control_point", flange.parentJoint,
                                                self._fid, flange.placement, pin.FrameType.OP_FRAME))
        self._data = model.createData()
        self._oMf = self._data.oMf

        self._chain: ArmAngleChain | None = None
        if n == 7:
            ej = tuple(elbow_joints if elbow_joints is not None
                       else getattr(robot, "elbow_joints", DEFAULT_ELBOW_JOINTS))
            if len(ej) != 3 or not all(0 <= int(i) < n for i in ej) or not ej[0] < ej[1] < ej[2]:
                raise KinematicsError(f"elbow_joints: three increasing axis indices in 0..{n - 1}, got {ej}")
            s, e, w = (jids[int(i)] for i in ej)
            self._chain = ArmAngleChain(model, self._data, (s, e, w))
        self._ik = IkSolver(model, self._data, self._fid, self._chain, self._plo, self._phi, seed_table, seed)

    # ------------------------------------------------------------------ basics

    @property
    def axis_num(self) -> int:
        """Number of arm axes n."""
        return self._n

    @property
    def lower(self) -> np.ndarray:
        """Hard lower joint limits [rad or m], J1..Jn."""
        return self._lower.copy()

    @property
    def upper(self) -> np.ndarray:
        """Hard upper joint limits [rad or m], J1..Jn."""
        return self._upper.copy()

    @property
    def has_elbow(self) -> bool:
        """True for a 7-axis arm, whose arm angle :meth:`ik` can command."""
        return self._chain is not None

    @property
    def elbow_joint_ids(self) -> tuple[int, int, int] | None:
        """Pinocchio joint ids (in :attr:`pin_model`) of the shoulder, elbow and wrist; None for 1-6 axes."""
        return None if self._chain is None else self._chain.joints

    @property
    def pin_model(self) -> pin.Model:
        """The reduced Pinocchio model (read only; its coordinate order may differ from J1..Jn)."""
        return self._model

    def _q(self, q: npt.ArrayLike, what: str = "q") -> np.ndarray:
        """Arm joints J1..Jn -> Pinocchio coordinates."""
        a = np.asarray(q, dtype=float)
        if a.shape != (self._n,):
            raise KinematicsError(f"{what}: expected {self._n} joint values, got shape {a.shape}")
        if self._perm is None:
            return a
        out = np.empty(self._n)
        out[self._perm] = a
        return out

    def _user_q(self, q: np.ndarray) -> np.ndarray:
        """Pinocchio coordinates -> arm joints J1..Jn (a new array)."""
        return q.copy() if self._perm is None else q[self._perm]

    def _frame(self, tool: pin.SE3 | None) -> int:
        """Frame id of the flange (tool None) or of the control point ``flange · tool``."""
        if tool is None:
            return self._fid
        self._model.frames[self._cp_fid].placement = self._flange_placement * _se3(tool, "tool")
        return self._cp_fid

    def within_limits(self, q: npt.ArrayLike, tol: float = 0.0) -> bool:
        """True when every axis lies in its hard limits widened by ``tol`` [rad or m]."""
        a = np.asarray(q, dtype=float)
        return bool(np.all(a >= self._lower - tol) and np.all(a <= self._upper + tol))

    # ------------------------------------------------------------------ limits

    def _pin_limits(self, lower: npt.ArrayLike | None,
                    upper: npt.ArrayLike | None) -> tuple[np.ndarray, np.ndarray]:
        """Checked limits [rad or m] J1..Jn (None: the hard ones) in Pinocchio order."""
        lo = self._lower if lower is None else np.asarray(lower, dtype=float)
        hi = self._upper if upper is None else np.asarray(upper, dtype=float)
        if lo.shape != (self._n,) or hi.shape != (self._n,):
            raise KinematicsError(f"limits: expected {self._n} values each")
        if (np.any(lo > hi) or np.any(lo < self._lower - _LIMIT_SLACK)
                or np.any(hi > self._upper + _LIMIT_SLACK)):
            raise KinematicsError("limits: need lower <= upper within the hard limits")
        if self._perm is None:
            return lo, hi
        plo, phi = np.empty(self._n), np.empty(self._n)
        plo[self._perm] = lo
        phi[self._perm] = hi
        return plo, phi

    def _limits(self, lower: npt.ArrayLike | None,
                upper: npt.ArrayLike | None) -> tuple[np.ndarray, np.ndarray, bool]:
        """Checked limits in Pinocchio order and the wrap flag; the last pair is cached by value."""
        lo_a = self._lower if lower is None else np.asarray(lower, dtype=float)
        hi_a = self._upper if upper is None else np.asarray(upper, dtype=float)
        key = (lo_a.tobytes(), hi_a.tobytes())
        cached = self._limits_cache
        if cached is not None and cached[0] == key:
            return cached[1]
        lo, hi = self._pin_limits(lo_a, hi_a)
        value = (lo.copy(), hi.copy(), self._wraps(lo, hi))
        self._limits_cache = (key, value)
        return value

    def _wraps(self, lo: np.ndarray, hi: np.ndarray) -> bool:
        """True when some revolute joint has more than a full turn of travel (IK then picks the turn)."""
        return bool(np.any((hi - lo > math.tau) & self._revolute_pin))

    @property
    def _revolute_pin(self) -> np.ndarray:
        """Revolute flags in Pinocchio order."""
        if self._perm is None:
            return self._revolute
        out = np.empty(self._n, dtype=bool)
        out[self._perm] = self._revolute
        return out

    # ------------------------------------------------------------------ forward

    def fk(self, q: npt.ArrayLike) -> pin.SE3:
        """Flange pose in the arm base frame at joints ``q`` [rad or m] (a new SE3)."""
        qp = self._q(q)
        pin.forwardKinematics(self._model, self._data, qp)
        pin.updateFramePlacement(self._model, self._data, self._fid)
        return self._oMf[self._fid].copy()  # oMf is the work area: the next call overwrites it

    def control_point(self, q: npt.ArrayLike, tool: pin.SE3 | None = None) -> pin.SE3:
        """Control point pose ``T_flange · C`` in the arm base frame (a new SE3); ``tool`` = C."""
        qp = self._q(q)
        fid = self._frame(tool)
        pin.forwardKinematics(self._model, self._data, qp)
        pin.updateFramePlacement(self._model, self._data, fid)
        return self._oMf[fid].copy()

    def jacobian(self, q: npt.ArrayLike, tool: pin.SE3 | None = None) -> np.ndarray:
        """Jacobian (6 x n) of the control point, frame LOCAL_WORLD_ALIGNED.

        Rows: linear velocity [m/s] of the control point origin, then angular
        velocity [rad/s], both along the arm base frame axes; columns: J1..Jn
        ([rad/s] or [m/s]).
        """
        qp = self._q(q)
        fid = self._frame(tool)
        J = pin.computeFrameJacobian(self._model, self._data, qp, fid, pin.LOCAL_WORLD_ALIGNED)
        J = J.reshape(6, self._n)  # eigenpy hands a 6x1 matrix back as a vector
        return J if self._perm is None else J[:, self._perm]

    # ------------------------------------------------------------------ arm angle

    def elbow_angle(self, q: npt.ArrayLike) -> float:
        """Arm angle [rad] in (-pi, pi] of a 7-axis arm (DECISIONS.md "Frames"); 0 for 1-6 axes.

        Shoulder, elbow and wrist are the origins of the joint frames of the
        ``elbow_joints`` axes; the definition is in :mod:`.arm_angle` (and
        :func:`.arm_angle.arm_angle`).
        """
        if self._chain is None:
            return 0.0
        pin.forwardKinematics(self._model, self._data, self._q(q))
        return self._chain.angle(False)[0]

    def elbow_points(self, q: npt.ArrayLike) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Shoulder, elbow and wrist points [m] in the arm base frame (7-axis arms only)."""
        if self._chain is None:
            raise KinematicsError(f"{self.robot.name}: the arm angle is defined for 7-axis arms only, "
                                  f"this arm has {self._n}")
        pin.forwardKinematics(self._model, self._data, self._q(q))
        return self._chain.points()

    def elbow_jacobian(self, q: npt.ArrayLike) -> np.ndarray:
        """Gradient d(arm angle)/dq (n,) [rad per rad or m], J1..Jn; zeros for 1-6 axes."""
        if self._chain is None:
            return np.zeros(self._n)
        pin.computeJointJacobians(self._model, self._data, self._q(q))
        g = self._chain.angle(True)[1]
        assert g is not None  # asked for with grad=True
        return g if self._perm is None else g[self._perm]

    # ------------------------------------------------------------------ inverse

    def ik(
        self,
        target: pin.SE3,
        q_seed: npt.ArrayLike,
        *,
        tool: pin.SE3 | None = None,
        elbow: float | None = None,
        mask: Sequence[bool] = FULL_MASK,
        tol_pos: float = 1e-5,
        tol_rot: float = 1e-5,
        tol_elbow: float = 1e-4,
        max_iter: int = 1000,
        lower: npt.ArrayLike | None = None,
        upper: npt.ArrayLike | None = None,
    ) -> IkResult:
        """Joints that put the control point at ``target``.

        ``target``: control point pose in the arm base frame; ``q_seed`` [rad or m]: start configuration; ``tool``:
        control point offset C (identity if None); ``elbow`` [rad]: arm angle
        to reach as well (7-axis arms; ignored otherwise); ``tol_pos`` [m],
        ``tol_rot``, ``tol_elbow`` [rad]: convergence tolerances;
        ``lower``/``upper`` [rad or m]: joint limits to respect (default: the
        hard limits; narrower soft limits may be given); ``max_iter``: budget
        of Newton iterations.

        ``mask`` selects the constrained components (x, y, z, rx, ry, rz), all
        along the arm base frame axes. Position components are those of
        ``p_target - p``. Rotation components are those of the rotation vector
        ``w = log(R_target · R^T)`` expressed in the arm base frame: when some
        are free, the result satisfies ``R_target = exp(w) · R`` with ``w``
        zero on the constrained axes -- e.g. with rx free the reached
        orientation is the target turned about the base x axis. ``rot_err`` is
        the norm of the constrained components of ``w``.

        Method (:class:`.ik.IkSolver`): Levenberg-Marquardt (damped least
        squares, damping = 0.05 x squared error [m^2 + rad^2] + 1e-7) on the
        pose error, with Pinocchio's frame Jacobian. Joint limits are a box: a
        step that leaves the box is redone with the offending joints stopped
        at their limit and the others re-solved, then clamped. A commanded arm
        angle is one more task row, with its analytic gradient. The first
        attempt starts at the seed, so that a solution near the seed is
        preferred. An attempt is abandoned when two successive iterations fail
        to bring the squared error below 0.3 x its best value so far in the
        attempt (Newton converging does far better; an attempt caught at a
        joint limit does not), or after 14 iterations (once the squared error
        is below 1e-6: 0.9 x and 60 iterations, as convergence near a
        singularity is slow). The next attempt starts from the next nearest
        entry of the seed table (12 of them), then from uniform random
        configurations (seeded: the result is reproducible). Revolute joints
        with more than 2 pi of travel are finally moved by whole turns towards
        the seed.

        Choose a ``mask`` the arm can satisfy: with fewer than six axes the
        full pose is generally out of reach and IK then spends ``max_iter``.
        """
        t = _se3(target, "target")
        if not (tol_pos > 0.0 and tol_rot > 0.0 and tol_elbow > 0.0 and max_iter >= 1):
            raise KinematicsError("ik: tolerances must be > 0 and max_iter >= 1")
        m: Mask = FULL_MASK if mask is FULL_MASK else check_mask(mask)
        if lower is None and upper is None:
            lo, hi, wraps = self._plo, self._phi, self._wrap_default
        else:
            lo, hi, wraps = self._limits(lower, upper)
        q0 = np.minimum(np.maximum(self._q(q_seed, "q_seed"), lo), hi)
        c = None if tool is None else _se3(tool, "tool")
        fid = self._frame(c)
        psi = None if elbow is None or self._chain is None else math.remainder(float(elbow), math.tau)
        q, ok, it, pe, re, ee = self._ik.solve(t, c, fid, q0, lo, hi, m, psi, tol_pos, tol_rot, tol_elbow,
                                               max_iter)
        if ok and wraps:
            q = nearest_turn(q, q0, lo, hi, self._revolute_pin)
        return IkResult(self._user_q(q), ok, it, pe, re, ee)
