"""Posture bits (``CarPosWithElbow.structFlag``) of a 6- or 7-axis arm: reading them and IK that holds them.

After the Status bits of industrial controllers (KUKA's "Status" ``S``): the
discrete choices among the IK solutions of one pose (and, on 7 axes, one arm
angle). The wire value is ``POSTURE_SET | bits``, so that 0 keeps meaning
"the solution nearest to the start joints" (DECISIONS.md, docs/decisions.md
"Posture bits"). A robot that defines them names three joints,
``RobotModel.posture_joints`` = (S, E, W), zero-based: the origins of S and W
are the shoulder and wrist points, E is the elbow joint.

=============  ==============================================================
``SHOULDER``   6 axes: the wrist point lies behind J1's axis ("overhead"):
               its component along ``axis(S) x axis(J1)`` (J1's rotating
               frame) is negative. 7 axes: ``sin(q_S) < 0`` (J2 negative).
``ELBOW``      ``sin(q_E - q_E*) < 0``: the elbow bent the other way from the
               stretched arm, ``q_E*`` being the elbow angle at which S, E and
               W line up (the wrist farthest from the shoulder; from the URDF).
``WRIST``      ``sin(q_W) < 0``: the wrist flipped (J5 on 6 axes, J6 on 7).
=============  ==============================================================

Every bit reads "the posture joint's angle lies below its reference": ``sin(q_j - r_j) < 0``.
On 6 axes the shoulder's reference depends on the pose: with the wrist point at
azimuth ``phi`` about J1's axis, it is ``phi - pi / 2``. So a posture is a box
of joint intervals for a given pose, and IK toward a posture is the one IK loop
(:meth:`Kinematics.ik`) run within those intervals.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from typing import Final

import numpy as np
import numpy.typing as npt
import pinocchio as pin

from .errors import KinematicsError
from .ik import FULL_MASK, IkResult
from .model import Kinematics

__all__ = ["BITS", "ELBOW", "POSTURE_SET", "SHOULDER", "WRIST", "Postures", "describe"]

POSTURE_SET: Final = 0x100
"""Marks a ``structFlag`` that commands (or reports) a posture; 0 = "nearest"."""
SHOULDER: Final = 0x1
ELBOW: Final = 0x2
WRIST: Final = 0x4
BITS: Final = SHOULDER | ELBOW | WRIST

_NAMES: Final = ((SHOULDER, "shoulder back", "shoulder front"), (ELBOW, "elbow down", "elbow up"),
                 (WRIST, "wrist flipped", "wrist not flipped"))


def describe(flag: int) -> str:
    """``0x105 (shoulder back, elbow up, wrist flipped)`` for a wire value ``POSTURE_SET | bits``."""
    return f"{flag:#x} ({', '.join(on if flag & bit else off for bit, on, off in _NAMES)})"


def _signed_angle(a: np.ndarray, b: np.ndarray, axis: np.ndarray) -> float:
    """Angle [rad] from ``a`` to ``b``, right-handed about the unit ``axis``, both projected on its normal plane."""
    return math.atan2(float(axis.dot(np.cross(a, b))), float(a.dot(b) - axis.dot(a) * axis.dot(b)))


def _below(q: float, ref: float) -> bool:
    """The bit rule: ``sin(q - ref) < 0`` [rad]."""
    return math.sin(q - ref) < 0.0


class Postures:
    """The posture bits of one arm on its :class:`Kinematics`; one instance per thread (own Pinocchio data)."""

    def __init__(self, kinematics: Kinematics) -> None:
        robot = kinematics.robot
        joints = robot.posture_joints
        if joints is None:
            raise KinematicsError(f"{robot.name} defines no posture bits")
        self.kin: Final = kinematics
        self._n = n = kinematics.axis_num
        if n not in (6, 7):
            raise KinematicsError(f"{robot.name}: posture bits are defined for 6 and 7 axes, not {n}")
        self.shoulder, self.elbow, self.wrist = joints
        model = kinematics.pin_model
        self._model, self._data = model, model.createData()
        self._jids = [model.getJointId(name) for name in robot.arm_joints]
        self._idx = np.array([model.joints[j].idx_q for j in self._jids])
        # Joint axes, each in its own joint frame (the LOCAL Jacobian's column of that joint).
        pin.computeJointJacobians(model, self._data, pin.neutral(model))
        self._axes = [pin.getJointJacobian(model, self._data, j, pin.LOCAL)[3:, model.joints[j].idx_v].copy()
                      for j in self._jids]
        q0 = np.zeros(n)
        oMi = self._fk(q0)
        s, e, w = (oMi[self._jids[i]] for i in joints)
        axis_e = e.rotation @ self._axes[self.elbow]
        # Stretched elbow: the angle that turns E->W to point away from S.
        self.elbow_reference: Final = _signed_angle(w.translation - e.translation, e.translation - s.translation,
                                                    axis_e)
        j1 = oMi[self._jids[0]]
        self._j1_zero = j1.copy()  # J1's frame at q = 0 (its parent is the base: fixed)
        self._a1 = self._axes[0]
        # "Front" (6 axes) in J1's frame: the shoulder axis x J1's axis, constant as both turn with J1.
        front = np.cross(j1.rotation.T @ s.rotation @ self._axes[self.shoulder], self._a1)
        self._front = front / np.linalg.norm(front)

    # ------------------------------------------------------------------ reading

    def _fk(self, q: npt.ArrayLike) -> pin.StdVec_SE3:
        qp = np.empty(self._n)
        qp[self._idx] = np.asarray(q, dtype=float)
        pin.forwardKinematics(self._model, self._data, qp)
        return self._data.oMi

    def of(self, q: npt.ArrayLike) -> int:
        """The posture of arm joints ``q`` [rad] as on the wire: ``POSTURE_SET | bits``."""
        a = np.asarray(q, dtype=float)
        bits = 0
        if self._n == 7:
            bits |= SHOULDER if _below(a[self.shoulder], 0.0) else 0
        else:
            oMi = self._fk(a)
            w = oMi[self._jids[0]].actInv(oMi[self._jids[self.wrist]].translation)
            bits |= SHOULDER if float(w.dot(self._front)) < 0.0 else 0
        bits |= ELBOW if _below(a[self.elbow], self.elbow_reference) else 0
        bits |= WRIST if _below(a[self.wrist], 0.0) else 0
        return POSTURE_SET | bits

    # ------------------------------------------------------------------ IK toward a posture

    def _references(self, target: pin.SE3, tool: pin.SE3 | None) -> list[tuple[int, float]]:
        """(joint, reference [rad]) of the three bits for the control point pose ``target`` (arm frame)."""
        refs = [(self.elbow, self.elbow_reference), (self.wrist, 0.0)]
        if self._n == 7:
            return [(self.shoulder, 0.0), *refs]
        # The wrist point is fixed in the control point's frame (spherical wrist): read it at any q.
        q0 = np.asarray(self.kin.robot.ready_pose, dtype=float)
        oMi = self._fk(q0)
        w_cp = self.kin.control_point(q0, tool).actInv(oMi[self._jids[self.wrist]].translation)
        w1 = self._j1_zero.actInv(target.act(w_cp))
        phi = _signed_angle(self._front, w1, self._a1)
        return [(0, phi - math.pi / 2.0), *refs]

    def boxes(self, flag: int, target: pin.SE3, tool: pin.SE3 | None, lower: npt.ArrayLike,
              upper: npt.ArrayLike) -> list[tuple[np.ndarray, np.ndarray]]:
        """Joint boxes [rad] within ``lower``..``upper`` in which every configuration has posture ``flag``
        (up to the boundaries) at the pose ``target``: one per combination of the bits' intervals."""
        lo, hi = np.asarray(lower, dtype=float), np.asarray(upper, dtype=float)
        choices: list[list[tuple[int, float, float]]] = []
        for bit, (j, ref) in zip((SHOULDER, ELBOW, WRIST), self._references(target, tool)):
            # Below the reference: (ref - pi, ref) + 2 pi k; else [ref, ref + pi] + 2 pi k.
            start = ref - math.pi if flag & bit else ref
            spans = []
            for k in range(-2, 3):
                a, b = max(start + k * math.tau, lo[j]), min(start + math.pi + k * math.tau, hi[j])
                if a <= b:
                    spans.append((j, a, b))
            if not spans:
                return []
            choices.append(spans)
        out = []
        for combo in itertools.product(*choices):
            blo, bhi = lo.copy(), hi.copy()
            for j, a, b in combo:
                blo[j], bhi[j] = a, b
            out.append((blo, bhi))
        return out

    def flipped(self, q: npt.ArrayLike, flag: int, target: pin.SE3, tool: pin.SE3 | None) -> np.ndarray:
        """A seed [rad] near posture ``flag`` made from ``q``: every bit that differs mirrored about its reference.

        Exact where the bit's joint sits between two joints whose axes meet its own (a spherical
        shoulder, elbow or wrist: ``q_j -> 2 r_j - q_j`` with its neighbours turned by pi, the other
        Euler solution); on a 6-axis shoulder or elbow an approximation that IK then corrects.
        """
        out = np.array(q, dtype=float)
        lo, hi = self.kin.lower, self.kin.upper
        differ = (self.of(out) ^ flag) & BITS

        def turn(i: int) -> None:  # by pi, whichever way stays within the limits
            out[i] = out[i] - math.pi if out[i] - math.pi >= lo[i] else out[i] + math.pi

        for bit, (j, ref) in zip((SHOULDER, ELBOW, WRIST), self._references(target, tool)):
            if not differ & bit:
                continue
            if self._n == 6 and bit == SHOULDER:  # J1 half a turn, the arm mirrored in its plane
                turn(0)
                out[self.shoulder] = -out[self.shoulder]
                out[self.elbow] = 2.0 * self.elbow_reference - out[self.elbow]
            elif self._n == 6 and bit == ELBOW:
                out[j] = 2.0 * ref - out[j]
            else:
                out[j] = 2.0 * ref - out[j]
                turn(j - 1)
                if j + 1 < self._n:
                    turn(j + 1)
        return out

    def ik(self, flag: int, target: pin.SE3, seeds: Sequence[npt.ArrayLike], *, lower: npt.ArrayLike,
           upper: npt.ArrayLike, tool: pin.SE3 | None = None, elbow: float | None = None,
           mask: Sequence[bool] = FULL_MASK, tol_pos: float = 1e-5, tol_rot: float = 1e-5,
           max_iter: int = 1000) -> IkResult | None:
        """Joints with posture ``flag`` (``POSTURE_SET | bits``) that put the control point at ``target``.

        :meth:`Kinematics.ik` within each box of :meth:`boxes`, from each of the ``seeds`` [rad] and
        its :meth:`flipped` twin clamped into it (nearest first: the first success wins), its restarts
        kept in the box;
        a solution counts only if :meth:`of` reads ``flag`` on it. None when no box holds one.
        Arguments as :meth:`Kinematics.ik`.
        """
        starts = [x for seed in seeds for x in (np.asarray(seed, dtype=float), self.flipped(seed, flag, target, tool))]
        for blo, bhi in self.boxes(flag, target, tool, lower, upper):
            for seed in starts:
                res = self.kin.ik(target, np.clip(np.asarray(seed, dtype=float), blo, bhi), tool=tool,
                                  elbow=elbow, mask=mask, tol_pos=tol_pos, tol_rot=tol_rot, max_iter=max_iter,
                                  lower=blo, upper=bhi)
                if res.success and self.of(res.q) == flag:
                    return res
        return None
