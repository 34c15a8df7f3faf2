"""Geometric paths of the middle level: where the arm goes, not when.

Every motion (PTP, LIN, CIRC) is one geometric path plus one speed profile
along it (DECISIONS.md, "Timing law"); the profile lives in ``profile.py``.

Parametrisation
---------------
All three paths use the same **normalised** parameter ``s`` in
``[0, length]`` with ``length == 1.0``: ``s`` is the fraction of the move done.

* :class:`JointLine`: ``q(s) = q0 + s * (q1 - q0)``.  Axis ``i`` moves at
  ``|q1_i - q0_i| * ds/dt`` [rad/s or m/s], so a bound on every axis speed is
  a bound on ``ds/dt``; the slowest axis (relative to its max) sets it.
* :class:`CartesianLine` and :class:`CartesianArc`: ``s`` is the fraction of
  the translation (arc length, uniform along the line or circle) **and** of the
  rotation angle.  Translation speed is ``translation_length * ds/dt`` [m/s],
  rotation speed ``rotation_angle * ds/dt`` [rad/s]; pure rotations
  (``translation_length == 0``) need no special case.

A normalised parameter (rather than metres) keeps pure-rotation moves and
joint moves on the same footing; the physical lengths are exposed as
``translation_length`` [m] and ``rotation_angle`` [rad].

The endpoints are given as ``pin.SE3`` (a 4x4 homogeneous transform or a 3x4
``HgMatrix`` is accepted too); inside, and in what :meth:`sample` returns, poses
are 4x4 numpy arrays: a sampled path is a vectorised batch of N poses, kept as
an (N, 4, 4) array for speed.  Orientation moves the short way from ``R0`` to
``R1``: ``R(u) = R0 · exp3(u · log3(R0ᵀ R1))``.

The endpoints are returned bit-exactly (``at(0)`` is the start, ``at(length)``
the target) so that a motion ends exactly on its commanded target.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

import numpy as np
import pinocchio
from numpy.typing import ArrayLike, NDArray

from jara_arm.schema.errors import JaraArmError

__all__ = [
    "ARC_TOLERANCE",
    "CartesianArc",
    "CartesianLine",
    "JointLine",
    "Path",
    "PathGeometryError",
    "ROTATION_TOLERANCE",
]

ARC_TOLERANCE = 1e-6
"""[m] CIRC degeneracy: two points closer than this, or a triangle height
(distance of a point from the line through the other two) below this, is
refused as coincident / collinear."""

ROTATION_TOLERANCE = 1e-6
"""[-] Largest accepted deviation of a pose's rotation block from a proper
rotation matrix (``|RᵀR - I|`` and ``|det R - 1|``)."""

_S_TOLERANCE = 1e-9  # [-] how far outside [0, length] s may be before it is a caller bug


class PathGeometryError(JaraArmError, ValueError):
    """A path cannot be built from the given points (the message says why)."""


@runtime_checkable
class Path(Protocol):
    """What the profile and the executor need from any path."""

    @property
    def length(self) -> float:
        """Parameter range ``[0, length]`` of ``s`` (1.0 for every path here)."""
        ...

    def at(self, s: float) -> NDArray[np.float64]:
        """The point at parameter ``s``: joints ``(n,)`` or a 4x4 pose."""
        ...

    def sample(self, s: ArrayLike) -> NDArray[np.float64]:
        """Vectorised :meth:`at`: ``(N, n)`` joints or ``(N, 4, 4)`` poses."""
        ...


# --------------------------------------------------------------------------- helpers


def _readonly(a: NDArray[np.float64]) -> NDArray[np.float64]:
    a.setflags(write=False)
    return a


def _fraction(s: ArrayLike, length: float) -> NDArray[np.float64]:
    """``s / length`` clamped to [0, 1]; values beyond rounding noise are an error."""
    u = np.asarray(s, dtype=float) / length
    if not np.all(np.isfinite(u)):
        raise PathGeometryError("path parameter s must be finite")
    if np.any(u < -_S_TOLERANCE) or np.any(u > 1.0 + _S_TOLERANCE):
        raise PathGeometryError(f"path parameter s outside [0, {length}]")
    return np.clip(u, 0.0, 1.0)


def _as_pose(T: ArrayLike | pinocchio.SE3, name: str) -> NDArray[np.float64]:
    """A validated 4x4 homogeneous transform (copy) of a ``pin.SE3``, a 4x4 or a 3x4 HgMatrix."""
    a = T.homogeneous if isinstance(T, pinocchio.SE3) else np.array(T, dtype=float)
    if a.shape == (3, 4):
        a = np.vstack([a, [0.0, 0.0, 0.0, 1.0]])
    if a.shape != (4, 4):
        raise PathGeometryError(f"{name} must be a 4x4 (or 3x4) homogeneous transform, got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise PathGeometryError(f"{name} contains a non-finite value")
    if not np.allclose(a[3], [0.0, 0.0, 0.0, 1.0], rtol=0.0, atol=ROTATION_TOLERANCE):
        raise PathGeometryError(f"{name} last row must be [0, 0, 0, 1]")
    R = a[:3, :3]
    orthonormal_error = np.max(np.abs(R.T @ R - np.eye(3)))
    if orthonormal_error > ROTATION_TOLERANCE or abs(np.linalg.det(R) - 1.0) > ROTATION_TOLERANCE:
        raise PathGeometryError(
            f"{name} rotation block is not a proper rotation matrix (tolerance {ROTATION_TOLERANCE})"
        )
    a[3] = [0.0, 0.0, 0.0, 1.0]
    return _readonly(a)


def _as_point(p: ArrayLike, name: str) -> NDArray[np.float64]:
    """A 3-vector [m]; a pose (4x4 / 3x4) gives its translation."""
    a = np.array(p, dtype=float)
    if a.shape in ((4, 4), (3, 4)):
        a = a[:3, 3].copy()
    if a.shape != (3,):
        raise PathGeometryError(f"{name} must be a 3-vector or a homogeneous transform, got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise PathGeometryError(f"{name} contains a non-finite value")
    return _readonly(a)


class _Slerp:
    """``R(u) = R0 · exp3(u · ω)`` with ``ω = log3(R0ᵀ R1)``, vectorised over u."""

    def __init__(self, R0: NDArray[np.float64], R1: NDArray[np.float64]) -> None:
        self.R0 = R0
        self.R1 = R1
        omega = np.asarray(pinocchio.log3(R0.T @ R1), dtype=float)  # robust near pi
        self.angle = float(np.linalg.norm(omega))  # [rad] in [0, pi]
        if self.angle > 0.0:
            k = omega / self.angle
            K = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
        else:
            K = np.zeros((3, 3))
        self._K = K
        self._K2 = K @ K

    def __call__(self, u: NDArray[np.float64]) -> NDArray[np.float64]:
        """Rotations ``(N, 3, 3)`` at fractions ``u`` (already clamped to [0, 1])."""
        th = u * self.angle
        # Rodrigues: exp3(th k) = I + sin(th) K + (1 - cos(th)) K²
        E = (
            np.eye(3)[None]
            + np.sin(th)[:, None, None] * self._K[None]
            + (1.0 - np.cos(th))[:, None, None] * self._K2[None]
        )
        R = np.einsum("ij,njk->nik", self.R0, E)
        R[u == 0.0] = self.R0  # endpoints bit-exact: the target must be reached exactly
        R[u == 1.0] = self.R1
        return R


def _poses(p: NDArray[np.float64], R: NDArray[np.float64]) -> NDArray[np.float64]:
    out = np.zeros((p.shape[0], 4, 4))
    out[:, :3, :3] = R
    out[:, :3, 3] = p
    out[:, 3, 3] = 1.0
    return out


# --------------------------------------------------------------------------- paths


@dataclass(frozen=True, eq=False)
class JointLine:
    """Straight line in joint space from ``q0`` to ``q1`` [rad or m per axis].

    ``s`` in [0, 1] is the fraction of the move; ``q(s) = q0 + s·(q1 - q0)``, so
    every axis starts and stops together and all points are on the line.
    """

    q0: NDArray[np.float64]
    q1: NDArray[np.float64]
    delta: NDArray[np.float64] = field(init=False)  # q1 - q0 [rad or m]

    def __post_init__(self) -> None:
        q0 = np.array(self.q0, dtype=float)
        q1 = np.array(self.q1, dtype=float)
        if q0.ndim != 1 or q0.shape != q1.shape or q0.size == 0:
            raise PathGeometryError(
                f"q0 and q1 must be non-empty 1-D and of equal length, got {q0.shape} and {q1.shape}"
            )
        if not (np.all(np.isfinite(q0)) and np.all(np.isfinite(q1))):
            raise PathGeometryError("q0 and q1 must be finite")
        object.__setattr__(self, "q0", _readonly(q0))
        object.__setattr__(self, "q1", _readonly(q1))
        object.__setattr__(self, "delta", _readonly(q1 - q0))

    @property
    def length(self) -> float:
        return 1.0

    @property
    def axis_count(self) -> int:
        return int(self.q0.size)

    def at(self, s: float) -> NDArray[np.float64]:
        """Joint positions ``(n,)`` [rad or m] at ``s``."""
        return self.sample(np.array([s]))[0]

    def sample(self, s: ArrayLike) -> NDArray[np.float64]:
        """Joint positions ``(N, n)`` [rad or m] at each ``s``."""
        u = np.atleast_1d(_fraction(s, self.length))
        q = self.q0[None, :] + u[:, None] * self.delta[None, :]
        q[u == 1.0] = self.q1  # bit-exact target
        return q


@dataclass(frozen=True, eq=False)
class CartesianLine:
    """Straight line of the control point from pose ``T0`` to ``T1``.

    Position ``p(u) = p0 + u·(p1 - p0)`` [m]; orientation
    ``R(u) = R0 · exp3(u · log3(R0ᵀ R1))``; ``u = s / length`` in [0, 1].
    ``T0``, ``T1``: ``pin.SE3`` (or 4x4 / 3x4 arrays), kept as read-only 4x4 arrays.
    """

    T0: NDArray[np.float64]
    T1: NDArray[np.float64]
    translation_length: float = field(init=False)  # [m] |p1 - p0|
    rotation_angle: float = field(init=False)  # [rad] angle of R0ᵀR1, in [0, pi]
    _slerp: _Slerp = field(init=False, repr=False)

    def __post_init__(self) -> None:
        T0 = _as_pose(self.T0, "T0")
        T1 = _as_pose(self.T1, "T1")
        object.__setattr__(self, "T0", T0)
        object.__setattr__(self, "T1", T1)
        object.__setattr__(self, "translation_length", float(np.linalg.norm(T1[:3, 3] - T0[:3, 3])))
        slerp = _Slerp(T0[:3, :3], T1[:3, :3])
        object.__setattr__(self, "_slerp", slerp)
        object.__setattr__(self, "rotation_angle", slerp.angle)

    @property
    def length(self) -> float:
        return 1.0

    def positions(self, s: ArrayLike) -> NDArray[np.float64]:
        """Control-point positions ``(N, 3)`` [m] at each ``s``."""
        u = np.atleast_1d(_fraction(s, self.length))
        p0, p1 = self.T0[:3, 3], self.T1[:3, 3]
        p = p0[None, :] + u[:, None] * (p1 - p0)[None, :]
        p[u == 1.0] = p1  # bit-exact target
        return p

    def at(self, s: float) -> NDArray[np.float64]:
        """Pose 4x4 at ``s``."""
        return self.sample(np.array([s]))[0]

    def sample(self, s: ArrayLike) -> NDArray[np.float64]:
        """Poses ``(N, 4, 4)`` at each ``s``."""
        u = np.atleast_1d(_fraction(s, self.length))
        return _poses(self.positions(u * self.length), self._slerp(u))


@dataclass(frozen=True, eq=False)
class CartesianArc:
    """Circular arc of the control point from ``T0`` through ``via`` to ``T1``.

    The circle is the one through the three positions; the arc is the one that
    starts at ``p0``, contains ``p_via`` and ends at ``p1`` (it may exceed 180°).
    Position at ``u = s / length``: ``center + radius·(cos(uφ) e1 + sin(uφ) e2)``
    with ``φ = sweep_angle``, i.e. uniform in arc length.  Orientation goes from
    ``R0`` to ``R1`` with the same ``u`` (the via orientation is ignored,
    DECISIONS.md).  ``T0``, ``T1``: ``pin.SE3`` (or 4x4 / 3x4 arrays), kept as
    read-only 4x4 arrays; ``via`` is a 3-vector [m] (or a 4x4 / 3x4 pose).

    Raises :class:`PathGeometryError` when two points are closer than
    :data:`ARC_TOLERANCE` [m] or the three are collinear (a point lies within
    :data:`ARC_TOLERANCE` of the line through the other two).
    """

    T0: NDArray[np.float64]
    via: NDArray[np.float64]
    T1: NDArray[np.float64]
    center: NDArray[np.float64] = field(init=False)  # [m]
    radius: float = field(init=False)  # [m]
    normal: NDArray[np.float64] = field(init=False)  # unit axis; the arc turns positively about it
    sweep_angle: float = field(init=False)  # [rad] in (0, 2 pi): angle from p0 to p1 through via
    via_fraction: float = field(init=False)  # [-] u at which the arc passes the via point
    translation_length: float = field(init=False)  # [m] arc length radius * sweep_angle
    rotation_angle: float = field(init=False)  # [rad] angle of R0ᵀR1, in [0, pi]
    _e1: NDArray[np.float64] = field(init=False, repr=False)
    _e2: NDArray[np.float64] = field(init=False, repr=False)
    _slerp: _Slerp = field(init=False, repr=False)

    def __post_init__(self) -> None:
        T0 = _as_pose(self.T0, "T0")
        T1 = _as_pose(self.T1, "T1")
        pv = _as_point(self.via, "via")
        p0, p1 = T0[:3, 3], T1[:3, 3]
        for (na, a), (nb, b) in (
            (("start", p0), ("via", pv)),
            (("via", pv), ("target", p1)),
            (("start", p0), ("target", p1)),
        ):
            if np.linalg.norm(a - b) < ARC_TOLERANCE:
                raise PathGeometryError(
                    f"CIRC {na} and {nb} points coincide (closer than {ARC_TOLERANCE} m); no unique circle"
                )
        b = pv - p0
        c = p1 - p0
        n = np.cross(b, c)
        n_norm = float(np.linalg.norm(n))
        longest = max(np.linalg.norm(b), np.linalg.norm(c), np.linalg.norm(p1 - pv))
        height = n_norm / longest  # [m] smallest distance of a point from the line through the other two
        if height < ARC_TOLERANCE:
            raise PathGeometryError(
                f"CIRC start, via and target points are collinear (within {ARC_TOLERANCE} m); "
                "no unique circle"
            )
        # circumcentre of the triangle (p0, pv, p1), relative to p0
        offset = (np.dot(c, c) * np.cross(n, b) + np.dot(b, b) * np.cross(c, n)) / (2.0 * n_norm**2)
        center = p0 + offset
        radius = float(np.linalg.norm(p0 - center))
        normal = n / n_norm
        e1 = (p0 - center) / radius
        e2 = np.cross(normal, e1)
        e2 /= np.linalg.norm(e2)
        # Points in counter-clockwise order about n = (pv-p0) x (p1-p0) are p0, pv, p1,
        # so turning positively from p0 meets pv before p1: that arc contains the via point.

        def angle_of(p: NDArray[np.float64]) -> float:
            d = p - center
            return math.atan2(float(np.dot(d, e2)), float(np.dot(d, e1))) % (2.0 * math.pi)

        sweep = angle_of(p1)
        phi_via = angle_of(pv)
        if not 0.0 < phi_via < sweep:  # cannot happen for a valid triangle; guard against rounding
            raise PathGeometryError("CIRC points too close to degenerate to order them on the circle")
        slerp = _Slerp(T0[:3, :3], T1[:3, :3])
        for name, value in (
            ("T0", T0),
            ("via", pv),
            ("T1", T1),
            ("center", _readonly(center)),
            ("radius", radius),
            ("normal", _readonly(normal)),
            ("sweep_angle", sweep),
            ("via_fraction", phi_via / sweep),
            ("translation_length", radius * sweep),
            ("rotation_angle", slerp.angle),
            ("_e1", _readonly(e1)),
            ("_e2", _readonly(e2)),
            ("_slerp", slerp),
        ):
            object.__setattr__(self, name, value)

    @property
    def length(self) -> float:
        return 1.0

    @property
    def via_point(self) -> NDArray[np.float64]:
        """The via position [m] (``via`` as given, reduced to a point)."""
        return self.via

    def positions(self, s: ArrayLike) -> NDArray[np.float64]:
        """Control-point positions ``(N, 3)`` [m] at each ``s``; all on the circle."""
        u = np.atleast_1d(_fraction(s, self.length))
        ang = u * self.sweep_angle
        p = self.center[None, :] + self.radius * (
            np.cos(ang)[:, None] * self._e1[None, :] + np.sin(ang)[:, None] * self._e2[None, :]
        )
        p[u == 0.0] = self.T0[:3, 3]  # bit-exact endpoints
        p[u == 1.0] = self.T1[:3, 3]
        return p

    def at(self, s: float) -> NDArray[np.float64]:
        """Pose 4x4 at ``s``."""
        return self.sample(np.array([s]))[0]

    def sample(self, s: ArrayLike) -> NDArray[np.float64]:
        """Poses ``(N, 4, 4)`` at each ``s``."""
        u = np.atleast_1d(_fraction(s, self.length))
        return _poses(self.positions(u * self.length), self._slerp(u))
