"""The servo loop of one arm: one position command per cycle from the SyncFIFO, one PyBullet step.

The loop is the I/O around the control law (``control.py``: each cycle's
target and the safety rules on every command, without I/O): it takes the
commands from Zenoh into the law's FIFO, steps the world, raises the alarms
the law calls for, watches the alarm monitor and publishes feedback, status
and timing.

Its cycles run on the process's :class:`~.clock.ServoClock` thread (one thread
for every arm of the process), the only code that touches the world. Other
threads change its state only through :meth:`ServoLoop.call`, which runs a
function at the arm's next cycle; reads use the values the loop publishes
every cycle (assigning a Python attribute is atomic).

Alarms: the servo's own latches and the alarm monitor's list it follows are
``alarms.py``'s :class:`~.alarms.AlarmState`; the loop stops the arm for them
in the cycle that raises or adopts them.

Over 500 lines on purpose: this module is the cycle and everything that
changes the state the cycle reads, at 1 kHz on the real-time thread (the
commanded state's source, servo on / off, the stops for alarms, the
interpolator's feed, feedback, status and ``Servo/motion``). Those parts act
on one another within the cycle (an alarm stops the arm in the cycle that
raises it; a hand-over is accepted against the law's state of that cycle) and
share its hot attributes; split into objects they would add indirection and
cross-object state to every cycle without making any part stand alone. What
needs none of that is outside: the control law (``control.py``), the
interpolator (``interpolator.py``), the alarm bookkeeping (``alarms.py``), the
alarm monitor's watch (``monitor_watch.py``) and the world (``world.py``).
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
from jara_arm.schema.alarms import ALARM_LIST, AlarmList, format_code
from jara_arm.schema.codes import AlarmCode, AlarmType, ReturnCode, StateBit
from jara_arm.schema.encoding import Encoding
from jara_arm.schema.errors import WireError
from jara_arm.schema.keys import ArmKeys
from jara_arm.schema.motion import MOTION_PROGRESS, MotionAction, MotionProgress, MotionReply, Trajectory, TrajectoryRefusal
from jara_arm.schema.types import Alarm, LimitValue, Time
from jara_arm.services.runtime.entities import Entities
from jara_arm.services.runtime.heartbeat import Pulse
from jara_arm.services.runtime.timing import (
    FEEDBACK_BLOCK_CYCLES,
    HEALTH_EVERY,
    SAME_HOST,
    STATUS_EVERY,
    STATUS_EVERY_AT_REST,
    UNDERRUN_GRACE,
    Health,
)
from jara_arm.services.runtime.wire import Publication, decode_sample

from .alarms import AlarmState
from .control import RAN_DRY, REST_SPEED, STOPPED, ControlLaw, Refusal
from .dropped import DropRun
from .interpolator import Interpolator, prepare
from .monitor_watch import MonitorWatch
from .world import World

log = logging.getLogger(__name__)
T = TypeVar("T")

#: At rest this many cycles in a row (nothing commanded, every axis below REST_SPEED), the
#: world is held as it is instead of stepped [cycles]: the brakes or the holding drives keep
#: the arm still, and a step costs a third of an idle servo's CPU. Any command, stop or
#: servo change steps it again in the same cycle.
SETTLED_CYCLES = 100
#: ... and every arm axis this close to its target [rad or m]: a world held while still closing on
#: its target would snap to it when stepped again. Drives keep 1.2e-6 at most against gravity. A
#: servoON whose arm is this close keeps the target it held (a motion planned from it stays valid).
SETTLE_TOLERANCE = 1e-5
#: Tracking tolerance when deciding that a soft-limit cause has gone [rad or m].
LIMIT_TOLERANCE = 1e-3
#: The alarm monitor's token and heartbeat are looked at every
#: this many cycles [cycles]: 10 ms against a hung bound of 1.5 s, a twentieth of a busy arm's cycle.
WATCH_EVERY = 10
#: ``Servo/motion`` at least this often [s], and at once on every change.
MOTION_EVERY = 0.1
#: Motions a servoOFF discarded are taken as discarded by an alarm that arrives this soon after it [s]:
#: the alarm monitor's reaction to a FAULT (servoOFF) may overtake its alarm list.
OFF_FOR_ALARM = 1.0

_SERVO_ON, _MOVING, _ALARM = int(StateBit.SERVO_ON), int(StateBit.MOVING), int(StateBit.ALARM)


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
                 health: Health = SAME_HOST, publish_targets: bool = False) -> None:
        """``publish_targets``: ``Servo/posTarget`` while someone subscribes (the servo's ``--publish-targets``)."""
        self.model = model
        self.arm = keys.arm
        # Records name their arm: one servo process may run several (logs.ZenohLogHandler).
        self._log = logging.LoggerAdapter(log, {"arm": keys.arm})
        self.health = health
        self._pulse = pulse or Pulse("the servo loop", health.hung_after)
        self.dt = model.cmd_cycle
        self.world = World(model, obstacles)
        pos, vel, eff = self.world.read()
        # The commanded state, the FIFO and any stop: the control law's (control.py).
        self.law = ControlLaw(model, pos)
        # The accepted motions, whole, and the time scale they run at (interpolator.py).
        self.interp = Interpolator(model.dof, self.dt)
        self._from_client = False  # the last command came from a low-level client's SyncFIFO
        self._off_discarded: tuple[list[int], float] | None = None  # (motions, monotonic time) of a servoOFF
        self._started = Time.now()
        self._motion_seq = 0
        self._motion_said: tuple[object, ...] = ()
        self._motion_at = 0.0  # [s] monotonic time of the last Servo/motion
        # What other threads read (replaced, never mutated, by the loop).
        self.fb_pos, self.fb_vel, self.fb_eff = pos, vel, eff
        self.state_bits = 0
        self.servo_on = False

        self._late_cycles = 0  # consecutive cycles waited for a command mid-motion
        self._still_for = 0  # consecutive cycles at rest (see SETTLED_CYCLES)
        self._arm_axes = model.axis_num  # the axes SETTLE_TOLERANCE looks at
        self._status_k = -STATUS_EVERY_AT_REST  # cycle of the last ServoStatus
        self._status_seq = 0  # ServoStatus made, published or not (ServoStatus.seq)
        self._watch_phase = 0  # ticks n % WATCH_EVERY == this watch the alarm monitor
        self._watch_k = 0
        self._status_said: tuple[object, ...] = ()  # what it said besides the measured values
        self._status_q: np.ndarray | None = None  # the target it said
        self._vel_list: list[float] = vel.tolist()
        self._pos_list: list[float] = pos.tolist()
        self._calls: collections.deque[tuple[Callable[[], Any], concurrent.futures.Future]] = collections.deque()
        #: Called after a call is queued (the clock's: a resting clock runs the cycle now, ``clock.REST_BATCH``).
        self.wake: Callable[[], None] = lambda: None
        self.received = self.underruns = self.dropped = 0
        self._drops = DropRun(self._log, keys.pos_cmd)

        self._entities = Entities()
        enter = self._entities.enter_context
        self._cmd_sub = enter(session.declare_subscriber(keys.pos_cmd, zenoh.handlers.FifoChannel(1 << 16)))
        self._estop_sub = enter(session.declare_subscriber(keys.estop, zenoh.handlers.FifoChannel(64)))
        self._alarms_sub = enter(session.declare_subscriber(keys.monitor_alarms, zenoh.handlers.FifoChannel(256)))
        self._monitor = MonitorWatch(session, keys, health)  # nobody else can watch the watcher
        # The servo's own alarms (its status carries them) and the monitor's list it follows.
        self.alarm_state = AlarmState(self._log, self._cause_present)
        # The feedback and the status are MessagePack built by hand (messages.*_payload), fast.
        self._fb_pub = enter(Publication(session, keys.pos_feedback, Encoding.MSGPACK))
        # The 1 kHz feedback is encoded only while someone subscribes (none of our services do).
        self._fb_matching = enter(self._fb_pub.publisher.declare_matching_listener(zenoh.handlers.FifoChannel(64)))
        self._fb_wanted = self._fb_pub.publisher.matching_status.matching
        self._fb_put = self._fb_pub.publisher.put  # every cycle: the labelled publisher's put, no wrapper call
        # While a client gateway takes the feedback in blocks, it serves its clients sample by sample, and
        # the per-sample publication stops: whoever subscribes through a gateway (a wildcard reaches this
        # publisher too), the bus carries one message per block.
        block_pub = enter(Publication(session, keys.pos_feedback_block, Encoding.MSGPACK))
        self._block_matching = enter(block_pub.publisher.declare_matching_listener(zenoh.handlers.FifoChannel(64)))
        self._block_wanted = block_pub.publisher.matching_status.matching
        self._block_put = block_pub.publisher.put
        self._block: list[tuple[int, list[float]]] = []  # (tm [ns], joints) since the last block
        # Opt-in: at 1 kHz beside the feedback it doubled what a JARA_ARM/** recorder takes, more than
        # `jara-arm record` kept up with on a 2-core machine.
        self._target_pub = enter(Publication(session, keys.pos_target, Encoding.MSGPACK)) if publish_targets else None
        self._target_matching = (enter(self._target_pub.publisher.declare_matching_listener(
            zenoh.handlers.FifoChannel(64))) if self._target_pub is not None else None)
        self._target_wanted = self._target_pub is not None and self._target_pub.publisher.matching_status.matching
        self._status_pub = enter(Publication(session, keys.servo_status, Encoding.MSGPACK))
        self._motion_pub = enter(Publication(session, keys.servo_motion))
        self._health_pub = enter(Publication(session, keys.servo_health))
        self._stats = _Stats()
        self._period_ns = model.cmd_cycle_ms * 1_000_000
        self._tm_ns = 0  # [ns] wall-clock time the newest feedback sample stands for
        self._cycles = 0
        self._window_start = time.monotonic()

    # -- life cycle ---------------------------------------------------------------
    def close(self) -> None:
        """Undeclare everything; call it once the clock has stopped."""
        self.interp.release()
        self._monitor.close()
        self._entities.close()  # in reverse: the matching listener before its publisher
        self.world.close()

    @property
    def soft_limits(self) -> tuple[LimitValue, ...]:
        """[rad or m] the joint soft limits in force, one per arm axis."""
        return self.law.soft_limits

    @property
    def q(self) -> np.ndarray:
        """[rad or m] the target applied this cycle."""
        return self.law.q

    @property
    def alarmed(self) -> bool:
        """A latch or an alarm listed by the monitor is active: the arm must not move."""
        state = self.alarm_state
        return bool(state.latches or state.monitor_alarms)

    @property
    def alarms(self) -> tuple[Alarm, ...]:
        """The servo's own latches (what ``getActiveAlarm`` says when the monitor is silent)."""
        return tuple(latch.status.alarm for latch in list(self.alarm_state.latches.values()))

    @property
    def monitor_silent(self) -> bool:
        """The alarm monitor is gone or hangs, by this servo's own evidence (0x403 or 0x413 latched, its cause
        still there): a query to it would only wait for its timeout. Read from a query worker: a stale answer
        costs that timeout once, or answers the servo's own view (said so) a moment after the monitor is back."""
        latches = self.alarm_state.latches
        return ((AlarmCode.MONITOR_LOST in latches and not self._monitor.alive)
                or (AlarmCode.MONITOR_HUNG in latches and self._monitor.hung()))

    def _held(self) -> bool:
        """The world is held as it is (``SETTLED_CYCLES``): at rest that long, nothing braking, commanded or moving."""
        law = self.law
        return self._still_for >= SETTLED_CYCLES and law.braking is None and not law.fifo and not law.moving

    @property
    def resting(self) -> bool:
        """Nothing to do but hold: the world held, nothing buffered or called; the clock may then run this
        arm's cycles in batches (``clock.REST_BATCH``)."""
        return self._held() and not self.interp.active and not self._calls

    def call(self, fn: Callable[[], T], timeout: float = 1.0) -> T:
        """Run ``fn`` on the clock's thread at this arm's next cycle and return its result."""
        fut: concurrent.futures.Future = concurrent.futures.Future()
        self._calls.append((fn, fut))
        self.wake()
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
        self._watch_phase = int(phase * WATCH_EVERY)

    def tick(self, deadline_wall_ns: int, deadline_ns: int, behind: bool) -> bool:
        """This arm's cycle due at ``deadline_ns`` (monotonic) / ``deadline_wall_ns`` (wall);
        ``behind``: the clock runs more than a period late. False if the arm waited for a late
        command instead (simulated time stands still; nothing was stepped or published)."""
        self._pulse.beat()
        start = time.monotonic_ns()
        period = self._period_ns
        law = self.law
        at_rest = not law.moving and not law.fifo
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
                self.adopt_monitor_list(decode_sample(ALARM_LIST, sample))
            except WireError as exc:
                self._log.error("ignored a malformed alarm list from the monitor: %s", exc)
        self._watch_k += 1  # not k: it stands still while a late client stream is waited for
        if self._watch_k % WATCH_EVERY == self._watch_phase:
            self._watch_monitor()
        while self._calls:
            fn, fut = self._calls.popleft()
            try:
                result = fn()
            except Exception as exc:
                fut.set_exception(exc)
                continue
            # The caller replies as soon as it has the result: a getState right after a servoON or a
            # clearAlarms must read the bits after it, not the last cycle's (CI run 54: 0x05 after a clear).
            self.state_bits = self._bits(self._vel_list)
            fut.set_result(result)
        self._take_commands()
        law = self.law
        interp = self.interp
        screened = None
        if interp.active and law.braking is None and not interp.holding:
            ran_out = interp.ran_out
            law.fifo.appendleft(interp.next())  # ahead of any client's: it is the one that runs
            screened = interp.screened
            self._from_client = False
            if interp.ran_out != ran_out:  # the cap should prevent it: worth knowing when it does not
                self._log.warning("the early start's head of motion %d held at its last sample: its rest "
                                  "was late", interp.running)
        # Only a low-level client's stream may be late (over the network); the interpolator never is.
        if (self._from_client and not law.fifo and law.moving and law.braking is None
                and self.servo_on and not self.alarmed):
            if behind or self._late_cycles < UNDERRUN_GRACE:
                self._late_cycles += 1
                return False
        else:
            self._late_cycles = 0
        consumed = law.consumed
        self._advance(screened)
        if interp.done:
            self._log.debug("motions %s done", interp.done)
            interp.done.clear()
        settled = self._held()
        if not settled:
            self.world.command(law.q, law.qd)
            self.world.step()
            pos, vel, eff = self.world.read()
            self.fb_pos, self.fb_vel, self.fb_eff = pos, vel, eff
            self._pos_list, self._vel_list = pos.tolist(), vel.tolist()
            self.state_bits = self._bits(self._vel_list)
            if self.state_bits & _MOVING:
                self._still_for = 0
            else:  # at rest only: a gripper held closed on a part keeps its target on purpose (ControlLaw.let_go)
                n = self._arm_axes
                closing = float(np.max(np.abs(pos[:n] - law.q[:n]))) > SETTLE_TOLERANCE
                self._still_for = 0 if closing else self._still_for + 1
        else:  # settled: the world is held as it is (SETTLED_CYCLES)
            self.state_bits = self._bits(self._vel_list)
        while (matching := self._fb_matching.try_recv()) is not None:
            self._fb_wanted = matching.matching
        while (matching := self._block_matching.try_recv()) is not None:
            self._block_wanted = matching.matching
            self._block = []
        if self._block_wanted:
            self._block.append((tm_ns, self._pos_list))  # a new list each cycle the arm moves: kept, not copied
            if len(self._block) >= FEEDBACK_BLOCK_CYCLES:
                self._block_put(messages.feedback_block_payload(self._block))
                self._block = []
        elif self._fb_wanted:  # not both: a gateway's client of JARA_ARM/** would get every sample twice
            self._fb_put(messages.timed_joint_pos_payload(tm_ns, self._pos_list))
        if self._target_matching is not None:
            while (matching := self._target_matching.try_recv()) is not None:
                self._target_wanted = matching.matching
        if self._target_wanted and law.consumed != consumed and self._target_pub is not None:
            self._target_pub.publisher.put(messages.timed_joint_pos_payload(tm_ns, law.q.tolist()))
        self._publish_motion()
        if self.alarm_state.latches:  # every cycle: the monitor learns at once that a cause has gone
            self.alarm_state.look()
        if (k - self._status_k >= (STATUS_EVERY_AT_REST if settled else STATUS_EVERY) or self.alarm_state.changed
                or (settled and self._status_changed())):  # moving: the FIFO changes every cycle
            self._status_k = k
            self._publish_status(tm_ns)
        return True

    def _take_commands(self) -> None:
        """Move what arrived into the FIFO (or drop it while commands are not accepted, said: ``dropped.py``)."""
        # One source moves the arm at a time: while motions are buffered, a client's stream is dropped.
        refused = ("the servo is off" if not self.servo_on else "an alarm is active" if self.alarmed else
                   "a motion is running (one source moves the arm at a time)" if self.interp.active else None)
        self._drops.holds(refused)
        while (sample := self._cmd_sub.try_recv()) is not None:
            self.received += 1
            if refused is not None:
                self.dropped += 1
                self._drops.drop(refused)
                continue
            try:
                msg = codec.decode_message(w.TIMED_JOINT_POS, sample.payload.to_bytes())
                if len(msg.pos) != self.model.dof:
                    raise WireError("pos", f"expected {self.model.dof} axes, got {len(msg.pos)}")
            except WireError as exc:
                self.dropped += 1
                self._log.warning("dropped a malformed position command: %s", exc)
                continue
            self.law.fifo.append(np.array(msg.pos))
            self._from_client = True

    def _advance(self, screened: object = None) -> None:
        """Choose this cycle's target (the control law; ``screened``: see ``ControlLaw.advance``)
        and act on what it says."""
        law = self.law
        outcome = law.advance(self.servo_on and not self.alarmed, screened)
        if isinstance(outcome, Refusal):
            self._raise(outcome.code, outcome.kind, outcome.description)
            if law.braking is not None:  # the stop starts this cycle, not one cycle later
                outcome = law.advance(False)  # with the target standing still (a jerk)
        if outcome == RAN_DRY:
            self.underruns += 1
            self._stats.underruns += 1
            self._log.warning("position commands ran dry while moving: controlled stop")
        elif outcome == STOPPED and self.alarmed:
            self._hold_where_it_is()

    def _hold_where_it_is(self) -> None:
        """After a stop for an alarm: if the arm did not follow (blocked), hold it where it is."""
        blocked = self.law.let_go(self.fb_pos)
        if blocked is not None:
            i, gap = blocked
            self._log.warning("the arm stopped %.3g away from its target (J%d): blocked; holding it where it is",
                              gap, i + 1)

    # -- actions (loop thread only: call them through call() from elsewhere) -----
    def brake(self, before_limit: bool = False) -> None:
        """Controlled stop from the commanded state; the FIFO is emptied (``ControlLaw.brake``)."""
        self.law.brake(before_limit)

    def emergency_stop(self) -> None:
        self._log.error("emergency stop")
        self._raise(AlarmCode.EMERGENCY_STOP, AlarmType.FAULT, "emergency stop")

    def _raise(self, code: AlarmCode, kind: AlarmType, description: str) -> None:
        """Stop (and for a FAULT switch off) now; latch the alarm (the next status carries it to the monitor)."""
        cut = self._stop_for(int(code), kind)
        self.alarm_state.latch(code, kind, description)
        if cut is not None:  # after its cause, in the list too
            self.alarm_state.not_completed(*cut)

    def _stop_for(self, code: int, kind: AlarmType) -> tuple[list[int], str] | None:
        """Stop the arm for alarm ``code``; the motions it cut short and why (for 0x420), if any."""
        why = f"alarm {format_code(code)} stopped the arm"
        cut = None
        if self.interp.active:
            cut = self.interp.discard(), why
        elif self._off_discarded is not None and time.monotonic() - self._off_discarded[1] <= OFF_FOR_ALARM:
            cut = self._off_discarded[0], f"{why} (the servo was switched off for it first)"
        self._off_discarded = None
        self.brake(before_limit=code == AlarmCode.SOFT_LIMIT_JOINT)
        if self.law.braking is None:  # already at rest: still, do not push on if blocked
            self._hold_where_it_is()
        if kind is AlarmType.FAULT and self.servo_on:
            self.servo_on = False
            self._log.warning("servo off after the %s fault", format_code(code))
        return cut

    def adopt_monitor_list(self, alarms: AlarmList) -> None:
        """Follow the monitor's list: stop for what is new there, release the latches it cleared."""
        self.alarm_state.adopt(alarms, self._stop_for_listed)

    def _stop_for_listed(self, alarm: Alarm) -> None:
        """Stop the arm for ``alarm``, new in the monitor's list."""
        cut = self._stop_for(alarm.code, alarm.type)
        if cut is not None:
            self.alarm_state.not_completed(*cut)

    def servo_on_now(self) -> str | None:
        """Servo on; returns why not, or None."""
        if self.alarmed:
            state = self.alarm_state
            codes = sorted({*state.latches, *(a.code for a in state.monitor_alarms)})
            return "alarms active: " + ", ".join(format_code(c) for c in codes) + "; clear them first"
        if self.law.braking is not None and not self.servo_on:  # already on (after a WARNING): nothing to do
            return "the arm is still stopping"
        if not self.servo_on:
            if float(np.max(np.abs(self.fb_pos - self.law.q))) > SETTLE_TOLERANCE:
                self.law.hold(self.fb_pos)  # hold where the brakes held it
            else:  # settled on its target: the same hold, so a motion planned from it is not stale
                self.law.hold(self.law.q)
            self.servo_on = True
            self._log.info("servo on")
        return None

    def servo_off_now(self) -> None:
        if self.interp.active:  # a client's request, not an alarm (unless one follows): said in the log
            ids = self.interp.discard()
            self._off_discarded = (ids, time.monotonic())
            self._log.warning("servo off: motions %s discarded before their end", ids)
        if self.servo_on:
            self.servo_on = False
            self._log.info("servo off")
        self.brake()

    def clear_alarms_now(self) -> tuple[list[Alarm], list[Alarm]]:
        """Without an alarm monitor: clear the latches whose cause has gone, forget the monitor's list.

        Returns (cleared, still active).
        """
        return self.alarm_state.clear()

    def _watch_monitor(self) -> None:
        """The alarm monitor's token and heartbeat (``monitor_watch.py``): 0x403 gone, 0x413 hung."""
        for found in self._monitor.look(AlarmCode.MONITOR_HUNG in self.alarm_state.latches):
            if found.alarm is not None:
                self._raise(found.alarm, AlarmType.FAULT, found.description)
            elif found.warning:
                self._log.warning(found.warning)
            elif found.error:
                self._log.error(found.error)

    def _cause_present(self, code: int) -> bool:
        """Whether the cause of the servo's own alarm ``code`` is still there (the arm still stopping, too)."""
        if self.law.braking is not None:
            return True
        if code == AlarmCode.MONITOR_LOST:
            return not self._monitor.alive
        if code == AlarmCode.MONITOR_HUNG:
            return self._monitor.hung()
        if code == AlarmCode.SOFT_LIMIT_JOINT:
            return any(not lim.lower - LIMIT_TOLERANCE <= q <= lim.upper + LIMIT_TOLERANCE
                       for q, lim in zip(self.fb_pos, self.soft_limits))
        return False  # emergency stop: a put is an event; a jump: the command was not applied

    def set_soft_limits_now(self, limits: tuple[LimitValue, ...]) -> str | None:
        if self.state_bits & StateBit.MOVING:
            return "the arm is moving"
        if self.alarmed:
            return "an alarm is active"
        self.law.soft_limits = limits
        self._log.info("joint soft limits set: %s", [(lim.lower, lim.upper) for lim in limits])
        return None

    # -- state and publishing -------------------------------------------------------
    def _bits(self, vel: list[float]) -> int:
        bits = _SERVO_ON if self.servo_on else 0  # plain ints: enum arithmetic costs every cycle
        law = self.law
        if (law.braking is not None or law.fifo or law.moving or (self.interp.active and not self.interp.holding)
                or max(vel) > REST_SPEED or min(vel) < -REST_SPEED):
            bits |= _MOVING
        if self.alarmed:
            bits |= _ALARM
        return bits

    def _status_changed(self) -> bool:
        """Whether anything a status says other than the measured values changed since the last one."""
        law = self.law
        return self._status_said != (self.state_bits, len(law.fifo), law.soft_limits) or self._status_q is not law.q

    def _publish_status(self, tm_ns: int) -> None:
        law = self.law
        self._status_said = (self.state_bits, len(law.fifo), law.soft_limits)
        self._status_q = law.q
        self.alarm_state.changed = False
        self._status_pub.put(messages.servo_status_payload(self._status(tm_ns)))

    def status_now(self) -> messages.ServoStatus:
        """The status now, numbered, for a reply (loop thread: through :meth:`call`, whose bits are
        already those after the call before it)."""
        return self._status(self._tm_ns)

    def _status(self, tm_ns: int) -> messages.ServoStatus:
        """The next status, of the newest feedback sample's time ``tm_ns`` [ns]: every one made is numbered."""
        law = self.law
        self._status_seq += 1
        return messages.ServoStatus(
            Time.from_ns(tm_ns), self.servo_on, bool(self.state_bits & _MOVING),
            self.alarmed, len(law.fifo), law.consumed, self.received, self.underruns,
            tuple(self.fb_vel.tolist()), tuple(self.fb_eff.tolist()), tuple(law.q.tolist()),
            law.soft_limits, tuple(self.fb_pos.tolist()), self._started, self._status_seq,
            self.alarm_state.snapshot())

    # -- the interpolator (schema/motion.py) ------------------------------------------------
    def submit(self, traj: Trajectory) -> MotionReply:
        """``Servo/trajectory``: buffer one motion (or a head, or a head's rest). Raises WireError
        (VALUE_ERR) for samples that do not fit the arm; a refusal is a reply, not an exception."""
        rows = traj.rows()
        if traj.dof != self.model.dof:
            raise WireError("dof", f"the arm has {self.model.dof} axes (gripper included), got {traj.dof}")
        buffered = prepare(traj.motion, rows, traj.final, self.dt, self.law.max_accel)  # here, not in the cycle
        buffered.screen(*self.law.screen(buffered.q))

        def apply() -> MotionReply:
            law = self.law
            if not self.servo_on:
                return MotionReply(int(ReturnCode.NOT_SV_ON_ERR), "the servo is off", TrajectoryRefusal.STATE.value,
                                   self._motion_progress())
            if self.alarmed:
                late, why = TrajectoryRefusal.STATE, "an alarm is active"
            else:
                at_rest = law.braking is None and not law.fifo and not (law.moving and self._from_client)
                late, why = self.interp.submit(buffered, traj.epoch, traj.after, traj.splice, law.q, at_rest)
            if late is None:
                return MotionReply(0, f"OK: motion {traj.motion} {why}", "", self._motion_progress())
            return MotionReply(int(ReturnCode.STATUS_ERR), why, late.value, self._motion_progress())

        return self.call(apply)

    def motion_control(self, action: MotionAction, ratio: float) -> MotionReply:
        """``Servo/motionControl``: pause, resume, stop, abort or override (``ratio`` [%], checked)."""
        if not 0.0 <= ratio <= 100.0:
            raise WireError("ratio", f"the speed override is 0 .. 100 %, got {ratio}")

        def apply() -> MotionReply:
            moving = self.interp.active
            comment = self.interp.control(action, ratio / 100.0)
            if action is MotionAction.ABORT and moving:
                self.brake()  # off the path, within the limits: the law's controlled stop, not a dry FIFO
            if action is not MotionAction.OVERRIDE and not comment.startswith("OK: ignored"):
                self._log.info("%s: %s", action.value, comment[4:])
            return MotionReply(0, comment, "", self._motion_progress())

        return self.call(apply)

    def motion_progress_now(self) -> MotionProgress:
        """The interpolator's progress (on the loop's thread: through :meth:`call`)."""
        return self._motion_progress()

    def _motion_progress(self) -> MotionProgress:
        """The interpolator now, numbered (``seq`` grows on every change but of tm, scale and runningShare)."""
        said = self.interp.state(self.law.q)
        if said != self._motion_said:
            self._motion_said = said
            self._motion_seq += 1
        return self.interp.progress(said, self._started, self._motion_seq)

    def _publish_motion(self) -> None:
        """``Servo/motion`` on every change, and every ``MOTION_EVERY``."""
        now = time.monotonic()
        if self.interp.state(self.law.q) != self._motion_said or now - self._motion_at >= MOTION_EVERY:
            self._motion_at = now
            self._motion_pub.put_message(MOTION_PROGRESS, self._motion_progress())

    def _publish_health(self) -> None:
        st, self._stats = self._stats, _Stats()
        lat = np.array(st.lateness) if st.lateness else np.zeros(1)
        hist = np.histogram(lat, bins=list(messages.LATENESS_BIN_EDGES) + [np.inf])[0]
        msg = messages.LoopHealth(
            Time.now(), len(st.lateness), self.dt, float(np.percentile(lat, 50)),
            float(np.percentile(lat, 99)), float(lat.max()), st.late, st.overruns,
            len(self.law.fifo), st.underruns, tuple(int(c) for c in hist))
        self._health_pub.put_message(messages.LOOP_HEALTH, msg)
        if st.waits:
            self._log.info("servo loop: waited %d cycle(s) mid-motion for late commands (simulated "
                     "time stood still) instead of running dry", st.waits)
        if st.late + st.overruns > 0.01 * max(1, len(st.lateness)):  # the 1 % budget
            self._log.warning("servo loop: %d of %d cycles late by more than one period, %d overruns, "
                        "max lateness %.2f ms", st.late, len(st.lateness), st.overruns, lat.max() * 1e3)
