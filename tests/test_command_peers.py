"""The command service with its peers played in-process: what it sends the planner, and how it reads the
planner's queue, pause and override, and the servo's status.

A command process (arm ``fake``) as a client of an in-process Zenoh router of the test's own
(``command_rig.py``), started once for the module; its servo and planner are ``FakePeers``,
to see exactly what the command sends the planner (the settings snapshot of every motion) and
how it reads the planner's queue and pause from its progress and its replies.
"""

from __future__ import annotations

import dataclasses
import math
import threading
import time
from collections.abc import Callable, Iterator
from typing import Any

import msgpack
import numpy as np
import pytest
import zenoh

from jara_arm.robots import robot
from jara_arm.schema import codec, messages
from jara_arm.schema.alarms import NO_LIST
from jara_arm.schema.codec import Reply
from jara_arm.schema.codes import ReturnCode, StateBit
from jara_arm.schema.keys import ArmKeys, Service, op_of
from jara_arm.schema.operations import COMMON, MIDDLE, OP, Interface
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
from jara_arm.schema.power import POWER_REPLY, POWER_REQUEST, PowerAction, PowerReply, PowerRequest
from jara_arm.schema.types import CarPosWithElbow, CartesianSpeed, LimitValue, Time, hg_matrix
from jara_arm.services.runtime.timing import CONTROL_TIMEOUT

from .command_rig import reset, rot, router
from .harness import LiveArm, Processes, Ticker
from .support import service_argv, wait_alive, wait_until

pytestmark = pytest.mark.timeout(120)

IIWA = robot("iiwa")
N = IIWA.axis_num
RATED = IIWA.rated_speed
OK, NG = ReturnCode.OK, ReturnCode.NG
VALUE_ERR, STATUS_ERR = ReturnCode.VALUE_ERR, ReturnCode.STATUS_ERR
FAKE_PLAN_TIMEOUT = 0.5  # [s] --plan-timeout of the fake rig's command
FAKE_HUNG_AFTER = 2.0  # [s] --hung-after of the fake rig's command (the same-host profile's is 1.5)


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
        self.powers: list[PowerRequest] = []  # the Servo/power requests, as they came
        # The servo's state and its numbered statuses change together, as on the servo's loop thread.
        self._servo_lock = threading.Lock()
        self.status_seq = 0
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
        self._power_q = session.declare_queryable(self.keys.servo_power, self._power)
        self._plan_q = session.declare_queryable(self.keys.planner_plan, self._plan)
        self._control_q = session.declare_queryable(self.keys.planner_control, self._control)
        self.planner_token = session.liveliness().declare_token(self.keys.alive(Service.PLANNER))
        self._ticker = Ticker(0.01, self._publish_status)

    def close(self) -> None:
        self._ticker.close()
        self.held.clear()

    def _publish_status(self) -> None:
        if self.talking.is_set():
            self.publish_status()

    def _status_now(self, seq: int | None = None) -> messages.ServoStatus:
        """The servo's status now (lock held), numbered as the servo numbers its statuses; ``seq``: an older
        number (a status made before)."""
        if seq is None:
            self.status_seq += 1
        z = (0.0,) * N
        return messages.ServoStatus(Time.now(), self.servo_on, self.moving, self.alarm, 0, 0, 0, 0, z, z,
                                    IIWA.ready_pose, started=self.started,
                                    seq=self.status_seq if seq is None else seq)

    def publish_status(self, seq: int | None = None, **changes: Any) -> None:
        """Publish the status (with ``changes``), numbered ``seq`` if given, else the next number."""
        with self._servo_lock:
            st = dataclasses.replace(self._status_now(seq), **changes)
        self._status.put(codec.encode_message(messages.SERVO_STATUS, st))

    def _power(self, query: zenoh.Query) -> None:
        req = codec.decode_message(POWER_REQUEST, query.payload.to_bytes())
        self.powers.append(req)
        with self._servo_lock:
            if req.action in (PowerAction.ON, PowerAction.OFF):
                self.servo_on = req.action == PowerAction.ON
            body = PowerReply(OK, "OK", self._status_now())
        query.reply(query.key_expr, codec.encode_message(POWER_REPLY, body))

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


@pytest.fixture(scope="module")
def fake_rig() -> Iterator[tuple[LiveArm, FakePeers]]:
    with router() as (session, port):
        peers = FakePeers(session, "fake")
        try:
            with Processes() as procs:
                command = procs.start(service_argv(Service.COMMAND, port, "fake", IIWA.name, "--plan-timeout",
                                                   str(FAKE_PLAN_TIMEOUT), "--hung-after", str(FAKE_HUNG_AFTER),
                                                   client=True))
                wait_alive(session, "fake", [Service.COMMAND], timeout=60)
                yield LiveArm(session, arm="fake", proc=command), peers
        finally:
            peers.close()


@pytest.fixture
def fake(fake_rig: tuple[LiveArm, FakePeers]) -> Iterator[tuple[LiveArm, FakePeers]]:
    rig, peers = fake_rig
    peers.talking.set()
    peers.hang = False
    peers.plan_reply = (OK, "OK")
    peers.alarm = peers.moving = False
    reset(rig)
    peers.progress(queued=(), paused=False)
    peers.plans.clear()
    peers.controls.clear()
    peers.control_requests.clear()
    peers.powers.clear()
    yield rig, peers
    peers.held.clear()


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
        rig.call_ok(Interface.MIDDLE, name, args)
    rig.call_ok(Interface.EXT, OP.setBlendDistance, {"distance": 0.02})
    rig.call_ok(Interface.MIDDLE, OP.movePTPJointAbs, {"jointPoints": (0.2,) * N})
    car = CarPosWithElbow(hg_matrix(rot("x", 1.0), (0.4, 0.0, 0.5)), 0.3, 0)
    rig.call_ok(Interface.MIDDLE, OP.moveCircularCartesianAbs, {"carPointR": car, "carPointT": car})
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
    rig.call_ok(Interface.MIDDLE, OP.setSpeedJoint, {"spdRatio": 5})
    rig.call_ok(Interface.MIDDLE, OP.goHome)
    assert peers.plans[-1].settings.spdRatioJoint == 5 and peers.plans[-1].args == {}


def test_planner_refusal_is_passed_on_and_queues_nothing(fake):
    rig, peers = fake
    rig.call_ok(Interface.MIDDLE, OP.setSpeedCartesian, {"spdRatio": 10})
    peers.plan_reply = (VALUE_ERR, "target outside the Cartesian soft limits")
    car = CarPosWithElbow(hg_matrix(translation=(5.0, 0.0, 0.0)), 0.0, 0)
    r = rig.client.middle(OP.moveLinearCartesianAbs, {"carPoint": car})
    assert (r.id, r.comment) == (VALUE_ERR, "target outside the Cartesian soft limits")
    assert rig.state() == StateBit.SERVO_ON


class StateLog:
    """The ``state`` publications of a rig's command, in order, from now on."""

    def __init__(self, rig: LiveArm) -> None:
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
    rig.call_ok(Interface.MIDDLE, OP.setSpeedJoint, {"spdRatio": 50})
    move = {"jointPoints": (0.0,) * N}
    for _ in range(32):
        rig.call_ok(Interface.MIDDLE, OP.movePTPJointRel, move)
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
            rig.call_ok(Interface.MIDDLE, OP.movePTPJointRel, move)
        assert c.middle(OP.movePTPJointRel, move).id == ReturnCode.FULL_MOTION_QUEUE_ERR
        # setSoftLimitJoint is refused while motions are queued.
        r = c.common(OP.setSoftLimitJoint, {"softLimit": IIWA.hard_limits})
        assert r.id == STATUS_ERR and "queued" in r.comment, r
        # stop: forwarded; its reply empties the queue at once.
        rig.call_ok(Interface.MIDDLE, OP.stop)
        assert peers.controls[-1] == "stop"
        assert rig.state() == StateBit.SERVO_ON
    finally:
        states.close()


def test_pause_and_resume_from_the_planners_word(fake):
    rig, peers = fake
    c = rig.client
    rig.call_ok(Interface.MIDDLE, OP.setSpeedJoint, {"spdRatio": 50})
    rig.call_ok(Interface.MIDDLE, OP.movePTPJointRel, {"jointPoints": (0.1,) + (0.0,) * (N - 1)})
    motion = peers.queued[-1]
    rig.call_ok(Interface.MIDDLE, OP.pause)
    assert peers.controls == ["pause"]
    assert rig.state() == StateBit.SERVO_ON | StateBit.MOVING | StateBit.PAUSED  # from the reply
    r = c.middle(OP.pause)
    assert r.id == OK and "already paused" in r.comment and peers.controls == ["pause"]
    states = StateLog(rig)
    try:
        peers.progress(queued=(motion,), paused=False, seq=peers.seq - 1)  # published before the pause
        rig.call_ok(Interface.MIDDLE, OP.resume)
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
    rig.call_ok(Interface.COMMON, OP.servoOFF)
    assert peers.controls[-1] == "abort"


def test_a_servo_power_reply_is_the_state_at_once_and_an_older_publication_changes_nothing(fake):
    """The command takes in the status each ``Servo/power`` reply carries: ``getState`` shows servoOFF and
    servoON with the servo's publications silent, and a status made before the reply, arriving after it,
    changes nothing. Without a monitor, clearAlarms is the servo's ``clear``; the command holds no list."""
    rig, peers = fake
    peers.talking.clear()
    try:
        rig.call_ok(Interface.COMMON, OP.servoOFF)
        assert not rig.state() & StateBit.SERVO_ON
        stale = peers.status_seq  # the number of a status made before the next reply
        rig.call_ok(Interface.COMMON, OP.servoON)
        assert rig.state() & StateBit.SERVO_ON
        peers.publish_status(seq=stale, servoOn=False)  # on its way meanwhile
        peers.publish_status(moving=True)  # newer, one key, one publisher: read after the stale one
        wait_until(lambda: rig.state() & StateBit.MOVING, 0.8, what="the newer status read")
        assert rig.state() & StateBit.SERVO_ON
    finally:
        peers.talking.set()
    rig.call_ok(Interface.COMMON, OP.clearAlarms)
    assert [(p.action, p.alarms) for p in peers.powers] == [("off", NO_LIST), ("on", NO_LIST), ("clear", NO_LIST)]


def test_alarm_refuses_motions_and_set_soft_limit(fake):
    rig, peers = fake
    rig.call_ok(Interface.MIDDLE, OP.setSpeedJoint, {"spdRatio": 50})
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
    rig.call_ok(Interface.EXT, OP.setSpeedOverride, {"ratio": 30})
    assert peers.control_requests == [ControlRequest("override", 30.0)]
    assert c.ext(OP.getSpeedOverride)["ratio"] == 30.0  # from the reply's progress: no publication needed
    # 0 holds on the path: no pause (bit 0x10 clear, resume ignored), the queue untouched.
    rig.call_ok(Interface.MIDDLE, OP.setSpeedJoint, {"spdRatio": 50})
    rig.call_ok(Interface.MIDDLE, OP.goHome)
    rig.call_ok(Interface.EXT, OP.setSpeedOverride, {"ratio": 0.0})
    assert peers.control_requests[-1] == ControlRequest("override", 0.0)
    assert c.ext(OP.getSpeedOverride)["ratio"] == 0.0
    assert rig.state() == StateBit.SERVO_ON | StateBit.MOVING
    r = c.middle(OP.resume)
    assert r.id == OK and "not paused" in r.comment, r
    rig.call_ok(Interface.EXT, OP.setSpeedOverride, {"ratio": 100})
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
    rig.call_ok(Interface.MIDDLE, OP.setSpeedJoint, {"spdRatio": 50})
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
    silent = time.monotonic()  # its last status went out 10 ms before at most
    wait_until(lambda: not rig.state() & StateBit.SERVO_ON, FAKE_HUNG_AFTER + 3, 0.02, what="servo bit cleared")
    # Said off at the system's hung bound (when a monitor says 0x410), not at a silence of its own reckoning.
    assert time.monotonic() - silent > FAKE_HUNG_AFTER - 0.02
    r = rig.client.middle(OP.goHome)
    assert r.id == ReturnCode.NOT_SV_ON_ERR and "Servo/status" in r.comment, r
    peers.talking.set()
    wait_until(lambda: rig.state() & StateBit.SERVO_ON, 3, what="servo bit back")


def test_planner_gone_discards_the_queue(fake):
    rig, peers = fake
    rig.call_ok(Interface.MIDDLE, OP.setSpeedJoint, {"spdRatio": 50})
    rig.call_ok(Interface.MIDDLE, OP.goHome)
    assert rig.state() & StateBit.MOVING
    peers.planner_token.undeclare()
    try:
        wait_until(lambda: rig.state() == StateBit.SERVO_ON, 3, what="queue forgotten")
        r = rig.client.ext(OP.getSpeedOverride)  # the servo's override is known only through the planner
        assert r.id == NG and "planner" in r.comment, r
    finally:
        peers.planner_token = rig.session.liveliness().declare_token(peers.keys.alive(Service.PLANNER))
