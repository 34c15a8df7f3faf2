"""The newest measured joints, for ``getFeedbackPosJoint`` and ``getFeedbackPosCartesian``.

They come from ``Servo/status`` (every 10 servo cycles), which the state
watcher receives anyway: ``Servo/posFeedback`` (every cycle) would cost this
service and the router a thousand messages a second for an answer at most
10 ms fresher. Each answer first takes in the statuses that arrived and were not
read yet (``StateTracker.measured_joints``): a client told its motion ended reads
the pose it ended at. If the servo has been silent for ``STALE_AFTER``, the servo's
own ``getFeedbackPosJoint`` is asked instead, so that a dead servo gives an NG
reply that names it rather than an old pose.
"""

from __future__ import annotations

from jara_arm.schema.codec import Reply
from jara_arm.schema.operations import OP
from jara_arm.services.runtime.rpc import ok

from .links import ServoLink
from .state import StateTracker

#: A status older than this is not used [s] (the servo publishes one every 10 ms).
STALE_AFTER = 0.2


class JointFeedback:
    """The measured joints of the newest ``Servo/status``."""

    def __init__(self, tracker: StateTracker, servo: ServoLink) -> None:
        self._tracker = tracker
        self._servo = servo

    def joints(self) -> Reply:
        """``ok(pos=...)`` with the newest joints [rad or m], or the servo's refusal/silence."""
        newest = self._tracker.measured_joints()
        if newest is not None and newest[1] <= STALE_AFTER:
            return ok(pos=newest[0])
        return self._servo.call(OP.getFeedbackPosJoint)
