"""The alarm tests' system and what they check after each fault (``test_alarms_motion.py``,
``test_alarms_services.py``, ``bench/alarm_latency.py``).

``jara-arm up`` with servo, planner, command, alarm monitor, and an obstacle box in the
simulated world; ``AlarmArm``, a client of it that records the alarm events (with their
receipt times), every feedback sample and status, and sends a low-level client's position
commands. For each fault the tests check: the alarm in ``getActiveAlarm`` of both Common
interfaces with its code and type, bit 0x04 of both ``getState``, the arm at rest without a
jump (no feedback acceleration beyond the axes' limits), the motion queue discarded, and
``clearAlarms`` plus ``servoON`` bringing the arm back to work once the cause has gone.
Detection latencies (cause -> alarm event received here) are kept in ``LATENCIES``.
"""

from __future__ import annotations

import contextlib
import dataclasses
import sys
import time
from collections.abc import Callable, Iterator

import numpy as np
import zenoh

from jara_arm.kinematics import Kinematics
from jara_arm.robots import robot
from jara_arm.schema import messages
from jara_arm.schema.alarms import AlarmEventKind
from jara_arm.schema.codes import AlarmCode, AlarmType, StateBit
from jara_arm.schema.keys import Service
from jara_arm.schema.operations import OP
from jara_arm.schema.planner import MOTION_SETTINGS
from jara_arm.services.runtime.wire import decode_sample

from .harness import Newest, PosCommands, RecordingArm, StatusLog, launched
from .support import Proc, client_session, wait_alive, wait_until

IIWA = robot("iiwa")
N = IIWA.axis_num
DT = IIWA.cmd_cycle
AMAX = np.array(IIWA.max_accel)
READY = np.array(IIWA.ready_pose)


def _obstacle() -> str:
    """A box on the circle the flange of the ready pose follows when J1 turns, 0.5 rad ahead.

    Turning J1 positive by about 0.3 rad runs the wrist into it; nothing else
    in these tests goes there.
    """
    x, y, z = Kinematics(IIWA, seed_table=0).fk(READY).translation
    r, a = float(np.hypot(x, y)), float(np.arctan2(y, x)) + 0.5
    return f"{r * np.cos(a):.3f},{r * np.sin(a):.3f},{z:.3f},0.05,0.05,0.15"


OBSTACLE = _obstacle()
#: Feedback acceleration allowed while stopping, per axis: the limit x 1.5 (simulation noise) [rad/s^2].
ACC_ALLOWED = AMAX * 1.5
#: [s] of feedback, stamped by the servo, recorded after the arm was seen at rest: what "at rest
#: at the end of the recording" is judged on.
REST_TAIL = 0.05
ALL_SERVICES = [Service.SERVO, Service.PLANNER, Service.COMMAND, Service.ALARM_MONITOR]
LATENCIES: dict[str, list[float]] = {}  # [ms] per scenario


@dataclasses.dataclass(frozen=True)
class Streamed:
    """A low-level stream and the alarm event it raised (:meth:`AlarmArm.stream_to`)."""

    path: np.ndarray  # [rad] the commands streamed, one per servo cycle
    base: int  # the commands the servo had taken before it (``consumed``)
    sent: list[float]  # [s, wall] each command's publication
    t: float  # [s, wall] the event's receipt
    event: messages.AlarmEvent


class AlarmArm(RecordingArm):
    """The client of the alarm tests: the alarm events received, every feedback sample and servo status
    since ``mark()``, the command's newest settings, and a low-level client's position commands."""

    def __init__(self, session: zenoh.Session, robot_name: str = "iiwa", arm: str = "arm0",
                 proc: Proc | None = None) -> None:
        super().__init__(session, robot_name, arm, proc)
        self.events: list[tuple[float, messages.AlarmEvent]] = []
        # A callback that only stamps and stores: the receipt time is what is measured.
        self._event_sub = session.declare_subscriber(
            self.keys.alarm, lambda s: self.events.append(
                (time.time(), decode_sample(messages.ALARM_EVENT, s))))
        self.statuses = StatusLog(session, self.keys, explain=self.log_tail)
        # Every command counts (SyncFIFO): block rather than drop one (a gap is a jump).
        self.commands = PosCommands(session, self.keys, DT, express=True,
                                    congestion_control=zenoh.CongestionControl.BLOCK)
        # The command's settings (on every change and at 4 Hz): what the alarm monitor judges
        # the control point by.
        self.settings = Newest(session, self.keys.command_settings, lambda s: decode_sample(MOTION_SETTINGS, s))
        self.cart_limits = self.middle(OP.getSoftLimitCartesian)

    def mark(self) -> int:
        """Forget the recorded feedback and statuses; the index of the next alarm event."""
        self.record()
        self.statuses.drain()
        return len(self.events)

    def event(self, code: AlarmCode, since: int, kind: AlarmEventKind = AlarmEventKind.RAISED,
              timeout: float = 5.0) -> tuple[float, messages.AlarmEvent]:
        """The first ``kind`` event of ``code`` after index ``since``: (receipt time [s], event)."""
        def find():
            for t, e in self.events[since:]:
                if e.event == kind.value and e.alarm.code == code:
                    return t, e
            return None
        try:
            return wait_until(find, timeout, 0.002, f"{kind.value} event of 0x{code:02x}")
        except AssertionError as exc:
            raise AssertionError(f"{exc}; events {self.events[since:]}; log:\n{self.log_tail()}") from None

    def stream_to(self, code: AlarmCode, make: Callable[[np.ndarray], np.ndarray]) -> Streamed:
        """Stream the low-level path ``make(target)`` from where the servo holds the arm, and wait for the
        ``code`` event it must raise. A stream that ran dry first (the servo's controlled stop, which it logs
        and rightly raises nothing for) is said on stderr and streamed again from where the arm stopped, once:
        this client's 1 kHz stream crosses the client gateway, at normal priority by design, and on a
        saturated host (three test workers, CI runs 84 and 93) it was held up long enough (README, "plain
        client")."""
        lines = len(self.proc.lines) if self.proc is not None else 0
        try:
            return self._stream_once(code, make)
        except AssertionError:
            if self.proc is None or not any("ran dry" in line for line in self.proc.lines[lines:]):
                raise
            print(f"the stream ran dry before its 0x{code:02x}: streamed again from where the arm stopped\n"
                  f"{self.log_tail()}", file=sys.stderr)
            self.wait_rest()
        return self._stream_once(code, make)

    def _stream_once(self, code: AlarmCode, make: Callable[[np.ndarray], np.ndarray]) -> Streamed:
        path = make(self.target())
        since, base = self.mark(), self.consumed()
        sent = self.commands.stream(path)
        t, event = self.event(code, since)
        return Streamed(path, base, sent, t, event)

    def under_way(self, base: int, cycles: int, timeout: float = 10.0) -> None:
        """Until the servo has taken ``cycles`` commands since it had taken ``base`` (``consumed``):
        the arm that far into its motion."""
        self.statuses.until(lambda s: s.consumed >= base + cycles,
                            f"the servo to take {cycles} commands since {base}", timeout)

    def consumed(self) -> int:
        """How many position commands the servo has taken from its FIFO so far."""
        return self.statuses.newest(1.0).consumed

    def consumed_at(self, statuses: list[messages.ServoStatus], count: int) -> float:
        """When [s, servo clock] the servo took its ``count``-th command (one per cycle)."""
        before = [s for s in statuses if s.consumed < count]
        assert before and any(s.consumed >= count for s in statuses), "command not seen consumed"
        return before[-1].tm.to_seconds() + (count - before[-1].consumed) * DT

    def wait_cartesian_box(self, box: dict, timeout: float = 5.0) -> None:
        """Until the command publishes its settings with the Cartesian soft limits ``box``
        (``xLimit``, ``yLimit``, ``zLimit``): the alarm monitor, subscribed to the same, has them."""
        want = tuple((box[k].upper, box[k].lower) for k in ("xLimit", "yLimit", "zLimit"))
        self.settings.wait(lambda s: tuple((lim.upper, lim.lower) for lim in s.softLimitCartesian) == want,
                           f"the command's settings with the Cartesian box {want}", timeout, 0.01)

    def goto(self, q: np.ndarray, speed: int = 60, attempts: int = 3) -> None:
        """A PTP to ``q``, run to its end (again if the planner gave up on it on a busy machine)."""
        self.ok(self.middle(OP.setSpeedJoint, {"spdRatio": speed}))
        for _ in range(attempts):
            self.ok(self.middle(OP.movePTPJointAbs, {"jointPoints": tuple(map(float, q))}))
            self.wait_rest()
            off = np.abs(self.joints() - q).max()
            if off < 2e-3:
                return
        raise AssertionError(f"the PTP stopped {off:.4f} short of its target:\n{self.log_tail()}")

    def reset(self) -> None:
        """At rest, no alarm, default limits, servo on, at the ready pose."""
        self.common(OP.servoOFF)
        self.wait_rest()
        self.clear()
        self.ok(self.common(OP.setSoftLimitJoint, {"softLimit": IIWA.hard_limits}))
        c = self.cart_limits
        self.ok(self.middle(OP.setSoftLimitCartesian, {k: c[k] for k in ("xLimit", "yLimit", "zLimit")}))
        self.ok(self.common(OP.servoON))
        self.goto(READY)
        assert self.common(OP.getActiveAlarm)["alarms"] == ()


@contextlib.contextmanager
def started_system() -> Iterator[AlarmArm]:
    """The system with the box (hidden from the planner, which would refuse to drive into a box it knows)
    and its ``AlarmArm``, once every service is alive; no service printed a traceback, at the end."""
    with launched("--hidden-obstacle", OBSTACLE) as (proc, port):
        with client_session(port) as session:
            wait_alive(session, "arm0", ALL_SERVICES, timeout=30)
            yield AlarmArm(session, proc=proc)
    assert "Traceback" not in proc.output, proc.output


def report_latencies() -> None:
    """Print the latencies measured since the last report (``pytest -s`` shows them), and forget them."""
    if not LATENCIES:
        return
    print("\nalarm detection latency, cause -> alarm event received [ms]:")
    for name, values in LATENCIES.items():
        v = np.array(values)
        print(f"  {name:<34} n={len(v)}  min {v.min():6.1f}  median {np.median(v):6.1f}  max {v.max():6.1f}")
    LATENCIES.clear()


def latency(name: str, cause: float, detected: float) -> float:
    ms = (detected - cause) * 1e3
    LATENCIES.setdefault(name, []).append(ms)
    print(f"\n{name}: alarm {ms:.1f} ms after its cause")
    return ms


# ---------------------------------------------------------------------------- checks


def check_alarm(arm: AlarmArm, code: AlarmCode, kind: AlarmType, servo_on: bool) -> None:
    """Both Common interfaces list it with its type; bit 0x04 in both getState; servo as expected."""
    for reply in (arm.common(OP.getActiveAlarm), arm.servo(OP.getActiveAlarm)):
        alarms = {a.code: a for a in arm.ok(reply)["alarms"]}
        assert code in alarms and alarms[code].type is kind and alarms[code].description, reply
    # The reaction (servo off on a FAULT) follows the event; give it a moment, not forever.
    def reacted() -> bool:
        states = (arm.state(), arm.servo(OP.getState)["state"])
        return all(st & StateBit.ALARM and bool(st & StateBit.SERVO_ON) == servo_on for st in states)

    def explain() -> str:
        return (f"command state {arm.state():#x}, servo state {arm.servo(OP.getState)['state']:#x}\n"
                f"{arm.common(OP.getActiveAlarm)}\n{arm.log_tail()}")

    wait_until(reacted, 1.0, what=f"bit 0x04 set and servo {'on' if servo_on else 'off'} on both levels",
               explain=explain)


def check_no_jump(arm: AlarmArm, since: float = 0.0, allowed: np.ndarray = ACC_ALLOWED) -> np.ndarray:
    """At rest, and the feedback (from ``since`` [s] on) never accelerated beyond ``allowed``; the last joints."""
    arm.wait_rest()
    tm, q = arm.recorded_through(time.time() + REST_TAIL)
    keep = tm >= since
    tm, q = tm[keep], q[keep]
    assert len(tm) > 50, "no feedback recorded"
    # Differences over one cycle only: a sample may be lost (newest value wins), and a
    # servo that was stopped (SIGSTOP) resumes its clock later while its arm did not move.
    dt = np.diff(tm)
    one = np.abs(dt - DT) < 0.25 * DT
    vel = np.diff(q, axis=0) / dt[:, None]
    both = one[1:] & one[:-1]
    acc = np.diff(vel, axis=0)[both] / dt[1:][both, None]
    assert len(acc) > 50, "too few consecutive feedback samples"
    peak = np.abs(acc[:, :N]).max(axis=0)
    if not np.all(peak <= allowed):
        k = int(np.argmax((np.abs(acc[:, :N]) / allowed).max(axis=1)))  # the sample furthest beyond
        at = tm[1:-1][both][k]
        near = np.flatnonzero(np.abs(tm - at) < 0.005)
        raise AssertionError(
            f"feedback acceleration {peak.round(2)} beyond {allowed.round(2)}, at t = {at - since:.4f} s after "
            f"the first command sent; the feedback around it (t [s] after it, joints):\n"
            + "\n".join(f"{tm[i] - since:.4f} {np.round(q[i, :3], 6)}" for i in near)
            + (f"\nbefore it, the servo held J1-J3 at {np.round(arm.held.target[:3], 7)}, measured "
               f"{np.round(arm.held.pos[:3], 7)}" if arm.held is not None else "")
            + f"\n{arm.log_tail(lines=60)}")
    assert np.abs(vel[-20:, :N]).max() < 1e-2, "not at rest at the end of the recording"
    return q[-1]


def check_queue_discarded(arm: AlarmArm) -> None:
    arm.wait_rest(5.0)  # MOVING covers the queue: at rest with nothing queued
    assert not arm.state() & StateBit.BUFFER_FULL


def check_back_to_work(arm: AlarmArm, servo_on_needed: bool = True) -> None:
    """Cause gone: clearAlarms OK, servoON OK, and a motion runs to its end."""
    arm.clear()
    assert arm.common(OP.getActiveAlarm)["alarms"] == () and arm.servo(OP.getActiveAlarm)["alarms"] == ()
    if servo_on_needed:
        assert not arm.state() & StateBit.SERVO_ON
    arm.ok(arm.common(OP.servoON))
    assert arm.state() == StateBit.SERVO_ON and arm.servo(OP.getState)["state"] == StateBit.SERVO_ON
    arm.goto(READY)
