"""What the Common and Middle handlers share.

Each interface has its own RPC worker thread, so the queries of one interface
are handled in the order they arrive (a motion and a following ``stop`` on
Middle). Operations that change the arm's state -- motions, pause, resume,
stop, servoON, servoOFF, clearAlarms, setSoftLimitJoint, setHome -- also hold
``serial`` for their whole duration, so an operation of one interface never
interleaves with one of the other: a ``servoOFF`` either comes after a motion
was queued (and discards it) or before it (and the motion is refused), never
between the motion's checks and its queuing. Getters do not take it, so they
answer while a motion is being planned.
"""

from __future__ import annotations

import dataclasses
import threading

from jara_arm.robots import RobotModel
from jara_arm.schema.codec import Reply
from jara_arm.schema.keys import ArmKeys
from jara_arm.services.runtime.monitor_link import MonitorLink

from .links import PlannerLink, ServoLink
from .state import StateTracker


@dataclasses.dataclass(frozen=True)
class Core:
    """The arm, its peers, its state and the lock that serialises state changes."""

    robot: RobotModel
    keys: ArmKeys
    servo: ServoLink
    planner: PlannerLink
    monitor: MonitorLink
    state: StateTracker
    serial: threading.RLock = dataclasses.field(default_factory=threading.RLock)


def with_note(reply: Reply, note: str) -> Reply:
    """``reply`` with ``note`` added to its comment."""
    return Reply(reply.id, f"{reply.comment}; {note}", reply.outs)
