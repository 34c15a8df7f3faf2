"""The newest joint feedback, for ``getFeedbackPosCartesian``.

``Servo/posFeedback`` arrives every servo cycle; a RingChannel of one keeps
only the newest sample in Zenoh, and it is decoded only when asked for. If the
servo has been silent for ``STALE_AFTER``, the servo's own
``getFeedbackPosJoint`` is asked instead, so that a dead servo gives an NG
reply that names it rather than an old pose.
"""

from __future__ import annotations

import time

import zenoh

from jara_arm.schema import codec
from jara_arm.schema import wire_types as w
from jara_arm.schema.codec import Reply
from jara_arm.schema.errors import WireError
from jara_arm.schema.keys import ArmKeys
from jara_arm.schema.operations import OP
from jara_arm.schema.types import JointPos
from jara_arm.services.runtime.rpc import ok

from .links import ServoLink

#: A feedback sample older than this is not used [s] (the servo publishes every cycle, 1 ms).
STALE_AFTER = 0.2


class JointFeedback:
    """Newest ``Servo/posFeedback``; use from one thread."""

    def __init__(self, session: zenoh.Session, keys: ArmKeys, servo: ServoLink) -> None:
        self._sub = session.declare_subscriber(keys.pos_feedback, zenoh.handlers.RingChannel(1))
        self._servo = servo
        self._pos: JointPos | None = None
        self._at = -float("inf")  # [s] monotonic receipt time of _pos

    def joints(self) -> Reply:
        """``ok(pos=...)`` with the newest joints [rad or m], or the servo's refusal/silence."""
        sample = self._sub.try_recv()
        if sample is not None:
            try:
                self._pos = codec.decode_message(w.TIMED_JOINT_POS, sample.payload.to_bytes()).pos
                self._at = time.monotonic()
            except WireError:
                pass  # a malformed sample: the servo is asked below if nothing fresh is left
        if self._pos is not None and time.monotonic() - self._at <= STALE_AFTER:
            return ok(pos=self._pos)
        return self._servo.call(OP.getFeedbackPosJoint)

    def close(self) -> None:
        try:
            self._sub.undeclare()
        except Exception:
            pass
