"""A controlled stop (IEC 60204-1 category 1): decelerate within the limits, then hold.

Ruckig's velocity interface brings every axis from its commanded (q, qd, qdd) to
rest, all axes together, within the axes' acceleration and jerk limits, so that
a stop never jumps, whatever the motion was.
"""

from __future__ import annotations

import numpy as np
from ruckig import ControlInterface, InputParameter, Result, Ruckig, Synchronization, Trajectory


class Braking:
    """The stop trajectory from a commanded state, sampled one servo cycle at a time."""

    def __init__(self, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray, max_acc: np.ndarray,
                 max_jerk: np.ndarray, dt: float) -> None:
        n = len(q)
        inp = InputParameter(n)
        inp.control_interface = ControlInterface.Velocity
        inp.synchronization = Synchronization.Time  # all axes stop together: the path is kept
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

    def next(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, bool]:
        """The next cycle's (q, qd, qdd) and whether the arm is now at rest."""
        self._t += self._dt
        t = min(self._t, self._traj.duration)
        q, qd, qdd = self._traj.at_time(t)
        done = self._t >= self._traj.duration
        if done:
            return np.array(q), np.zeros(len(q)), np.zeros(len(q)), True
        return np.array(q), np.array(qd), np.array(qdd), False
