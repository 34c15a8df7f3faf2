"""Queries from the command service to the servo and the planner, with timeouts.

Every call returns a :class:`Reply`; a service that does not answer in time,
or answers with something that cannot be decoded, gives an ``NG`` reply whose
comment names the service and the key, so that the client learns which part
of the system is missing.
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Mapping
from typing import Any

import zenoh

from jara_arm.schema import codec
from jara_arm.schema.codec import Reply
from jara_arm.schema.codes import ReturnCode
from jara_arm.schema.errors import WireError
from jara_arm.schema.keys import ArmKeys, Service
from jara_arm.schema.operations import COMMON
from jara_arm.schema.planner import (
    CONTROL_REPLY,
    CONTROL_REQUEST,
    MOTION_REQUEST,
    PLAN_REPLY,
    ControlAction,
    ControlRequest,
    MotionRequest,
    PlannerProgress,
)
from jara_arm.services.runtime.ask import Answer, Asker
from jara_arm.services.runtime.timing import CONTROL_TIMEOUT, PLAN_TIMEOUT, SERVO_TIMEOUT

log = logging.getLogger(__name__)


class _Peer:
    """Queries to one service that may be absent: an :class:`Asker` per key."""

    def __init__(self, session: zenoh.Session, service: Service, timeouts: Mapping[str, float]) -> None:
        self.service = service
        self._askers = {key: Asker(session, key, timeout) for key, timeout in timeouts.items()}

    def query(self, key: str, payload: bytes) -> Answer | Reply:
        """The reply, or an NG reply saying that nobody answered (naming the service and the key)."""
        got = self._askers[key].ask(payload)
        if isinstance(got, Answer):
            return got
        return Reply(ReturnCode.NG, f"the {self.service.value} service: {got.why}")

    def malformed(self, key: str, exc: WireError) -> Reply:
        log.error("%s sent a malformed reply on %s: %s", self.service.value, key, exc)
        return Reply(ReturnCode.NG, f"the {self.service.value} service sent a malformed reply on "
                     f"{key}: {exc}")

    def close(self) -> None:
        for asker in self._askers.values():
            asker.close()


class ServoLink(_Peer):
    """``Servo/Common/<op>`` of the low level, through the schema."""

    def __init__(self, session: zenoh.Session, keys: ArmKeys, timeout: float = SERVO_TIMEOUT) -> None:
        super().__init__(session, Service.SERVO, {keys.servo_common(name): timeout for name in COMMON})
        self._keys = keys
        self.timeout = timeout

    def call(self, name: str, args: Mapping[str, Any] | None = None) -> Reply:
        """The servo's reply to Common operation ``name`` (outs decoded), or NG if it is silent."""
        op = COMMON[name]
        key = self._keys.servo_common(name)
        got = self.query(key, codec.encode_request(op, args))
        if isinstance(got, Reply):
            return got
        try:
            return codec.decode_reply(op, got.payload, got.encoding)
        except WireError as exc:
            return self.malformed(key, exc)


@dataclasses.dataclass(frozen=True)
class PlannerAnswer:
    """A planner call's verdict, passed on to the client, and the queue as the call left it."""

    reply: Reply
    motion: int = 0  # the id the planner gave a queued motion
    progress: PlannerProgress | None = None  # None when the planner did not answer


class PlannerLink(_Peer):
    """``Planner/plan`` and ``Planner/control`` (schema.planner)."""

    def __init__(self, session: zenoh.Session, keys: ArmKeys, plan_timeout: float = PLAN_TIMEOUT,
                 control_timeout: float = CONTROL_TIMEOUT) -> None:
        super().__init__(session, Service.PLANNER, {keys.planner_plan: plan_timeout,
                                                     keys.planner_control: control_timeout})
        self._keys = keys
        self.plan_timeout = plan_timeout
        self.control_timeout = control_timeout

    def plan(self, request: MotionRequest) -> PlannerAnswer:
        """The planner's verdict on one motion."""
        key = self._keys.planner_plan
        got = self.query(key, codec.encode_message(MOTION_REQUEST, request))
        if isinstance(got, Reply):
            return PlannerAnswer(got)
        try:
            plan = codec.decode_message(PLAN_REPLY, got.payload, got.encoding)
        except WireError as exc:
            return PlannerAnswer(self.malformed(key, exc))
        return PlannerAnswer(Reply(plan.id, plan.comment), plan.motion, plan.progress)

    def control(self, action: ControlAction, ratio: float = 100.0) -> PlannerAnswer:
        """The planner's verdict on ``action``; ``ratio`` [%] is the speed override (``OVERRIDE`` only)."""
        key = self._keys.planner_control
        got = self.query(key, codec.encode_message(CONTROL_REQUEST, ControlRequest(action.value, ratio)))
        if isinstance(got, Reply):
            return PlannerAnswer(got)
        try:
            control = codec.decode_message(CONTROL_REPLY, got.payload, got.encoding)
        except WireError as exc:
            return PlannerAnswer(self.malformed(key, exc))
        return PlannerAnswer(Reply(control.id, control.comment), progress=control.progress)
