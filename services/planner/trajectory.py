"""A planned motion: joints as a function of the path parameter, and its speed profile.

The planner needs joints at values of the path parameter ``s`` (the nominal
profile's samples, an early start's continuation after its head), so every
motion carries a :class:`JointMap` ``s -> q``:

* :class:`LineMap` -- a joint-space line (PTP, goHome, gripper): exact.
* :class:`TableMap` -- a Cartesian path (LIN, CIRC): the joints at the
  nominal profile's samples (``sampling.py``: IK at knots, a spline between,
  every sample checked on the path by FK); between them, joints are
  interpolated linearly in ``s``. Samples are 1 servo period apart, so the
  interpolated point leaves the Cartesian path by far less than a micrometre
  (chord of a sub-millimetre step).

Joint vectors are the wire's: arm axes J1..Jn, then the gripper axis if fitted
[rad or m].
"""

from __future__ import annotations

import dataclasses
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from .blend import Blend
from .paths import JointLine
from .profile import PathProfile, ProfileLimits, continue_profile, move_profile

Joints = NDArray[np.float64]


class JointMap(Protocol):
    """Joints at path parameters: ``(N,) -> (N, dof)`` [rad or m]."""

    def joints(self, s: NDArray[np.float64]) -> Joints:
        ...


@dataclasses.dataclass(frozen=True, eq=False)
class LineMap:
    """A straight line in joint space (all wire axes)."""

    line: JointLine

    def joints(self, s: NDArray[np.float64]) -> Joints:
        return self.line.sample(s)


@dataclasses.dataclass(frozen=True, eq=False)
class TableMap:
    """Joints tabulated at increasing ``s`` (from 0 to the path length), linear in between."""

    s: NDArray[np.float64]  # (M,) strictly increasing, s[0] = 0, s[-1] = length
    q: Joints  # (M, dof)

    @classmethod
    def build(cls, s: NDArray[np.float64], q: Joints) -> TableMap:
        """From profile samples, dropping repeated ``s`` (rest at the ends).

        With nothing to drop the table is ``q`` itself, not a copy: a motion's samples and its table are then
        one array, pickled once on the way from the planning process (half the bytes through the pipe).
        """
        keep = np.concatenate(([True], np.diff(s) > 0.0))
        if keep.all():
            return cls(np.ascontiguousarray(s), np.ascontiguousarray(q))
        return cls(np.ascontiguousarray(s[keep]), np.ascontiguousarray(q[keep]))

    def joints(self, s: NDArray[np.float64]) -> Joints:
        s = np.atleast_1d(np.asarray(s, dtype=float))
        tab = self.s
        if len(tab) == 1:
            return np.repeat(self.q[:1], len(s), axis=0)
        i = np.clip(np.searchsorted(tab, s, side="right") - 1, 0, len(tab) - 2)
        w = (s - tab[i]) / (tab[i + 1] - tab[i])
        out = self.q[i] + w[:, None] * (self.q[i + 1] - self.q[i])
        out[s >= tab[-1]] = self.q[-1]  # the target exactly
        out[s <= tab[0]] = self.q[0]
        return out


#: ``PlannedMotion.motion`` of a motion not handed over (yet): ``Handover.submit`` gives the ids.
UNQUEUED = 0


@dataclasses.dataclass(frozen=True, eq=False)
class PlannedMotion:
    """One planned motion: its id, its joint map, its nominal profile and samples."""

    motion: int  # id given at the hand-over to the servo, UNQUEUED before
    op: str  # IDL operation name
    path: JointMap
    profile: PathProfile  # nominal, from rest at s = 0 to rest at the end (an early start's: from where it went on)
    q: Joints  # (N, dof) joints at profile.sample(dt); q[0] is the start, q[-1] the end
    dt: float  # [s] sampling period (the servo period)
    #: (K, 3) [m] the control point at K of the samples, start to end, in the arm frame: what a
    #: viewer draws (``Planner/path``); empty until the planner fills it in
    preview: NDArray[np.float64] = dataclasses.field(default_factory=lambda: np.zeros((0, 3)))
    #: the blend of the corner with the previous queued motion (``blend.py``); None: exact stop. ``q``
    #: is always the exact-stop motion, handed over whenever the blend is too late for its cut
    blend: Blend | None = None

    @property
    def start(self) -> Joints:
        return self.q[0]

    @property
    def end(self) -> Joints:
        return self.q[-1]

    @property
    def duration(self) -> float:
        """[s] nominal duration."""
        return self.profile.duration

    def joints_along(self, profile: PathProfile) -> Joints:
        """Joints at the samples of ``profile`` (a braking or resumed profile on this path)."""
        return self.path.joints(profile.sample(self.dt).s)

    def __reduce__(self) -> tuple:
        # Ruckig trajectories do not pickle: the nominal profile (to rest at the end) is rebuilt.
        p = self.profile
        return (_rebuild, (self.motion, self.op, self.path, p.length, p.limits, p.s_start, self.q, self.dt,
                           self.preview, self.blend, p.sd_start, p.sdd_start))


def _rebuild(motion: int, op: str, path: JointMap, length: float, limits: ProfileLimits, s_start: float,
             q: Joints, dt: float, preview: NDArray[np.float64], blend: Blend | None = None, sd_start: float = 0.0,
             sdd_start: float = 0.0) -> PlannedMotion:
    profile = (continue_profile(length, s_start, sd_start, sdd_start, limits) if sd_start or sdd_start
               else move_profile(length, limits, s_start))
    return PlannedMotion(motion, op, path, profile, q, dt, preview, blend)
