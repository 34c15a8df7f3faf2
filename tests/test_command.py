"""The command service as a real process, against the real servo and the real planner.

Two rigs share one in-process Zenoh router, each started once for the module:

* ``arm0``: servo + command + planner;
* ``fake``: a command process whose servo and planner are played by this test
  (``FakePeers``), to see exactly what the command sends the planner (the
  settings snapshot of every motion) and how it reads the planner's queue and
  pause from its progress and its replies.
"""

from __future__ import annotations

import dataclasses
import json
import math
import sys
import threading
import time
from collections.abc import Callable, Iterator
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
from jara_arm.schema import wire_types as w
from jara_arm.schema.codec import Encoding, Reply
from jara_arm.schema.codes import ReturnCode, StateBit
from jara_arm.schema.keys import ArmKeys, Service, op_of
from jara_arm.schema.operations import ALL, COMMON, MIDDLE, OP, Interface
from jara_arm.schema.planner import (
    CONTROL_REPLY,
    CONTROL_REQUEST,
    MOTION_REQUEST,
    PLAN_REPLY,
    PLANNER_PROGRESS,
    ControlAction,
    ControlReply,
    ControlRequest,
    MotionRequest,
    PlannerProgress,
    PlanReply,
)
from jara_arm.schema.types import CarPosWithElbow, CartesianSpeed, LimitValue, Time, TimedJointPos, hg_matrix
from jara_arm.services.runtime.timing import CONTROL_TIMEOUT
from jara_arm.services.runtime.zenoh_args import zenoh_config

from .support import Client, Proc, endpoint, free_port, wait_alive, wait_until

pytestmark = pytest.mark.timeout(120)

IIWA = robot("iiwa")
N = IIWA.axis_num
OK, NG = ReturnCode.OK, ReturnCode.NG
VALUE_ERR, STATUS_ERR = ReturnCode.VALUE_ERR, ReturnCode.STATUS_ERR
FAKE_PLAN_TIMEOUT = 0.5  # [s] --plan-timeout of the fake rig's command


def service_argv(service: Service, port: int, arm: str, *extra: str) -> list[str]:
    """A service process as a client of the test's router (the launcher's topology)."""
    return [sys.executable, "-m", f"jara_arm.services.{service.value}", "--arm", arm, "--robot", IIWA.name,
            "--mode", "client", "--connect", endpoint(port), *extra]


# ---------------------------------------------------------------------------- the fake peers


class FakePeers:
    """Servo and planner of the ``fake`` arm, played in this process."""

    def __init__(self, session: zenoh.Session, arm: str) -> None:
        self.keys = ArmKeys(arm)
        self.session = session
        self.servo_on = False
        self.alarm = False
        self.moving = False
        self.talking = threading.Event()  # Servo/status is published while set
        self.talking.set()
        self.plans: list[MotionRequest] = []
        self.controls: list[str] = []
        self.control_requests: list[ControlRequest] = []  # each as it came, with its ratio
        self.plan_reply: tuple[int, str] = (OK, "OK")
        self.held: list[zenoh.Query] = []  # plan and control queries left unanswered (planner "hangs")
        self.hang = False
        # The queue this fake planner owns (motion ids), as schema/planner.py has it.
        self._lock = threading.Lock()
        self.started = Time.now()
        self.seq = 0
        self.last_id = 0
        self.queued: tuple[int, ...] = ()
        self.paused = False
        self.override = 100.0  # [%] the servo's speed override, as this planner reports it
        self._status = session.declare_publisher(self.keys.servo_status)
        self._progress = session.declare_publisher(self.keys.planner_progress)
        self._servo_q = session.declare_queryable(self.keys.servo_common(), self._servo_common)
        self._plan_q = session.declare_queryable(self.keys.planner_plan, self._plan)
        self._control_q = session.declare_queryable(self.keys.planner_control, self._control)
        self.planner_token = session.liveliness().declare_token(self.keys.alive(Service.PLANNER))
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._publish_status, daemon=True)
        self._thread.start()

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2)
        self.held.clear()

    def _publish_status(self) -> None:
        z = (0.0,) * N
        while not self._stop.wait(0.01):
            if self.talking.is_set():
                st = messages.ServoStatus(Time.now(), self.servo_on, self.moving, self.alarm, 0, 0, 0, 0,
                                          z, z, IIWA.ready_pose)
                self._status.put(codec.encode_message(messages.SERVO_STATUS, st))

    def _servo_common(self, query: zenoh.Query) -> None:
        op = COMMON[op_of(query.key_expr)]
        outs: dict[str, Any] = {}
        if op.name == OP.servoON:
            self.servo_on = True
        elif op.name == OP.servoOFF:
            self.servo_on = False
        elif op.name == OP.getSoftLimitJoint:
            outs["softLimit"] = IIWA.hard_limits
        elif op.name == OP.getFeedbackPosJoint:
            outs["pos"] = IIWA.ready_pose
        reply = Reply(OK, "OK", outs) if op.outputs == () or outs else Reply(NG, "not played")
        query.reply(query.key_expr, codec.encode_reply(op, reply))

    def _plan(self, query: zenoh.Query) -> None:
        req = codec.decode_message(MOTION_REQUEST, query.payload.to_bytes())
        if self.hang:
            self.held.append(query)
            return
        self.plans.append(req)
        code, comment = self.plan_reply
        with self._lock:
            motion = 0
            if code == OK:
                self.last_id = motion = self.last_id + 1
                self.queued += (motion,)
            body = PlanReply(code, comment, motion, IIWA.ready_pose, 1.0, self._snapshot(changed=code == OK))
        query.reply(query.key_expr, codec.encode_message(PLAN_REPLY, body))

    def _control(self, query: zenoh.Query) -> None:
        req = codec.decode_message(CONTROL_REQUEST, query.payload.to_bytes())
        if self.hang:
            self.held.append(query)
            return
        action = ControlAction(req.action)
        self.controls.append(action.value)
        self.control_requests.append(req)
        with self._lock:
            if action in (ControlAction.STOP, ControlAction.ABORT):
                self.queued, self.paused = (), False
            elif action is ControlAction.OVERRIDE:  # the servo's: neither the queue nor the pause changes
                self.override = req.ratio
            else:
                self.paused = action is ControlAction.PAUSE
            body = ControlReply(OK, "OK", self._snapshot())
        query.reply(query.key_expr, codec.encode_message(CONTROL_REPLY, body))

    def _snapshot(self, changed: bool = True) -> PlannerProgress:
        """The queue as it is now (lock held); a new number if it changed."""
        self.seq += changed
        return PlannerProgress(Time.now(), self.queued[0] if self.queued else 0, self.queued, 0, 0,
                               self.paused, bool(self.queued), self.started, self.seq, self.override)

    def progress(self, queued: tuple[int, ...] | None = None, paused: bool | None = None,
                 seq: int | None = None, override: float | None = None) -> PlannerProgress:
        """Publish the queue (changed to ``queued``/``paused``/``override`` if given), numbered ``seq`` if
        given (an older number: a message that was on its way), else the next number."""
        with self._lock:
            if seq is None:
                self.queued = self.queued if queued is None else tuple(queued)
                self.paused = self.paused if paused is None else paused
                self.override = self.override if override is None else override
                msg = self._snapshot()
            else:
                msg = dataclasses.replace(self._snapshot(changed=False), seq=seq,
                                          queued=tuple(queued or ()), paused=bool(paused),
                                          override=self.override if override is None else override)
        self._progress.put(codec.encode_message(PLANNER_PROGRESS, msg))
        return msg


# ---------------------------------------------------------------------------- rigs


class Rig:
    def __init__(self, session: zenoh.Session, arm: str, proc: Proc) -> None:
        self.session = session
        self.client = Client(session, arm)
        self.keys = ArmKeys(arm)
        self.proc = proc
        self.planner_proc: Proc | None = None

    def planner_log(self, lines: int = 20) -> str:
        """The tail of the planner's output, to tell a planner refusal from a command bug."""
        return "\n".join(self.planner_proc.lines[-lines:]) if self.planner_proc else ""

    def state(self) -> int:
        return self.client.common(OP.getState)["state"]

    def ok(self, interface: Interface, name: str, args: dict | None = None) -> Reply:
        reply = self.client.call(interface, name, args)
        assert reply.id == OK, (name, reply)
        return reply


class Rigs:
    """Everything started once for the module."""

    def __init__(self) -> None:
        self.port = free_port()
        self.router = zenoh.open(zenoh_config("router", listen=[endpoint(self.port)]))
        self.procs: list[Proc] = []
        self.fake_peers: FakePeers | None = None

    def start(self) -> None:
        self.fake_peers = FakePeers(self.router, "fake")
        servo = self._start(Service.SERVO, "arm0")
        command = self._start(Service.COMMAND, "arm0")
        self.planner_proc = self._start(Service.PLANNER, "arm0")
        fake = self._start(Service.COMMAND, "fake", "--plan-timeout", str(FAKE_PLAN_TIMEOUT))
        wait_alive(self.router, "arm0", [Service.SERVO, Service.COMMAND, Service.PLANNER], timeout=60)
        wait_alive(self.router, "fake", [Service.COMMAND], timeout=60)
        self.servo_proc = servo
        self.real = Rig(self.router, "arm0", command)
        self.real.planner_proc = self.planner_proc
        self.fake = Rig(self.router, "fake", fake)

    def _start(self, service: Service, arm: str, *extra: str) -> Proc:
        proc = Proc(service_argv(service, self.port, arm, *extra))
        self.procs.append(proc)
        return proc

    def close(self) -> None:
        outputs = []
        for proc in reversed(self.procs):
            code = proc.stop()
            outputs.append((proc.argv, code, proc.output))
        if self.fake_peers:
            self.fake_peers.close()
        self.router.close()
        for argv, code, output in outputs:
            assert code == 0, f"{argv} exited with {code}:\n{output}"
            assert "Traceback" not in output, output


@pytest.fixture(scope="module")
def rigs() -> Iterator[Rigs]:
    r = Rigs()
    try:
        r.start()
        yield r
    finally:
        r.close()


DEFAULT_SETTINGS: tuple[tuple[Interface, str, dict], ...] = (
    (Interface.MIDDLE, OP.setSpeedJoint, {"spdRatio": 0}),
    (Interface.MIDDLE, OP.setSpeedCartesian, {"spdRatio": 0}),
    (Interface.MIDDLE, OP.setMaxSpeedJoint, {"speed": IIWA.rated_speed}),
    (Interface.MIDDLE, OP.setMaxSpeedCartesian, {"speed": CartesianSpeed(0.25, 1.0)}),
    (Interface.MIDDLE, OP.setMinAccelTimeJoint, {"aclTime": IIWA.min_accel_time}),
    (Interface.MIDDLE, OP.setAccelTimeJoint, {"aclTime": IIWA.min_accel_time}),
    (Interface.MIDDLE, OP.setMinAccelTimeCartesian, {"aclTime": IIWA.min_accel_time_cartesian}),
    (Interface.MIDDLE, OP.setAccelTimeCartesian, {"aclTime": IIWA.min_accel_time_cartesian}),
    (Interface.MIDDLE, OP.setBaseOffset, {"offset": hg_matrix()}),
    (Interface.MIDDLE, OP.setControlPointOffset, {"offset": hg_matrix()}),
    (Interface.MIDDLE, OP.setHome, {"jointPoint": IIWA.ready_pose}),
    (Interface.EXT, OP.setBlendDistance, {"distance": 0.0}),
    (Interface.EXT, OP.setSpeedOverride, {"ratio": 100.0}),  # the servo keeps it across servoOFF
)


def reset(rig: Rig) -> None:
    """Servo off (queue discarded), at rest, alarms cleared, default settings, servo on."""
    rig.ok(Interface.COMMON, OP.servoOFF)
    wait_until(lambda: not rig.state() & StateBit.MOVING, 10, what="the arm at rest")
    rig.ok(Interface.COMMON, OP.clearAlarms)
    rig.ok(Interface.COMMON, OP.setSoftLimitJoint, {"softLimit": IIWA.hard_limits})
    for interface, name, args in DEFAULT_SETTINGS:
        rig.ok(interface, name, args)
    rig.ok(Interface.COMMON, OP.servoON)


@pytest.fixture
def real(rigs: Rigs) -> Rig:
    reset(rigs.real)
    return rigs.real


@pytest.fixture
def fake(rigs: Rigs) -> Iterator[tuple[Rig, FakePeers]]:
    peers = rigs.fake_peers
    assert peers is not None
    peers.talking.set()
    peers.hang = False
    peers.plan_reply = (OK, "OK")
    peers.alarm = peers.moving = False
    reset(rigs.fake)
    peers.progress(queued=(), paused=False)
    peers.plans.clear()
    peers.controls.clear()
    peers.control_requests.clear()
    yield rigs.fake, peers
    peers.held.clear()


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


def rot(axis: str, angle: float) -> np.ndarray:
    return pin.utils.rpyToMatrix(*(angle if a == axis else 0.0 for a in "xyz"))


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
    real.ok(Interface.MIDDLE, OP.setBaseOffset, {"offset": shift})
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
    real.ok(Interface.MIDDLE, setter, args)
    assert real.client.middle(getter)[out] == expected


def test_offsets_and_cartesian_limits_round_trip(real: Rig):
    c = real.client
    b = hg_matrix(rot("z", 0.3), (0.1, -0.2, 0.05))
    real.ok(Interface.MIDDLE, OP.setBaseOffset, {"offset": b})
    assert np.allclose(c.middle(OP.getBaseOffset)["offset"], b, atol=1e-12)
    limits = {"xLimit": LimitValue(0.9, -0.8), "yLimit": LimitValue(0.7, -0.6), "zLimit": LimitValue(1.1, 0.05)}
    real.ok(Interface.MIDDLE, OP.setSoftLimitCartesian, limits)
    got = c.middle(OP.getSoftLimitCartesian)
    assert {k: got[k] for k in limits} == limits


def test_accel_time_is_checked_against_the_minimum(real: Rig):
    c = real.client
    r = c.middle(OP.setAccelTimeJoint, {"aclTime": IIWA.min_accel_time / 2})
    assert r.id == VALUE_ERR and r.comment.startswith("aclTime") and OP.setMinAccelTimeJoint in r.comment
    real.ok(Interface.MIDDLE, OP.setMinAccelTimeJoint, {"aclTime": 0.5})
    assert c.middle(OP.setAccelTimeJoint, {"aclTime": 0.4}).id == VALUE_ERR
    real.ok(Interface.MIDDLE, OP.setAccelTimeJoint, {"aclTime": 0.6})
    real.ok(Interface.MIDDLE, OP.setMinAccelTimeCartesian, {"aclTime": 0.3})
    assert c.middle(OP.setAccelTimeCartesian, {"aclTime": 0.29}).id == VALUE_ERR
    real.ok(Interface.MIDDLE, OP.setAccelTimeCartesian, {"aclTime": 0.3})


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
    real.ok(Interface.COMMON, OP.servoOFF)
    assert not c.servo(OP.getState)["state"] & StateBit.SERVO_ON
    assert real.state() == 0
    real.ok(Interface.COMMON, OP.servoON)
    assert c.servo(OP.getState)["state"] & StateBit.SERVO_ON
    assert real.state() & StateBit.SERVO_ON
    mine, theirs = c.common(OP.getFeedbackPosJoint)["pos"], c.servo(OP.getFeedbackPosJoint)["pos"]
    assert len(mine) == N and np.allclose(mine, theirs, atol=1e-6)
    for name in (OP.getManipInfo, OP.getSoftLimitJoint, OP.getActiveAlarm):
        assert c.common(name) == c.servo(name), name


def test_set_soft_limit_joint_lands_in_the_servo(real: Rig):
    c = real.client
    narrow = tuple(LimitValue(lim.upper * 0.9, lim.lower * 0.9) for lim in IIWA.hard_limits)
    real.ok(Interface.COMMON, OP.setSoftLimitJoint, {"softLimit": narrow})
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
    real.ok(Interface.COMMON, OP.servoOFF)
    r = c.middle(OP.movePTPJointRel, ptp)
    assert r.id == ReturnCode.NOT_SV_ON_ERR and OP.servoON in r.comment, r
    real.ok(Interface.COMMON, OP.servoON)
    for name, args, setter in ((OP.movePTPJointRel, ptp, OP.setSpeedJoint),
                               (OP.movePTPCartesianRel, lin, OP.setSpeedJoint),
                               (OP.goHome, {}, OP.setSpeedJoint),
                               (OP.moveLinearCartesianRel, lin, OP.setSpeedCartesian)):
        r = c.middle(name, args)
        assert r.id == STATUS_ERR and setter in r.comment, (name, r)
    real.ok(Interface.MIDDLE, OP.setSpeedJoint, {"spdRatio": 10})
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
    real.ok(Interface.COMMON, OP.servoOFF)
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
        real.ok(Interface.COMMON, OP.servoOFF)
        real.ok(Interface.COMMON, OP.servoON)

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
    pub = real.session.declare_publisher(real.keys.pos_cmd)
    q0 = np.array(real.client.common(OP.getFeedbackPosJoint)["pos"])
    n = int(duration / IIWA.cmd_cycle)
    t0 = time.monotonic()
    for k in range(n + 1):
        u = k / n
        s = 10 * u**3 - 15 * u**4 + 6 * u**5
        q = q0 + (np.asarray(target) - q0) * s
        pub.put(codec.encode_message(w.TIMED_JOINT_POS, TimedJointPos(Time.now(), tuple(map(float, q)))))
        if k >= 100:  # keep 100 commands ahead of the servo
            delay = t0 + (k - 100) * IIWA.cmd_cycle - time.monotonic()
            if delay > 0:
                time.sleep(delay)
    pub.undeclare()
    wait_until(lambda: not real.state() & StateBit.MOVING, 10, what="the arm at rest")


def test_feedback_pos_cartesian_follows_base_and_control_point_offsets(real: Rig):
    c = real.client
    stream_to(real, np.array(IIWA.ready_pose) + [0.3, 0.0, 0.5, 0.0, 0.0, 0.0, 0.0])
    q = c.servo(OP.getFeedbackPosJoint)["pos"]
    b = hg_matrix(rot("z", 0.7) @ rot("x", 0.2), (0.3, -0.1, 0.2))
    tool = hg_matrix(rot("y", 0.5), (0.0, 0.02, 0.15))
    for base, cp in ((hg_matrix(), hg_matrix()), (b, hg_matrix()), (hg_matrix(), tool), (b, tool)):
        real.ok(Interface.MIDDLE, OP.setBaseOffset, {"offset": base})
        real.ok(Interface.MIDDLE, OP.setControlPointOffset, {"offset": cp})
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
def test_bad_payloads_get_value_err_and_the_service_keeps_running(rigs: Rigs, op):
    real = rigs.real
    key = real.keys.interface(op.interface, op.name)
    state = real.state()
    for payload in (b"\xc1\xc1", msgpack.packb([1, 2]), msgpack.packb({"bogus": 1})):
        reply = real.client.raw(key, payload)
        assert reply["id"] == VALUE_ERR and set(reply) == {"id", "comment"} and reply["comment"], reply
    assert real.client.raw(key, b'{"bogus": NaN', json=True)["id"] == VALUE_ERR
    if op.inputs:  # every in parameter missing
        assert real.client.raw(key, msgpack.packb({}))["id"] == VALUE_ERR
    assert real.state() == state and real.proc.popen.poll() is None


# ---------------------------------------------------------------------------- with the fake peers


def test_every_motion_carries_the_settings_accepted_before_it(fake):
    rig, peers = fake
    b = hg_matrix(rot("z", 0.5), (0.1, 0.2, 0.3))
    tool = hg_matrix(translation=(0.0, 0.0, 0.1))
    for name, args in ((OP.setSpeedJoint, {"spdRatio": 40}), (OP.setSpeedCartesian, {"spdRatio": 60}),
                       (OP.setMaxSpeedJoint, {"speed": tuple(v / 2 for v in RATED)}),
                       (OP.setMaxSpeedCartesian, {"speed": CartesianSpeed(0.2, 0.8)}),
                       (OP.setAccelTimeJoint, {"aclTime": 0.3}),
                       (OP.setMinAccelTimeCartesian, {"aclTime": 0.5}),  # raises the accel time to 0.5
                       (OP.setBaseOffset, {"offset": b}), (OP.setControlPointOffset, {"offset": tool}),
                       (OP.setSoftLimitCartesian, {"xLimit": LimitValue(1, -1), "yLimit": LimitValue(1, -1),
                                                   "zLimit": LimitValue(1, 0)}),
                       (OP.setHome, {"jointPoint": (0.1,) * N})):
        rig.ok(Interface.MIDDLE, name, args)
    rig.ok(Interface.EXT, OP.setBlendDistance, {"distance": 0.02})
    rig.ok(Interface.MIDDLE, OP.movePTPJointAbs, {"jointPoints": (0.2,) * N})
    car = CarPosWithElbow(hg_matrix(rot("x", 1.0), (0.4, 0.0, 0.5)), 0.3, 0)
    rig.ok(Interface.MIDDLE, OP.moveCircularCartesianAbs, {"carPointR": car, "carPointT": car})
    first, second = peers.plans
    assert (first.op, second.op) == (OP.movePTPJointAbs, OP.moveCircularCartesianAbs)
    assert first.args == {"jointPoints": [0.2] * N}
    assert codec.decode_request(MIDDLE[OP.moveCircularCartesianAbs], msgpack.packb(second.args)) == {
        "carPointR": car, "carPointT": car}
    s = first.settings
    assert (s.spdRatioJoint, s.spdRatioCartesian) == (40, 60)
    assert s.maxSpeedJoint == tuple(v / 2 for v in RATED) and s.maxSpeedCartesian == CartesianSpeed(0.2, 0.8)
    assert (s.accelTimeJoint, s.accelTimeCartesian) == (0.3, 0.5)
    assert s.softLimitJoint == IIWA.hard_limits  # the servo's
    assert s.softLimitCartesian == (LimitValue(1, -1), LimitValue(1, -1), LimitValue(1, 0))
    assert np.allclose(s.baseOffset, b) and np.allclose(s.controlPointOffset, tool)
    assert s.home == (0.1,) * N
    assert s.blendDistance == 0.02 == second.settings.blendDistance
    rig.ok(Interface.MIDDLE, OP.setSpeedJoint, {"spdRatio": 5})
    rig.ok(Interface.MIDDLE, OP.goHome)
    assert peers.plans[-1].settings.spdRatioJoint == 5 and peers.plans[-1].args == {}


def test_planner_refusal_is_passed_on_and_queues_nothing(fake):
    rig, peers = fake
    rig.ok(Interface.MIDDLE, OP.setSpeedCartesian, {"spdRatio": 10})
    peers.plan_reply = (VALUE_ERR, "target outside the Cartesian soft limits")
    car = CarPosWithElbow(hg_matrix(translation=(5.0, 0.0, 0.0)), 0.0, 0)
    r = rig.client.middle(OP.moveLinearCartesianAbs, {"carPoint": car})
    assert (r.id, r.comment) == (VALUE_ERR, "target outside the Cartesian soft limits")
    assert rig.state() == StateBit.SERVO_ON


class StateLog:
    """The ``state`` publications of a rig's command, in order, from now on."""

    def __init__(self, rig: Rig) -> None:
        self._sub = rig.session.declare_subscriber(rig.keys.state, zenoh.handlers.FifoChannel(1024))
        self.seen: list[dict] = []

    def until(self, done: Callable[[dict], bool], what: str, timeout: float = 2.0) -> list[dict]:
        """Everything published up to the first message for which ``done`` holds."""
        start = len(self.seen)

        def arrived() -> bool:
            while (sample := self._sub.try_recv()) is not None:
                self.seen.append(codec.loads(sample.payload.to_bytes(), codec.Encoding.of(sample.encoding)))
                if done(self.seen[-1]):
                    return True
            return False

        wait_until(arrived, timeout, what=f"{what}; published: {self.seen[start:]}")
        return self.seen[start:]

    def close(self) -> None:
        self._sub.undeclare()


def test_queue_full_from_the_planners_queue(fake):
    rig, peers = fake
    c = rig.client
    rig.ok(Interface.MIDDLE, OP.setSpeedJoint, {"spdRatio": 50})
    move = {"jointPoints": (0.0,) * N}
    for _ in range(32):
        rig.ok(Interface.MIDDLE, OP.movePTPJointRel, move)
    # The replies carried the queue: full at once, no publication needed.
    r = c.middle(OP.movePTPJointRel, move)
    assert r.id == ReturnCode.FULL_MOTION_QUEUE_ERR and "32 of 32" in r.comment, r
    assert rig.state() == StateBit.SERVO_ON | StateBit.MOVING | StateBit.BUFFER_FULL
    assert len(peers.plans) == 32  # the 33rd never reached the planner
    ids = peers.queued
    assert ids == tuple(range(ids[0], ids[0] + 32))
    states = StateLog(rig)
    try:
        # A message numbered before the last reply (on its way meanwhile) changes nothing; the
        # next one does. Both on one key from one publisher: they are taken up in this order.
        stale = peers.progress(queued=ids[:10], seq=peers.seq - 1)
        assert len(stale.queued) == 10
        peers.progress(queued=ids[3:])  # three motions done
        published = states.until(lambda m: m["queueLength"] == 29, "three motions done")
        assert [m["queueLength"] for m in published] == [29], published
        assert published[-1]["state"] == StateBit.SERVO_ON | StateBit.MOVING
        for _ in range(3):
            rig.ok(Interface.MIDDLE, OP.movePTPJointRel, move)
        assert c.middle(OP.movePTPJointRel, move).id == ReturnCode.FULL_MOTION_QUEUE_ERR
        # setSoftLimitJoint is refused while motions are queued.
        r = c.common(OP.setSoftLimitJoint, {"softLimit": IIWA.hard_limits})
        assert r.id == STATUS_ERR and "queued" in r.comment, r
        # stop: forwarded; its reply empties the queue at once.
        rig.ok(Interface.MIDDLE, OP.stop)
        assert peers.controls[-1] == "stop"
        assert rig.state() == StateBit.SERVO_ON
    finally:
        states.close()


def test_pause_and_resume_from_the_planners_word(fake):
    rig, peers = fake
    c = rig.client
    rig.ok(Interface.MIDDLE, OP.setSpeedJoint, {"spdRatio": 50})
    rig.ok(Interface.MIDDLE, OP.movePTPJointRel, {"jointPoints": (0.1,) + (0.0,) * (N - 1)})
    motion = peers.queued[-1]
    rig.ok(Interface.MIDDLE, OP.pause)
    assert peers.controls == ["pause"]
    assert rig.state() == StateBit.SERVO_ON | StateBit.MOVING | StateBit.PAUSED  # from the reply
    r = c.middle(OP.pause)
    assert r.id == OK and "already paused" in r.comment and peers.controls == ["pause"]
    states = StateLog(rig)
    try:
        peers.progress(queued=(motion,), paused=False, seq=peers.seq - 1)  # published before the pause
        rig.ok(Interface.MIDDLE, OP.resume)
        published = states.until(lambda m: not m["state"] & StateBit.PAUSED, "resumed")
        assert [m["state"] for m in published] == [StateBit.SERVO_ON | StateBit.MOVING], published
        assert peers.controls == ["pause", "resume"] and not rig.state() & StateBit.PAUSED
        # The planner's own changes, published.
        peers.progress(paused=True)
        states.until(lambda m: m["state"] & StateBit.PAUSED, "the planner's own pause adopted")
        peers.progress(paused=False)
        states.until(lambda m: not m["state"] & StateBit.PAUSED, "the planner's own resume adopted")
        peers.progress(queued=())
        states.until(lambda m: m["state"] == StateBit.SERVO_ON, "queue empty")
    finally:
        states.close()
    # servoOFF aborts the planner.
    rig.ok(Interface.COMMON, OP.servoOFF)
    assert peers.controls[-1] == "abort"


def test_alarm_refuses_motions_and_set_soft_limit(fake):
    rig, peers = fake
    rig.ok(Interface.MIDDLE, OP.setSpeedJoint, {"spdRatio": 50})
    peers.alarm = True
    wait_until(lambda: rig.state() & StateBit.ALARM, 2, what="alarm bit")
    r = rig.client.middle(OP.goHome)
    assert r.id == STATUS_ERR and "alarm" in r.comment, r
    r = rig.client.common(OP.setSoftLimitJoint, {"softLimit": IIWA.hard_limits})
    assert r.id == STATUS_ERR and "alarm" in r.comment, r
    for name in (OP.pause, OP.stop):
        r = rig.client.middle(name)
        assert r.id == OK and "ignored" in r.comment and "alarm" in r.comment, r
    assert peers.plans == [] and peers.controls == []


# ---------------------------------------------------------------------------- the speed override (Ext)


def test_set_speed_override_reaches_the_planner_and_its_reply_is_read_at_once(fake):
    rig, peers = fake
    c = rig.client
    rig.ok(Interface.EXT, OP.setSpeedOverride, {"ratio": 30})
    assert peers.control_requests == [ControlRequest("override", 30.0)]
    assert c.ext(OP.getSpeedOverride)["ratio"] == 30.0  # from the reply's progress: no publication needed
    # 0 holds on the path: no pause (bit 0x10 clear, resume ignored), the queue untouched.
    rig.ok(Interface.MIDDLE, OP.setSpeedJoint, {"spdRatio": 50})
    rig.ok(Interface.MIDDLE, OP.goHome)
    rig.ok(Interface.EXT, OP.setSpeedOverride, {"ratio": 0.0})
    assert peers.control_requests[-1] == ControlRequest("override", 0.0)
    assert c.ext(OP.getSpeedOverride)["ratio"] == 0.0
    assert rig.state() == StateBit.SERVO_ON | StateBit.MOVING
    r = c.middle(OP.resume)
    assert r.id == OK and "not paused" in r.comment, r
    rig.ok(Interface.EXT, OP.setSpeedOverride, {"ratio": 100})
    assert peers.controls == ["override", "override", "override"] and len(peers.plans) == 1


def test_a_bad_speed_override_names_ratio_and_reaches_nothing(fake):
    rig, peers = fake
    key = rig.keys.interface(Interface.EXT, OP.setSpeedOverride)
    for bad in (-1, 101, 100.5, math.nan, "fast"):
        reply = rig.client.raw(key, msgpack.packb({"ratio": bad}))
        assert reply["id"] == VALUE_ERR and reply["comment"].startswith("ratio"), (bad, reply)
    assert peers.controls == [] and peers.control_requests == []
    assert rig.client.ext(OP.getSpeedOverride)["ratio"] == 100.0  # unchanged


def test_get_speed_override_answers_from_the_newest_progress(fake):
    rig, peers = fake
    c = rig.client
    assert c.ext(OP.getSpeedOverride)["ratio"] == 100.0  # reset set it through the planner
    peers.progress(override=55.0)  # the servo's override, published by the planner
    wait_until(lambda: c.ext(OP.getSpeedOverride)["ratio"] == 55.0, 2, what="the published override read")
    # A message numbered before the last (on its way meanwhile) changes nothing; the next one is read.
    # Both on one key from one publisher: once the second is in, the first was taken up too.
    peers.progress(override=10.0, seq=peers.seq - 1)
    peers.progress(queued=(1,))  # newer, the override still 55
    wait_until(lambda: rig.state() & StateBit.MOVING, 2, what="the newer progress read")
    assert c.ext(OP.getSpeedOverride)["ratio"] == 55.0
    assert peers.controls == []  # a getter asks no one


def test_silent_planner_and_servo_are_named(fake):
    rig, peers = fake
    rig.ok(Interface.MIDDLE, OP.setSpeedJoint, {"spdRatio": 50})
    peers.hang = True
    t0 = time.monotonic()
    r = rig.client.middle(OP.goHome)
    assert r.id == NG and "planner" in r.comment and time.monotonic() - t0 < FAKE_PLAN_TIMEOUT + 1.0, r
    t0 = time.monotonic()
    r = rig.client.ext(OP.setSpeedOverride, {"ratio": 50})
    assert r.id == NG and "planner" in r.comment and time.monotonic() - t0 < CONTROL_TIMEOUT + 1.0, r
    assert rig.client.ext(OP.getSpeedOverride)["ratio"] == 100.0  # the planner's last word, still held
    peers.hang = False
    peers.talking.clear()  # the servo falls silent
    wait_until(lambda: not rig.state() & StateBit.SERVO_ON, 3, what="servo bit cleared")
    r = rig.client.middle(OP.goHome)
    assert r.id == ReturnCode.NOT_SV_ON_ERR and "Servo/status" in r.comment, r
    peers.talking.set()
    wait_until(lambda: rig.state() & StateBit.SERVO_ON, 3, what="servo bit back")


def test_planner_gone_discards_the_queue(fake):
    rig, peers = fake
    rig.ok(Interface.MIDDLE, OP.setSpeedJoint, {"spdRatio": 50})
    rig.ok(Interface.MIDDLE, OP.goHome)
    assert rig.state() & StateBit.MOVING
    peers.planner_token.undeclare()
    try:
        wait_until(lambda: rig.state() == StateBit.SERVO_ON, 3, what="queue forgotten")
        r = rig.client.ext(OP.getSpeedOverride)  # the servo's override is known only through the planner
        assert r.id == NG and "planner" in r.comment, r
    finally:
        peers.planner_token = rig.session.liveliness().declare_token(peers.keys.alive(Service.PLANNER))


# ---------------------------------------------------------------------------- with the real planner


def slow_motions(real: Rig, count: int) -> list[Reply]:
    """``count`` joint moves of J1 back and forth at 1 % speed, about 12 s each, so they pile up. (0.05 rad,
    3.6 s each, was not enough beside a busy loop per core: 33 requests planned at up to 105 ms each took
    longer than the first motion, which ended before the 33rd came and left it room.)"""
    real.ok(Interface.MIDDLE, OP.setSpeedJoint, {"spdRatio": 1})
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
    real.ok(Interface.MIDDLE, OP.stop)
    assert not real.state() & StateBit.BUFFER_FULL
    wait_until(lambda: real.state() == StateBit.SERVO_ON, 10, what="at rest with an empty queue")


def test_real_pause_sets_the_paused_bit(real: Rig):
    assert [r.id for r in slow_motions(real, 2)] == [OK, OK], real.planner_log()
    wait_until(lambda: real.state() & StateBit.MOVING, 2, what="moving")
    real.ok(Interface.MIDDLE, OP.pause)
    assert real.state() & StateBit.PAUSED
    real.ok(Interface.MIDDLE, OP.resume)
    assert not real.state() & StateBit.PAUSED
    real.ok(Interface.MIDDLE, OP.stop)
    wait_until(lambda: real.state() == StateBit.SERVO_ON, 10, what="at rest with an empty queue")


# ---------------------------------------------------------------------------- queue bookkeeping (no process)


def progress(queued=(), paused=False, seq=1, started=100.0) -> PlannerProgress:
    return PlannerProgress(Time.now(), queued[0] if queued else 0, tuple(queued), 0, 0, paused, bool(queued),
                           Time.from_seconds(started), seq)


def test_the_newest_planner_message_wins_by_its_number():
    from jara_arm.services.command.state import StateTracker

    published: list[tuple[int, int]] = []
    tracker = StateTracker(3, publish=lambda view: published.append((view.bits, view.queue_length)))
    tracker.on_progress(progress((1, 2, 3), seq=5))
    assert tracker.view().full and tracker.view().queue_length == 3
    tracker.on_progress(progress((1,), seq=4))  # older: on its way before the last
    tracker.on_progress(progress((1,), seq=5))  # the same number: nothing new
    assert tracker.view().queue_length == 3
    tracker.on_progress(progress((2, 3), paused=True, seq=6))
    assert (tracker.view().queue_length, tracker.view().paused, tracker.view().full) == (2, True, False)
    tracker.on_progress(None)  # the planner did not answer: nothing learnt
    assert tracker.view().queue_length == 2
    tracker.on_progress(progress((7,), seq=1, started=200.0))  # a restarted planner
    assert tracker.view().queue_length == 1 and not tracker.view().paused
    tracker.on_planner_gone()
    assert tracker.view().queue_length == 0
    tracker.on_progress(progress((7,), seq=2, started=200.0))  # still on its way from the gone one
    assert tracker.view().queue_length == 0
    tracker.on_progress(progress((), seq=1, started=300.0))
    assert published == [(StateBit.MOVING | StateBit.BUFFER_FULL, 3), (StateBit.MOVING | StateBit.PAUSED, 2),
                         (StateBit.MOVING, 1), (0, 0)]


def test_the_state_is_published_only_when_it_changes():
    from jara_arm.services.command.state import StateTracker

    published: list[int] = []
    tracker = StateTracker(4, publish=lambda view: published.append(view.bits))
    z = (0.0,) * N
    status = messages.ServoStatus(Time.now(), True, False, False, 0, 0, 0, 0, z, z, z)
    for _ in range(100):
        tracker.on_status(status)
        tracker.on_progress(progress(seq=1))
        tracker.tick()
    assert published == [StateBit.SERVO_ON]
    tracker.on_status(dataclasses.replace(status, moving=True))
    assert published == [StateBit.SERVO_ON, StateBit.SERVO_ON | StateBit.MOVING]


def test_a_stale_view_first_takes_in_what_arrived():
    """A command service held up without a CPU has statuses waiting: the view reads them before it says
    "no status" (``StateTracker.catch_up``); with nothing waiting it still says so."""
    from jara_arm.services.command.state import StateTracker

    tracker = StateTracker(4, publish=lambda view: None, stale_after=0.05)
    z = (0.0,) * N
    status = messages.ServoStatus(Time.now(), True, False, False, 0, 0, 0, 0, z, z, z)
    tracker.on_status(status)
    assert tracker.view().servo_heard and tracker.view().servo_on
    waiting: list[messages.ServoStatus] = []
    tracker.catch_up = lambda: [tracker.on_status(s) for s in waiting] and waiting.clear()
    wait_until(lambda: not tracker.view().servo_heard, 2.0, what="the status stale")  # none waiting: stale
    waiting.append(status)
    view = tracker.view()  # stale, but one waits: taken in first
    assert view.servo_heard and view.servo_on and not waiting


def test_a_motion_request_listens_for_a_status_before_it_says_there_is_none():
    """A command service whose receiving threads were held up has no status yet: the view of a motion
    request waits up to ``listen`` for one (a status arriving meanwhile counts); a servo that stays
    silent is still "not heard", after ``listen``, not before."""
    from jara_arm.services.command.state import StateTracker

    tracker = StateTracker(4, publish=lambda view: None, stale_after=0.05)
    z = (0.0,) * N
    status = messages.ServoStatus(Time.now(), True, False, False, 0, 0, 0, 0, z, z, z)
    drains: list[float] = []
    tracker.catch_up = lambda: drains.append(time.monotonic())
    t0 = time.monotonic()
    view = tracker.view(listen=0.2)  # nothing ever came
    assert not view.servo_heard and time.monotonic() - t0 >= 0.2
    assert len(drains) >= 2  # what arrived meanwhile was looked for, not only once
    late = threading.Timer(0.1, tracker.on_status, (status,))
    late.start()
    try:
        view = tracker.view(listen=5.0)
    finally:
        late.join()
    assert view.servo_heard and view.servo_on
    wait_until(lambda: not tracker.view().servo_heard, 2.0, what="the status stale")
    drains.clear()
    assert not tracker.view().servo_heard  # a plain view (getState) looks once and does not wait
    assert len(drains) == 1
