"""What each robot family does with a Cartesian command (SPEC.md §7, "Per-family rules").

One table, looked up by (family, number of arm axes). A Cartesian command is
either refused (``NG``) or planned with a :class:`CartesianRule` that says
which parts of the commanded pose count:

* ``mask`` -- the components (x, y, z, rx, ry, rz) that inverse kinematics must
  meet, along the arm base frame axes (see ``Kinematics.ik``). The others are
  free: the arm reaches what it can of them.
* ``orientation`` -- how the commanded orientation becomes the path's target
  orientation, before any interpolation:

  - ``FULL``: as commanded.
  - ``YAW`` (SCARA): only the rotation about the robot frame's Z axis counts.
    The target is ``Rz(psi) · R_start`` where ``Rz(psi)`` is the rotation about
    Z nearest to ``R_cmd · R_startᵀ`` (Abs) or to ``R_rel`` (Rel); rotations
    about X and Y are ignored, so the tool keeps its tilt.
  - ``KEEP`` (1-3 axis gantries): every rotation is ignored; the orientation
    stays the start orientation along the whole path.
  - ``ARM_PLANE`` (5-axis arms, "rotation about X ignored"): a 5-axis arm
    (J1 yaw about the base z axis, then pitch axes and the tool roll) keeps
    its roll axis -- the tool's approach axis -- in its own vertical plane,
    the plane through the base z axis and the flange. The one rotation it
    cannot set is the one that tilts the approach axis out of that plane:
    the rotation about ``X_p = n x a`` (``n`` the plane's normal, ``a`` the
    approach axis), the axis in the arm plane perpendicular to the approach.
    With the arm facing along the base X axis and the tool pointing down,
    ``X_p`` is the base X axis -- hence the specification's "rotation about
    X" -- but it turns with J1 and with the tool's pitch, so it is taken in
    this arm-plane frame, not the base frame. Every pose handed to IK (the
    target, and each sample of a LIN / CIRC path, whose orientation is
    interpolated as commanded) is first turned about ``X_p`` by the least
    angle that brings its approach axis into the arm plane
    (:func:`reachable`, :func:`reachable_pose`), then solved exactly (full mask). The position is
    never changed. The duration counts the whole commanded rotation.

* ``elbow`` -- the 7-axis arm angle (DECISIONS.md "Frames") is commanded
  (``CarPosWithElbow.elbow``); ignored for 1-6 axes. Decisions:

  - Abs: the target's arm angle is ``elbow``; Rel: ``elbow`` is an increment,
    the target's arm angle is the start's (measured) plus ``elbow`` -- so a
    Rel command with ``elbow = 0`` keeps the arm angle.
  - LIN and CIRC move the arm angle linearly in the path parameter (the
    fraction of the path length), from the start's to the target's, the
    shorter way round (the difference wrapped into (-pi, pi]); every sample
    is solved with that arm angle, so it is reached at the target within the
    IK tolerance. PTP-Cartesian solves the target with it; the joint-space
    path between has no arm-angle constraint.
  - CIRC: the via point's ``elbow`` is ignored (its orientation too).
* ``planar`` (2-axis gantry CIRC): J1 = X, J2 = Y; the points are in the arm
  frame (no base offset) and their Z is ignored (the path stays at the start
  height).
"""

from __future__ import annotations

import dataclasses
import enum
import functools

import numpy as np
import pinocchio as pin
from numpy.typing import NDArray

from jara_arm.kinematics import FULL_MASK, Kinematics, Mask
from jara_arm.robots import Family, RobotModel

#: Components of a pose task: positions x, y, z, rotations rx, ry, rz (arm base frame axes).
_XY: Mask = (True, True, False, False, False, False)
_XYZ: Mask = (True, True, True, False, False, False)
_SCARA: Mask = (True, True, True, False, False, True)


class Orientation(enum.Enum):
    """How the commanded orientation is turned into the path's target orientation."""

    FULL = "full"
    YAW = "yaw"
    KEEP = "keep"
    ARM_PLANE = "arm-plane"


class CartesianKind(enum.Enum):
    """The two columns of the per-family table."""

    LINEAR = "LIN / PTP-Cartesian"  # moveLinearCartesian*, movePTPCartesian*
    CIRCULAR = "CIRC"  # moveCircularCartesian*


@dataclasses.dataclass(frozen=True)
class CartesianRule:
    """How one family plans one kind of Cartesian command (see module docstring)."""

    mask: Mask
    orientation: Orientation
    elbow: bool = False
    planar: bool = False


@dataclasses.dataclass(frozen=True)
class Refused:
    """The family cannot do this kind of command: ``NG`` with ``why``."""

    why: str


Rule = CartesianRule | Refused

_FULL = CartesianRule(FULL_MASK, Orientation.FULL)
_GANTRY_NG = Refused("a {n}-axis Cartesian robot cannot do {kind} moves (SPEC.md §7)")

#: (family, axes) -> (LIN / PTP-Cartesian rule, CIRC rule).
TABLE: dict[tuple[Family, int], tuple[Rule, Rule]] = {
    (Family.CARTESIAN, 1): (_GANTRY_NG, _GANTRY_NG),
    (Family.CARTESIAN, 2): (_GANTRY_NG, CartesianRule(_XY, Orientation.KEEP, planar=True)),
    (Family.CARTESIAN, 3): (_GANTRY_NG, CartesianRule(_XYZ, Orientation.KEEP)),
    (Family.SCARA, 4): (CartesianRule(_SCARA, Orientation.YAW),) * 2,
    (Family.ARTICULATED, 5): (CartesianRule(FULL_MASK, Orientation.ARM_PLANE),) * 2,
    (Family.ARTICULATED, 6): (_FULL, _FULL),
    (Family.ARTICULATED, 7): (CartesianRule(FULL_MASK, Orientation.FULL, elbow=True),) * 2,
}


def rule(model: RobotModel, kind: CartesianKind) -> Rule:
    """The rule for ``kind`` commands on ``model``; a family/axis count not in the table is refused."""
    n = model.axis_num
    rules = TABLE.get((model.family, n))
    if rules is None:
        return Refused(f"no Cartesian rules for a {n}-axis {model.family.value} robot")
    r = rules[0] if kind is CartesianKind.LINEAR else rules[1]
    if isinstance(r, Refused):
        return Refused(r.why.format(n=n, kind=kind.value))
    return r


# ---------------------------------------------------------------------- 5-axis arm plane

#: Below this horizontal distance [m] of the flange from the J1 axis, or this sine of the
#: approach axis from the arm plane's normal, the arm plane is undefined: the pose is left as it is.
_PLANE_EPS = 1e-9


@functools.lru_cache(maxsize=None)
def _approach_axis(kin: Kinematics) -> tuple[float, float, float]:
    """The last axis (the tool roll) as a unit vector in the flange frame (constant: it turns with the flange)."""
    q = np.asarray(kin.robot.ready_pose, dtype=float)
    w = kin.jacobian(q)[3:, -1]
    a = kin.fk(q).rotation.T @ w
    return tuple(float(x) for x in a / np.linalg.norm(a))  # type: ignore[return-value]


def _rotate(axis: NDArray[np.float64], cos: NDArray[np.float64], sin: NDArray[np.float64]) -> NDArray[np.float64]:
    """Rotation matrices (N, 3, 3) about unit ``axis`` (N, 3) by the angle of (cos, sin) (Rodrigues)."""
    K = np.zeros((len(axis), 3, 3))
    K[:, 0, 1], K[:, 0, 2], K[:, 1, 2] = -axis[:, 2], axis[:, 1], -axis[:, 0]
    K[:, 1, 0], K[:, 2, 0], K[:, 2, 1] = axis[:, 2], -axis[:, 1], axis[:, 0]
    return np.eye(3) + sin[:, None, None] * K + (1.0 - cos)[:, None, None] * (K @ K)


def reachable_pose(rule: CartesianRule, kin: Kinematics, target: pin.SE3, tool: pin.SE3) -> pin.SE3:
    """One control-point pose (arm base frame) as IK must meet it: :func:`reachable` of a batch of one."""
    if rule.orientation is not Orientation.ARM_PLANE:
        return target
    T = reachable(rule, kin, target.homogeneous[None], tool)[0]
    return pin.SE3(T[:3, :3], T[:3, 3])


def reachable(rule: CartesianRule, kin: Kinematics, targets: NDArray[np.float64],
              tool: pin.SE3) -> NDArray[np.float64]:
    """``targets`` ((N, 4, 4) control-point poses, arm base frame) as IK must meet them.

    Identity except for ``ARM_PLANE``: each orientation turned about the arm-plane X axis
    ``X_p`` by the least angle that puts the approach axis into the arm plane (module docstring).
    The plane goes through the flange, which moves with the orientation when the control
    point is off the flange axis; a few fixed-point rounds settle it. A batch stays an
    array for speed; ``tool`` (the control point offset C) enters it as its rotation and translation.
    """
    if rule.orientation is not Orientation.ARM_PLANE:
        return targets
    T = np.array(targets, dtype=float)
    a_f = np.array(_approach_axis(kin))
    rc, tc = tool.rotation, tool.translation
    r_cmd = T[:, :3, :3] @ rc.T  # commanded flange orientations
    a = r_cmd @ a_f  # commanded approach axes
    r_flange = r_cmd
    for _ in range(4):
        p_f = T[:, :3, 3] - r_flange @ tc
        n = np.stack([-p_f[:, 1], p_f[:, 0], np.zeros(len(p_f))], axis=1)  # base z x p_f
        ok = np.linalg.norm(n, axis=1) > _PLANE_EPS
        n[ok] /= np.linalg.norm(n[ok], axis=1)[:, None]
        an = np.einsum("ij,ij->i", a, n)
        axis = np.cross(a, n)  # X_p, up to sign and length
        s = np.linalg.norm(axis, axis=1)
        ok &= s > _PLANE_EPS
        axis[ok] /= s[ok, None]
        axis[~ok] = (1.0, 0.0, 0.0)
        sin = np.where(ok, -an, 0.0)  # turn by -asin(a.n): a loses its component along n
        new = _rotate(axis, np.sqrt(1.0 - sin * sin), sin) @ r_cmd
        done = np.abs(new - r_flange).max() < 1e-15
        r_flange = new
        if done or not tc.any():
            break
    T[:, :3, :3] = r_flange @ rc
    return T
