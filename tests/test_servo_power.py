"""``Servo/power``'s answer in-process, no process: ``ServoPower`` on a stand-in for the servo loop records what
it is asked to do on the loop's thread. The request's list is adopted before the action, every reply carries
a status made after it, and a malformed request is VALUE_ERR naming the field and changes nothing."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import pytest

from jara_arm.schema import codec
from jara_arm.schema.alarms import NO_LIST, AlarmList
from jara_arm.schema.codec import Encoding
from jara_arm.schema.codes import AlarmType, ReturnCode
from jara_arm.schema.messages import ServoStatus
from jara_arm.schema.power import POWER_REPLY, POWER_REQUEST, PowerReply, PowerRequest
from jara_arm.schema.types import Alarm, Time

KEY = "JARA_ARM/p/Servo/power"
LISTED = AlarmList(Time(1_795_331_205, 0), Time(1_795_331_200, 0), (Alarm(1, AlarmType.FAULT, "emergency stop"),))


class _AlarmState:
    monitor_alarms: tuple[Alarm, ...] = ()


class StandInLoop:
    """What ``ServoPower`` uses of ``ServoLoop``; ``done`` lists what ran on "the loop's thread", in order."""

    def __init__(self, refuse: str | None = None) -> None:
        self.done: list[str] = []
        self.refuse = refuse
        self.alarm_state = _AlarmState()
        self.seq = 0

    def call(self, fn: Callable[[], Any]) -> Any:
        return fn()

    def adopt_monitor_list(self, alarms: AlarmList) -> None:
        self.done.append(f"adopt {alarms.started.sec}")

    def servo_on_now(self) -> str | None:
        self.done.append("on")
        return self.refuse

    def servo_off_now(self) -> None:
        self.done.append("off")

    def clear_alarms_now(self) -> tuple[list[Alarm], list[Alarm]]:
        self.done.append("clear")
        return [], []

    def status_now(self) -> ServoStatus:
        self.seq += 1
        return ServoStatus(Time(1_795_331_210, 0), "on" in self.done, False, False, 0, 0, 0, 0, (), (), (),
                           started=Time(1_795_331_000, 0), seq=self.seq)


class SilentMonitor:
    def call(self, _name: str) -> None:
        return None

    def alarm_list(self) -> None:
        return None


def ask(loop: StandInLoop, request: dict[str, Any], enc: Encoding = Encoding.MSGPACK) -> PowerReply:
    from jara_arm.services.servo.power import ServoPower

    key, body = ServoPower(loop, SilentMonitor()).answer(KEY, codec.dumps(request, enc), enc)
    assert key == KEY
    reply: PowerReply = codec.decode_message(POWER_REPLY, body, enc)
    return reply


def test_the_list_is_adopted_first_and_the_reply_carries_the_status_after_the_action() -> None:
    loop = StandInLoop()
    wire = POWER_REQUEST.encode(PowerRequest("on", LISTED))
    reply = ask(loop, wire)
    assert (reply.id, reply.comment) == (ReturnCode.OK, "OK")
    assert loop.done == ["adopt 1795331200", "on"] and reply.status.servoOn and reply.status.seq == 1
    reply = ask(loop, {"action": "off"})  # no list: nothing adopted
    assert loop.done[2:] == ["off"] and reply.status.seq == 2
    reply = ask(loop, POWER_REQUEST.encode(PowerRequest("sync", NO_LIST)), Encoding.JSON)
    assert loop.done[3:] == [] and reply.id == ReturnCode.OK


def test_a_refused_servo_on_is_status_err_with_its_reason_and_a_status() -> None:
    loop = StandInLoop(refuse="alarms active: 0x01; clear them first")
    reply = ask(loop, {"action": "on"})
    assert reply.id == ReturnCode.STATUS_ERR and reply.status.seq == 1
    assert reply.comment == "servoON refused: alarms active: 0x01; clear them first"


def test_clear_without_a_monitor_clears_the_servos_own() -> None:
    loop = StandInLoop()
    reply = ask(loop, {"action": "clear"})
    assert loop.done == ["clear"] and reply.id == ReturnCode.OK and "the alarm monitor does not answer" in reply.comment


@pytest.mark.parametrize("request_, field", [
    ({"action": "reboot", "alarms": POWER_REQUEST.encode(PowerRequest("on", LISTED))["alarms"]}, "action"),
    ({"action": "on", "alarms": {"tm": {"sec": 1, "nsec": 0}}}, "alarms.started"),
    ({"action": "on", "force": True}, "force"),
])
def test_a_malformed_request_is_value_err_naming_the_field_and_changes_nothing(request_: dict[str, Any],
                                                                               field: str) -> None:
    loop = StandInLoop()
    reply = ask(loop, request_)
    assert reply.id == ReturnCode.VALUE_ERR and reply.comment.startswith(f"{field}: "), reply
    assert loop.done == [] and reply.status.seq == 1  # nothing adopted, nothing done; the status as it is
