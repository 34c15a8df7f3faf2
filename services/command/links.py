"""Queries from the command service to the servo and the planner, with timeouts.

Every call returns a :class:`Reply`; a service that does not answer in time,
or answers with something that cannot be decoded, gives an ``NG`` reply whose
comment names the service and the key, so that the client learns which part
of the system is missing.
"""

from __future__ import annotations

import dataclasses
import functools
import logging
from collections.abc import Callable, Mapping
from typing import Any, TypeVar

import zenoh

from jara_arm.schema import codec
from jara_arm.schema.alarms import NO_LIST, AlarmList
from jara_arm.schema.codec import Encoding, Reply
from jara_arm.schema.codes import ReturnCode
from jara_arm.schema.errors import WireError
from jara_arm.schema.keys import ArmKeys, Service
from jara_arm.schema.messages import ServoStatus
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
from jara_arm.schema.power import POWER_REPLY, POWER_REQUEST, PowerAction, PowerRequest
from jara_arm.services.runtime.ask import Answer, Asker
from jara_arm.services.runtime.timing import CONTROL_TIMEOUT, PLAN_TIMEOUT, SERVO_TIMEOUT

log = logging.getLogger(__name__)
R = TypeVar("R")


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

    def ask(self, key: str, payload: bytes, decode: Callable[[bytes, Encoding], R]) -> R | Reply:
        """The reply as ``decode`` reads it, or an NG reply saying that nobody answered or what was malformed."""
        got = self.query(key, payload)
        if isinstance(got, Reply):
            return got
        try:
            return decode(got.payload, got.encoding)
        except WireError as exc:
            return self.malformed(key, exc)

    def close(self) -> None:
        for asker in self._askers.values():
            asker.close()


@dataclasses.dataclass(frozen=True)
class PowerAnswer:
    """The servo's verdict on a ``Servo/power`` action, passed on to the client, and its status after it."""

    reply: Reply
    status: ServoStatus | None = None  # None when the servo did not answer


class ServoLink(_Peer):
    """``Servo/Common/<op>`` of the low level, through the schema, and ``Servo/power`` (schema.power)."""

    def __init__(self, session: zenoh.Session, keys: ArmKeys, timeout: float = SERVO_TIMEOUT) -> None:
        super().__init__(session, Service.SERVO, {**{keys.servo_common(name): timeout for name in COMMON},
                                                  keys.servo_power: timeout})
        self._keys = keys
        self.timeout = timeout

    def call(self, name: str, args: Mapping[str, Any] | None = None) -> Reply:
        """The servo's reply to Common operation ``name`` (outs decoded), or NG if it is silent."""
        op = COMMON[name]
        return self.ask(self._keys.servo_common(name), codec.encode_request(op, args),
                        functools.partial(codec.decode_reply, op))

    def power(self, action: PowerAction, alarms: AlarmList | None) -> PowerAnswer:
        """The servo's verdict on ``action`` after adopting ``alarms`` (the monitor's newest list the caller
        holds, None: none), and its status after it; NG naming the servo if it is silent."""
        request = codec.encode_message(POWER_REQUEST, PowerRequest(action.value, alarms or NO_LIST))
        power = self.ask(self._keys.servo_power, request, functools.partial(codec.decode_message, POWER_REPLY))
        if isinstance(power, Reply):
            return PowerAnswer(power)
        return PowerAnswer(Reply(power.id, power.comment), power.status)


@dataclasses.dataclass(frozen=True)
class PlannerAnswer:
    """A planner call's verdict, passed on to the client, and the queue as the call left it."""

    reply: Reply
    motion: int = 0  # the id the planner gave a queued motion
    progress: PlannerProgress | None = None  # None when the planner did not answer


class PlannerLink(_Peer):
    """``Planner/plan``, ``Planner/control`` and ``Planner/jog`` (schema.planner)."""

    def __init__(self, session: zenoh.Session, keys: ArmKeys, plan_timeout: float = PLAN_TIMEOUT,
                 control_timeout: float = CONTROL_TIMEOUT) -> None:
        super().__init__(session, Service.PLANNER, {keys.planner_plan: plan_timeout,
                                                     keys.planner_control: control_timeout,
                                                     keys.planner_jog: control_timeout})
        self._keys = keys
        self.plan_timeout = plan_timeout
        self.control_timeout = control_timeout

    def plan(self, request: MotionRequest) -> PlannerAnswer:
        """The planner's verdict on one motion."""
        plan = self.ask(self._keys.planner_plan, codec.encode_message(MOTION_REQUEST, request),
                        functools.partial(codec.decode_message, PLAN_REPLY))
        if isinstance(plan, Reply):
            return PlannerAnswer(plan)
        return PlannerAnswer(Reply(plan.id, plan.comment), plan.motion, plan.progress)

    def jog(self, request: MotionRequest) -> PlannerAnswer:
        """The planner's verdict on a jog call (``Ext/jogJoint``, ``jogCartesian``, ``jogStop``)."""
        jog = self.ask(self._keys.planner_jog, codec.encode_message(MOTION_REQUEST, request),
                       functools.partial(codec.decode_message, CONTROL_REPLY))
        if isinstance(jog, Reply):
            return PlannerAnswer(jog)
        return PlannerAnswer(Reply(jog.id, jog.comment), progress=jog.progress)

    def control(self, action: ControlAction, ratio: float = 100.0) -> PlannerAnswer:
        """The planner's verdict on ``action``; ``ratio`` [%] is the speed override (``OVERRIDE`` only)."""
        request = codec.encode_message(CONTROL_REQUEST, ControlRequest(action.value, ratio))
        control = self.ask(self._keys.planner_control, request, functools.partial(codec.decode_message, CONTROL_REPLY))
        if isinstance(control, Reply):
            return PlannerAnswer(control)
        return PlannerAnswer(Reply(control.id, control.comment), progress=control.progress)
