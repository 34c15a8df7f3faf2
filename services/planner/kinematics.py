"""Kinematics of one arm on Pinocchio: forward kinematics, Jacobian, inverse kinematics, arm angle.

Frames (DECISIONS.md "Frames"):

* **Arm base frame** -- the frame of the URDF root link. :meth:`Kinematics.fk`,
  :meth:`Kinematics.control_point`, :meth:`Kinematics.jacobian` and
  :meth:`Kinematics.ik` all work in it.
* **Flange** -- the URDF link ``RobotModel.flange_frame``.
* **Control point** -- ``T_cp = T_flange · C``, where ``C`` (the control point
  offset, the ``tool`` argument) is the pose of the control point in the flange
  frame; identity when not given.
* **Robot (reference) frame** -- ``T_robot = inv(B) · T_arm``, where the base
  offset ``B`` is the pose of the robot frame seen from the arm base frame:
  :func:`arm_to_robot` / :func:`robot_to_arm`.

Poses are 4x4 homogeneous matrices (``np.ndarray`` of shape (4, 4)); the wire's
``HgMatrix`` is the top 3x4 block (:func:`hg_to_se3`, :func:`se3_to_hg`).
Positions are [m], angles [rad]; joint values are [rad] (revolute) or [m]
(prismatic), always in the order J1..Jn = ``RobotModel.arm_joints``.

A :class:`Kinematics` owns one Pinocchio ``Data`` work area: use one instance
per thread.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from typing import Final

import eigenpy
import numpy as np
import numpy.typing as npt
import pinocchio as pin

from jara_arm.robots.model import RobotModel
from jara_arm.schema.errors import JaraArmError

__all__ = [
    "DEFAULT_ELBOW_JOINTS",
    "FULL_MASK",
    "POSITION_MASK",
    "IkResult",
    "Kinematics",
    "KinematicsError",
    "Mask",
    "arm_angle",
    "arm_to_robot",
    "hg_to_se3",
    "pose_error",
    "robot_to_arm",
    "se3_to_hg",
]

ArrayLike = npt.ArrayLike
Mask = tuple[bool, bool, bool, bool, bool, bool]
"""Which task components IK constrains: (x, y, z, rx, ry, rz) of the arm base frame."""

FULL_MASK: Final[Mask] = (True, True, True, True, True, True)
POSITION_MASK: Final[Mask] = (True, True, True, False, False, False)

DEFAULT_ELBOW_JOINTS: Final[tuple[int, int, int]] = (1, 3, 5)
"""Zero-based arm axes whose joint origins are the shoulder, elbow and wrist of a 7-axis arm."""

_TWO_PI: Final = 2.0 * math.pi
_TABLE_STREAM: Final = 0x5EED7AB1E  # RNG streams of the seed table and of random restarts,
_RESTART_STREAM: Final = 0x4E5747  # distinct from a caller's default_rng(seed)
_VERTICAL: Final = 1e-6  # sin(angle) below which the shoulder-wrist line counts as vertical

# IK tuning (see Kinematics.ik). Errors are summed as [m^2] + [rad^2].
_DAMP_GAIN: Final = 0.05  # Levenberg-Marquardt damping = gain * squared error + floor
_DAMP_FLOOR: Final = 1e-7
_STALL_DECREASE: Final = 0.3  # progress: the error falls below 0.3 x the attempt's best so far
_STALL_ITERS: Final = 1  # iterations without progress tolerated; one more and the attempt restarts
_ATTEMPT_ITERS: Final = 14  # iterations per attempt before a restart
_NEAR_ERR: Final = 1e-6  # [m^2 + rad^2] below it an attempt is close: slow (near-singular) convergence
_NEAR_DECREASE: Final = 0.9  # needs only this progress ratio
_NEAR_ITERS: Final = 60  # and may last this long
_TABLE_RESTARTS: Final = 12  # restarts drawn from the seed table before uniform random ones
_TABLE_ROT_WEIGHT: Final = 0.1  # [m^2] per unit of (3 - trace(Ra^T Rb)) in the table distance
_TABLE_ELBOW_WEIGHT: Final = 0.1  # [m^2] per unit of (1 - cos(elbow difference))


class KinematicsError(JaraArmError, ValueError):
    """A kinematics request that cannot be evaluated (bad shape, unknown joint or frame...)."""


@dataclasses.dataclass(frozen=True, slots=True)
class IkResult:
    """Outcome of :meth:`Kinematics.ik`.

    On failure ``q`` is the best configuration found (smallest error); it is
    always within the joint limits used.
    """

    q: np.ndarray  # [rad or m] per arm axis, J1..Jn
    success: bool  # True when every tolerance is met
    iterations: int  # Newton iterations spent, restarts included
    pos_err: float  # [m] norm of the constrained position error
    rot_err: float  # [rad] norm of the constrained rotation error (the angle when unmasked)
    elbow_err: float = 0.0  # [rad] arm angle error, 0 unless an elbow was commanded


# ---------------------------------------------------------------------------- frames


def _pose_array(pose: ArrayLike | pin.SE3, what: str) -> np.ndarray:
    """A 4x4 or 3x4 float array of a pose whose rotation block is a proper rotation (1e-6)."""
    if isinstance(pose, pin.SE3):
        return pose.homogeneous
    a = np.asarray(pose, dtype=float)
    if a.shape != (4, 4) and a.shape != (3, 4):
        raise KinematicsError(f"{what}: expected a 4x4 or 3x4 matrix, got shape {a.shape}")
    (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = a[:3, :3].tolist()
    det = r00 * (r11 * r22 - r12 * r21) - r01 * (r10 * r22 - r12 * r20) + r02 * (r10 * r21 - r11 * r20)
    if not (abs(det - 1.0) < 1e-6
            and abs(r00 * r00 + r10 * r10 + r20 * r20 - 1.0) < 1e-6
            and abs(r01 * r01 + r11 * r11 + r21 * r21 - 1.0) < 1e-6
            and abs(r00 * r01 + r10 * r11 + r20 * r21) < 1e-6
            and abs(r00 * r02 + r10 * r12 + r20 * r22) < 1e-6
            and abs(r01 * r02 + r11 * r12 + r21 * r22) < 1e-6):
        raise KinematicsError(f"{what}: the 3x3 block is not a rotation matrix (orthonormal, det +1)")
    return a


def _se3(pose: ArrayLike | pin.SE3, what: str = "pose") -> pin.SE3:
    """A Pinocchio SE3 from a 4x4 homogeneous matrix, a 3x4 HgMatrix or an SE3 (checked)."""
    if isinstance(pose, pin.SE3):
        return pose
    a = _pose_array(pose, what)
    return pin.SE3(a[:3, :3], a[:3, 3])


def hg_to_se3(hg: ArrayLike) -> np.ndarray:
    """4x4 homogeneous matrix from a 3x4 ``HgMatrix`` ([R | p], p in [m])."""
    a = np.asarray(hg, dtype=float)
    if a.shape != (3, 4):
        raise KinematicsError(f"HgMatrix: expected shape (3, 4), got {a.shape}")
    out = np.eye(4)
    out[:3] = a
    return out


def se3_to_hg(pose: ArrayLike) -> np.ndarray:
    """3x4 ``HgMatrix`` ([R | p], p in [m]) from a 4x4 homogeneous matrix."""
    a = np.asarray(pose, dtype=float)
    if a.shape != (4, 4):
        raise KinematicsError(f"pose: expected shape (4, 4), got {a.shape}")
    return a[:3].copy()


def arm_to_robot(pose_arm: ArrayLike, base: ArrayLike | None = None) -> np.ndarray:
    """Pose in the robot frame, ``inv(B) · T_arm``; ``base`` = B, identity if None (4x4)."""
    t = _se3(pose_arm)
    if base is None:
        return t.homogeneous
    return _se3(base, "base offset").actInv(t).homogeneous


def robot_to_arm(pose_robot: ArrayLike, base: ArrayLike | None = None) -> np.ndarray:
    """Pose in the arm base frame, ``B · T_robot``; ``base`` = B, identity if None (4x4)."""
    t = _se3(pose_robot)
    if base is None:
        return t.homogeneous
    return (_se3(base, "base offset") * t).homogeneous


def pose_error(a: ArrayLike, b: ArrayLike) -> tuple[float, float]:
    """(position error [m], rotation angle [rad]) between two poses."""
    sa, sb = _se3(a), _se3(b)
    return (float(np.linalg.norm(sa.translation - sb.translation)),
            float(np.linalg.norm(pin.log3(sa.rotation.T @ sb.rotation))))


def arm_angle(shoulder: ArrayLike, elbow: ArrayLike, wrist: ArrayLike) -> float:
    """Arm angle [rad] in (-pi, pi] of the points S, E, W [m] (arm base frame), DECISIONS.md "Frames".

    The rotation, right-handed about the unit vector u = S->W, of the half-plane
    bounded by the line S-W that contains E, measured from the half-plane that
    contains the base z axis (the base x axis when S-W is vertical): 0 when E
    lies in the vertical plane through S-W on the +z side ("elbow up").
    Undefined -- 0 is returned -- when E lies on the line S-W.
    """
    s, e, w = (np.asarray(x, dtype=float) for x in (shoulder, elbow, wrist))
    u = (w - s) / np.linalg.norm(w - s)
    n_ref = np.cross(u, (0.0, 0.0, 1.0))
    if np.linalg.norm(n_ref) < _VERTICAL:
        n_ref = np.cross(u, (1.0, 0.0, 0.0))
    n_arm = np.cross(u, e - s)  # normals of the two half-planes, same orientation about u
    if np.linalg.norm(n_arm) < 1e-12:
        return 0.0
    return math.atan2(float(u.dot(np.cross(n_ref, n_arm))), float(n_ref.dot(n_arm)))


def _mask(mask: Sequence[bool]) -> Mask:
    m = tuple(bool(x) for x in mask)
    if len(m) != 6:
        raise KinematicsError(f"mask: expected 6 flags (x, y, z, rx, ry, rz), got {len(m)}")
    if not any(m):
        raise KinematicsError("mask: at least one component must be constrained")
    return m  # type: ignore[return-value]


# ---------------------------------------------------------------------------- model


class _Restarts:
    """Start configurations of IK restarts: the nearest seed-table entries, then uniform random.

    The table distances and the RNG are only computed when a first restart is needed.
    """

    __slots__ = ("kin", "target", "tool", "mask", "elbow", "lo", "hi", "count", "dist", "rng")

    def __init__(self, kin: Kinematics, target: np.ndarray, tool: ArrayLike | None, mask: Mask,
                 elbow: float | None, lo: np.ndarray, hi: np.ndarray) -> None:
        self.kin, self.target, self.tool, self.mask, self.elbow = kin, target, tool, mask, elbow
        self.lo, self.hi = lo, hi
        self.count = 0
        self.dist: np.ndarray | None = None
        self.rng: np.random.Generator | None = None

    def next(self) -> np.ndarray:
        kin = self.kin
        k = self.count
        self.count += 1
        if k < _TABLE_RESTARTS and len(kin._table_q):
            if self.dist is None:
                flange = _se3(self.target, "target")
                if self.tool is not None:
                    flange = flange * _se3(self.tool, "tool").inverse()
                self.dist = kin._table_distance(flange, self.mask, self.elbow)
            i = int(self.dist.argmin())
            self.dist[i] = np.inf
            return np.minimum(np.maximum(kin._table_q[i], self.lo), self.hi)
        if self.rng is None:
            self.rng = np.random.default_rng((kin._seed, _RESTART_STREAM))
        return self.lo + (self.hi - self.lo) * self.rng.random(kin._n)


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
        self._seed = seed
        full = pin.buildModelFromUrdf(str(robot.urdf))
        arm = set(robot.arm_joints)
        for name in robot.arm_joints:
            if not full.existJointName(name):
                raise KinematicsError(f"{robot.name}: joint {name!r} not in {robot.urdf}")
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
            raise KinematicsError(f"{robot.name}: flange frame {robot.flange_frame!r} not in URDF")

        self._model = model
        self._n = n
        # Pinocchio's coordinate index of arm axis i (identity for a serial URDF in order).
        self._jids = [model.getJointId(name) for name in robot.arm_joints]
        idx = np.array([model.joints[j].idx_q for j in self._jids])
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
        self._cp_fid = model.addFrame(pin.Frame("jara_arm_control_point", flange.parentJoint,
                                                self._fid, flange.placement, pin.FrameType.OP_FRAME))
        self._data = model.createData()
        self._oMf = self._data.oMf
        self._oMi = self._data.oMi

        self._elbow: tuple[int, int, int] | None = None
        if n == 7:
            ej = tuple(elbow_joints if elbow_joints is not None
                       else getattr(robot, "elbow_joints", DEFAULT_ELBOW_JOINTS))
            if len(ej) != 3 or not all(0 <= int(i) < n for i in ej) or not ej[0] < ej[1] < ej[2]:
                raise KinematicsError(f"elbow_joints: three increasing axis indices in 0..{n - 1}, got {ej}")
            self._elbow = tuple(self._jids[int(i)] for i in ej)  # type: ignore[assignment]
            # Which columns of the WORLD joint Jacobian move each of the points S, E, W.
            self._elbow_support = np.zeros((3, n))
            for row, jid in enumerate(self._elbow):  # type: ignore[union-attr]
                for sj in model.supports[jid]:
                    if sj > 0:
                        self._elbow_support[row, model.joints[sj].idx_v] = 1.0
        self._llt = eigenpy.LLT(6)
        self._A = np.empty((6, 6))  # work area of the fast IK path
        self._Ad = self._A.reshape(-1)[::7]  # its diagonal (a view)
        self._e = np.empty(6)
        self._build_table(seed_table)

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
        return self._elbow is not None

    @property
    def pin_model(self) -> pin.Model:
        """The reduced Pinocchio model (read only; its coordinate order may differ from J1..Jn)."""
        return self._model

    def _q(self, q: ArrayLike, what: str = "q") -> np.ndarray:
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

    def _frame(self, tool: ArrayLike | None) -> int:
        """Frame id of the flange (tool None) or of the control point ``flange · tool``."""
        if tool is None:
            return self._fid
        self._model.frames[self._cp_fid].placement = self._flange_placement * _se3(tool, "tool")
        return self._cp_fid

    def within_limits(self, q: ArrayLike, tol: float = 0.0) -> bool:
        """True when every axis lies in its hard limits widened by ``tol`` [rad or m]."""
        a = np.asarray(q, dtype=float)
        return bool(np.all(a >= self._lower - tol) and np.all(a <= self._upper + tol))

    # ------------------------------------------------------------------ forward

    def fk(self, q: ArrayLike) -> np.ndarray:
        """Flange pose in the arm base frame (4x4) at joints ``q`` [rad or m]."""
        qp = self._q(q)
        pin.forwardKinematics(self._model, self._data, qp)
        pin.updateFramePlacement(self._model, self._data, self._fid)
        return self._oMf[self._fid].homogeneous

    def control_point(self, q: ArrayLike, tool: ArrayLike | None = None) -> np.ndarray:
        """Control point pose ``T_flange · C`` in the arm base frame (4x4); ``tool`` = C (4x4 or 3x4)."""
        qp = self._q(q)
        fid = self._frame(tool)
        pin.forwardKinematics(self._model, self._data, qp)
        pin.updateFramePlacement(self._model, self._data, fid)
        return self._oMf[fid].homogeneous

    def jacobian(self, q: ArrayLike, tool: ArrayLike | None = None) -> np.ndarray:
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

    def elbow_angle(self, q: ArrayLike) -> float:
        """Arm angle [rad] in (-pi, pi] of a 7-axis arm (DECISIONS.md "Frames"); 0 for 1-6 axes.

        Shoulder S, elbow E and wrist W are the origins of the joint frames of
        the ``elbow_joints`` axes (J2, J4, J6 by default; on the Panda these
        joint origins carry the link offsets, and they are used as they are).
        With u the unit vector S->W, the reference direction r is the base z
        axis (the base x axis when S->W is vertical) made orthogonal to u, and
        v is S->E made orthogonal to u. The angle is the rotation from r to v,
        right-handed about u: 0 when the elbow lies in the vertical plane
        through S->W on the +z side ("elbow up"); see :func:`arm_angle`.
        Undefined -- 0 is returned -- when E lies on the line S-W.
        """
        if self._elbow is None:
            return 0.0
        pin.forwardKinematics(self._model, self._data, self._q(q))
        return self._arm_angle(False)[0]

    def elbow_points(self, q: ArrayLike) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Shoulder, elbow and wrist points [m] in the arm base frame (7-axis arms only)."""
        if self._elbow is None:
            raise KinematicsError(f"{self.robot.name}: the arm angle is defined for 7-axis arms only")
        pin.forwardKinematics(self._model, self._data, self._q(q))
        return tuple(self._oMi[j].translation.copy() for j in self._elbow)  # type: ignore[return-value]

    def elbow_jacobian(self, q: ArrayLike) -> np.ndarray:
        """Gradient d(arm angle)/dq (n,) [rad per rad or m], J1..Jn; zeros for 1-6 axes."""
        if self._elbow is None:
            return np.zeros(self._n)
        pin.computeJointJacobians(self._model, self._data, self._q(q))
        g = self._arm_angle(True)[1]
        return g if self._perm is None else g[self._perm]  # type: ignore[index]

    def _arm_angle(self, grad: bool) -> tuple[float, np.ndarray | None]:
        """Arm angle from ``data.oMi`` (FK done); with ``grad`` also d(psi)/dq (Pinocchio order).

        For the gradient ``computeJointJacobians`` must have run. With u, r, v
        the unit vectors of :meth:`elbow_angle`, a = SE, L = |SW|, rho and
        sigma the lengths of v and r before normalising, t_v = u x v and
        t_r = u x r: d(psi) = g_e . (dE - dS) + g_w . (dW - dS) with
        g_e = t_v / rho and g_w = -(a . u) t_v / (L rho) + (ref . u) t_r / (L sigma).
        Scalar Python arithmetic: faster than numpy on 3-vectors.
        """
        js, je, jw = self._elbow  # type: ignore[misc]
        oMi = self._oMi
        sx, sy, sz = oMi[js].translation.tolist()
        ex, ey, ez = oMi[je].translation.tolist()
        wx, wy, wz = oMi[jw].translation.tolist()
        dx, dy, dz = wx - sx, wy - sy, wz - sz
        length = math.sqrt(dx * dx + dy * dy + dz * dz)
        ux, uy, uz = dx / length, dy / length, dz / length
        ax, ay, az = ex - sx, ey - sy, ez - sz
        ref_u = uz  # reference: base z made orthogonal to u
        rx, ry, rz = -ref_u * ux, -ref_u * uy, 1.0 - ref_u * uz
        sigma = math.sqrt(rx * rx + ry * ry + rz * rz)
        if sigma < _VERTICAL:  # vertical shoulder-wrist line: base x instead
            ref_u = ux
            rx, ry, rz = 1.0 - ref_u * ux, -ref_u * uy, -ref_u * uz
            sigma = math.sqrt(rx * rx + ry * ry + rz * rz)
        au = ax * ux + ay * uy + az * uz
        vx, vy, vz = ax - au * ux, ay - au * uy, az - au * uz
        rho = math.sqrt(vx * vx + vy * vy + vz * vz)
        if rho < 1e-12:  # elbow on the shoulder-wrist line: undefined
            return 0.0, (np.zeros(self._n) if grad else None)
        rx, ry, rz = rx / sigma, ry / sigma, rz / sigma
        vx, vy, vz = vx / rho, vy / rho, vz / rho
        tx, ty, tz = uy * rz - uz * ry, uz * rx - ux * rz, ux * ry - uy * rx  # t_r = u x r
        psi = math.atan2(vx * tx + vy * ty + vz * tz, vx * rx + vy * ry + vz * rz)
        if not grad:
            return psi, None
        px, py, pz = uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx  # t_v = u x v
        ce = 1.0 / rho
        cw = -au / (length * rho)
        cr = ref_u / (length * sigma)
        gex, gey, gez = ce * px, ce * py, ce * pz
        gwx, gwy, gwz = cw * px + cr * tx, cw * py + cr * ty, cw * pz + cr * tz
        gsx, gsy, gsz = -gex - gwx, -gey - gwy, -gez - gwz
        # Point P moves at v + omega x P for a WORLD Jacobian column (v, omega): g.(v + omega x P)
        # = g.v + (P x g).omega. One row per point, masked by the columns that move it.
        c = np.array((
            (gsx, gsy, gsz, sy * gsz - sz * gsy, sz * gsx - sx * gsz, sx * gsy - sy * gsx),
            (gex, gey, gez, ey * gez - ez * gey, ez * gex - ex * gez, ex * gey - ey * gex),
            (gwx, gwy, gwz, wy * gwz - wz * gwy, wz * gwx - wx * gwz, wx * gwy - wy * gwx)))
        return psi, (c.dot(self._data.J) * self._elbow_support).sum(axis=0)

    # ------------------------------------------------------------------ seed table

    def _build_table(self, size: int) -> None:
        """Random configurations with their flange poses (and arm angles) for IK restarts."""
        self._table_q = np.empty((0, self._n))
        if size <= 0:
            return
        rng = np.random.default_rng((self._seed, _TABLE_STREAM))
        lo, hi = self._pin_limits(None, None)
        qs = lo + (hi - lo) * rng.random((size, self._n))
        feats = np.empty((size, 14))  # p (3), R row-major (9), cos(psi), sin(psi)
        m, d, fid = self._model, self._data, self._fid
        for i, q in enumerate(qs):
            pin.forwardKinematics(m, d, q)
            pin.updateFramePlacement(m, d, fid)
            h = self._oMf[fid].homogeneous
            feats[i, :3] = h[:3, 3]
            feats[i, 3:12] = h[:3, :3].reshape(-1)
            psi = self._arm_angle(False)[0] if self._elbow is not None else 0.0
            feats[i, 12] = math.cos(psi)
            feats[i, 13] = math.sin(psi)
        self._table_q = qs
        self._table_f = feats.astype(np.float32)  # only ranks restarts: single precision is plenty
        self._table_p2 = (feats[:, :3] ** 2).sum(axis=1).astype(np.float32)

    def _table_distance(self, flange_target: pin.SE3, mask: Mask, elbow: float | None) -> np.ndarray:
        """Squared-ish distance of every table entry to the target (flange pose, arm angle)."""
        g = np.zeros(14, dtype=np.float32)
        mp = np.array(mask[:3])
        p = flange_target.translation
        g[:3] = -2.0 * p * mp
        c = self._table_p2 if mp.all() else (self._table_f[:, :3][:, mp] ** 2).sum(axis=1)
        if all(mask[3:]):  # orientation used only when fully constrained
            g[3:12] = -_TABLE_ROT_WEIGHT * flange_target.rotation.reshape(-1)
        if elbow is not None:
            g[12] = -_TABLE_ELBOW_WEIGHT * math.cos(elbow)
            g[13] = -_TABLE_ELBOW_WEIGHT * math.sin(elbow)
        return c + self._table_f @ g

    # ------------------------------------------------------------------ inverse

    def _pin_limits(self, lower: ArrayLike | None, upper: ArrayLike | None) -> tuple[np.ndarray, np.ndarray]:
        lo = self._lower if lower is None else np.asarray(lower, dtype=float)
        hi = self._upper if upper is None else np.asarray(upper, dtype=float)
        if lo.shape != (self._n,) or hi.shape != (self._n,):
            raise KinematicsError(f"limits: expected {self._n} values each")
        if np.any(lo > hi) or np.any(lo < self._lower - 1e-12) or np.any(hi > self._upper + 1e-12):
            raise KinematicsError("limits: need lower <= upper within the hard limits")
        if self._perm is None:
            return lo, hi
        plo, phi = np.empty(self._n), np.empty(self._n)
        plo[self._perm] = lo
        phi[self._perm] = hi
        return plo, phi

    def ik(
        self,
        target: ArrayLike,
        q_seed: ArrayLike,
        *,
        tool: ArrayLike | None = None,
        elbow: float | None = None,
        mask: Sequence[bool] = FULL_MASK,
        tol_pos: float = 1e-5,
        tol_rot: float = 1e-5,
        tol_elbow: float = 1e-4,
        max_iter: int = 1000,
        lower: ArrayLike | None = None,
        upper: ArrayLike | None = None,
    ) -> IkResult:
        """Joints that put the control point at ``target``.

        ``target``: control point pose in the arm base frame (4x4 or 3x4);
        ``q_seed`` [rad or m]: start configuration; ``tool``: control point
        offset C (identity if None); ``elbow`` [rad]: arm angle to reach as
        well (7-axis arms; ignored otherwise); ``tol_pos`` [m], ``tol_rot``,
        ``tol_elbow`` [rad]: convergence tolerances; ``lower``/``upper``
        [rad or m]: joint limits to respect (default: the hard limits; narrower
        soft limits may be given); ``max_iter``: budget of Newton iterations.

        ``mask`` selects the constrained components (x, y, z, rx, ry, rz), all
        along the arm base frame axes. Position components are those of
        ``p_target - p``. Rotation components are those of the rotation vector
        ``w = log(R_target · R^T)`` expressed in the arm base frame: when some
        are free, the result satisfies ``R_target = exp(w) · R`` with ``w``
        zero on the constrained axes -- e.g. with rx free the reached
        orientation is the target turned about the base x axis. ``rot_err`` is
        the norm of the constrained components of ``w``.

        Method: Levenberg-Marquardt (damped least squares, damping = 0.05 x
        squared error [m^2 + rad^2] + 1e-7) on the pose error, with Pinocchio's
        frame Jacobian. Joint limits are a box: a step that leaves the box is
        redone with the offending joints stopped at their limit and the others
        re-solved, then clamped. A commanded arm angle is one more task row,
        with its analytic gradient. The first attempt starts at the seed, so
        that a solution near the seed is preferred. An attempt is abandoned
        when two successive iterations fail to bring the squared error below
        0.3 x its best value so far in the attempt (Newton converging does far
        better; an attempt caught at a joint limit does not), or after 14
        iterations (once the squared error is below 1e-6: 0.9 x and 60
        iterations, as convergence near a singularity is slow). The next
        attempt starts from the next nearest entry of the seed table (12 of
        them), then from uniform random configurations (seeded: the result is
        reproducible). Revolute joints with more than 2 pi of travel are
        finally moved by whole turns towards the seed.

        Choose a ``mask`` the arm can satisfy: with fewer than six axes the
        full pose is generally out of reach and IK then spends ``max_iter``.
        """
        a = _pose_array(target, "target")
        if not (tol_pos > 0.0 and tol_rot > 0.0 and tol_elbow > 0.0 and max_iter >= 1):
            raise KinematicsError("ik: tolerances must be > 0 and max_iter >= 1")
        if mask is not FULL_MASK:
            mask = _mask(mask)
        if lower is None and upper is None:
            lo, hi, wraps = self._plo, self._phi, self._wrap_default
        else:
            lo, hi, wraps = self._limits(lower, upper)
        q0 = np.minimum(np.maximum(self._q(q_seed, "q_seed"), lo), hi)
        fid = self._frame(tool)
        ctx = _Restarts(self, a, tool, mask, None, lo, hi)
        if elbow is not None and self._elbow is not None:
            ctx.elbow = math.remainder(float(elbow), _TWO_PI)
        if ctx.elbow is None and all(mask):
            q, ok, it, pe, re, ee = self._solve_pose(a, q0, fid, lo, hi, tol_pos, tol_rot, max_iter, ctx)
        else:
            q, ok, it, pe, re, ee = self._solve_general(a, q0, fid, lo, hi, tol_pos, tol_rot, tol_elbow,
                                                        max_iter, ctx)
        if ok and wraps:
            q = self._nearest_turn(q, q0, lo, hi)
        return IkResult(self._user_q(q), ok, it, pe, re, ee)

    def _limits(self, lower: ArrayLike | None, upper: ArrayLike | None) -> tuple[np.ndarray, np.ndarray, bool]:
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
        return bool(np.any((hi - lo > _TWO_PI) & self._revolute_pin))

    @property
    def _revolute_pin(self) -> np.ndarray:
        if self._perm is None:
            return self._revolute
        out = np.empty(self._n, dtype=bool)
        out[self._perm] = self._revolute
        return out

    def _nearest_turn(self, q: np.ndarray, seed: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        """Move revolute joints by whole turns towards the seed, within limits."""
        out = q.copy()
        for i in np.flatnonzero(self._revolute_pin & (hi - lo > _TWO_PI)):
            c = q[i] + _TWO_PI * round((seed[i] - q[i]) / _TWO_PI)
            if lo[i] <= c <= hi[i]:
                out[i] = c
        return out

    def _solve_pose(self, target: np.ndarray, q: np.ndarray, fid: int, lo: np.ndarray, hi: np.ndarray,
                    tol_pos: float, tol_rot: float, max_iter: int, restarts: _Restarts
                    ) -> tuple[np.ndarray, bool, int, float, float, float]:
        """Full 6-D pose IK, the fast path (every Python operation counts here).

        Error ``[p_t - p, log3(R_t R^T)]`` along the arm base axes with the
        LOCAL_WORLD_ALIGNED Jacobian (``computeFrameJacobian`` in that frame
        also updates ``data.oMf``; in LOCAL it does not).
        """
        m, d, oMf = self._model, self._data, self._oMf
        cfj, log3, lwa = pin.computeFrameJacobian, pin.log3, pin.LOCAL_WORLD_ALIGNED
        mn, mx, dot = np.minimum, np.maximum, np.dot
        llt, A, Ad, e = self._llt, self._A, self._Ad, self._e
        one_axis = self._n == 1
        stall_dec, stall_iters, att_iters = _STALL_DECREASE, _STALL_ITERS, _ATTEMPT_ITERS
        near, near_dec, near_iters = _NEAR_ERR, _NEAR_DECREASE, _NEAR_ITERS
        gain, floor = _DAMP_GAIN, _DAMP_FLOOR
        pt, rt = target[:3, 3].copy(), target[:3, :3].copy()
        tp2, tr2 = tol_pos * tol_pos, tol_rot * tol_rot
        best, best_q, best_pe, best_re = math.inf, q, math.inf, math.inf
        att_best, since, att = math.inf, 0, 0
        for it in range(max_iter):
            J = cfj(m, d, q, fid, lwa)
            if one_axis:  # eigenpy hands a 6x1 matrix back as a vector
                J = J.reshape(6, 1)
            M = oMf[fid]
            t = pt - M.translation
            w = log3(rt.dot(M.rotation.T))
            pe = t.dot(t)
            re = w.dot(w)
            if pe <= tp2 and re <= tr2:
                return q, True, it, math.sqrt(pe), math.sqrt(re), 0.0
            err = pe + re
            if err < best:
                best, best_q, best_pe, best_re = err, q, pe, re
            if err < att_best * (stall_dec if err > near else near_dec):
                att_best = err
                since = 0
            else:
                since += 1
            att += 1
            if since > stall_iters or att > (att_iters if err > near else near_iters):
                q = restarts.next()
                att_best, since, att = math.inf, 0, 0
                continue
            e[:3] = t
            e[3:] = w
            lam = gain * err + floor
            JT = J.T
            dot(J, JT, out=A)
            Ad += lam
            llt.compute(A)
            qn = q + JT.dot(llt.solve(e))
            qc = mn(mx(qn, lo), hi)
            dv = qn - qc
            if dv.dot(dv) > 0.0:
                # Limit-aware step: stop the offending joints at their limit, re-solve the others.
                free = dv == 0.0
                dqf = qc - q
                dqf *= ~free
                Jf = J * free
                dot(Jf, Jf.T, out=A)
                Ad += lam
                llt.compute(A)
                qn = q + dqf + Jf.T.dot(llt.solve(e - J.dot(dqf)))
                qc = mn(mx(qn, lo), hi)
            q = qc
        return best_q, False, max_iter, math.sqrt(best_pe), math.sqrt(best_re), 0.0

    def _solve_general(self, target: np.ndarray, q: np.ndarray, fid: int, lo: np.ndarray, hi: np.ndarray,
                       tol_pos: float, tol_rot: float, tol_elbow: float, max_iter: int,
                       restarts: _Restarts) -> tuple[np.ndarray, bool, int, float, float, float]:
        """IK with a task mask and/or a commanded arm angle (errors along the arm base axes).

        Rotation rows use the exact derivative of ``w = log3(R_t R^T)``:
        ``dw = -Jlog3(R_t R^T) · omega dt``, which matters when some components
        of ``w`` are left free (they need not be small). The arm angle row is
        ``d(psi)/dq`` (see :meth:`_arm_angle`).
        """
        m, d, oMf, n = self._model, self._data, self._oMf, self._n
        lwa, log3, jlog3 = pin.LOCAL_WORLD_ALIGNED, pin.log3, pin.Jlog3
        mn, mx, dot = np.minimum, np.maximum, np.dot
        mask, elbow = restarts.mask, restarts.elbow
        pos_all, rot_all = all(mask[:3]), all(mask[3:])
        mp = np.array(mask[:3], dtype=float)
        mr = np.array(mask[3:], dtype=float)
        partial_rot = any(mask[3:]) and not rot_all
        full = pos_all and rot_all
        rows = np.flatnonzero(np.array(mask))
        k = len(rows)
        nrow = k + (1 if elbow is not None else 0)
        llt = eigenpy.LLT(nrow)
        A = np.empty((nrow, nrow))
        Ad = A.reshape(-1)[:: nrow + 1]
        Jm = np.empty((nrow, n))  # task Jacobian: constrained rows, then the arm angle row
        e = np.empty(nrow)
        Jt = np.empty((6, n))
        e6 = np.empty(6)
        pt, rt = target[:3, 3].copy(), target[:3, :3].copy()
        tp2, tr2, te2 = tol_pos * tol_pos, tol_rot * tol_rot, tol_elbow * tol_elbow
        best, best_q, best_pe, best_re, best_ee = math.inf, q, math.inf, math.inf, math.inf
        att_best, since, att = math.inf, 0, 0
        for it in range(max_iter):
            if elbow is None:
                J = pin.computeFrameJacobian(m, d, q, fid, lwa)
            else:
                pin.computeJointJacobians(m, d, q)
                J = pin.getFrameJacobian(m, d, fid, lwa)
            if n == 1:
                J = J.reshape(6, 1)  # eigenpy hands a 6x1 matrix back as a vector
            M = oMf[fid]
            ep = pt - M.translation
            E = rt.dot(M.rotation.T)
            w = log3(E)
            pe = ep.dot(ep) if pos_all else (ep * mp).dot(ep)
            re = w.dot(w) if rot_all else (w * mr).dot(w)
            ee = 0.0
            if elbow is not None:
                psi, g = self._arm_angle(True)
                de = math.remainder(elbow - psi, _TWO_PI)
                ee = de * de
                Jm[k] = g
                e[k] = de
            if pe <= tp2 and re <= tr2 and ee <= te2:
                return q, True, it, math.sqrt(pe), math.sqrt(re), math.sqrt(ee)
            err = pe + re + ee
            if err < best:
                best, best_q, best_pe, best_re, best_ee = err, q, pe, re, ee
            if err < att_best * (_STALL_DECREASE if err > _NEAR_ERR else _NEAR_DECREASE):
                att_best = err
                since = 0
            else:
                since += 1
            att += 1
            if since > _STALL_ITERS or att > (_ATTEMPT_ITERS if err > _NEAR_ERR else _NEAR_ITERS):
                q = restarts.next()
                att_best, since, att = math.inf, 0, 0
                continue
            if full:
                Jm[:6] = J
                e[:3] = ep
                e[3:6] = w
            else:
                Jt[:3] = J[:3]
                Jt[3:] = jlog3(E).dot(J[3:]) if partial_rot else J[3:]
                e6[:3] = ep
                e6[3:] = w
                Jm[:k] = Jt[rows]
                e[:k] = e6[rows]
            lam = _DAMP_GAIN * err + _DAMP_FLOOR
            JT = Jm.T
            dot(Jm, JT, out=A)
            Ad += lam
            llt.compute(A)
            qn = q + JT.dot(llt.solve(e).reshape(nrow))  # eigenpy: a size-1 vector comes back 1x1
            qc = mn(mx(qn, lo), hi)
            dv = qn - qc
            if dv.dot(dv) > 0.0:
                free = dv == 0.0
                dqf = qc - q
                dqf *= ~free
                Jf = Jm * free
                dot(Jf, Jf.T, out=A)
                Ad += lam
                llt.compute(A)
                qn = q + dqf + Jf.T.dot(llt.solve(e - Jm.dot(dqf)).reshape(nrow))
                qc = mn(mx(qn, lo), hi)
            q = qc
        return best_q, False, max_iter, math.sqrt(best_pe), math.sqrt(best_re), math.sqrt(best_ee)
