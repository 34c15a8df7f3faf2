"""Queries to the alarm monitor, for the services whose Common interface forwards to it.

The alarm monitor owns the list of active alarms (``schema/alarms.py``); the
servo and the command service pass ``getActiveAlarm`` and ``clearAlarms`` on
to it, and fall back to what they know themselves when it does not answer
within ``MONITOR_TIMEOUT`` (a missing monitor must not block the arm's
interfaces for long).
"""

from __future__ import annotations

import logging

import zenoh

from jara_arm.schema import codec
from jara_arm.schema.alarms import ALARM_LIST, MONITOR_OPERATIONS, AlarmList, format_code
from jara_arm.schema.codec import Encoding, Reply
from jara_arm.schema.codes import ReturnCode
from jara_arm.schema.errors import WireError
from jara_arm.schema.keys import ArmKeys
from jara_arm.schema.types import Alarm

from .rpc import ok, refuse

log = logging.getLogger(__name__)

#: Time the alarm monitor has to answer [s]; it answers from memory in about a millisecond.
MONITOR_TIMEOUT = 0.3


def clear_reply(cleared: list[Alarm], kept: list[Alarm]) -> Reply:
    """The ``clearAlarms`` reply: OK if nothing stayed, else STATUS_ERR naming what stayed and why."""
    if kept:
        return refuse(ReturnCode.STATUS_ERR, "cause still present, not cleared: " + "; ".join(
            f"{format_code(a.code)} {a.description}" for a in kept)
            + (f" (cleared: {', '.join(format_code(a.code) for a in cleared)})" if cleared else ""))
    return ok("OK" if cleared else "OK: no active alarm")


def is_newer(candidate: AlarmList, current: AlarmList | None) -> bool:
    """Whether ``candidate`` replaces ``current``: a later monitor start, or a later list of it."""
    if current is None:
        return True
    return ((candidate.started.to_seconds(), candidate.tm.to_seconds())
            >= (current.started.to_seconds(), current.tm.to_seconds()))


class MonitorLink:
    """``Monitor/Common/<op>`` and ``Monitor/alarms`` of one arm; usable from any thread."""

    def __init__(self, session: zenoh.Session, keys: ArmKeys, timeout: float = MONITOR_TIMEOUT) -> None:
        self._session = session
        self._keys = keys
        self.timeout = timeout

    def _get(self, key: str, payload: bytes) -> tuple[bytes, Encoding] | None:
        try:
            for reply in self._session.get(key, payload=payload, timeout=self.timeout):
                if reply.ok is not None:
                    return reply.ok.payload.to_bytes(), Encoding.of(reply.ok.encoding)
        except zenoh.ZError as exc:
            log.warning("query to the alarm monitor on %s failed: %s", key, exc)
        return None

    def call(self, name: str) -> Reply | None:
        """The monitor's reply to ``name`` (getActiveAlarm or clearAlarms); None if it did not answer."""
        op = MONITOR_OPERATIONS[name]
        key = self._keys.monitor_common(name)
        got = self._get(key, codec.encode_request(op))
        if got is None:
            return None
        try:
            return codec.decode_reply(op, *got)
        except WireError as exc:
            log.error("the alarm monitor sent a malformed reply on %s: %s", key, exc)
            return None

    def alarm_list(self) -> AlarmList | None:
        """The monitor's current list; None if it did not answer."""
        got = self._get(self._keys.monitor_alarms, b"")
        if got is None:
            return None
        try:
            return codec.decode_message(ALARM_LIST, *got)
        except WireError as exc:
            log.error("the alarm monitor sent a malformed alarm list: %s", exc)
            return None
