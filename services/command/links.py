"""Queries from the command service to the servo and the planner, with timeouts.

Every call returns a :class:`Reply`; a service that does not answer in time,
or answers with something that cannot be decoded, gives an ``NG`` reply whose
comment names the service and the key, so that the client learns which part
of the system is missing.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Mapping
from typing import Any

import zenoh

from jara_arm.schema import codec
from jara_arm.schema import wire_types as w
from jara_arm.schema.codec import Encoding, Reply
from jara_arm.schema.codes import ReturnCode
from jara_arm.schema.errors import WireError
from jara_arm.schema.keys import ArmKeys, Service
from jara_arm.schema.operations import COMMON
from jara_arm.schema.planner import (CONTROL_REQUEST, MOTION_REQUEST, ControlAction, ControlRequest,
                                     MotionRequest)
from jara_arm.services.runtime.timing import CONTROL_TIMEOUT, PLAN_TIMEOUT, SERVO_TIMEOUT

log = logging.getLogger(__name__)



class _Peer:
    """One query, one reply, from a service that may be absent."""

    def __init__(self, session: zenoh.Session, service: Service) -> None:
        self._session = session
        self.service = service

    def query(self, key: str, payload: bytes, timeout: float) -> tuple[bytes, Encoding] | Reply:
        """The reply payload and its encoding, or an NG reply saying that nobody answered."""
        start = time.monotonic()
        try:
            for reply in self._session.get(key, payload=payload, timeout=timeout,
                                              attachment=codec.deadline_attachment(timeout)):
                if reply.ok is not None:
                    return reply.ok.payload.to_bytes(), Encoding.of(reply.ok.encoding)
                log.warning("%s answered %s with an error: %s", self.service.value, key, reply.err)
        except zenoh.ZError as exc:
            return Reply(ReturnCode.NG, f"the query to the {self.service.value} service on {key} "
                         f"failed: {exc}")
        if time.monotonic() - start < 0.9 * timeout:  # Zenoh knew at once that nobody serves the key
            return Reply(ReturnCode.NG, f"the {self.service.value} service does not answer {key}: "
                         "is it running?")
        return Reply(ReturnCode.NG, f"the {self.service.value} service did not answer {key} "
                     f"within {timeout:g} s")

    def malformed(self, key: str, exc: WireError) -> Reply:
        log.error("%s sent a malformed reply on %s: %s", self.service.value, key, exc)
        return Reply(ReturnCode.NG, f"the {self.service.value} service sent a malformed reply on "
                     f"{key}: {exc}")


class ServoLink(_Peer):
    """``Servo/Common/<op>`` of the low level, through the schema."""

    def __init__(self, session: zenoh.Session, keys: ArmKeys, timeout: float = SERVO_TIMEOUT) -> None:
        super().__init__(session, Service.SERVO)
        self._keys = keys
        self.timeout = timeout

    def call(self, name: str, args: Mapping[str, Any] | None = None) -> Reply:
        """The servo's reply to Common operation ``name`` (outs decoded), or NG if it is silent."""
        op = COMMON[name]
        key = self._keys.servo_common(name)
        got = self.query(key, codec.encode_request(op, args), self.timeout)
        if isinstance(got, Reply):
            return got
        try:
            return codec.decode_reply(op, *got)
        except WireError as exc:
            return self.malformed(key, exc)


class PlannerLink(_Peer):
    """``Planner/plan`` and ``Planner/control`` (schema.planner)."""

    def __init__(self, session: zenoh.Session, keys: ArmKeys, plan_timeout: float = PLAN_TIMEOUT,
                 control_timeout: float = CONTROL_TIMEOUT) -> None:
        super().__init__(session, Service.PLANNER)
        self._keys = keys
        self.plan_timeout = plan_timeout
        self.control_timeout = control_timeout

    def plan(self, request: MotionRequest) -> Reply:
        """The planner's verdict on one motion (its id and comment, passed on to the client)."""
        key = self._keys.planner_plan
        got = self.query(key, codec.encode_message(MOTION_REQUEST, request), self.plan_timeout)
        return got if isinstance(got, Reply) else self._return_id(key, *got)

    def control(self, action: ControlAction) -> Reply:
        key = self._keys.planner_control
        got = self.query(key, codec.encode_message(CONTROL_REQUEST, ControlRequest(action.value)),
                         self.control_timeout)
        return got if isinstance(got, Reply) else self._return_id(key, *got)

    def _return_id(self, key: str, payload: bytes, encoding: Encoding) -> Reply:
        """``{id, comment}`` of a planner reply; a ``PlanReply`` refusal may carry nothing else."""
        try:
            value = codec.loads(payload, encoding)
            if not isinstance(value, dict):
                raise WireError("payload", "a reply must be a map")
            return Reply(w.LONG.decode(value.get("id"), "id"),
                         w.STRING.decode(value.get("comment"), "comment"))
        except WireError as exc:
            return self.malformed(key, exc)
