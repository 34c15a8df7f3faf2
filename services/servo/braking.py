"""A controlled stop (IEC 60204-1 category 1): decelerate within the limits, then hold.

Ruckig's velocity interface brings every axis from its commanded (q, qd, qdd) to
rest, all axes together, within the axes' acceleration and jerk limits, so that
a stop never jumps, whatever the motion was.
"""

from __future__ import annotations

import math

import numpy as np
from ruckig import ControlInterface, InputParameter, Result, Ruckig, Synchronization, Trajectory


class Braking:
    """The stop trajectory from a commanded state, sampled one servo cycle at a time."""

    def __init__(self, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray, max_acc: np.ndarray,
                 max_jerk: np.ndarray, dt: float, synchronized: bool = True) -> None:
        """``synchronized``: all axes stop together (the path is kept); otherwise each stops as
        fast as it can (the shortest stop of every axis: in front of a soft limit)."""
        n = len(q)
        inp = InputParameter(n)
        inp.control_interface = ControlInterface.Velocity
        inp.synchronization = Synchronization.Time if synchronized else Synchronization.No
        inp.current_position = list(map(float, q))
        inp.current_velocity = list(map(float, qd))
        # A measured/finite-difference acceleration may exceed the limit by noise.
        inp.current_acceleration = list(map(float, np.clip(qdd, -max_acc, max_acc)))
        inp.target_velocity = [0.0] * n
        inp.target_acceleration = [0.0] * n
        inp.max_velocity = [1e9] * n  # unused by the velocity interface, required by the API
        inp.max_acceleration = list(map(float, max_acc))
        inp.max_jerk = list(map(float, max_jerk))
        self._traj = Trajectory(n)
        result = Ruckig(n).calculate(inp, self._traj)
        if result not in (Result.Working, Result.Finished):
            # Never leave the arm without a plan: fall back to the same stop per axis.
            inp.synchronization = Synchronization.No
            Ruckig(n).calculate(inp, self._traj)
        self._dt = dt
        self._t = 0.0

    @property
    def duration(self) -> float:
        """[s] from the start of the stop to rest."""
        return self._traj.duration

    def extrema(self) -> tuple[np.ndarray, np.ndarray]:
        """(lowest, highest) position of every axis during the stop [rad or m].

        From the profiles' phases (constant jerk each): their boundary positions
        and where the velocity crosses zero inside one. (Ruckig's own
        ``position_extrema`` is not right for the velocity interface.)
        """
        profiles = [section for section in self._traj.profiles]
        n = len(profiles[0])
        low, high = np.full(n, np.inf), np.full(n, -np.inf)
        for section in profiles:
            for axis, prof in enumerate(section):
                phases = []
                if prof.brake.duration > 0.0:
                    b = prof.brake
                    phases += [(b.p[k], b.v[k], b.a[k], b.j[k], b.t[k]) for k in range(len(b.t))]
                phases += [(prof.p[k], prof.v[k], prof.a[k], prof.j[k], prof.t[k]) for k in range(len(prof.t))]
                for x in _phase_positions(phases):
                    low[axis] = min(low[axis], x)
                    high[axis] = max(high[axis], x)
        return low, high

    def next(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, bool]:
        """The next cycle's (q, qd, qdd) and whether the arm is now at rest."""
        self._t += self._dt
        t = min(self._t, self._traj.duration)
        q, qd, qdd = self._traj.at_time(t)
        done = self._t >= self._traj.duration
        if done:
            return np.array(q), np.zeros(len(q)), np.zeros(len(q)), True
        return np.array(q), np.array(qd), np.array(qdd), False


def _phase_positions(phases: list[tuple[float, float, float, float, float]]) -> list[float]:
    """Start and end positions of constant-jerk phases (p, v, a, j, duration), and where v = 0 inside."""
    out = []
    for p, v, a, j, dt in phases:
        out.append(p)
        if j != 0.0:  # v + a t + j t^2 / 2 = 0
            disc = a * a - 2.0 * j * v
            roots = () if disc < 0.0 else ((-a + math.sqrt(disc)) / j, (-a - math.sqrt(disc)) / j)
        else:
            roots = (-v / a,) if a != 0.0 else ()
        for t in roots:
            if 0.0 < t < dt:
                out.append(p + v * t + a * t * t / 2.0 + j * t ** 3 / 6.0)
        out.append(p + v * dt + a * dt * dt / 2.0 + j * dt ** 3 / 6.0)
    return out


class Glide:
    """A short, smooth move of the target alone, from ``q0`` to ``q1`` [rad or m] (half cosine).

    Lets go of a push: when the arm is blocked (an obstacle), its target is
    brought back to where the arm is, and the force it pushes with fades over
    ``duration`` [s] instead of dropping at once (which would let the arm and
    what it presses on spring back).
    """

    def __init__(self, q0: np.ndarray, q1: np.ndarray, duration: float, dt: float) -> None:
        self._q0 = np.array(q0, dtype=float)
        self._dq = np.array(q1, dtype=float) - self._q0
        self._w = math.pi / duration  # [rad/s]
        self.duration = duration
        self._dt = dt
        self._t = 0.0

    def next(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, bool]:
        """The next cycle's (q, qd, qdd) and whether the target has arrived."""
        self._t = min(self._t + self._dt, self.duration)
        w, t = self._w, self._t
        q = self._q0 + self._dq * (1.0 - math.cos(w * t)) / 2.0
        done = self._t >= self.duration
        if done:
            return q, np.zeros_like(q), np.zeros_like(q), True
        return q, self._dq * w * math.sin(w * t) / 2.0, self._dq * w * w * math.cos(w * t) / 2.0, False
