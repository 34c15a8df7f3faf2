"""Generic Zenoh tools, black box: the whole system from `jara-arm up`, driven and watched as
``z_get`` and ``z_sub`` (zenoh-python's examples, unmodified) do it.

A generic ``get`` sends its payload as a plain string with no encoding, and
prints the reply with ``payload.to_string()``; a generic subscriber prints
every sample with ``payload.to_string()``. Nothing of this project's codec is
used to talk to the arm here: only JSON text in and out (the keys and
operation names come from ``schema/``, their single source).
"""

from __future__ import annotations

import json
import threading
from typing import Any

import numpy as np
import pytest
import zenoh

from jara_arm.launcher.tools.client import ArmClient
from jara_arm.robots import robot
from jara_arm.schema.codes import AlarmCode, ReturnCode, StateBit
from jara_arm.schema.keys import ArmKeys
from jara_arm.schema.operations import OP, Interface

from .support import ServoTime, wait_until

pytestmark = pytest.mark.timeout(180)
#: [s] a motion of these tests takes well under this at the speeds set.
MOTION_TIMEOUT = 30.0
#: [s] of the servo's own time (support.ServoTime) after refused requests: nothing may move in it.
QUIET_WINDOW = 0.3


class Watch:
    """A ``z_sub``: every sample on ``key`` as the text ``payload.to_string()`` gives, with its encoding."""

    def __init__(self, session: zenoh.Session, key: str) -> None:
        self._lock = threading.Lock()
        self._texts: list[tuple[str, str, str]] = []  # (key, encoding, text)
        self._sub = session.declare_subscriber(key, self._on_sample)

    def _on_sample(self, sample: zenoh.Sample) -> None:
        text = sample.payload.to_string()  # what z_sub does; raises on anything but UTF-8
        with self._lock:
            self._texts.append((str(sample.key_expr), str(sample.encoding), text))

    def mark(self) -> int:
        with self._lock:
            return len(self._texts)

    def since(self, mark: int = 0) -> list[dict[str, Any]]:
        """The samples from ``mark`` on, parsed as JSON; each must be labelled JSON."""
        with self._lock:
            got = self._texts[mark:]
        for key, encoding, _text in got:
            assert encoding == "application/json", (key, encoding)
        return [json.loads(text) for _key, _enc, text in got]


class Arm:
    """The live system seen from generic tools: JSON strings in, ``to_string()`` out."""

    def __init__(self, session: zenoh.Session, robot_name: str) -> None:
        self.session = session
        self.model = robot(robot_name)
        self.client = ArmClient(session)  # only for conftest's wait_alive: the tests talk JSON
        self.keys = ArmKeys(self.client.keys.arm)
        self.state = Watch(session, self.keys.state)
        self.alarms = Watch(session, self.keys.alarm)
        self.logs = Watch(session, self.keys.log())
        self.servo_time = ServoTime(session, self.keys)  # the test's clock, not a generic tool

    def get(self, key: str, text: str = "{}") -> dict[str, Any]:
        """``z_get -s <key> -p <text>``: a str payload, no encoding; the one reply's text as JSON."""
        replies = list(self.session.get(key, payload=text, timeout=10.0))
        oks = [r.ok for r in replies if r.ok is not None]
        assert len(oks) == 1, f"{key}: expected one reply, got {len(oks)} ({[str(r.err) for r in replies]})"
        assert str(oks[0].encoding) == "application/json", (key, str(oks[0].encoding))
        return json.loads(oks[0].payload.to_string())

    def call(self, interface: Interface, op: str, args: dict[str, Any] | None = None) -> dict[str, Any]:
        return self.get(self.keys.interface(interface, op), json.dumps(args or {}))

    def ok(self, interface: Interface, op: str, args: dict[str, Any] | None = None) -> dict[str, Any]:
        reply = self.call(interface, op, args)
        assert reply["id"] == ReturnCode.OK, (op, reply)
        return reply

    def state_bits(self) -> int:
        return int(self.ok(Interface.COMMON, OP.getState)["state"])

    def joints(self) -> np.ndarray:
        return np.asarray(self.ok(Interface.COMMON, OP.getFeedbackPosJoint)["pos"], dtype=float)

    def idle(self, timeout: float = MOTION_TIMEOUT) -> None:
        """Until the arm neither moves nor has motions queued (the command's state)."""
        wait_until(lambda: not self.state_bits() & StateBit.MOVING, timeout, 0.05, "the arm idle")

    def reset(self) -> None:
        bits = self.state_bits()
        if bits & StateBit.MOVING:
            self.ok(Interface.MIDDLE, OP.stop)
            self.idle()
        if self.state_bits() & StateBit.ALARM:
            self.ok(Interface.COMMON, OP.clearAlarms)
        self.ok(Interface.COMMON, OP.servoON)
        self.ok(Interface.MIDDLE, OP.setSpeedJoint, {"spdRatio": 100})
        self.ok(Interface.MIDDLE, OP.setSpeedCartesian, {"spdRatio": 100})
        self.ok(Interface.MIDDLE, OP.setHome, {"jointPoint": list(self.model.ready_pose)})
        self.ok(Interface.MIDDLE, OP.goHome)
        self.idle()

    def record(self) -> None:
        """Nothing recorded here beyond the watches, which are read from marks."""


@pytest.fixture(scope="module")
def robot_name() -> str:
    """One robot: what is tested is the wire, not the kinematics (``test_middle.py`` runs both)."""
    return "iiwa"


def moved_and_settled(arm: Arm, mark: int) -> bool:
    """The state publications since ``mark`` show the arm moving, and the newest one idle."""
    seen = arm.state.since(mark)
    return (any(m["state"] & StateBit.MOVING for m in seen)
            and not seen[-1]["state"] & StateBit.MOVING and seen[-1]["queueLength"] == 0)


def test_a_whole_session_from_generic_tools(arm: Arm):
    logs_mark = arm.logs.mark()
    # servo on, speeds: replies come back as JSON text
    assert arm.call(Interface.COMMON, OP.servoON) == {"id": 0, "comment": "OK"}
    assert arm.call(Interface.MIDDLE, OP.setSpeedJoint, {"spdRatio": 50}) == {"id": 0, "comment": "OK"}
    assert arm.call(Interface.MIDDLE, OP.setSpeedCartesian, {"spdRatio": 50}) == {"id": 0, "comment": "OK"}
    assert arm.state_bits() & StateBit.SERVO_ON

    # a PTP in joint space
    q0 = arm.joints()
    target = q0.copy()
    target[: arm.model.axis_num] += np.array([0.2, -0.15, 0.1, 0.15, -0.1, 0.1, 0.2])[: arm.model.axis_num]
    mark = arm.state.mark()
    arm.ok(Interface.MIDDLE, OP.movePTPJointAbs, {"jointPoints": target.tolist()})
    wait_until(lambda: moved_and_settled(arm, mark), MOTION_TIMEOUT, 0.02,
               "state publications: moving, then idle", explain=lambda: arm.state.since(mark)[-5:])
    assert np.abs(arm.joints() - target).max() < 1e-3

    # a LIN: 5 cm down from where the PTP ended, the pose as getFeedbackPosCartesian gave it
    pose = arm.ok(Interface.MIDDLE, OP.getFeedbackPosCartesian)["pos"]
    goal = json.loads(json.dumps(pose))
    goal["carPos"][2][3] -= 0.05
    mark = arm.state.mark()
    arm.ok(Interface.MIDDLE, OP.moveLinearCartesianAbs, {"carPoint": goal})
    wait_until(lambda: moved_and_settled(arm, mark), MOTION_TIMEOUT, 0.02,
               "state publications: moving, then idle", explain=lambda: arm.state.since(mark)[-5:])
    now = arm.ok(Interface.MIDDLE, OP.getFeedbackPosCartesian)["pos"]["carPos"]
    assert np.abs(np.asarray(now)[:, 3] - np.asarray(goal["carPos"])[:, 3]).max() < 1e-3, (now, goal)

    # the state, read as a generic tool reads it
    reply = arm.ok(Interface.COMMON, OP.getState)
    assert reply["state"] & StateBit.SERVO_ON and not reply["state"] & StateBit.MOVING, reply

    # the logs a generic subscriber printed: JSON LogRecords, the planner's acceptance of both motions
    def accepted(op: str) -> bool:
        return any(r["service"] == "planner" and f" {op} accepted" in r["msg"] for r in arm.logs.since(logs_mark))

    wait_until(lambda: accepted(OP.movePTPJointAbs) and accepted(OP.moveLinearCartesianAbs), 10.0, 0.05,
               "the planner's log of both motions", explain=lambda: arm.logs.since(logs_mark)[-10:])
    assert all({"t", "level", "service", "msg", "logger"} <= set(r) for r in arm.logs.since(logs_mark))


def test_an_alarm_seen_and_cleared_from_generic_tools(arm: Arm):
    alarms_mark, state_mark = arm.alarms.mark(), arm.state.mark()
    arm.session.put(arm.keys.estop, "")  # z_put -k <estop> -p ''

    def events(kind: str) -> list[dict[str, Any]]:
        return [e for e in arm.alarms.since(alarms_mark)
                if e["event"] == kind and e["alarm"]["code"] == AlarmCode.EMERGENCY_STOP]

    wait_until(lambda: events("raised"), 10.0, 0.02, "the e-stop alarm event",
               explain=lambda: arm.alarms.since(alarms_mark))
    assert events("raised")[0]["alarm"]["type"] == "FAULT"
    wait_until(lambda: any(m["state"] & StateBit.ALARM for m in arm.state.since(state_mark)), 10.0, 0.02,
               "the alarm bit in the state publications")
    active = arm.ok(Interface.COMMON, OP.getActiveAlarm)["alarms"]
    assert [a["code"] for a in active] == [AlarmCode.EMERGENCY_STOP], active
    wait_until(lambda: not arm.state_bits() & StateBit.SERVO_ON, 5.0, 0.02, "the FAULT to switch the servo off")
    arm.idle()
    # a cause may take a moment to go: clearAlarms until it says OK
    wait_until(lambda: arm.call(Interface.COMMON, OP.clearAlarms)["id"] == ReturnCode.OK, 5.0, 0.05,
               "clearAlarms to succeed", explain=lambda: arm.call(Interface.COMMON, OP.clearAlarms))
    wait_until(lambda: events("cleared"), 10.0, 0.02, "the cleared event",
               explain=lambda: arm.alarms.since(alarms_mark))
    assert arm.ok(Interface.COMMON, OP.getActiveAlarm)["alarms"] == []


def test_bad_input_from_generic_tools_is_refused_in_json_and_nothing_moves(arm: Arm):
    q0 = arm.joints()
    mark = arm.state.mark()
    bad_type = arm.call(Interface.MIDDLE, OP.setSpeedJoint, {"spdRatio": "fast"})
    assert bad_type["id"] == ReturnCode.VALUE_ERR and bad_type["comment"].startswith("spdRatio"), bad_type
    bad_json = arm.get(arm.keys.interface(Interface.MIDDLE, OP.movePTPJointAbs), '{"jointPoints": [0.1,')
    assert bad_json["id"] == ReturnCode.VALUE_ERR and bad_json["comment"].startswith("payload"), bad_json
    missing = arm.call(Interface.MIDDLE, OP.movePTPJointAbs)
    assert missing["id"] == ReturnCode.VALUE_ERR and missing["comment"].startswith("jointPoints"), missing
    unknown = arm.get(arm.keys.interface(Interface.MIDDLE).replace("*", "movePTPJoint"))
    assert unknown["id"] == ReturnCode.NOT_IMPLEMENTED, unknown
    arm.servo_time.passes(QUIET_WINDOW)  # a motion wrongly accepted would move the arm in it
    assert not any(m["state"] & StateBit.MOVING for m in arm.state.since(mark))
    assert np.abs(arm.joints() - q0).max() < 1e-4
