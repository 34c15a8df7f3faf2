"""The alarm monitor's thread: every input drained, every detector run, every change published.

Zenoh only fills channels; one thread drains them every ``POLL_PERIOD`` and
owns all the state (the :class:`AlarmBook` and the detectors). Other threads
(the ``Monitor/Common`` RPC worker) hand it functions through :meth:`call`.
Every change goes out at once as an ``AlarmEvent`` on ``JARA_ARM/<arm>/alarm``
and as the new ``AlarmList`` on ``Monitor/alarms`` (and the list again every
``LIST_PERIOD``, so that a late subscriber catches up).
"""

from __future__ import annotations

import collections
import concurrent.futures
import logging
import threading
import time
from collections.abc import Callable
from typing import TypeVar

import numpy as np
import pinocchio as pin
import zenoh

from jara_arm.kinematics import Kinematics, hg_to_se3
from jara_arm.robots import RobotModel
from jara_arm.schema import messages
from jara_arm.schema.alarms import (
    ALARM_LIST,
    AlarmEventKind,
    AlarmList,
    format_code,
    make_alarm,
)
from jara_arm.schema.codes import AlarmCode
from jara_arm.schema.errors import WireError
from jara_arm.schema.keys import ArmKeys, Service
from jara_arm.schema.planner import MOTION_SETTINGS, MotionSettings
from jara_arm.schema.types import Alarm, Time
from jara_arm.services.runtime.entities import Entities
from jara_arm.services.runtime.heartbeat import Pulse, ServiceWatch
from jara_arm.services.runtime.inbox import Inbox
from jara_arm.services.runtime.presence import Change, Presence
from jara_arm.services.runtime.threads import LoopThread
from jara_arm.services.runtime.timing import MONITOR_WAIT, SAME_HOST, Health
from jara_arm.services.runtime.wire import Publication, decode_sample

from .book import AlarmBook
from .detectors import (
    CARTESIAN_LIMIT_TOLERANCE,
    HUNG_CODE,
    JOINT_LIMIT_TOLERANCE,
    LOST_CODE,
    OVERLOAD_MARGIN,
    OVERLOAD_SAMPLES,
    OVERSPEED_MARGIN,
    OVERSPEED_SAMPLES,
    AboveRating,
    Crossing,
)
from .reactions import Reactions

log = logging.getLogger(__name__)
T = TypeVar("T")

LIST_PERIOD = 0.5  #: [s] the AlarmList is published at least this often (2 Hz)
_STALL_LOG_EVERY = 10.0  #: [s] at most one warning about the monitor's own pauses this often
_AXES = "XYZ"


class Monitor:
    """Owner of one arm's active alarms (see the module docstring)."""

    def __init__(self, session: zenoh.Session, keys: ArmKeys, robot: RobotModel,
                 pulse: Pulse | None = None, health: Health = SAME_HOST) -> None:
        self.robot = robot
        self.health = health
        self._pulse = pulse or Pulse("the alarm monitor loop", health.hung_after)
        self.keys = keys
        self.started = Time.now()
        self.book = AlarmBook()
        self._last_tm_ns = 0
        n = robot.axis_num
        self._unit = ["m" if p else "rad" for p in robot.prismatic]
        self._effort_unit = ["N" if p else "N m" for p in robot.prismatic]
        self._overload = AboveRating(robot.rated_effort, OVERLOAD_MARGIN, OVERLOAD_SAMPLES)
        speeds = list(robot.rated_speed) + ([robot.gripper_speed] if robot.has_gripper else [])
        self._overspeed = AboveRating(speeds, OVERSPEED_MARGIN, OVERSPEED_SAMPLES)
        self._joint = Crossing(JOINT_LIMIT_TOLERANCE)
        self._cartesian = Crossing(CARTESIAN_LIMIT_TOLERANCE)
        self._kinematics = Kinematics(robot, seed_table=0)  # FK only
        self._settings: MotionSettings | None = None
        self._judged: tuple[object, ...] | None = None  # the (joints, limits, settings) judged last
        self._servo_status: messages.ServoStatus | None = None  # the newest heard
        self._settings_seq = 0  # counts MotionSettings received
        self._base = pin.SE3.Identity()  # B: robot frame seen from the arm frame
        self._tool = np.zeros(3)  # [m] control point in the flange frame (translation of C)
        self._n = n
        self.watches = {s: ServiceWatch(s, health) for s in (Service.SERVO, Service.PLANNER, Service.COMMAND)}
        self._entities = Entities()
        enter = self._entities.enter_context
        inbox = self._inbox = Inbox()
        self._estop, self._status, self._settings_sub = inbox.box(64), inbox.box(256), inbox.box(1)
        enter(session.declare_subscriber(keys.estop, self._estop))
        # Not its own heartbeat: 10 wakes a second for nothing.
        self._presence = enter(Presence(session, keys, self.watches, inbox))
        # Servo/status (100 Hz) carries the servo's latched alarms and the measured joints: Servo/posFeedback
        # (1 kHz) would cost the monitor and the router ten times the work for no alarm sooner than 10 ms.
        enter(session.declare_subscriber(keys.servo_status, self._status))
        enter(session.declare_subscriber(keys.command_settings, self._settings_sub))
        self._event_pub = enter(Publication(session, keys.alarm))
        self._list_pub = enter(Publication(session, keys.monitor_alarms))
        self._reactions = Reactions(session, keys)
        self._calls: collections.deque[tuple[Callable[[], object], concurrent.futures.Future]] = \
            collections.deque()
        self._dirty = True
        self._list_at = -float("inf")
        self._judge_after = 0.0  # [s] monotonic: staleness is judged from then on
        self._loop = LoopThread(self._run, "alarm-monitor", wake=inbox.ring)

    # -- life cycle ---------------------------------------------------------------
    def take_over(self, held: AlarmList | None) -> None:
        """Before :meth:`start`: the alarms an earlier monitor of this arm left active.

        ``held`` is the list the servo holds (``Monitor/copy``): a monitor restarted while the arm was stopped by a
        FAULT keeps it listed, and ``clearAlarms`` judges its cause as usual.
        """
        if held is None or held.started == self.started or not held.alarms:
            return
        for alarm in held.alarms:
            self.book.raise_alarm(alarm)
        log.warning("took over %d active alarms from the previous alarm monitor: %s", len(held.alarms),
                    ", ".join(f"{format_code(a.code)} {a.description}" for a in held.alarms))

    def start(self) -> None:
        self._loop.start()

    @property
    def alive(self) -> bool:
        return self._loop.alive

    def stop(self) -> None:
        self._loop.stop()
        self._reactions.close()
        self._entities.close()

    def call(self, fn: Callable[[], T], timeout: float = 2.0) -> T:
        """Run ``fn`` on the monitor thread once the pending inputs are drained; its result."""
        fut: concurrent.futures.Future = concurrent.futures.Future()
        self._calls.append((fn, fut))
        self._inbox.ring()
        return fut.result(timeout=timeout)

    # -- the loop -----------------------------------------------------------------
    def _run(self, stop: threading.Event) -> None:
        last = time.monotonic()
        stall_logged = -float("inf")
        while not stop.is_set():
            self._inbox.wait(MONITOR_WAIT)  # no spacing: an e-stop right after a heartbeat is taken at once
            self._pulse.beat()
            now = time.monotonic()
            if now - last > self.health.stall_after:
                if now - stall_logged >= _STALL_LOG_EVERY:
                    log.warning("the alarm monitor itself paused %.0f ms (staleness not judged meanwhile)",
                                (now - last) * 1e3)
                    stall_logged = now
                # Its own pause: the beats still in Zenoh's queues come first, then silences count.
                self._judge_after = now + self.health.heartbeat_period
            last = now
            try:
                self._iterate(now)
            except Exception:  # a bug must not end the monitoring: log it, go on
                log.exception("alarm monitor iteration failed")

    def _iterate(self, now: float) -> None:
        if self._estop.try_recv() is not None:
            while self._estop.try_recv() is not None:
                pass
            log.error("emergency stop")
            self._raise(AlarmCode.EMERGENCY_STOP, f"emergency stop: a put on {self.keys.estop}")
        self._take_presence(now)
        while (s := self._status.try_recv()) is not None:
            # Working through a backlog (its CPU share was short for a while) is progress, not a hang.
            self._pulse.beat()
            try:
                self._on_status(decode_sample(messages.SERVO_STATUS, s))
            except WireError as exc:
                log.error("ignored a malformed servo status: %s", exc)
        if (s := self._settings_sub.try_recv()) is not None:
            try:
                self._on_settings(decode_sample(MOTION_SETTINGS, s))
            except WireError as exc:
                log.error("ignored malformed command settings: %s", exc)
        if now >= self._judge_after:
            self._judge_staleness(now)
        while self._calls:
            fn, fut = self._calls.popleft()
            try:
                fut.set_result(fn())
            except Exception as exc:
                fut.set_exception(exc)
        if self._dirty or now - self._list_at >= LIST_PERIOD:
            self._list_pub.put_message(ALARM_LIST, self.alarm_list())
            self._dirty = False
            self._list_at = now

    # -- detectors ----------------------------------------------------------------
    def _take_presence(self, now: float) -> None:
        for event in self._presence.drain(now):
            name = event.watch.service.value
            if event.change is Change.LEFT:  # shut down in order (a launcher that stops, an operator)
                log.warning("the %s service stopped: it shut down in order", name)
            elif event.change is Change.LOST:
                self._raise(LOST_CODE[event.watch.service], f"the {name} service is gone: its liveliness "
                            "token was deleted (process ended or unreachable)")
            elif event.change is Change.UP:
                log.info("the %s service is up", name)
            elif event.change is Change.STALL:
                log.warning(event.watch.stall_line(event.gap))
            else:
                log.error("ignored a malformed heartbeat of the %s: %s", name, event.error)

    def _judge_staleness(self, now: float) -> None:
        for service, watch in self.watches.items():
            code = HUNG_CODE[service]
            if code in self.book or not watch.hung(now):
                if (line := watch.evidence_line(now)) is not None:
                    log.warning(line)
                continue
            why = watch.why_hung(now)
            self._raise(code, f"the {service.value} service hangs while its liveliness token is up: {why}")

    def _on_status(self, st: messages.ServoStatus) -> None:
        last = self._servo_status
        if not messages.is_newer(st, last):
            return  # made before the one already heard (a servo process before this one)
        self._servo_status = st
        if last is not None and st.started != last.started:
            for latch in last.latches:  # the status of a new process says nothing of the old one's latches
                if latch.present and latch.alarm.code in self.book:
                    log.info("alarm %s: its cause as the servo before this one saw it is void (the servo "
                             "restarted); a clear decides on the new servo's status", format_code(latch.alarm.code))
        for alarm in self.book.adopt(st.latches):
            self._raised(alarm, "latched by the servo")
        if st.softLimitJoint:
            self._joint.set_limits(st.softLimitJoint)
        axis = self._overload.update(st.effort)
        if axis is not None:
            u = self._effort_unit[axis]
            self._raise(AlarmCode.OVERLOAD, f"J{axis + 1} effort {abs(st.effort[axis]):.4g} {u} is above "
                        f"{OVERLOAD_MARGIN:g} x its rating {self.robot.rated_effort[axis]:.4g} {u} for "
                        f"{OVERLOAD_SAMPLES} samples: pushing against an obstacle?")
        axis = self._overspeed.update(st.vel)
        if axis is not None:
            u = self._unit[axis] if axis < self._n else "m"
            rated = self._overspeed.threshold[axis] / OVERSPEED_MARGIN
            self._raise(AlarmCode.OVERSPEED, f"J{axis + 1} measured speed {abs(st.vel[axis]):.4g} {u}/s is "
                        f"above {OVERSPEED_MARGIN:g} x its rated {rated:.4g} {u}/s")
        # A servo at rest repeats the same joints: judged once per joints, limits and frames
        # (forward kinematics 100 times a second for an arm that stands still is most of an
        # idle monitor's work).
        judged = (st.pos, st.softLimitJoint, self._settings_seq)
        if st.pos and judged != self._judged:
            self._judged = judged
            self._on_position(st.pos)

    def _on_position(self, pos: tuple[float, ...]) -> None:
        axis = self._joint.update(pos)
        if axis is not None:
            lim, u = self._joint.limit(axis), self._unit[axis]
            self._raise(AlarmCode.SOFT_LIMIT_JOINT, f"J{axis + 1} = {pos[axis]:.6g} {u} crossed its joint "
                        f"soft limit [{lim.lower:.6g}, {lim.upper:.6g}] {u} (measured, during motion)")
        if self._settings is None or not self._cartesian.armed:
            return
        # Control point in the robot frame: inv(B) · T_flange(q) · C (its position only).
        flange = self._kinematics.fk(np.asarray(pos[: self._n], dtype=float))
        p = self._base.actInv(flange.act(self._tool))
        axis = self._cartesian.update(p)
        if axis is not None:
            lim = self._cartesian.limit(axis)
            self._raise(AlarmCode.SOFT_LIMIT_CARTESIAN, f"the control point crossed the Cartesian soft "
                        f"limit: {_AXES[axis].lower()} = {p[axis]:.4g} m outside "
                        f"[{lim.lower:.4g}, {lim.upper:.4g}] m (robot frame, during motion)")

    def _on_settings(self, s: MotionSettings) -> None:
        old = self._settings
        self._settings = s
        self._settings_seq += 1
        if old is None or not (np.array_equal(old.baseOffset, s.baseOffset)
                               and np.array_equal(old.controlPointOffset, s.controlPointOffset)):
            self._base = hg_to_se3(s.baseOffset)
            self._tool = hg_to_se3(s.controlPointOffset).translation.copy()
            self._cartesian.reset()  # new frames: the next sample only says where the arm is
        self._cartesian.set_limits(s.softLimitCartesian)

    def detected(self, code: int) -> bool:
        """Whether the monitor's own detectors see the cause of ``code`` now."""
        if code == AlarmCode.OVERLOAD:
            return self._overload.present
        if code == AlarmCode.OVERSPEED:
            return self._overspeed.present
        if code == AlarmCode.SOFT_LIMIT_JOINT:
            return self._joint.present
        if code == AlarmCode.SOFT_LIMIT_CARTESIAN:
            return self._cartesian.present
        for service, watch in self.watches.items():
            if code == LOST_CODE[service]:
                return not watch.alive
            if code == HUNG_CODE[service]:
                return watch.hung(time.monotonic())
        return False  # emergency stop: a put is an event, gone once acknowledged

    # -- the list -------------------------------------------------------------------
    def _raise(self, code: AlarmCode, description: str) -> None:
        alarm = make_alarm(code, description)
        if self.book.raise_alarm(alarm):
            self._raised(alarm, "detected by the alarm monitor")

    def _raised(self, alarm: Alarm, how: str) -> None:
        log.error("alarm %s %s raised (%s): %s", format_code(alarm.code), alarm.type.value, how,
                  alarm.description)
        self._publish_event(AlarmEventKind.RAISED, alarm)
        self._reactions.react(alarm)

    def clear_now(self) -> tuple[list[Alarm], list[Alarm]]:
        """``clearAlarms``: clear what has no cause any more; (cleared, kept)."""
        cleared, kept = self.book.clear(self.detected)
        for alarm in cleared:
            log.info("alarm %s cleared: %s", format_code(alarm.code), alarm.description)
            self._publish_event(AlarmEventKind.CLEARED, alarm)
        for alarm in kept:
            log.info("alarm %s kept: its cause is still present", format_code(alarm.code))
        if cleared:  # the list first, so that the caller's next reads already see it
            self._list_pub.put_message(ALARM_LIST, self.alarm_list())
            self._list_at = time.monotonic()
        return cleared, kept

    def _publish_event(self, kind: AlarmEventKind, alarm: Alarm) -> None:
        self._event_pub.put_message(messages.ALARM_EVENT, messages.AlarmEvent(kind.value, alarm))
        self._dirty = True

    def alarm_list(self) -> AlarmList:
        """The list now; ``tm`` strictly increases, so that a newer list always compares newer."""
        ns = max(time.time_ns(), self._last_tm_ns + 1)
        self._last_tm_ns = ns
        return AlarmList(Time.from_ns(ns), self.started, self.book.alarms)
