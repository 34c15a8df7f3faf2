"""The arm angle of a 7-axis arm (DECISIONS.md "Frames"): its definition and, on Pinocchio, its gradient.

Shoulder S, elbow E and wrist W are points of the arm [m] in the arm base
frame; on a Pinocchio model they are the origins of three joint frames (the
``elbow_joints`` axes, J2, J4, J6 by default; on the Panda these joint origins
carry the link offsets, and they are used as they are). With u the unit vector
S->W, the reference direction r is the base z axis (the base x axis when S->W
is vertical) made orthogonal to u, and v is S->E made orthogonal to u. The arm
angle is the rotation from r to v, right-handed about u, in (-pi, pi]: 0 when
the elbow lies in the vertical plane through S->W on the +z side ("elbow up").
Undefined -- 0 is returned -- when E lies on the line S-W.
"""

from __future__ import annotations

import math
from typing import Final

import numpy as np
import numpy.typing as npt
import pinocchio as pin

__all__ = ["DEFAULT_ELBOW_JOINTS", "ArmAngleChain", "arm_angle"]

DEFAULT_ELBOW_JOINTS: Final[tuple[int, int, int]] = (1, 3, 5)
"""Zero-based arm axes whose joint origins are the shoulder, elbow and wrist of a 7-axis arm."""

_VERTICAL: Final = 1e-6  # sin(angle) below which the shoulder-wrist line counts as vertical
_ON_LINE: Final = 1e-12  # [m] distance of E from the line S-W below which the angle is undefined


def arm_angle(shoulder: npt.ArrayLike, elbow: npt.ArrayLike, wrist: npt.ArrayLike) -> float:
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
    if np.linalg.norm(n_arm) < _ON_LINE:
        return 0.0
    return math.atan2(float(u.dot(np.cross(n_ref, n_arm))), float(n_ref.dot(n_arm)))


class ArmAngleChain:
    """The shoulder, elbow and wrist joints of a 7-axis arm on one Pinocchio ``Data`` work area.

    Reads the points from ``data.oMi`` (forward kinematics done) and, for the
    gradient, the joint Jacobians from ``data.J`` (``computeJointJacobians``
    done); the caller runs those, so that IK computes them once per iteration.
    """

    __slots__ = ("joints", "_data", "_oMi", "_n", "_support")

    def __init__(self, model: pin.Model, data: pin.Data, joints: tuple[int, int, int]) -> None:
        self.joints: Final = joints  # Pinocchio joint ids of S, E, W
        self._data = data
        self._oMi = data.oMi  # bound once: read on every IK iteration
        self._n = model.nv
        # Which columns of the WORLD joint Jacobian move each of the points S, E, W.
        self._support = np.zeros((3, model.nv))
        for row, jid in enumerate(joints):
            for sj in model.supports[jid]:
                if sj > 0:
                    self._support[row, model.joints[sj].idx_v] = 1.0

    def points(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Shoulder, elbow and wrist points [m] in the arm base frame (new arrays)."""
        s, e, w = (self._oMi[j].translation.copy() for j in self.joints)
        return s, e, w

    def angle(self, grad: bool) -> tuple[float, np.ndarray | None]:
        """Arm angle psi [rad]; with ``grad`` also d(psi)/dq (n,) in Pinocchio coordinate order.

        With u, r, v the unit vectors of the module docstring, a = SE, L = |SW|,
        rho and sigma the lengths of v and r before normalising, t_v = u x v and
        t_r = u x r: d(psi) = g_e . (dE - dS) + g_w . (dW - dS) with
        g_e = t_v / rho and g_w = -(a . u) t_v / (L rho) + (ref . u) t_r / (L sigma).
        Scalar Python arithmetic: faster than numpy on 3-vectors.
        """
        js, je, jw = self.joints
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
        if rho < _ON_LINE:  # elbow on the shoulder-wrist line: undefined
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
        return psi, (c.dot(self._data.J) * self._support).sum(axis=0)
