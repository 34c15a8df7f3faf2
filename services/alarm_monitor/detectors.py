"""What the alarm monitor detects itself, as plain state machines fed with samples.

Thresholds and margins (the README's "Alarms" table repeats them):

* overload (0x02, WARNING): a joint's measured effort above ``OVERLOAD_MARGIN``
  x its rated effort in ``OVERLOAD_SAMPLES`` consecutive ``Servo/status``
  samples (the servo publishes one every 10 cycles: 30 ms at 1 kHz). The
  simulated drives deliver up to twice their rating (``servo/world.py``), as
  real drives do for short times, so pushing against an obstacle shows. The
  gripper axis is left out: gripping is pushing. The cause is present while
  the newest sample is above.
* overspeed (0x03, FAULT): a joint's measured speed above ``OVERSPEED_MARGIN``
  x its rated speed in ``OVERSPEED_SAMPLES`` consecutive samples. The servo
  refuses commands that need more than 1.1 x (its own check, same code), so
  this one catches what commands do not explain.
* joint soft limit (0x04, WARNING): a measured joint (``Servo/status``, 100 Hz)
  goes from inside its soft
  limit to beyond it by more than ``JOINT_LIMIT_TOLERANCE`` (the servo clamps
  its targets to the limits; a few mrad of physical overshoot are not a
  crossing). Cartesian soft limit (0x05, WARNING): the control point (command
  settings: base offset, control point offset, box) goes from inside the box
  to beyond it by more than ``CARTESIAN_LIMIT_TOLERANCE``. Both react to a
  *crossing* (motion), not to limits set where the arm already is; the cause
  is present while the arm is beyond the tolerance.
* lost (0x400-0x402, FAULT): the liveliness token of the servo, planner or
  command service is deleted after it was seen. The cause is present until the
  token is back (the launcher restarts the process).
* hung (0x410-0x412, FAULT): the token is up, but the service's heartbeat
  (``heartbeat/<service>``, every ``Health.heartbeat_period`` from a real-time
  thread) has been silent for longer than ``Health.hung_after``
  (``services/runtime/timing.py``: 1.5 s on one host; a process stopped,
  deadlocked or starved so long it no longer serves), or the heartbeat names a
  working loop of the service that has not turned for as long (``stuck``). A
  shorter silence that ends is a stall: logged with its length, not an alarm
  (``ServiceWatch.heard``). The cause is present while the heartbeat is silent
  or names a stuck loop.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from jara_arm.schema.codes import AlarmCode
from jara_arm.schema.keys import Service
from jara_arm.schema.types import LimitValue

#: Overload: effort above this multiple of the rated effort [-] ...
OVERLOAD_MARGIN = 1.0
#: ... in this many consecutive Servo/status samples (10 ms apart at 1 kHz).
OVERLOAD_SAMPLES = 3
#: Overspeed: measured speed above this multiple of the rated speed [-] ...
OVERSPEED_MARGIN = 1.2
#: ... in this many consecutive samples.
OVERSPEED_SAMPLES = 2
#: A measured joint beyond its soft limit by more than this has crossed it [rad or m].
JOINT_LIMIT_TOLERANCE = 5e-3
#: The control point beyond the Cartesian soft limit by more than this has crossed it [m].
CARTESIAN_LIMIT_TOLERANCE = 1e-3
LOST_CODE: dict[Service, AlarmCode] = {
    Service.SERVO: AlarmCode.SERVO_LOST,
    Service.PLANNER: AlarmCode.PLANNER_LOST,
    Service.COMMAND: AlarmCode.COMMAND_LOST,
}
HUNG_CODE: dict[Service, AlarmCode] = {
    Service.SERVO: AlarmCode.SERVO_HUNG,
    Service.PLANNER: AlarmCode.PLANNER_HUNG,
    Service.COMMAND: AlarmCode.COMMAND_HUNG,
}


class AboveRating:
    """Per axis: |value| above ``margin`` x ``rating`` in ``samples`` consecutive samples."""

    def __init__(self, rating: Sequence[float], margin: float, samples: int) -> None:
        self.threshold = np.abs(np.asarray(rating, dtype=float)) * margin
        self.samples = samples
        self._count = np.zeros(len(self.threshold), dtype=int)
        self.present = False  # some axis is above in the newest sample

    def update(self, values: Sequence[float]) -> int | None:
        """Feed one sample (extra trailing values are ignored); the axis that just tripped, or None."""
        v = np.abs(np.asarray(values, dtype=float)[: len(self.threshold)])
        if v.shape != self.threshold.shape:
            return None  # a sample of another robot: not ours to judge
        above = v > self.threshold
        self.present = bool(above.any())
        tripped = above & (self._count == self.samples - 1)
        self._count = np.where(above, self._count + 1, 0)
        return int(np.argmax(tripped)) if tripped.any() else None


class Crossing:
    """Inside -> beyond (limit + ``tolerance``) transitions of values against per-axis limits."""

    def __init__(self, tolerance: float) -> None:
        self.tolerance = tolerance
        self._limits: tuple[LimitValue, ...] = ()
        self._lower = self._upper = np.zeros(0)
        self._inside: bool | None = None  # None: not judged since the limits changed
        self.present = False  # beyond the tolerance in the newest sample

    def set_limits(self, limits: Sequence[LimitValue]) -> None:
        """New limits: the next sample only says where the arm is; it cannot be a crossing."""
        limits = tuple(limits)
        if limits != self._limits:
            self._limits = limits
            self._lower = np.array([lim.lower for lim in limits], dtype=float)
            self._upper = np.array([lim.upper for lim in limits], dtype=float)
            self._inside = None

    def reset(self) -> None:
        """The values now mean something else (new frames): the next sample cannot be a crossing."""
        self._inside = None

    @property
    def armed(self) -> bool:
        return self._lower.size > 0

    def update(self, values: Sequence[float]) -> int | None:
        """Feed one sample; the axis that just crossed, or None."""
        if not self.armed:
            return None
        v = np.asarray(values, dtype=float)[: self._lower.size]
        beyond = (v > self._upper + self.tolerance) | (v < self._lower - self.tolerance)
        self.present = bool(beyond.any())
        was_inside, self._inside = self._inside, not self.present
        if was_inside and self.present:
            return int(np.argmax(beyond))
        return None

    def limit(self, axis: int) -> LimitValue:
        return LimitValue(float(self._upper[axis]), float(self._lower[axis]))
