"""The servo loop of one arm: one position command per cycle from the SyncFIFO, one PyBullet step.

Its cycles run on the process's :class:`~.clock.ServoClock` thread (one thread
for every arm of the process), the only code that touches the world. Other
threads change its state only through :meth:`ServoLoop.call`, which runs a
function at the arm's next cycle; reads use the values the loop publishes
every cycle (assigning a Python attribute is atomic).

Alarms: the alarm monitor owns the arm's list (``schema/alarms.py``). What the
servo detects itself (an e-stop put, a command that jumps or leaves the joint
soft limits) it acts on in the same cycle and keeps as a *latch*, reported to
the monitor on ``Monitor/report`` (again when its cause has gone, and again
every ``REPORT_AGAIN`` until the monitor lists it). The servo follows the
monitor's ``Monitor/alarms``: an alarm that appears there stops the arm (a
FAULT also switches the servo off), and a latch is released once the monitor
that listed it no longer does. While any latch or any listed alarm is active,
position commands are dropped.
"""

from __future__ import annotations

import collections
import concurrent.futures
import dataclasses
import logging
import time
from collections.abc import Callable
from typing import Any, TypeVar

import numpy as np
import zenoh

from jara_arm.robots import Obstacle, RobotModel
from jara_arm.schema import codec, messages
from jara_arm.schema import wire_types as w
from jara_arm.schema.alarms import ALARM_LIST, ALARM_REPORT, HEARTBEAT, AlarmList, AlarmReport, format_code
from jara_arm.schema.codes import AlarmCode, AlarmType, StateBit
from jara_arm.schema.errors import WireError
from jara_arm.schema.keys import ArmKeys, Service
from jara_arm.schema.types import Alarm, LimitValue, Time
from jara_arm.services.runtime.monitor_link import AlarmListCopy, is_newer
from jara_arm.services.runtime.heartbeat import Pulse, ServiceWatch
from jara_arm.services.runtime.timing import (HEALTH_EVERY, SAME_HOST, STATUS_EVERY,
                                              STATUS_EVERY_AT_REST, UNDERRUN_GRACE, Health)

from .braking import Braking, Glide
from .world import World

log = logging.getLogger(__name__)
T = TypeVar("T")

#: A command may ask for at most this multiple of an axis' rated speed [-];
#: beyond it the stream is taken as a jump: OVERSPEED fault, controlled stop.
OVERSPEED_MARGIN = 1.1
#: Jerk of a controlled stop: full deceleration is reached in this time [s].
BRAKE_JERK_TIME = 0.02
#: Below this speed an axis counts as at rest [rad/s or m/s].
REST_SPEED = 1e-3
#: At rest this many cycles in a row (nothing commanded, every axis below REST_SPEED), the
#: world is held as it is instead of stepped [cycles]: the brakes or the holding drives keep
#: the arm still, and a step costs a third of an idle servo's CPU. Any command, stop or
#: servo change steps it again in the same cycle.
SETTLED_CYCLES = 100
#: Tracking tolerance when deciding that a soft-limit cause has gone [rad or m].
LIMIT_TOLERANCE = 1e-3
#: A stop in front of a joint soft limit may decelerate at up to this multiple of an
#: axis' max_accel (rated speed / min accel time) [-]: the peak deceleration of the
#: planner's S-curve at the min accel time (2 v / T), so that a planned motion that
#: ends on a limit is never taken for one that would overrun it.
LIMIT_STOP_ACCEL = 2.0
#: After the stream ran dry, a command this close to the held target counts as starting
#: from rest there (e.g. a client that starts from the measured joints) [rad or m].
RESUME_TOLERANCE = 1e-4
#: Slack of the "stops before the soft limit" check, for rounding only [rad or m].
_LIMIT_EPS = 1e-9
#: A latch the alarm monitor has not listed yet is reported again this often [s]
#: (the monitor was down or restarted and lost it).
REPORT_AGAIN = 0.5
#: After a stop for an alarm, a target this far from the measured joints means the
#: arm is blocked (an obstacle): the servo then holds it where it is, not pushing on [rad or m].
RELAX_TOLERANCE = 0.01
#: ... bringing the target there in this time, so that the push fades rather than drops [s].
RELAX_TIME = 0.2


_SERVO_ON, _MOVING, _ALARM = int(StateBit.SERVO_ON), int(StateBit.MOVING), int(StateBit.ALARM)


@dataclasses.dataclass
class _Latch:
    """An alarm the servo detected itself; it keeps the arm stopped until the monitor clears it."""

    alarm: Alarm
    present: bool  # the cause was present when last reported
    acked: Time | None = None  # ``started`` of the monitor whose list held it; None: not listed yet
    reported_at: float = -float("inf")  # [s] monotonic time of the last report


@dataclasses.dataclass
class _Stats:
    """Timing of the current health window."""

    lateness: list[float] = dataclasses.field(default_factory=list)
    overruns: int = 0
    underruns: int = 0
    late: int = 0
    waits: int = 0  # times the loop, behind schedule, waited for commands instead of running dry


class ServoLoop:
    """The low-level controller of one arm (see module docstring)."""

    def __init__(self, model: RobotModel, session: zenoh.Session, keys: ArmKeys,
                 obstacles: tuple[Obstacle, ...] = (), pulse: Pulse | None = None,
                 health: Health = SAME_HOST) -> None:
        self.model = model
        self.arm = keys.arm
        # Records name their arm: one servo process may run several (logs.ZenohLogHandler).
        self._log = logging.LoggerAdapter(log, {"arm": keys.arm})
        self.health = health
        self._pulse = pulse or Pulse("the servo loop", health.hung_after)
        self.dt = model.cmd_cycle
        self.world = World(model, obstacles)
        n = model.dof
        self._vmax = np.array(list(model.rated_speed) + ([model.gripper_speed] if model.has_gripper else []))
        min_acc_t = model.min_accel_time
        self._amax = self._vmax / min_acc_t
        self._jmax = self._amax / BRAKE_JERK_TIME
        self._limit_amax = self._amax * LIMIT_STOP_ACCEL
        self._limit_jmax = self._limit_amax / BRAKE_JERK_TIME
        self._step_max = self._vmax * self.dt * OVERSPEED_MARGIN  # [rad or m] per cycle
        self._per_cycle = 1.0 / self.dt  # [1/s]
        # Stopping distance bound (_overruns_soft_limit) = (v + a·T)·((v + a·T)/(2a) + 2T).
        arm_amax = self._limit_amax[:model.axis_num]
        self._reach_at = arm_amax * BRAKE_JERK_TIME
        self._reach_half_inv_a = 0.5 / arm_amax
        grip = model.gripper_limits
        self._hard = list(model.hard_limits) + ([grip] if grip else [])
        self.soft_limits = model.hard_limits

        pos, vel, eff = self.world.read()
        self.q, self.qd, self.qdd = pos.copy(), np.zeros(n), np.zeros(n)
        # What other threads read (replaced, never mutated, by the loop).
        self.fb_pos, self.fb_vel, self.fb_eff = pos, vel, eff
        self.state_bits = 0
        self.servo_on = False
        self.latches: dict[int, _Latch] = {}  # by code: what the servo detected itself
        self.monitor_alarms: tuple[Alarm, ...] = ()  # the alarm monitor's newest list
        self._monitor_list: AlarmList | None = None

        self._fifo: collections.deque[np.ndarray] = collections.deque()
        self._braking: Braking | Glide | None = None  # a stop, or letting go of a push
        self._interrupted = False  # the stream ran dry mid-motion; wait for a consistent command
        self._cmd_moving = False  # the commanded velocity qd is not all zero
        self._late_cycles = 0  # consecutive cycles waited for a command mid-motion
        self._still_for = 0  # consecutive cycles at rest (see SETTLED_CYCLES)
        self._status_k = -STATUS_EVERY_AT_REST  # cycle of the last ServoStatus
        self._status_said: tuple[object, ...] = ()  # what it said besides the measured values
        self._status_q: np.ndarray | None = None  # the target it said
        self._vel_list: list[float] = vel.tolist()
        self._pos_list: list[float] = pos.tolist()
        self._calls: collections.deque[tuple[Callable[[], Any], concurrent.futures.Future]] = collections.deque()
        self.received = self.consumed = self.underruns = self.dropped = 0

        self._cmd_sub = session.declare_subscriber(keys.pos_cmd, zenoh.handlers.FifoChannel(1 << 16))
        self._block_sub = session.declare_subscriber(keys.pos_block, zenoh.handlers.FifoChannel(1 << 12))
        self._estop_sub = session.declare_subscriber(keys.estop, zenoh.handlers.FifoChannel(64))
        self._alarms_sub = session.declare_subscriber(keys.monitor_alarms, zenoh.handlers.FifoChannel(256))
        self._alarm_copy = AlarmListCopy(session, keys, Service.SERVO)
        # The servo watches the alarm monitor (nobody else can): without it nothing watches
        # overload, overspeed, the Cartesian box or the other services.
        self._monitor_token = session.liveliness().declare_subscriber(
            keys.alive(Service.ALARM_MONITOR), zenoh.handlers.FifoChannel(64), history=True)
        self._monitor_beats = session.declare_subscriber(keys.heartbeat(Service.ALARM_MONITOR),
                                                         zenoh.handlers.RingChannel(1))
        self._monitor_watch = ServiceWatch(Service.ALARM_MONITOR, health)
        self._watched_at = time.monotonic()  # [s] the previous _watch_monitor
        self._judge_monitor_after = 0.0  # [s] monotonic: the monitor's silence counts from then on
        self._report_pub = session.declare_publisher(keys.monitor_report, express=True)
        self._fb_pub = session.declare_publisher(keys.pos_feedback, express=True)
        # The 1 kHz feedback is encoded only while someone subscribes (none of our services do).
        self._fb_matching = self._fb_pub.declare_matching_listener(zenoh.handlers.FifoChannel(64))
        self._fb_wanted = self._fb_pub.matching_status.matching
        self._status_pub = session.declare_publisher(keys.servo_status, express=True)
        self._health_pub = session.declare_publisher(keys.servo_health)
        self._stats = _Stats()
        self._period_ns = model.cmd_cycle_ms * 1_000_000
        self._tm_ns = 0  # [ns] wall-clock time the newest feedback sample stands for
        self._cycles = 0
        self._window_start = time.monotonic()

    # -- life cycle ---------------------------------------------------------------
    def close(self) -> None:
        """Undeclare everything; call it once the clock has stopped."""
        self._alarm_copy.close()
        for entity in (self._fb_matching, self._monitor_token, self._monitor_beats, self._cmd_sub, self._block_sub, self._estop_sub,
                       self._alarms_sub, self._report_pub, self._fb_pub,
                       self._status_pub, self._health_pub):
            try:
                entity.undeclare()
            except Exception:
                pass
        self.world.close()

    @property
    def soft_limits(self) -> tuple[LimitValue, ...]:
        """[rad or m] the joint soft limits in force, one per arm axis."""
        return self._soft_limits

    @soft_limits.setter
    def soft_limits(self, limits: tuple[LimitValue, ...]) -> None:
        # Kept as arrays too: the loop checks every command against them.
        self._soft_lower = np.array([lim.lower for lim in limits])
        self._soft_upper = np.array([lim.upper for lim in limits])
        self._soft_limits = limits
        # The same bounds for a whole command; the gripper axis is clamped, not checked.
        free = [np.inf] * (self.model.dof - len(limits))
        self._cmd_lower = np.array([lim.lower for lim in limits] + [-x for x in free])
        self._cmd_upper = np.array([lim.upper for lim in limits] + free)

    @property
    def alarmed(self) -> bool:
        """A latch or an alarm listed by the monitor is active: the arm must not move."""
        return bool(self.latches or self.monitor_alarms)

    @property
    def alarms(self) -> tuple[Alarm, ...]:
        """The servo's own latches (what ``getActiveAlarm`` says when the monitor is silent)."""
        return tuple(latch.alarm for latch in list(self.latches.values()))

    def call(self, fn: Callable[[], T], timeout: float = 1.0) -> T:
        """Run ``fn`` on the clock's thread at this arm's next cycle and return its result."""
        fut: concurrent.futures.Future = concurrent.futures.Future()
        self._calls.append((fn, fut))
        return fut.result(timeout=timeout)

    # -- the cycle, driven by the process's ServoClock (clock.py) ---------------------
    def begin(self, deadline_wall_ns: int, phase: float = 0.0) -> None:
        """Before the first :meth:`tick`: the wall-clock time of the first cycle's deadline [ns];
        ``phase`` in [0, 1) shifts this arm's status and health messages within their periods,
        so that the arms of one clock do not all publish in the same cycle."""
        # A sample's tm is the time its cycle stands for: one period after the previous
        # sample while the arm moves (simulated time; the clock may catch up, the arm may
        # wait), the cycle's wall-clock deadline again once it is at rest.
        self._tm_ns = deadline_wall_ns - self._period_ns
        self._window_start = time.monotonic() - phase * HEALTH_EVERY
        self._status_k = -STATUS_EVERY_AT_REST + int(phase * STATUS_EVERY)

    def tick(self, deadline_wall_ns: int, deadline_ns: int, behind: bool) -> bool:
        """This arm's cycle due at ``deadline_ns`` (monotonic) / ``deadline_wall_ns`` (wall);
        ``behind``: the clock runs more than a period late. False if the arm waited for a late
        command instead (simulated time stands still; nothing was stepped or published)."""
        self._pulse.beat()
        start = time.monotonic_ns()
        period = self._period_ns
        at_rest = not self._cmd_moving and not self._fifo
        tm_ns = max(self._tm_ns + period, deadline_wall_ns) if at_rest else self._tm_ns + period
        if not self._cycle(self._cycles, tm_ns, behind=behind):
            self._stats.waits += 1
            return False
        self._tm_ns = tm_ns
        done = time.monotonic_ns()
        st = self._stats
        lateness = (start - deadline_ns) * 1e-9
        st.lateness.append(lateness)
        if lateness > self.dt:
            st.late += 1
        if done - start > period:
            st.overruns += 1
        self._cycles += 1
        if time.monotonic() - self._window_start >= HEALTH_EVERY:
            self._publish_health()
            self._window_start = time.monotonic()
        return True

    def _cycle(self, k: int, tm_ns: int, behind: bool = False) -> bool:
        """One servo cycle; False (nothing done) mid-motion with an empty FIFO while ``behind``
        schedule (the commands were not sent yet, not lost) or within ``UNDERRUN_GRACE``."""
        if self._estop_sub.try_recv() is not None:
            while self._estop_sub.try_recv() is not None:
                pass
            self.emergency_stop()
        while (sample := self._alarms_sub.try_recv()) is not None:
            try:
                self.adopt_monitor_list(codec.decode_message(ALARM_LIST, sample.payload.to_bytes()))
            except WireError as exc:
                self._log.error("ignored a malformed alarm list from the monitor: %s", exc)
        self._alarm_copy.answer(self._alarm_list_held)
        self._watch_monitor()
        while self._calls:
            fn, fut = self._calls.popleft()
            try:
                fut.set_result(fn())
            except Exception as exc:
                fut.set_exception(exc)
        self._take_commands()
        if (not self._fifo and self._cmd_moving and self._braking is None
                and self.servo_on and not self.alarmed):
            if behind or self._late_cycles < UNDERRUN_GRACE:
                self._late_cycles += 1
                return False
        else:
            self._late_cycles = 0
        self._advance()
        settled = not (self._still_for < SETTLED_CYCLES or self._braking is not None or self._fifo
                       or self._cmd_moving)
        if not settled:
            self.world.command(self.q, self.qd)
            self.world.step()
            pos, vel, eff = self.world.read()
            self.fb_pos, self.fb_vel, self.fb_eff = pos, vel, eff
            self._pos_list, self._vel_list = pos.tolist(), vel.tolist()
            self.state_bits = self._bits(self._vel_list)
            self._still_for = 0 if self.state_bits & _MOVING else self._still_for + 1
        else:  # settled: the world is held as it is (SETTLED_CYCLES)
            self.state_bits = self._bits(self._vel_list)
        while (matching := self._fb_matching.try_recv()) is not None:
            self._fb_wanted = matching.matching
        if self._fb_wanted:
            self._fb_pub.put(messages.timed_joint_pos_payload(tm_ns, self._pos_list))
        if self.latches:  # every cycle: the monitor learns at once that a cause has gone
            self._report_latches()
        if (k - self._status_k >= (STATUS_EVERY_AT_REST if settled else STATUS_EVERY)
                or (settled and self._status_changed())):  # moving: the FIFO changes every cycle
            self._status_k = k
            self._publish_status(Time(tm_ns // 1_000_000_000, tm_ns % 1_000_000_000))
        return True

    def _take_commands(self) -> None:
        """Move what arrived into the FIFO (or drop it while commands are not accepted)."""
        accepting = self.servo_on and not self.alarmed
        while (sample := self._cmd_sub.try_recv()) is not None:
            self.received += 1
            if not accepting:
                self.dropped += 1
                continue
            try:
                msg = codec.decode_message(w.TIMED_JOINT_POS, sample.payload.to_bytes())
                if len(msg.pos) != self.model.dof:
                    raise WireError("pos", f"expected {self.model.dof} axes, got {len(msg.pos)}")
            except WireError as exc:
                self.dropped += 1
                self._log.warning("dropped a malformed position command: %s", exc)
                continue
            self._fifo.append(np.array(msg.pos))
        while (sample := self._block_sub.try_recv()) is not None:
            try:
                rows = messages.position_block_rows(sample.payload.to_bytes(), self.model.dof)
            except WireError as exc:
                self.dropped += 1
                self._log.warning("dropped a malformed position block: %s", exc)
                continue
            self.received += len(rows)
            if not accepting:
                self.dropped += len(rows)
                continue
            self._fifo.extend(rows)

    def _advance(self) -> None:
        """Choose this cycle's target: brake, follow the FIFO, or hold."""
        if self._braking is not None:
            q, self.qd, self.qdd, done = self._braking.next()
            self.q = self._inside_soft_limits(q)
            self._cmd_moving = not done
            if done:
                self._braking = None
                if self.alarmed:
                    self._hold_where_it_is()
            return
        if self.servo_on and not self.alarmed and self._fifo:
            cmd = self._fifo.popleft()
            self.consumed += 1
            self._follow(cmd)
            if self._braking is not None:  # the command was refused: the stop starts this cycle,
                self._advance()  # not one cycle later with the target standing still (a jerk)
            return
        if self._cmd_moving and self.servo_on and not self.alarmed and np.any(np.abs(self.qd) > REST_SPEED):
            self.underruns += 1
            self._stats.underruns += 1
            self._interrupted = True
            self._log.warning("position commands ran dry while moving: controlled stop")
            self.brake()
            self._advance()
            return
        if self._cmd_moving:
            self.qd = np.zeros_like(self.qd)
            self.qdd = np.zeros_like(self.qdd)
            self._cmd_moving = False

    def _hold_where_it_is(self) -> None:
        """After a stop for an alarm: if the arm did not follow (blocked), hold it where it is.

        Otherwise the drives would keep pushing the arm into whatever stopped it
        (at up to their peak effort) and an overload could never go away. The
        target glides to where the arm already is in ``RELAX_TIME``, so nothing
        moves and the push fades. The gripper axis keeps its target: it may be
        holding a part.
        """
        n = self.model.axis_num
        gap = np.abs(self.q[:n] - self.fb_pos[:n])
        if np.any(gap > RELAX_TOLERANCE):
            i = int(np.argmax(gap))
            self._log.warning("the arm stopped %.3g away from its target (J%d): blocked; holding it where it is",
                        gap[i], i + 1)
            target = self.q.copy()
            target[:n] = self.fb_pos[:n]
            self._braking = Glide(self.q, target, RELAX_TIME, self.dt)

    def _inside_soft_limits(self, q: np.ndarray) -> np.ndarray:
        """``q`` with the arm axes clamped into the soft limits.

        A stop that starts next to a limit may not be able to end before it;
        the limit wins over smoothness there, as it is the last line of defence.
        """
        for i, lim in enumerate(self.soft_limits):
            if q[i] > lim.upper or q[i] < lim.lower:
                q[i] = min(max(q[i], lim.lower), lim.upper)
        return q

    def _follow(self, cmd: np.ndarray) -> None:
        step = cmd - self.q
        if not self._interrupted and ((cmd >= self._cmd_lower) & (cmd <= self._cmd_upper)
                                      & (np.abs(step) <= self._step_max)).all():
            # Every check below passes (a NaN fails every comparison): the usual command, in
            # a fraction of the work. Only the stop before a soft limit is left to check.
            if self.model.has_gripper:
                axis = self.model.axis_num
                g = self._hard[axis]
                cmd[axis] = min(max(cmd[axis], g.lower), g.upper)
            self._apply(cmd, step)
            return
        too_fast = np.abs(step) > self._step_max
        if self._interrupted:
            # After a stop for a stream that ran dry, only a stream that starts again from
            # rest where the arm stopped is followed: joining a moving stream halfway would
            # step the velocity from zero to the stream's in one cycle.
            if np.any(np.abs(step) > RESUME_TOLERANCE):
                self.dropped += 1  # stale commands of the interrupted stream
                return
            self._interrupted = False
        if not np.all(np.isfinite(cmd)):
            self._raise(AlarmCode.OVERSPEED, AlarmType.FAULT, "non-finite position command")
            return
        axis = self.model.axis_num
        outside = (cmd[:axis] < self._soft_lower) | (cmd[:axis] > self._soft_upper)
        if outside.any():
            i = int(np.argmax(outside))
            lim = self.soft_limits[i]
            self._raise(AlarmCode.SOFT_LIMIT_JOINT, AlarmType.WARNING,
                        f"position command J{i + 1}={cmd[i]:.6g} outside the joint soft limit "
                        f"[{lim.lower:.6g}, {lim.upper:.6g}]; not applied")
            return
        if self.model.has_gripper:
            g = self._hard[axis]
            cmd[axis] = min(max(cmd[axis], g.lower), g.upper)
        if too_fast.any():
            i = int(np.argmax(np.abs(step) / (self._vmax * self.dt)))
            self._raise(AlarmCode.OVERSPEED, AlarmType.FAULT,
                        f"position command asks J{i + 1} for {abs(step[i]) / self.dt:.3g} per s, "
                        f"above {OVERSPEED_MARGIN:g} x its rated {self._vmax[i]:.3g}; not applied")
            return
        self._apply(cmd, step)

    def _apply(self, cmd: np.ndarray, step: np.ndarray) -> None:
        """Follow ``cmd``, which passed every check but the stop before a soft limit."""
        qd = step * self._per_cycle
        qdd = (qd - self.qd) * self._per_cycle
        i = self._overruns_soft_limit(cmd, qd, qdd)
        if i is not None:
            lim = self.soft_limits[i]
            self._raise(AlarmCode.SOFT_LIMIT_JOINT, AlarmType.WARNING,
                        f"position command J{i + 1}={cmd[i]:.6g} at {qd[i]:.3g} per s could not stop "
                        f"before the joint soft limit [{lim.lower:.6g}, {lim.upper:.6g}]; not applied")
            return
        self.q, self.qd, self.qdd = cmd, qd, qdd
        self._cmd_moving = True

    def _limit_stop(self, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> Braking:
        """The shortest stop of every axis (see LIMIT_STOP_ACCEL), not synchronized."""
        return Braking(q, qd, qdd, self._limit_amax, self._limit_jmax, self.dt, synchronized=False)

    def _overruns_soft_limit(self, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> int | None:
        """The first arm axis whose shortest stop from (q, qd, qdd) would leave its soft limit.

        Checked for every command, so that the stop from the last applied one
        always ends inside: a stream heading through a limit is stopped in
        front of it, smoothly. The exact stop (Ruckig) is computed only for the
        axes a cheap upper bound of the stopping distance brings near a limit.
        """
        n = self.model.axis_num
        lower, upper = self._soft_lower, self._soft_upper
        va = np.abs(qd[:n]) + self._reach_at
        reach = va * (va * self._reach_half_inv_a + 2 * BRAKE_JERK_TIME)
        qn = q[:n]
        if not ((qn + reach > upper) | (qn - reach < lower)).any():
            return None
        near = np.flatnonzero((qn + reach > upper) | (qn - reach < lower))
        # Unsynchronized: every axis stops on its own, so only the near ones need computing.
        low, high = Braking(q[near], qd[near], qdd[near], self._limit_amax[near], self._limit_jmax[near],
                            self.dt, synchronized=False).extrema()
        beyond = (high > upper[near] + _LIMIT_EPS) | (low < lower[near] - _LIMIT_EPS)
        return int(near[np.argmax(beyond)]) if beyond.any() else None

    # -- actions (loop thread only: call them through call() from elsewhere) -----
    def brake(self, before_limit: bool = False) -> None:
        """Controlled stop from the commanded state; the FIFO is emptied.

        ``before_limit``: the shortest stop of each axis, which ends inside the
        joint soft limits (every applied command was checked for it).
        """
        self._fifo.clear()
        if self._braking is None and np.any(np.abs(self.qd) > 0.0):
            if before_limit:
                self._braking = self._limit_stop(self.q, self.qd, self.qdd)
            else:
                self._braking = Braking(self.q, self.qd, self.qdd, self._amax, self._jmax, self.dt)

    def emergency_stop(self) -> None:
        self._log.error("emergency stop")
        self._raise(AlarmCode.EMERGENCY_STOP, AlarmType.FAULT, "emergency stop")

    def _raise(self, code: AlarmCode, kind: AlarmType, description: str) -> None:
        """Stop (and for a FAULT switch off) now; latch the alarm and report it to the monitor."""
        self._stop_for(int(code), kind)
        if int(code) not in self.latches:
            latch = _Latch(Alarm(int(code), kind, description), self._cause_present(int(code)))
            self.latches[int(code)] = latch
            self._log.error("alarm %s %s: %s", format_code(code), kind.value, description)
            self._report(latch)

    def _stop_for(self, code: int, kind: AlarmType) -> None:
        self.brake(before_limit=code == AlarmCode.SOFT_LIMIT_JOINT)
        if self._braking is None:  # already at rest: still, do not push on if blocked
            self._hold_where_it_is()
        if kind is AlarmType.FAULT and self.servo_on:
            self.servo_on = False
            self._log.warning("servo off after the %s fault", format_code(code))

    def _report(self, latch: _Latch) -> None:
        report = AlarmReport(latch.alarm, latch.present, Service.SERVO.value)
        latch.reported_at = time.monotonic()
        try:
            self._report_pub.put(codec.encode_message(ALARM_REPORT, report))
        except Exception as exc:  # a report that cannot be sent is sent again later
            self._log.warning("could not report alarm %s to the monitor: %s", format_code(latch.alarm.code), exc)

    def _report_latches(self) -> None:
        """Report every latch whose cause came or went, and again those not listed yet."""
        now = time.monotonic()
        for code, latch in list(self.latches.items()):
            present = self._cause_present(code)
            if present != latch.present or (latch.acked is None and now - latch.reported_at >= REPORT_AGAIN):
                latch.present = present
                self._report(latch)

    def _alarm_list_held(self) -> AlarmList | None:
        """The monitor's newest list less what was cleared without it: what this servo acts on."""
        if self._monitor_list is None:
            return None
        return dataclasses.replace(self._monitor_list, alarms=self.monitor_alarms)

    def adopt_monitor_list(self, alarms: AlarmList) -> None:
        """Follow the monitor's list: stop for what is new there, release the latches it cleared."""
        if not is_newer(alarms, self._monitor_list):
            return  # published before the one already adopted
        previous = self._monitor_list
        self._monitor_list = alarms
        listed = {a.code for a in alarms.alarms}
        for code, latch in list(self.latches.items()):
            if code in listed:
                latch.acked = alarms.started
            elif latch.acked == alarms.started:
                del self.latches[code]
                self._log.info("alarm %s released: the alarm monitor cleared it", format_code(code))
            elif previous is not None and alarms.started != previous.started:
                latch.acked = None  # a new monitor: tell it at once
                latch.reported_at = -float("inf")
        before = {a.code for a in self.monitor_alarms}
        self.monitor_alarms = alarms.alarms
        for alarm in alarms.alarms:
            if alarm.code not in before and alarm.code not in self.latches:
                self._log.warning("alarm %s %s from the alarm monitor: stopping the arm (%s)",
                            format_code(alarm.code), alarm.type.value, alarm.description)
                self._stop_for(alarm.code, alarm.type)

    def servo_on_now(self) -> str | None:
        """Servo on; returns why not, or None."""
        if self.alarmed:
            codes = sorted({*self.latches, *(a.code for a in self.monitor_alarms)})
            return "alarms active: " + ", ".join(format_code(c) for c in codes) + "; clear them first"
        if self._braking is not None and not self.servo_on:  # already on (after a WARNING): nothing to do
            return "the arm is still stopping"
        if not self.servo_on:
            self.q = self.fb_pos.copy()  # hold where the brakes held it
            self.qd = np.zeros_like(self.qd)
            self.qdd = np.zeros_like(self.qdd)
            self._cmd_moving = False
            self._fifo.clear()
            self._interrupted = False
            self.servo_on = True
            self._log.info("servo on")
        return None

    def servo_off_now(self) -> None:
        if self.servo_on:
            self.servo_on = False
            self._log.info("servo off")
        self.brake()

    def clear_alarms_now(self) -> tuple[list[Alarm], list[Alarm]]:
        """Without an alarm monitor: clear the latches whose cause has gone, forget the monitor's list.

        Returns (cleared, still active).
        """
        cleared, kept = list(self.monitor_alarms), []
        self.monitor_alarms = ()
        for code, latch in list(self.latches.items()):
            if self._cause_present(code):
                kept.append(latch.alarm)
            else:
                cleared.append(self.latches.pop(code).alarm)
                self._log.info("alarm %s cleared", format_code(code))
        return cleared, kept

    def _watch_monitor(self) -> None:
        """The alarm monitor's token and heartbeat: 0x403 when it is gone, 0x413 when it hangs."""
        now = time.monotonic()
        if now - self._watched_at > self.health.stall_after:
            # This loop was held up: the beats still in Zenoh's queue come first.
            self._judge_monitor_after = now + self.health.heartbeat_period
        self._watched_at = now
        watch = self._monitor_watch
        while (sample := self._monitor_token.try_recv()) is not None:
            if watch.token(sample.kind == zenoh.SampleKind.PUT, now):
                # Even in order: nothing would watch overload, overspeed or the other services.
                why = ("it shut down in order" if watch.leaving
                       else "its liveliness token was deleted (process ended or unreachable)")
                self._raise(AlarmCode.MONITOR_LOST, AlarmType.FAULT, f"the alarm monitor is gone: {why}")
        if (sample := self._monitor_beats.try_recv()) is not None:
            try:
                beat = codec.decode_message(HEARTBEAT, sample.payload.to_bytes())
                gap = watch.heard(now, beat.stuck, beat.leaving)
            except WireError as exc:
                self._log.error("ignored a malformed heartbeat of the alarm monitor: %s", exc)
            else:
                if gap is not None:
                    self._log.warning(watch.stall_line(gap))
        if (now >= self._judge_monitor_after and AlarmCode.MONITOR_HUNG not in self.latches
                and watch.hung(now)):
            why = watch.why_hung(now)
            self._raise(AlarmCode.MONITOR_HUNG, AlarmType.FAULT,
                        f"the alarm monitor hangs while its liveliness token is up: {why}")

    def _cause_present(self, code: int) -> bool:
        """Whether the cause of the servo's own alarm ``code`` is still there (the arm still stopping, too)."""
        if self._braking is not None:
            return True
        if code == AlarmCode.MONITOR_LOST:
            return not self._monitor_watch.alive
        if code == AlarmCode.MONITOR_HUNG:
            return self._monitor_watch.hung(time.monotonic())
        if code == AlarmCode.SOFT_LIMIT_JOINT:
            return any(not lim.lower - LIMIT_TOLERANCE <= q <= lim.upper + LIMIT_TOLERANCE
                       for q, lim in zip(self.fb_pos, self.soft_limits))
        return False  # emergency stop: a put is an event; a jump: the command was not applied

    def set_soft_limits_now(self, limits: tuple[LimitValue, ...]) -> str | None:
        if self.state_bits & StateBit.MOVING:
            return "the arm is moving"
        if self.alarmed:
            return "an alarm is active"
        self.soft_limits = limits
        self._log.info("joint soft limits set: %s", [(lim.lower, lim.upper) for lim in limits])
        return None

    # -- state and publishing -------------------------------------------------------
    def _bits(self, vel: list[float]) -> int:
        bits = _SERVO_ON if self.servo_on else 0  # plain ints: enum arithmetic costs every cycle
        if (self._braking is not None or self._fifo or self._cmd_moving
                or max(vel) > REST_SPEED or min(vel) < -REST_SPEED):
            bits |= _MOVING
        if self.alarmed:
            bits |= _ALARM
        return bits

    def _status_changed(self) -> bool:
        """Whether anything a status says other than the measured values changed since the last one."""
        return self._status_said != (self.state_bits, len(self._fifo), self.soft_limits) or self._status_q is not self.q

    def _publish_status(self, tm: Time) -> None:
        self._status_said = (self.state_bits, len(self._fifo), self.soft_limits)
        self._status_q = self.q
        st = messages.ServoStatus(
            tm, self.servo_on, bool(self.state_bits & _MOVING), self.alarmed,
            len(self._fifo), self.consumed, self.received, self.underruns,
            tuple(self.fb_vel.tolist()), tuple(self.fb_eff.tolist()), tuple(self.q.tolist()),
            self.soft_limits, tuple(self.fb_pos.tolist()))
        self._status_pub.put(messages.servo_status_payload(st))

    def _publish_health(self) -> None:
        st, self._stats = self._stats, _Stats()
        lat = np.array(st.lateness) if st.lateness else np.zeros(1)
        hist = np.histogram(lat, bins=list(messages.LATENESS_BIN_EDGES) + [np.inf])[0]
        msg = messages.LoopHealth(
            Time.now(), len(st.lateness), self.dt, float(np.percentile(lat, 50)),
            float(np.percentile(lat, 99)), float(lat.max()), st.late, st.overruns,
            len(self._fifo), st.underruns, tuple(int(c) for c in hist))
        self._health_pub.put(codec.encode_message(messages.LOOP_HEALTH, msg))
        if st.waits:
            self._log.info("servo loop: waited %d cycle(s) mid-motion for late commands (simulated "
                     "time stood still) instead of running dry", st.waits)
        if st.late + st.overruns > 0.01 * max(1, len(st.lateness)):  # the 1 % budget
            self._log.warning("servo loop: %d of %d cycles late by more than one period, %d overruns, "
                        "max lateness %.2f ms", st.late, len(st.lateness), st.overruns, lat.max() * 1e3)
