"""What the alarm monitor does about a new alarm (DECISIONS.md "Alarms").

* FAULT: ``Servo/Common/servoOFF`` (the servo makes a controlled stop and
  holds; it has already stopped by itself if it follows ``Monitor/alarms``)
  and ``Planner/control abort`` (the servo's buffered motions are discarded,
  if the servo has not done it itself; the command service sees it in
  ``Planner/progress``).
* WARNING: ``Planner/control stop`` (the queue is discarded); the servo stays
  on (it stops the arm by itself on the new list and holds it).

Each peer has a worker thread of its own, so that a hung servo (a query that
times out) does not delay the planner's abort, and the monitor thread never
waits for a query.
"""

from __future__ import annotations

import logging
import queue
import threading

import zenoh

from jara_arm.schema import codec
from jara_arm.schema.alarms import format_code
from jara_arm.schema.codes import AlarmType
from jara_arm.schema.keys import ArmKeys
from jara_arm.schema.operations import COMMON, OP
from jara_arm.schema.planner import CONTROL_REQUEST, ControlAction, ControlRequest
from jara_arm.schema.types import Alarm
from jara_arm.services.runtime.ask import Asker, Silence

log = logging.getLogger(__name__)

#: Time the servo or the planner has to confirm a reaction [s].
REACTION_TIMEOUT = 0.5


class _Worker:
    """Queries to one peer, one at a time, in order."""

    def __init__(self, session: zenoh.Session, name: str, keys: tuple[str, ...]) -> None:
        self._name = name
        self._askers = {key: Asker(session, key, REACTION_TIMEOUT) for key in keys}
        self._queue: queue.SimpleQueue[tuple[str, bytes, str] | None] = queue.SimpleQueue()
        self._thread = threading.Thread(target=self._run, name=f"react-{name}", daemon=True)
        self._thread.start()

    def submit(self, key: str, payload: bytes, what: str) -> None:
        self._queue.put((key, payload, what))

    def close(self) -> None:
        self._queue.put(None)
        self._thread.join(timeout=2 * REACTION_TIMEOUT)
        for asker in self._askers.values():
            asker.close()

    def _run(self) -> None:
        while (job := self._queue.get()) is not None:
            key, payload, what = job
            try:
                got = self._askers[key].ask(payload)
                if isinstance(got, Silence):
                    log.warning("%s: the %s: %s", what, self._name, got.why)
                    continue
                body = codec.loads(got.payload, got.encoding)
                log.info("%s: %s answered %s", what, self._name,
                         body.get("comment") if isinstance(body, dict) else body)
            except Exception as exc:  # a reaction that fails must not stop the next ones
                log.warning("%s: query to the %s failed: %s", what, self._name, exc)


class Reactions:
    """Sends the reactions to new alarms to the servo and the planner."""

    def __init__(self, session: zenoh.Session, keys: ArmKeys) -> None:
        self._keys = keys
        self._servo = _Worker(session, "servo", (keys.servo_common(OP.servoOFF),))
        self._planner = _Worker(session, "planner", (keys.planner_control,))

    def react(self, alarm: Alarm) -> None:
        what = f"alarm {format_code(alarm.code)} {alarm.type.value}"
        if alarm.type is AlarmType.FAULT:
            self._servo.submit(self._keys.servo_common(OP.servoOFF),
                               codec.encode_request(COMMON[OP.servoOFF]), f"{what}: servoOFF")
            self._planner.submit(self._keys.planner_control, _control(ControlAction.ABORT),
                                 f"{what}: planner abort")
        else:
            self._planner.submit(self._keys.planner_control, _control(ControlAction.STOP),
                                 f"{what}: planner stop")

    def close(self) -> None:
        self._servo.close()
        self._planner.close()


def _control(action: ControlAction) -> bytes:
    return codec.encode_message(CONTROL_REQUEST, ControlRequest(action.value))
