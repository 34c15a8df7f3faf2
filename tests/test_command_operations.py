"""The command service's operations as a real process, against the real servo and the real planner.

``arm0``'s servo, command and planner, clients of an in-process Zenoh router of the test's own
(``command_rig.py``), started once for the module: the defaults and what each setter changes,
validation, Common agreeing with the servo, motions refused by state, the state's publication,
the Cartesian feedback, bad input, and the motion queue with the real planner.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterator
from typing import Any

import msgpack
import numpy as np
import pinocchio as pin
import pytest
import zenoh

from jara_arm.kinematics import Kinematics
from jara_arm.kinematics.posture import Postures
from jara_arm.robots import robot
from jara_arm.schema import codec, messages
from jara_arm.schema.codec import Encoding, Reply
from jara_arm.schema.codes import ReturnCode, StateBit
from jara_arm.schema.keys import Service
from jara_arm.schema.operations import ALL, MIDDLE, OP, Interface
from jara_arm.schema.types import CarPosWithElbow, CartesianSpeed, LimitValue, hg_matrix

from .command_rig import reset, rot, router
from .harness import LiveArm, PosCommands, Processes
from .support import Proc, service_argv, wait_alive, wait_until

pytestmark = pytest.mark.timeout(120)

IIWA = robot("iiwa")
N = IIWA.axis_num
OK = ReturnCode.OK
VALUE_ERR, STATUS_ERR = ReturnCode.VALUE_ERR, ReturnCode.STATUS_ERR


class Rig(LiveArm):
    """``arm0``'s client, its process the command service; the planner's log tells a planner refusal from
    a command bug."""

    def __init__(self, session: zenoh.Session, command: Proc, planner: Proc) -> None:
        super().__init__(session, proc=command)
        self.planner_proc = planner

    def planner_log(self, lines: int = 20) -> str:
        return self.log_tail(lines, proc=self.planner_proc)


@pytest.fixture(scope="module")
def real_rig() -> Iterator[Rig]:
    with router() as (session, port), Processes() as procs:
        procs.start(service_argv(Service.SERVO, port, client=True))
        command = procs.start(service_argv(Service.COMMAND, port, client=True))
        planner = procs.start(service_argv(Service.PLANNER, port, client=True))
        wait_alive(session, "arm0", [Service.SERVO, Service.COMMAND, Service.PLANNER], timeout=60)
        yield Rig(session, command, planner)


@pytest.fixture
def real(real_rig: Rig) -> Rig:
    reset(real_rig)
    return real_rig


# ---------------------------------------------------------------------------- independent kinematics


_PIN = pin.buildModelFromUrdf(str(IIWA.urdf))
_PIN_DATA = _PIN.createData()


def flange_pose(q) -> np.ndarray:
    """Flange pose in the arm base frame (4x4), straight from the URDF with Pinocchio."""
    pin.framesForwardKinematics(_PIN, _PIN_DATA, np.asarray(q, dtype=float))
    return _PIN_DATA.oMf[_PIN.getFrameId(IIWA.flange_frame)].homogeneous.copy()


def arm_angle(q) -> float:
    """DECISIONS.md "Frames" arm angle of the iiwa: shoulder J2, elbow J4, wrist J6 origins."""
    pin.forwardKinematics(_PIN, _PIN_DATA, np.asarray(q, dtype=float))
    s, e, wr = (_PIN_DATA.oMi[_PIN.getJointId(IIWA.arm_joints[i])].translation for i in (1, 3, 5))
    u = (wr - s) / np.linalg.norm(wr - s)
    ref = np.array([0.0, 0.0, 1.0])
    r = ref - ref.dot(u) * u
    v = (e - s) - (e - s).dot(u) * u
    r, v = r / np.linalg.norm(r), v / np.linalg.norm(v)
    return math.atan2(u.dot(np.cross(r, v)), r.dot(v))


def h4(hg) -> np.ndarray:
    out = np.eye(4)
    out[:3] = np.asarray(hg)
    return out


# ---------------------------------------------------------------------------- defaults and settings


def test_every_getter_has_its_default(real: Rig):
    c = real.client
    assert c.middle(OP.getMaxSpeedJoint)["speed"] == IIWA.rated_speed
    assert c.middle(OP.getMaxSpeedCartesian)["speed"] == CartesianSpeed(0.25, 1.0)
    assert c.middle(OP.getMinAccelTimeJoint)["aclTime"] == IIWA.min_accel_time
    assert c.middle(OP.getMinAccelTimeCartesian)["aclTime"] == IIWA.min_accel_time_cartesian
    assert np.array_equal(c.middle(OP.getBaseOffset)["offset"], hg_matrix())
    assert c.middle(OP.getHome)["jointPoint"] == IIWA.ready_pose
    assert c.common(OP.getSoftLimitJoint)["softLimit"] == IIWA.hard_limits
    assert c.common(OP.getActiveAlarm)["alarms"] == ()
    assert c.common(OP.getManipInfo)["mInfo"] == IIWA.manip_info
    assert real.state() == StateBit.SERVO_ON

    # Cartesian soft limits: a box about the arm base that holds every reachable flange position.
    lim = c.middle(OP.getSoftLimitCartesian)
    box = [lim["xLimit"], lim["yLimit"], lim["zLimit"]]
    rng = np.random.default_rng(1)
    lo, hi = np.array([x.lower for x in IIWA.hard_limits]), np.array([x.upper for x in IIWA.hard_limits])
    points = np.array([flange_pose(lo + (hi - lo) * rng.random(N))[:3, 3] for _ in range(2000)])
    for axis, b in enumerate(box):
        assert b.lower < points[:, axis].min() and points[:, axis].max() < b.upper, (axis, b)
        assert b.lower == -b.upper and b.upper < 2.0  # centred on the base, not absurdly large
    # ... which follows the base offset while it has not been set.
    shift = hg_matrix(translation=(0.5, 0.0, 0.0))
    real.call_ok(Interface.MIDDLE, OP.setBaseOffset, {"offset": shift})
    moved = c.middle(OP.getSoftLimitCartesian)["xLimit"]
    assert moved.upper == pytest.approx(box[0].upper - 0.5) and moved.lower == pytest.approx(box[0].lower - 0.5)


SETTERS: tuple[tuple[str, dict, str, str, Any], ...] = (
    # setter, its argument, getter, the getter's out parameter, expected value
    (OP.setMaxSpeedJoint, {"speed": tuple(v / 2 for v in IIWA.rated_speed)}, OP.getMaxSpeedJoint, "speed",
     tuple(v / 2 for v in IIWA.rated_speed)),
    (OP.setMaxSpeedCartesian, {"speed": CartesianSpeed(0.1, 0.5)}, OP.getMaxSpeedCartesian, "speed",
     CartesianSpeed(0.1, 0.5)),
    (OP.setMinAccelTimeJoint, {"aclTime": 0.5}, OP.getMinAccelTimeJoint, "aclTime", 0.5),
    (OP.setMinAccelTimeCartesian, {"aclTime": 0.4}, OP.getMinAccelTimeCartesian, "aclTime", 0.4),
    (OP.setHome, {"jointPoint": (0.1, 0.2, 0.3, -0.4, 0.5, 0.6, 0.7)}, OP.getHome, "jointPoint",
     (0.1, 0.2, 0.3, -0.4, 0.5, 0.6, 0.7)),
)


@pytest.mark.parametrize("setter, args, getter, out, expected", SETTERS, ids=[s[0] for s in SETTERS])
def test_every_setter_changes_its_getter(real: Rig, setter, args, getter, out, expected):
    real.call_ok(Interface.MIDDLE, setter, args)
    assert real.client.middle(getter)[out] == expected


def test_offsets_and_cartesian_limits_round_trip(real: Rig):
    c = real.client
    b = hg_matrix(rot("z", 0.3), (0.1, -0.2, 0.05))
    real.call_ok(Interface.MIDDLE, OP.setBaseOffset, {"offset": b})
    assert np.allclose(c.middle(OP.getBaseOffset)["offset"], b, atol=1e-12)
    limits = {"xLimit": LimitValue(0.9, -0.8), "yLimit": LimitValue(0.7, -0.6), "zLimit": LimitValue(1.1, 0.05)}
    real.call_ok(Interface.MIDDLE, OP.setSoftLimitCartesian, limits)
    got = c.middle(OP.getSoftLimitCartesian)
    assert {k: got[k] for k in limits} == limits


def test_accel_time_is_checked_against_the_minimum(real: Rig):
    c = real.client
    r = c.middle(OP.setAccelTimeJoint, {"aclTime": IIWA.min_accel_time / 2})
    assert r.id == VALUE_ERR and r.comment.startswith("aclTime") and OP.setMinAccelTimeJoint in r.comment
    real.call_ok(Interface.MIDDLE, OP.setMinAccelTimeJoint, {"aclTime": 0.5})
    assert c.middle(OP.setAccelTimeJoint, {"aclTime": 0.4}).id == VALUE_ERR
    real.call_ok(Interface.MIDDLE, OP.setAccelTimeJoint, {"aclTime": 0.6})
    real.call_ok(Interface.MIDDLE, OP.setMinAccelTimeCartesian, {"aclTime": 0.3})
    assert c.middle(OP.setAccelTimeCartesian, {"aclTime": 0.29}).id == VALUE_ERR
    real.call_ok(Interface.MIDDLE, OP.setAccelTimeCartesian, {"aclTime": 0.3})


RATED = IIWA.rated_speed
INVALID: tuple[tuple[str, dict, str, str], ...] = (
    # setter, bad argument (Python value, or wire form as a list), field named in the comment, getter
    (OP.setSpeedJoint, {"spdRatio": 101}, "spdRatio", ""),
    (OP.setSpeedCartesian, {"spdRatio": 150}, "spdRatio", ""),
    (OP.setMaxSpeedJoint, {"speed": RATED[:6]}, "speed", OP.getMaxSpeedJoint),
    (OP.setMaxSpeedJoint, {"speed": RATED[:2] + (RATED[2] * 1.01,) + RATED[3:]}, "speed[2]", OP.getMaxSpeedJoint),
    (OP.setMaxSpeedJoint, {"speed": (0.0,) + RATED[1:]}, "speed[0]", OP.getMaxSpeedJoint),
    (OP.setMaxSpeedCartesian, {"speed": CartesianSpeed(0.0, 1.0)}, "speed.translation", OP.getMaxSpeedCartesian),
    (OP.setMaxSpeedCartesian, {"speed": CartesianSpeed(0.3, -1.0)}, "speed.rotation", OP.getMaxSpeedCartesian),
    (OP.setMinAccelTimeJoint, {"aclTime": 0.0}, "aclTime", OP.getMinAccelTimeJoint),
    (OP.setMinAccelTimeCartesian, {"aclTime": -1.0}, "aclTime", OP.getMinAccelTimeCartesian),
    (OP.setAccelTimeJoint, {"aclTime": 0.01}, "aclTime", ""),
    (OP.setAccelTimeCartesian, {"aclTime": 0.01}, "aclTime", ""),
    (OP.setSoftLimitCartesian, {"xLimit": LimitValue(1, -1), "yLimit": LimitValue(-1, 1),
                                "zLimit": LimitValue(1, 0)}, "yLimit", OP.getSoftLimitCartesian),
    (OP.setHome, {"jointPoint": IIWA.ready_pose[:5]}, "jointPoint", OP.getHome),
    (OP.setHome, {"jointPoint": (0.0, 0.0, 0.0, 2.5, 0.0, 0.0, 0.0)}, "jointPoint[3]", OP.getHome),
    (OP.setBaseOffset, {"offset": [[2.0, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0]]}, "offset", OP.getBaseOffset),
    (OP.setControlPointOffset, {"offset": [[1.0, 0, 0, 0], [0, 1, 0, 0]]}, "offset", ""),
)


def same(a: Reply, b: Reply) -> bool:
    return a.id == b.id and a.outs.keys() == b.outs.keys() and all(
        np.array_equal(a[k], b[k]) if isinstance(a[k], np.ndarray) else a[k] == b[k] for k in a.outs)


@pytest.mark.parametrize("setter, args, field, getter", INVALID, ids=[f"{s[0]}-{s[2]}" for s in INVALID])
def test_validation_failure_names_the_field_and_changes_nothing(real: Rig, setter, args, field, getter):
    op = MIDDLE[setter]
    payload = msgpack.packb({p.name: args[p.name] if isinstance(args[p.name], list)
                             else p.type.encode(args[p.name]) for p in op.inputs})
    before = real.client.middle(getter) if getter else None
    reply = real.client.raw(real.keys.interface(Interface.MIDDLE, setter), payload)
    assert reply["id"] == VALUE_ERR and reply["comment"].startswith(field), reply
    if before is not None:
        assert same(real.client.middle(getter), before)
    if setter in (OP.setSpeedJoint, OP.setSpeedCartesian):  # still 0 %: motions still refused
        name = OP.movePTPJointRel if setter == OP.setSpeedJoint else OP.moveLinearCartesianRel
        move = {"jointPoints": (0.0,) * N} if name == OP.movePTPJointRel else {
            "carPoint": CarPosWithElbow(hg_matrix(), 0.0, 0)}
        assert real.client.middle(name, move).id == STATUS_ERR


# ---------------------------------------------------------------------------- Common agrees with the servo


def test_common_operations_agree_with_the_servo(real: Rig):
    c = real.client
    real.call_ok(Interface.COMMON, OP.servoOFF)
    assert not c.servo(OP.getState)["state"] & StateBit.SERVO_ON
    assert real.state() == 0
    real.call_ok(Interface.COMMON, OP.servoON)
    assert c.servo(OP.getState)["state"] & StateBit.SERVO_ON
    assert real.state() & StateBit.SERVO_ON
    mine, theirs = c.common(OP.getFeedbackPosJoint)["pos"], c.servo(OP.getFeedbackPosJoint)["pos"]
    assert len(mine) == N and np.allclose(mine, theirs, atol=1e-6)
    for name in (OP.getManipInfo, OP.getSoftLimitJoint, OP.getActiveAlarm):
        assert c.common(name) == c.servo(name), name


def test_set_soft_limit_joint_lands_in_the_servo(real: Rig):
    c = real.client
    narrow = tuple(LimitValue(lim.upper * 0.9, lim.lower * 0.9) for lim in IIWA.hard_limits)
    real.call_ok(Interface.COMMON, OP.setSoftLimitJoint, {"softLimit": narrow})
    assert c.servo(OP.getSoftLimitJoint)["softLimit"] == narrow
    bad = (LimitValue(0.1, 0.2),) + narrow[1:]
    r = c.common(OP.setSoftLimitJoint, {"softLimit": bad})
    assert r.id == VALUE_ERR and r.comment.startswith("softLimit[0]"), r
    assert c.servo(OP.getSoftLimitJoint)["softLimit"] == narrow
    # setHome is checked against the servo's limits as they are now.
    r = c.middle(OP.setHome, {"jointPoint": (0.0, 0.5, 0.0, -1.2, 0.0, 0.8, 3.0)})
    assert r.id == VALUE_ERR and r.comment.startswith("jointPoint[6]"), r


# ---------------------------------------------------------------------------- motions refused by state


def test_motion_refusals_in_order(real: Rig):
    c = real.client
    ptp = {"jointPoints": (0.01,) + (0.0,) * (N - 1)}
    lin = {"carPoint": CarPosWithElbow(hg_matrix(translation=(0.0, 0.0, 0.01)), 0.0, 0)}
    real.call_ok(Interface.COMMON, OP.servoOFF)
    r = c.middle(OP.movePTPJointRel, ptp)
    assert r.id == ReturnCode.NOT_SV_ON_ERR and OP.servoON in r.comment, r
    real.call_ok(Interface.COMMON, OP.servoON)
    for name, args, setter in ((OP.movePTPJointRel, ptp, OP.setSpeedJoint),
                               (OP.movePTPCartesianRel, lin, OP.setSpeedJoint),
                               (OP.goHome, {}, OP.setSpeedJoint),
                               (OP.moveLinearCartesianRel, lin, OP.setSpeedCartesian)):
        r = c.middle(name, args)
        assert r.id == STATUS_ERR and setter in r.comment, (name, r)
    real.call_ok(Interface.MIDDLE, OP.setSpeedJoint, {"spdRatio": 10})
    r = c.middle(OP.moveLinearCartesianRel, lin)  # the Cartesian ratio is still 0 %
    assert r.id == STATUS_ERR and OP.setSpeedCartesian in r.comment, r
    for name in (OP.movePTPJointAbs, OP.movePTPJointRel):
        r = c.middle(name, {"jointPoints": (0.0,) * (N + 1)})
        assert r.id == VALUE_ERR and r.comment.startswith("jointPoints"), r
    assert not real.state() & StateBit.MOVING  # nothing was queued


def test_pause_resume_stop_ignored_when_the_spec_says_so(real: Rig):
    c = real.client
    for name, words in ((OP.pause, "not moving"), (OP.resume, "not paused")):
        r = c.middle(name)
        assert r.id == OK and "ignored" in r.comment and words in r.comment, r
    real.call_ok(Interface.COMMON, OP.servoOFF)
    for name in (OP.pause, OP.stop):
        r = c.middle(name)
        assert r.id == OK and "ignored" in r.comment and "servo is off" in r.comment, r


# ---------------------------------------------------------------------------- state publication


def test_state_is_published_on_every_change(real: Rig):
    sub = real.session.declare_subscriber(real.keys.state, zenoh.handlers.FifoChannel(256))
    # Declared after ``sub``, on a key nobody else subscribes to here: once a heartbeat of the
    # command arrives, the command routes its publications to both subscribers.
    beats = real.session.declare_subscriber(real.keys.heartbeat(Service.COMMAND), zenoh.handlers.RingChannel(1))
    try:
        wait_until(lambda: beats.try_recv() is not None, 5, 0.01, "a heartbeat of the command")
        real.call_ok(Interface.COMMON, OP.servoOFF)
        real.call_ok(Interface.COMMON, OP.servoON)

        def states() -> list[dict]:
            out = []
            while (s := sub.try_recv()) is not None:
                assert str(s.encoding) == "application/json", s.encoding  # what people watch: JSON
                out.append(json.loads(s.payload.to_string()))
            return out

        seen: list[dict] = []
        wait_until(lambda: seen.extend(states()) or [m["state"] for m in seen][-2:] == [0, StateBit.SERVO_ON],
                   5, what=f"state 0 then 1 published; got {seen}")
        decoded = codec.decode_message(messages.STATE_MESSAGE, codec.dumps(seen[-1], Encoding.JSON), Encoding.JSON)
        assert decoded.state == StateBit.SERVO_ON
        assert seen[-1]["queueLength"] == 0 and seen[-1]["queueCapacity"] == 32
    finally:
        sub.undeclare()
        beats.undeclare()


# ---------------------------------------------------------------------------- Cartesian feedback


def stream_to(real: Rig, target, duration: float = 0.8) -> None:
    """Move the arm by streaming position commands straight to the servo (no planner needed)."""
    q0 = real.joints()
    n = int(duration / IIWA.cmd_cycle)
    u = np.arange(n + 1)[:, None] / n  # one command per cycle, minimum jerk
    commands = PosCommands(real.session, real.keys, IIWA.cmd_cycle)
    commands.stream(q0 + (np.asarray(target) - q0) * (10 * u**3 - 15 * u**4 + 6 * u**5))
    commands.close()
    real.wait_rest()


def test_feedback_pos_cartesian_follows_base_and_control_point_offsets(real: Rig):
    c = real.client
    stream_to(real, np.array(IIWA.ready_pose) + [0.3, 0.0, 0.5, 0.0, 0.0, 0.0, 0.0])
    q = c.servo(OP.getFeedbackPosJoint)["pos"]
    b = hg_matrix(rot("z", 0.7) @ rot("x", 0.2), (0.3, -0.1, 0.2))
    tool = hg_matrix(rot("y", 0.5), (0.0, 0.02, 0.15))
    for base, cp in ((hg_matrix(), hg_matrix()), (b, hg_matrix()), (hg_matrix(), tool), (b, tool)):
        real.call_ok(Interface.MIDDLE, OP.setBaseOffset, {"offset": base})
        real.call_ok(Interface.MIDDLE, OP.setControlPointOffset, {"offset": cp})
        pos = c.middle(OP.getFeedbackPosCartesian)["pos"]
        expected = np.linalg.inv(h4(base)) @ flange_pose(q) @ h4(cp)
        assert np.allclose(pos.carPos, expected[:3], atol=1e-5), (pos.carPos, expected)
        assert pos.elbow == pytest.approx(arm_angle(q), abs=1e-5) and abs(pos.elbow) > 0.1
        assert pos.structFlag == Postures(Kinematics(IIWA, seed_table=0)).of(q[:7])  # issue 15: posture bits


# ---------------------------------------------------------------------------- bad input


def test_unknown_operation_is_not_implemented(real: Rig):
    for interface in Interface:
        key = real.keys.interface(interface).replace("*", "getActivAlarm")
        assert real.client.raw(key, b"")["id"] == ReturnCode.NOT_IMPLEMENTED
    assert real.client.raw(real.keys.interface(Interface.COMMON, OP.getState), b"{}", json=True) == {
        "id": 0, "comment": "OK", "state": int(StateBit.SERVO_ON)}


@pytest.mark.parametrize("op", ALL, ids=[f"{o.interface.value}-{o.name}" for o in ALL])
def test_bad_payloads_get_value_err_and_the_service_keeps_running(real_rig: Rig, op):
    real = real_rig
    key = real.keys.interface(op.interface, op.name)
    state = real.state()
    for payload in (b"\xc1\xc1", msgpack.packb([1, 2]), msgpack.packb({"bogus": 1})):
        reply = real.client.raw(key, payload)
        assert reply["id"] == VALUE_ERR and set(reply) == {"id", "comment"} and reply["comment"], reply
    assert real.client.raw(key, b'{"bogus": NaN', json=True)["id"] == VALUE_ERR
    if op.inputs:  # every in parameter missing
        assert real.client.raw(key, msgpack.packb({}))["id"] == VALUE_ERR
    assert real.state() == state and real.proc.popen.poll() is None


# ---------------------------------------------------------------------------- with the real planner


def slow_motions(real: Rig, count: int) -> list[Reply]:
    """``count`` joint moves of J1 back and forth at 1 % speed, about 12 s each, so they pile up. (0.05 rad,
    3.6 s each, was not enough beside a busy loop per core: 33 requests planned at up to 105 ms each took
    longer than the first motion, which ended before the 33rd came and left it room.)"""
    real.call_ok(Interface.MIDDLE, OP.setSpeedJoint, {"spdRatio": 1})
    out = []
    for k in range(count):
        step = 0.2 if k % 2 == 0 else -0.2
        out.append(real.client.middle(OP.movePTPJointRel, {"jointPoints": (step,) + (0.0,) * (N - 1)}))
    return out


def test_real_queue_full_on_the_33rd_motion_and_stop_discards(real: Rig):
    replies = slow_motions(real, 33)
    assert [r.id for r in replies[:32]] == [OK] * 32, (replies, real.planner_log())
    assert replies[32].id == ReturnCode.FULL_MOTION_QUEUE_ERR, (replies[32], real.planner_log())
    assert real.state() & StateBit.BUFFER_FULL and real.state() & StateBit.MOVING
    real.call_ok(Interface.MIDDLE, OP.stop)
    assert not real.state() & StateBit.BUFFER_FULL
    wait_until(lambda: real.state() == StateBit.SERVO_ON, 10, what="at rest with an empty queue")


def test_real_pause_sets_the_paused_bit(real: Rig):
    assert [r.id for r in slow_motions(real, 2)] == [OK, OK], real.planner_log()
    wait_until(lambda: real.state() & StateBit.MOVING, 2, what="moving")
    real.call_ok(Interface.MIDDLE, OP.pause)
    assert real.state() & StateBit.PAUSED
    real.call_ok(Interface.MIDDLE, OP.resume)
    assert not real.state() & StateBit.PAUSED
    real.call_ok(Interface.MIDDLE, OP.stop)
    wait_until(lambda: real.state() == StateBit.SERVO_ON, 10, what="at rest with an empty queue")
