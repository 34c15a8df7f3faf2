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
  - ``FREE_X`` (5-axis arms): the commanded orientation is interpolated as
    given, but IK leaves the rotation about the base X axis free (the
    orientation a 5-axis arm cannot set when it faces along X). The reached
    orientation is the commanded one turned about the base X axis; the
    duration counts the whole commanded rotation.

* ``elbow`` -- the 7-axis arm angle is commanded (``CarPosWithElbow.elbow``);
  ignored for 1-6 axes.
* ``planar`` (2-axis gantry CIRC): J1 = X, J2 = Y; the points are in the arm
  frame (no base offset) and their Z is ignored (the path stays at the start
  height).
"""

from __future__ import annotations

import dataclasses
import enum

from jara_arm.robots import Family, RobotModel

from .kinematics import FULL_MASK, Mask

#: Components of a pose task: positions x, y, z, rotations rx, ry, rz (arm base frame axes).
_XY: Mask = (True, True, False, False, False, False)
_XYZ: Mask = (True, True, True, False, False, False)
_SCARA: Mask = (True, True, True, False, False, True)
_NO_RX: Mask = (True, True, True, False, True, True)


class Orientation(enum.Enum):
    """How the commanded orientation is turned into the path's target orientation."""

    FULL = "full"
    YAW = "yaw"
    KEEP = "keep"
    FREE_X = "free-x"


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
    (Family.ARTICULATED, 5): (CartesianRule(_NO_RX, Orientation.FREE_X),) * 2,
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
