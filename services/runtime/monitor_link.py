"""Queries to the alarm monitor, for the services whose Common interface forwards to it.

The alarm monitor owns the list of active alarms (``schema/alarms.py``); the
servo and the command service pass ``getActiveAlarm`` and ``clearAlarms`` on
to it, and fall back to what they know themselves when it does not answer
within ``MONITOR_TIMEOUT`` (a missing monitor must not block the arm's
interfaces for long).

The servo keeps the newest list it adopted (it must: those alarms keep the
arm stopped while there is no monitor) and answers it on ``Monitor/copy``
(:func:`alarm_copy_answer`): a monitor that restarts takes the active alarms over
from there (:func:`servo_copy`) instead of starting with an empty list while
the arm is still stopped by them.
"""

from __future__ import annotations

import logging
from collections.abc import Callable

import zenoh

from jara_arm.schema import codec
from jara_arm.schema.alarms import ALARM_LIST, MONITOR_OPERATIONS, NO_LIST, AlarmList, format_code
from jara_arm.schema.codec import Encoding, Reply
from jara_arm.schema.codes import ReturnCode
from jara_arm.schema.errors import Refusal, WireError
from jara_arm.schema.keys import ArmKeys
from jara_arm.schema.types import Alarm

from .ask import Answer, Asker, Silence
from .rpc import Answer as QueryAnswer
from .rpc import ok
from .timing import MONITOR_TIMEOUT

log = logging.getLogger(__name__)



def clear_reply(cleared: list[Alarm], kept: list[Alarm], note: str = "") -> Reply:
    """The ``clearAlarms`` reply: OK if nothing stayed, else a STATUS_ERR :class:`Refusal` naming what stayed
    and why; ``note`` in brackets after either comment."""
    after = f" ({note})" if note else ""
    if kept:
        raise Refusal(ReturnCode.STATUS_ERR, "cause still present, not cleared: " + "; ".join(
            f"{format_code(a.code)} {a.description}" for a in kept)
            + (f" (cleared: {', '.join(format_code(a.code) for a in cleared)})" if cleared else "") + after)
    return ok(("OK" if cleared else "OK: no active alarm") + after)


class MonitorLink:
    """``Monitor/Common/<op>`` and ``Monitor/alarms`` of one arm; usable from any thread."""

    def __init__(self, session: zenoh.Session, keys: ArmKeys, timeout: float = MONITOR_TIMEOUT) -> None:
        self._keys = keys
        self.timeout = timeout
        self._askers = {key: Asker(session, key, timeout)
                        for key in (*(keys.monitor_common(op) for op in MONITOR_OPERATIONS), keys.monitor_alarms)}

    def _get(self, key: str, payload: bytes) -> Answer | None:
        got = self._askers[key].ask(payload)
        if isinstance(got, Silence):
            log.debug("the alarm monitor: %s", got.why)
            return None
        return got

    def close(self) -> None:
        for asker in self._askers.values():
            asker.close()

    def call(self, name: str) -> Reply | None:
        """The monitor's reply to ``name`` (getActiveAlarm or clearAlarms); None if it did not answer."""
        op = MONITOR_OPERATIONS[name]
        key = self._keys.monitor_common(name)
        got = self._get(key, codec.encode_request(op))
        if got is None:
            return None
        try:
            return codec.decode_reply(op, got.payload, got.encoding)
        except WireError as exc:
            log.error("the alarm monitor sent a malformed reply on %s: %s", key, exc)
            return None

    def alarm_list(self) -> AlarmList | None:
        """The monitor's current list; None if it did not answer."""
        got = self._get(self._keys.monitor_alarms, b"")
        if got is None:
            return None
        try:
            alarms: AlarmList = codec.decode_message(ALARM_LIST, got.payload, got.encoding)
            return alarms
        except WireError as exc:
            log.error("the alarm monitor sent a malformed alarm list: %s", exc)
            return None


def alarm_copy_answer(current: Callable[[], AlarmList | None]) -> QueryAnswer:
    """``Monitor/copy``'s answer for the servo's ``QueryServer``: ``current()``, the newest list the servo
    adopted (:data:`NO_LIST` before the first), in the request's encoding. ``current`` runs on the thread that
    holds the list (the servo loop's ``call``), which may be held up; the query worker waits for it, not the loop
    for the query."""

    def answer(key: str, _payload: bytes, encoding: Encoding) -> tuple[str, bytes]:
        return key, codec.encode_message(ALARM_LIST, current() or NO_LIST, encoding)

    return answer


def servo_copy(session: zenoh.Session, keys: ArmKeys, timeout: float = MONITOR_TIMEOUT) -> AlarmList | None:
    """The list the servo holds (see :func:`alarm_copy_answer`); None if it does not answer."""
    asker = Asker(session, keys.alarm_copy, timeout)
    try:
        got = asker.ask(b"")
    finally:
        asker.close()
    if isinstance(got, Silence):
        log.info("no alarm list to take over: %s", got.why)
        return None
    try:
        held: AlarmList = codec.decode_message(ALARM_LIST, got.payload, got.encoding)
        return held
    except WireError as exc:
        log.error("ignored a malformed alarm list copy from the servo: %s", exc)
        return None
