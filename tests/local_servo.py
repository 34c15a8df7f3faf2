"""The servo's interpolator in-process, behind the planner's :class:`Handover`: no Zenoh, no clock.

``LocalServo`` answers ``Servo/trajectory`` and ``Servo/motionControl`` as the servo does (the same
``Interpolator``, the same ``prepare``) and runs its cycles on demand (:meth:`LocalServo.run`), so that a
test sees every command a motion gives, cycle by cycle.
"""

from __future__ import annotations

import time

import numpy as np

from jara_arm.robots import RobotModel
from jara_arm.schema.codes import ReturnCode
from jara_arm.schema.messages import ServoStatus
from jara_arm.schema.motion import MotionAction, MotionControl, MotionProgress, MotionReply, Trajectory
from jara_arm.schema.types import Time
from jara_arm.services.planner.handover import Handover
from jara_arm.services.servo.control import ControlLaw
from jara_arm.services.servo.interpolator import Interpolator, prepare


class LocalServo:
    """One arm's interpolator, holding ``q0`` [rad or m] at first."""

    def __init__(self, model: RobotModel, q0: np.ndarray) -> None:
        self.model = model
        self.dt = model.cmd_cycle
        self.interp = Interpolator(model.dof, self.dt)
        self.max_accel = ControlLaw(model, q0).max_accel
        self.q = np.array(q0, dtype=float)
        self.seq = 0
        self.started = Time.now()

    def handover(self) -> Handover:
        """The planner's side, wired to this servo (its relay thread is not started)."""
        return Handover(self.model.dof, self.dt, self.ask_trajectory, self.ask_control, lambda _p: None,
                        self.status, self.progress)

    def status(self) -> ServoStatus:
        n = self.model.dof
        return ServoStatus(Time.from_seconds(time.time()), True, False, False, 0, 0, 0, 0, (0.0,) * n, (0.0,) * n,
                           tuple(self.q.tolist()))

    def progress(self) -> MotionProgress:
        self.seq += 1
        return self.interp.progress(self.interp.state(self.q), self.started, self.seq)

    def ask_trajectory(self, traj: Trajectory) -> MotionReply:
        b = prepare(traj.motion, traj.rows(), traj.final, self.dt, self.max_accel)
        refusal, why = self.interp.submit(b, traj.epoch, traj.after, traj.splice, self.q, True)
        if refusal is None:
            return MotionReply(0, f"OK: {why}", "", self.progress())
        return MotionReply(int(ReturnCode.STATUS_ERR), why, refusal.value, self.progress())

    def ask_control(self, control: MotionControl) -> MotionReply:
        comment = self.interp.control(MotionAction(control.action), control.ratio / 100.0)
        return MotionReply(0, comment, "", self.progress())

    def run(self, count: int | None = None) -> list[np.ndarray]:
        """Up to ``count`` cycles (None: until nothing moves), each one's command [rad or m]."""
        out: list[np.ndarray] = []
        it = self.interp
        while (count is None or len(out) < count) and it.active and not it.holding:
            q = it.next()
            assert q is not None
            if count is None and out and it.queue and not it.queue[-1].final and it.scale == 0.0:
                break  # a head held at its end, waiting for its rest: nothing moves any more
            self.q = q
            out.append(q.copy())
            if len(out) > 200_000:
                raise AssertionError("the interpolator never ends")
        return out
