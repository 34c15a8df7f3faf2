"""The servo loop: one position command per cycle from the SyncFIFO, one PyBullet step.

Runs on its own thread and is the only code that touches the world. Other
threads change its state only through :meth:`ServoLoop.call`, which runs a
function at the next cycle boundary; reads use the values the loop publishes
every cycle (assigning a Python attribute is atomic).
"""

from __future__ import annotations

import collections
import concurrent.futures
import ctypes
import dataclasses
import logging
import os
import sys
import threading
import time
from collections.abc import Callable
from typing import Any, TypeVar

import numpy as np
import zenoh

from jara_arm.robots import RobotModel
from jara_arm.schema import codec, messages
from jara_arm.schema import wire_types as w
from jara_arm.schema.codes import AlarmCode, AlarmType, StateBit
from jara_arm.schema.errors import WireError
from jara_arm.schema.keys import ArmKeys
from jara_arm.schema.types import Alarm, LimitValue, Time

from .braking import Braking
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
#: Tracking tolerance when deciding that a soft-limit cause has gone [rad or m].
LIMIT_TOLERANCE = 1e-3
#: Behind schedule by more than this, the loop stops catching up and restarts its clock [s].
RESYNC_AFTER = 0.1
STATUS_EVERY = 10  # cycles between ServoStatus messages
HEALTH_EVERY = 1.0  # [s] between LoopHealth messages
_PR_SET_TIMERSLACK = 29
#: SCHED_FIFO priority of the loop thread (Linux 1..99; 0 = normal scheduling).
DEFAULT_RT_PRIORITY = 40
#: Other threads of the servo process hand the GIL back to the loop this often [s].
GIL_SWITCH_INTERVAL = 0.0005


def _realtime_thread(priority: int) -> None:
    """Make the calling thread a real-time one, as servo drives are.

    1 us timer slack so that sleeps end close to their deadline, and SCHED_FIFO
    at ``priority`` (0: leave the scheduler alone) so that other processes do
    not delay the cycle. Both need privileges that a container may lack: then
    the loop runs as a normal thread and says so.
    """
    try:
        ctypes.CDLL(None, use_errno=True).prctl(_PR_SET_TIMERSLACK, 1, 0, 0, 0)
    except Exception:
        pass
    if priority > 0:
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
            log.info("servo loop runs with SCHED_FIFO priority %d", priority)
        except (OSError, AttributeError) as exc:
            log.warning("servo loop without real-time priority (%s): expect more jitter", exc)


@dataclasses.dataclass
class _Stats:
    """Timing of the current health window."""

    lateness: list[float] = dataclasses.field(default_factory=list)
    overruns: int = 0
    underruns: int = 0
    late: int = 0


class ServoLoop:
    """The low-level controller of one arm (see module docstring)."""

    def __init__(self, model: RobotModel, session: zenoh.Session, keys: ArmKeys,
                 realtime_priority: int = DEFAULT_RT_PRIORITY) -> None:
        self.model = model
        self._rt_priority = realtime_priority
        self.dt = model.cmd_cycle
        self.world = World(model)
        n = model.dof
        self._vmax = np.array(list(model.rated_speed) + ([model.gripper_speed] if model.has_gripper else []))
        min_acc_t = model.min_accel_time
        self._amax = self._vmax / min_acc_t
        self._jmax = self._amax / BRAKE_JERK_TIME
        grip = model.gripper_limits
        self._hard = list(model.hard_limits) + ([grip] if grip else [])
        self.soft_limits: tuple[LimitValue, ...] = model.hard_limits

        pos, vel, eff = self.world.read()
        self.q, self.qd, self.qdd = pos.copy(), np.zeros(n), np.zeros(n)
        # What other threads read (replaced, never mutated, by the loop).
        self.fb_pos, self.fb_vel, self.fb_eff = pos, vel, eff
        self.state_bits = 0
        self.servo_on = False
        self.alarms: dict[int, Alarm] = {}

        self._fifo: collections.deque[np.ndarray] = collections.deque()
        self._braking: Braking | None = None
        self._interrupted = False  # the stream ran dry mid-motion; wait for a consistent command
        self._cmd_moving = False  # the commanded velocity qd is not all zero
        self._calls: collections.deque[tuple[Callable[[], Any], concurrent.futures.Future]] = collections.deque()
        self.received = self.consumed = self.underruns = self.dropped = 0

        self._cmd_sub = session.declare_subscriber(keys.pos_cmd, zenoh.handlers.FifoChannel(1 << 16))
        self._estop_sub = session.declare_subscriber(keys.estop, zenoh.handlers.FifoChannel(64))
        self._fb_pub = session.declare_publisher(keys.pos_feedback, express=True)
        self._status_pub = session.declare_publisher(keys.servo_status, express=True)
        self._health_pub = session.declare_publisher(keys.servo_health)
        self._stats = _Stats()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="servo-loop", daemon=True)
        self._failed: BaseException | None = None

    # -- life cycle ---------------------------------------------------------------
    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5.0)
        for entity in (self._cmd_sub, self._estop_sub, self._fb_pub, self._status_pub, self._health_pub):
            try:
                entity.undeclare()
            except Exception:
                pass
        self.world.close()

    @property
    def alive(self) -> bool:
        return self._thread.is_alive()

    def call(self, fn: Callable[[], T], timeout: float = 1.0) -> T:
        """Run ``fn`` on the loop thread at the next cycle boundary and return its result."""
        fut: concurrent.futures.Future = concurrent.futures.Future()
        self._calls.append((fn, fut))
        return fut.result(timeout=timeout)

    # -- the loop -----------------------------------------------------------------
    def _run(self) -> None:
        _realtime_thread(self._rt_priority)
        sys.setswitchinterval(GIL_SWITCH_INTERVAL)
        period_ns = self.model.cmd_cycle_ms * 1_000_000
        next_ns = time.monotonic_ns()
        # A sample's tm is the wall-clock time its cycle stands for (its deadline), so
        # consecutive samples are exactly one period apart even while the loop catches up.
        wall_offset = time.time_ns() - next_ns
        window_start = time.monotonic()
        cycles = 0
        try:
            while not self._stop.is_set():
                now = time.monotonic_ns()
                if now < next_ns:
                    time.sleep((next_ns - now) * 1e-9)
                    now = time.monotonic_ns()
                lateness = (now - next_ns) * 1e-9
                if lateness > RESYNC_AFTER:
                    log.warning("servo loop %.0f ms behind schedule; restarting its clock", lateness * 1e3)
                    next_ns = now
                    wall_offset = time.time_ns() - now
                self._cycle(cycles, next_ns + wall_offset)
                done = time.monotonic_ns()
                st = self._stats
                st.lateness.append(lateness)
                if lateness > self.dt:
                    st.late += 1
                if done - now > period_ns:
                    st.overruns += 1
                cycles += 1
                next_ns += period_ns
                if time.monotonic() - window_start >= HEALTH_EVERY:
                    self._publish_health()
                    window_start = time.monotonic()
        except BaseException as exc:  # surfaced by main(): the service exits and is restarted
            self._failed = exc
            log.exception("servo loop failed")

    def _cycle(self, k: int, tm_ns: int) -> None:
        if self._estop_sub.try_recv() is not None:
            while self._estop_sub.try_recv() is not None:
                pass
            self.emergency_stop()
        while self._calls:
            fn, fut = self._calls.popleft()
            try:
                fut.set_result(fn())
            except Exception as exc:
                fut.set_exception(exc)
        self._take_commands()
        self._advance()
        self.world.command(self.q, self.qd)
        self.world.step()
        pos, vel, eff = self.world.read()
        self.fb_pos, self.fb_vel, self.fb_eff = pos, vel, eff
        pos_list = pos.tolist()
        self.state_bits = self._bits(vel.tolist())
        self._fb_pub.put(messages.timed_joint_pos_payload(tm_ns, pos_list))
        if k % STATUS_EVERY == 0:
            self._publish_status(Time(tm_ns // 1_000_000_000, tm_ns % 1_000_000_000))

    def _take_commands(self) -> None:
        """Move what arrived into the FIFO (or drop it while commands are not accepted)."""
        accepting = self.servo_on and not self.alarms
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
                log.warning("dropped a malformed position command: %s", exc)
                continue
            self._fifo.append(np.array(msg.pos))

    def _advance(self) -> None:
        """Choose this cycle's target: brake, follow the FIFO, or hold."""
        if self._braking is not None:
            q, self.qd, self.qdd, done = self._braking.next()
            self.q = self._inside_soft_limits(q)
            self._cmd_moving = not done
            if done:
                self._braking = None
            return
        if self.servo_on and not self.alarms and self._fifo:
            cmd = self._fifo.popleft()
            self.consumed += 1
            self._follow(cmd)
            return
        if self._cmd_moving and self.servo_on and not self.alarms and np.any(np.abs(self.qd) > REST_SPEED):
            self.underruns += 1
            self._stats.underruns += 1
            self._interrupted = True
            log.warning("position commands ran dry while moving: controlled stop")
            self.brake()
            self._advance()
            return
        if self._cmd_moving:
            self.qd = np.zeros_like(self.qd)
            self.qdd = np.zeros_like(self.qdd)
            self._cmd_moving = False

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
        too_fast = np.abs(step) > self._vmax * self.dt * OVERSPEED_MARGIN
        if self._interrupted:
            if np.any(too_fast):
                self.dropped += 1  # stale commands of the interrupted stream
                return
            self._interrupted = False
        if not np.all(np.isfinite(cmd)):
            self._raise(AlarmCode.OVERSPEED, AlarmType.FAULT, "non-finite position command")
            return
        axis = self.model.axis_num
        outside = [i for i in range(axis)
                   if not self.soft_limits[i].lower <= cmd[i] <= self.soft_limits[i].upper]
        if outside:
            i = outside[0]
            lim = self.soft_limits[i]
            self._raise(AlarmCode.SOFT_LIMIT_JOINT, AlarmType.WARNING,
                        f"position command J{i + 1}={cmd[i]:.6g} outside the joint soft limit "
                        f"[{lim.lower:.6g}, {lim.upper:.6g}]; not applied")
            return
        if self.model.has_gripper:
            g = self._hard[axis]
            cmd[axis] = min(max(cmd[axis], g.lower), g.upper)
        if np.any(too_fast):
            i = int(np.argmax(np.abs(step) / (self._vmax * self.dt)))
            self._raise(AlarmCode.OVERSPEED, AlarmType.FAULT,
                        f"position command asks J{i + 1} for {abs(step[i]) / self.dt:.3g} per s, "
                        f"above {OVERSPEED_MARGIN:g} x its rated {self._vmax[i]:.3g}; not applied")
            return
        qd = step / self.dt
        self.qdd = (qd - self.qd) / self.dt
        self.q, self.qd = cmd, qd
        self._cmd_moving = True

    # -- actions (loop thread only: call them through call() from elsewhere) -----
    def brake(self) -> None:
        """Controlled stop from the commanded state; the FIFO is emptied."""
        self._fifo.clear()
        if self._braking is None and np.any(np.abs(self.qd) > 0.0):
            self._braking = Braking(self.q, self.qd, self.qdd, self._amax, self._jmax, self.dt)

    def emergency_stop(self) -> None:
        log.error("emergency stop")
        self._raise(AlarmCode.EMERGENCY_STOP, AlarmType.FAULT, "emergency stop")

    def _raise(self, code: AlarmCode, kind: AlarmType, description: str) -> None:
        if int(code) not in self.alarms:
            self.alarms[int(code)] = Alarm(int(code), kind, description)
            log.error("alarm 0x%02x %s: %s", code, kind.value, description)
        self.brake()
        if kind is AlarmType.FAULT and self.servo_on:
            self.servo_on = False
            log.warning("servo off after %s fault", code.name)

    def servo_on_now(self) -> str | None:
        """Servo on; returns why not, or None."""
        if self.alarms:
            return "alarms active: " + ", ".join(f"0x{c:02x}" for c in self.alarms) + "; clear them first"
        if self._braking is not None:
            return "the arm is still stopping"
        if not self.servo_on:
            self.q = self.fb_pos.copy()  # hold where the brakes held it
            self.qd = np.zeros_like(self.qd)
            self.qdd = np.zeros_like(self.qdd)
            self._cmd_moving = False
            self._fifo.clear()
            self._interrupted = False
            self.servo_on = True
            log.info("servo on")
        return None

    def servo_off_now(self) -> None:
        if self.servo_on:
            self.servo_on = False
            log.info("servo off")
        self.brake()

    def clear_alarms_now(self) -> tuple[list[Alarm], list[Alarm]]:
        """Clear alarms whose cause has gone; returns (cleared, still active)."""
        cleared, kept = [], []
        for code, alarm in list(self.alarms.items()):
            if self._cause_present(code):
                kept.append(alarm)
            else:
                cleared.append(self.alarms.pop(code))
        for a in cleared:
            log.info("alarm 0x%02x cleared", a.code)
        return cleared, kept

    def _cause_present(self, code: int) -> bool:
        if code == AlarmCode.SOFT_LIMIT_JOINT:
            return any(not lim.lower - LIMIT_TOLERANCE <= q <= lim.upper + LIMIT_TOLERANCE
                       for q, lim in zip(self.fb_pos, self.soft_limits))
        if code == AlarmCode.OVERSPEED:
            return self._braking is not None
        return False  # emergency stop: a put is an event, gone once acknowledged

    def set_soft_limits_now(self, limits: tuple[LimitValue, ...]) -> str | None:
        if self.state_bits & StateBit.MOVING:
            return "the arm is moving"
        if self.alarms:
            return "an alarm is active"
        self.soft_limits = limits
        log.info("joint soft limits set: %s", [(lim.lower, lim.upper) for lim in limits])
        return None

    # -- state and publishing -------------------------------------------------------
    def _bits(self, vel: list[float]) -> int:
        bits = 0
        if self.servo_on:
            bits |= StateBit.SERVO_ON
        if (self._braking is not None or self._fifo or self._cmd_moving
                or max(abs(v) for v in vel) > REST_SPEED):
            bits |= StateBit.MOVING
        if self.alarms:
            bits |= StateBit.ALARM
        return int(bits)

    def _publish_status(self, tm: Time) -> None:
        st = messages.ServoStatus(
            tm, self.servo_on, bool(self.state_bits & StateBit.MOVING), bool(self.alarms),
            len(self._fifo), self.consumed, self.received, self.underruns,
            tuple(self.fb_vel.tolist()), tuple(self.fb_eff.tolist()), tuple(self.q.tolist()))
        self._status_pub.put(codec.encode_message(messages.SERVO_STATUS, st))

    def _publish_health(self) -> None:
        st, self._stats = self._stats, _Stats()
        lat = np.array(st.lateness) if st.lateness else np.zeros(1)
        hist = np.histogram(lat, bins=list(messages.LATENESS_BIN_EDGES) + [np.inf])[0]
        msg = messages.LoopHealth(
            Time.now(), len(st.lateness), self.dt, float(np.percentile(lat, 50)),
            float(np.percentile(lat, 99)), float(lat.max()), st.late, st.overruns,
            len(self._fifo), st.underruns, tuple(int(c) for c in hist))
        self._health_pub.put(codec.encode_message(messages.LOOP_HEALTH, msg))
        if st.late > 0.01 * max(1, len(st.lateness)) or st.overruns:
            log.warning("servo loop: %d of %d cycles late by more than one period, %d overruns, "
                        "max lateness %.2f ms", st.late, len(st.lateness), st.overruns, lat.max() * 1e3)
