"""Each call a query server answered, published on its trace key while something subscribes.

Zenoh shows a query to its queryable alone, so a recorder cannot see the calls
of the Common and Middle interfaces; the server that answers them publishes
each call with its reply (``CallTrace`` on ``trace/<served>/<op>``,
``schema.keys.ArmKeys.trace``). A publisher declared on the wildcard trace key,
never put on, tells from its matching status (a local look-up, well under a
microsecond) whether any subscriber listens: with none, a call costs that
look-up and nothing else. With one, the trace is a small JSON put after the
reply went out, dropped rather than waited for if the network is congested.
"""

from __future__ import annotations

import logging
import time
from typing import Any

import zenoh

from jara_arm.schema import codec
from jara_arm.schema.encoding import Encoding
from jara_arm.schema.errors import JaraArmError
from jara_arm.schema.keys import ArmKeys, arm_of, encoding_of, traffic_of
from jara_arm.schema.messages import CALL_TRACE, CallTrace

from .wire import label, qos

log = logging.getLogger(__name__)


def wire_map(payload: bytes, encoding: Encoding) -> dict[str, Any]:
    """A request or reply as the map it carries; a payload that is not one as ``{"payload": its text}``."""
    try:
        value = codec.loads(payload, encoding)
    except JaraArmError:
        value = None
    return value if isinstance(value, dict) else {"payload": payload.decode("utf-8", errors="replace")}


class CallTracer:
    """Publishes the calls answered on the operation queryable ``served_all`` (``.../Common/*``…)."""

    def __init__(self, session: zenoh.Session, served_all: str) -> None:
        self._session = session
        self._keys = ArmKeys(arm_of(served_all))
        trace_all = self._keys.traced(served_all)
        self._encoding = encoding_of(trace_all)
        self._label = label(self._encoding)
        self._probe = session.declare_publisher(trace_all, encoding=self._label)  # for its matching status only
        self._trace_keys: dict[str, str] = {}  # by the answered key, for the interface's own operations

    @property
    def listened(self) -> bool:
        """Whether any subscriber's key expression meets the trace keys."""
        status: Any = self._probe.matching_status  # the stub says bool; it is a MatchingStatus
        return bool(status.matching)

    def _trace_key(self, answered: str) -> str | None:
        key = self._trace_keys.get(answered)
        if key is None:
            try:
                key = self._trace_keys[answered] = self._keys.traced(answered)
            except JaraArmError:  # an operation the interface lacks (NOT_IMPLEMENTED): no trace, nothing kept
                return None  # (a client's made-up names must not grow the cache)
        return key

    def publish(self, answered: str, request: bytes, encoding: Encoding, reply: bytes) -> None:
        """Publish the call on ``answered`` (its key) if anyone listens; never raises."""
        try:
            if not self.listened:
                return
            key = self._trace_key(answered)
            if key is None:
                return
            trace = CallTrace(time.time(), wire_map(request, encoding), wire_map(reply, encoding))
            payload = codec.encode_message(CALL_TRACE, trace, self._encoding)
            self._session.put(key, payload, encoding=self._label, **qos(traffic_of(key)))
        except Exception as exc:  # a trace must never cost a reply, nor the service (closing: undeclared)
            log.debug("no trace of %s: %s", answered, exc)

    def close(self) -> None:
        self._probe.undeclare()
