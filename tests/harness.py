"""The live harness: one way to launch the system, and one client-side arm helper built from small parts.

``launched()`` starts ``jara-arm up`` (the whole system) on a loopback port of its own. ``LiveArm`` is a
client of a live arm, whichever processes run it: that system, or a rig of some of its services
(``Processes`` starts and checks those). It holds what every live test checks the arm by: Common, Middle
and Ext calls checked OK, state and joints, waits for rest, FK, clearing alarms, the servo's clock and
newest status, and the process log that explains a failure. ``RecordingArm`` adds a recorder of every
feedback sample.

The parts, for the rigs that need more: ``Recorder`` (every sample of a joint stream), ``StatusLog``
(every servo status), ``Newest`` (the newest message of a key), ``ServoTime`` (the servo's own clock),
``PosCommands`` (a low-level client's position commands) and ``Ticker`` (what a fake peer publishes on its
own). conftest.py's ``live`` and ``arm`` fixtures give a module the system of one robot with its ``Arm``.
"""

from __future__ import annotations

import concurrent.futures
import contextlib
import functools
import os
import re
import signal
import threading
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from typing import Any, Generic, TypeVar

import numpy as np
import zenoh

from jara_arm.client import StateTimeout
from jara_arm.kinematics import Kinematics
from jara_arm.robots import RobotModel, robot
from jara_arm.schema import codec, messages
from jara_arm.schema import wire_types as w
from jara_arm.schema.codec import Reply
from jara_arm.schema.codes import ReturnCode, StateBit
from jara_arm.schema.keys import ArmKeys, Service, arm_of
from jara_arm.schema.operations import OP, Interface
from jara_arm.schema.types import CarPosWithElbow, Time, TimedJointPos, hg_matrix

from .support import (LAUNCHER, STREAM_PRIORITY, Client, Proc, free_port, processes_with, realtime_process_section,
                      wait_until)

T = TypeVar("T")
#: Within this of the ready pose on every axis [rad or m], ``reset`` leaves the arm where it is: a test that did not
#: move it left it at home to within the servo's tracking (about 1e-6).
AT_HOME = 1e-4
Explain = Callable[[], str]
_STARTED = re.compile(r"started (\S+) \((\S+)\): pid (\d+)")
#: Threads that ask the arm's independent calls at once (``LiveArm.reset``).
_CALLS = concurrent.futures.ThreadPoolExecutor(8, thread_name_prefix="arm-call")


# ---------------------------------------------------------------------------- processes


@contextlib.contextmanager
def launched(*args: str, scheme: str = "tcp", timeout: float = 60.0, checked: bool = True
             ) -> Iterator[tuple[Proc, int]]:
    """``jara-arm up`` (the full system) listening on a loopback port of its own (``scheme`` ``tcp``, or ``tls``
    with ``--secure``), ready; stopped afterwards, and required to exit 0 if ``checked`` (not: a test that
    kills the launcher itself)."""
    port = free_port()
    proc = Proc([*LAUNCHER, "up", "--listen", f"{scheme}/127.0.0.1:{port}", *args])
    try:
        proc.wait_for_line("jara-arm: ready", timeout=timeout)
        yield proc, port
    finally:
        code = proc.stop(signal.SIGINT, timeout=20)
        for pid in processes_with(f"127.0.0.1:{port}"):  # only after a failure: none left to the next test
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)
        assert code == 0 or not checked, f"launcher exit {code}:\n{proc.output[-4000:]}"


def listening(proc: Proc) -> str:
    """The endpoint a launched system listens on: where a client or a ``jara-arm`` process connects."""
    return proc.argv[proc.argv.index("--listen") + 1]


class Processes:
    """The service processes of a rig (a context): stopped in reverse order at its end, each one started
    ``checked`` required to exit 0 without a traceback."""

    def __init__(self) -> None:
        self._started: list[tuple[Proc, bool]] = []

    def start(self, argv: Sequence[str], checked: bool = True) -> Proc:
        proc = Proc(argv)
        self._started.append((proc, checked))
        return proc

    def __enter__(self) -> Processes:
        return self

    def __exit__(self, *exc: object) -> None:
        # All stopped before any is judged: a failed check must not leave the others running.
        stopped = [(proc, checked, proc.stop()) for proc, checked in reversed(self._started)]
        for proc, checked, code in stopped:
            if checked:
                assert code == 0, f"{proc.argv} exited with {code}:\n{proc.output}"
                assert "Traceback" not in proc.output, proc.output


# ---------------------------------------------------------------------------- the parts


def timed_joints(sample: zenoh.Sample) -> TimedJointPos:
    """A ``Servo/posFeedback`` or ``Servo/posTarget`` sample, decoded."""
    msg: TimedJointPos = codec.decode_message(w.TIMED_JOINT_POS, sample.payload.to_bytes())
    return msg


def feedback_block(sample: zenoh.Sample) -> messages.FeedbackBlock:
    """A ``Servo/posFeedbackBlock`` sample, decoded."""
    msg: messages.FeedbackBlock = codec.decode_message(messages.FEEDBACK_BLOCK, sample.payload.to_bytes())
    return msg


def servo_status(sample: zenoh.Sample) -> messages.ServoStatus:
    """A ``Servo/status`` sample, decoded."""
    msg: messages.ServoStatus = codec.decode_message(messages.SERVO_STATUS, sample.payload.to_bytes())
    return msg


class Newest(Generic[T]):
    """The newest message on ``key``: a ring of one, so a poll sees what is newest now, not every message."""

    def __init__(self, session: zenoh.Session, key: str, decode: Callable[[zenoh.Sample], T]) -> None:
        self._sub = session.declare_subscriber(key, zenoh.handlers.RingChannel(1))
        self._decode = decode
        self._latest: T | None = None

    def poll(self) -> T | None:
        """A message newer than the one read last, or None."""
        sample = self._sub.try_recv()
        if sample is None:
            return None
        self._latest = self._decode(sample)
        return self._latest

    def current(self) -> T | None:
        """The newest message read so far, a newer one read first if there is one (None before the first)."""
        self.poll()
        return self._latest

    def wait(self, predicate: Callable[[T], Any], what: str, timeout: float = 10.0, interval: float = 0.005) -> T:
        """Until a message newer than the one read last satisfies ``predicate``; that message."""
        def found() -> T | None:
            msg = self.poll()
            return msg if msg is not None and predicate(msg) else None

        value: T = wait_until(found, timeout, interval, what)
        return value


class ServoTime:
    """The servo's own clock and joints, read from its newest ``Servo/posFeedback`` sample.

    A sample's ``tm`` is the time its cycle stands for (at rest the cycle's wall-clock
    deadline; a cycle never runs before its deadline), so a sample stamped ``t`` or
    later proves that the servo ran a cycle at ``t`` or later. Observation windows
    ("nothing moves for 0.3 s") are measured on it: a window of the servo's time has
    really been run through by the servo, however slowly the machine went, which a
    wall-clock sleep does not prove.
    """

    def __init__(self, session: zenoh.Session, keys: ArmKeys) -> None:
        self._feedback = Newest(session, keys.pos_feedback, timed_joints)

    def sample(self, timeout: float = 5.0) -> tuple[float, np.ndarray]:
        """``(tm [s], joints)`` of a sample newer than the one read last, waiting for it."""
        msg = self._feedback.wait(lambda _msg: True, "a servo feedback sample", timeout, 0.002)
        return msg.tm.to_seconds(), np.array(msg.pos)

    def passes(self, seconds: float, timeout: float = 10.0) -> None:
        """Until the servo has stamped a sample ``seconds`` [s] after now: an observation window
        of ``seconds`` of the servo's own cycles."""
        end = time.time() + seconds
        wait_until(lambda: self.sample(timeout)[0] >= end, seconds + timeout, 0.002,
                   f"the servo's clock {seconds:g} s on")

    def settled(self, apart: float = 0.02, tol: float = 1e-9, timeout: float = 10.0) -> np.ndarray:
        """Until two samples ``apart`` [s] of the servo's time show the same joints (within
        ``tol``): the arm at rest and settled (the servo then holds it exactly where it is);
        those joints."""
        first = [self.sample(timeout)]

        def still():
            tm, q = self.sample(timeout)
            t0, q0 = first[0]
            if tm - t0 < apart:
                return None
            if np.abs(q - q0).max() <= tol:
                return (q,)
            first[0] = (tm, q)
            return None

        return wait_until(still, timeout, 0.002, "the arm at rest and settled")[0]


class Recorder:
    """Every sample of a joint stream (``Servo/posFeedback``, ``Servo/posTarget``) since the last read; or of
    the 1 kHz feedback in the servo's blocks (``Servo/posFeedbackBlock``): the same samples, ten to a message.

    ``RecordingArm`` records the blocks: a client of ``Servo/posFeedback`` makes the client gateway relay
    each block sample by sample, which cost the system 0.06 core more than a client of the blocks (an idle
    iiwa, every process of its system over 15 s each, 2026-12-05: 0.17 core alone, 0.29 with a subscriber
    of the samples, 0.23 with one of the blocks); the recorders of a suite run for minutes."""

    def __init__(self, session: zenoh.Session, key: str, explain: Explain | None = None) -> None:
        # A FIFO, not a ring: every sample counts (a gap would look like a jump). It is bounded (over two
        # minutes of feedback): its holder reads or clears it at least once per test.
        self._sub = session.declare_subscriber(key, zenoh.handlers.FifoChannel(1 << 17))
        self._blocks = key == ArmKeys(arm_of(key)).pos_feedback_block
        self._explain = explain

    def _take(self) -> list[TimedJointPos]:
        """The samples that arrived since the last take, decoded, oldest first."""
        got = list(iter(self._sub.try_recv, None))
        if not self._blocks:
            return [timed_joints(s) for s in got]
        return [m for s in got for m in feedback_block(s).samples]

    def clear(self, timeout: float = 10.0) -> None:
        """Forget what was recorded so far and what of it is still on its way: every sample up to the first
        one the servo stamped now or later (it stamps every cycle; at rest with the cycle's wall-clock
        time). On a saturated host the gateway's relay (normal priority) fell seconds behind: a LIN recorded
        from a plain clear began 45 mm off its line (fresh-clone run 104, a busy loop per core), and with a
        1 s bound here a blended square's recording began with the previous test's stop at a corner (run
        107). Without such a sample within ``timeout`` [s] (a servo stopped or gone), what arrived."""
        now = time.time()
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if any(m.tm.to_seconds() >= now for m in self._take()):
                return
            time.sleep(0.002)

    def timed(self) -> tuple[np.ndarray, np.ndarray]:
        """``(tm [s], joints)`` of every sample since the last read (the servo's times: a lost sample leaves a
        gap)."""
        msgs = self._take()
        return np.array([m.tm.to_seconds() for m in msgs]), np.array([m.pos for m in msgs])

    def through(self, t: float, timeout: float = 5.0) -> tuple[np.ndarray, np.ndarray]:
        """``(tm [s], joints)`` since the last read, up to (at least) a sample the servo stamped ``t`` [s] or
        later (a cycle never runs before its deadline, its stamp at rest)."""
        tms: list[np.ndarray] = []
        qs: list[np.ndarray] = []

        def through() -> bool:
            tm, q = self.timed()
            if len(tm):
                tms.append(tm)
                qs.append(q)
            return bool(tms) and tms[-1][-1] >= t

        wait_until(through, timeout, 0.005, f"a feedback sample stamped {t:.3f} or later", explain=self._explain)
        return np.concatenate(tms), np.concatenate(qs)


class StatusLog:
    """Every ``Servo/status`` since the last read."""

    def __init__(self, session: zenoh.Session, keys: ArmKeys, explain: Explain | None = None) -> None:
        self._sub = session.declare_subscriber(keys.servo_status, zenoh.handlers.FifoChannel(1 << 14))
        self._explain = explain

    def drain(self) -> list[messages.ServoStatus]:
        """The statuses since the last read, oldest first."""
        return [servo_status(s) for s in iter(self._sub.try_recv, None)]

    def until(self, predicate: Callable[[messages.ServoStatus], Any], what: str,
              timeout: float = 5.0) -> list[messages.ServoStatus]:
        """The statuses since the last read, up to (at least) one for which ``predicate`` holds, waiting for it."""
        got: list[messages.ServoStatus] = []
        wait_until(lambda: got.extend(self.drain()) or any(predicate(s) for s in got), timeout, 0.005, what,
                   explain=self._explain)
        return got

    def first(self, predicate: Callable[[messages.ServoStatus], Any], what: str,
              timeout: float = 5.0) -> messages.ServoStatus:
        """The first status (those already queued included) for which ``predicate`` holds, waiting for it;
        the statuses before it, and those read with it, are gone."""
        status: messages.ServoStatus = wait_until(
            lambda: next((st for st in self.drain() if predicate(st)), None), timeout, 0.005, what,
            explain=self._explain)
        return status

    def newest(self, timeout: float = 2.0) -> messages.ServoStatus:
        """The newest status, waiting for one (at rest the servo sends one every 100 ms)."""
        statuses: list[messages.ServoStatus] = wait_until(lambda: self.drain() or None, timeout, 0.005,
                                                          "a servo status", explain=self._explain)
        return statuses[-1]


class PosCommands:
    """A low-level client's position commands to the servo (``Servo/posCmd``), one per ``cycle`` [s];
    ``options`` are the publisher's."""

    def __init__(self, session: zenoh.Session, keys: ArmKeys, cycle: float, **options: Any) -> None:
        self._pub = session.declare_publisher(keys.pos_cmd, **options)
        self._cycle = cycle

    def put(self, payload: bytes) -> None:
        """A payload as it is (bad-input tests)."""
        self._pub.put(payload)

    def send(self, q: Sequence[float]) -> float:
        """One position command, stamped now; the time it was published [s]."""
        self._pub.put(codec.encode_message(w.TIMED_JOINT_POS, TimedJointPos(Time.now(), tuple(map(float, q)))))
        return time.time()

    def stream(self, points: np.ndarray, lead: int = 400, realtime: bool = True) -> list[float]:
        """Publish ``points`` keeping ``lead`` commands ahead of the servo, then one per cycle; their
        publication times. ``realtime``: every thread of this process at ``STREAM_PRIORITY`` meanwhile, as a
        low-level client's stack must be (``realtime_process_section``): at normal priority beside a busy loop per
        core a stream ran dry mid-motion, and with the sending thread alone at real-time priority a stream sent
        whole ran dry 0.2 s in, its samples waiting in the session's transmission thread.

        400 ahead: at 100, beside a busy loop per core and another worker's cell (whose servo and bus run at
        higher real-time priorities than this stream), the stream was held up long enough that the servo
        rightly ran dry and stopped a third of the way (CI run 81), as the alarm tests' stream once did, held up
        300 ms at normal priority."""
        sent = []
        with realtime_process_section(STREAM_PRIORITY) if realtime else contextlib.nullcontext():
            t0 = time.monotonic()
            for k, q in enumerate(points):
                sent.append(self.send(q))
                if k >= lead:
                    delay = t0 + (k - lead) * self._cycle - time.monotonic()
                    if delay > 0:
                        time.sleep(delay)
        return sent

    def close(self) -> None:
        self._pub.undeclare()


class Ticker:
    """``tick()`` every ``period`` [s] on a daemon thread until ``close()``: what a fake peer publishes on its
    own."""

    def __init__(self, period: float, tick: Callable[[], None]) -> None:
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, args=(period, tick), daemon=True)
        self._thread.start()

    def _run(self, period: float, tick: Callable[[], None]) -> None:
        while not self._stop.wait(period):
            tick()

    @property
    def closed(self) -> bool:
        return self._stop.is_set()

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2.0)


# ---------------------------------------------------------------------------- the arm


class LiveArm:
    """A client of a live arm and what the tests check it by.

    ``proc`` is the process whose log explains a failure: the launcher, or a rig's service. A rig
    without a command service overrides ``common`` (the servo's own Common interface), and the rest
    follows. Its clock, its newest status and its kinematics are made on first use: the servo
    publishes its feedback only while someone subscribes to it.
    """

    def __init__(self, session: zenoh.Session, robot_name: str = "iiwa", arm: str = "arm0",
                 proc: Proc | None = None) -> None:
        self.session = session
        self.client = Client(session, arm)
        self.keys = self.client.keys
        self.model: RobotModel = robot(robot_name)
        self.n = self.model.axis_num
        self.proc = proc
        self.held: messages.ServoStatus | None = None  # the status target() read: where a stream started

    @functools.cached_property
    def kin(self) -> Kinematics:
        """Kinematics of the arm, for FK (no IK here: no seed table)."""
        return Kinematics(self.model, seed_table=0)

    @functools.cached_property
    def servo_time(self) -> ServoTime:
        return ServoTime(self.session, self.keys)

    @functools.cached_property
    def status(self) -> Newest[messages.ServoStatus]:
        """The servo's newest status."""
        return Newest(self.session, self.keys.servo_status, servo_status)

    @property
    def endpoint(self) -> str:
        """Where the launched system listens: what a ``jara-arm`` process connects to."""
        assert self.proc is not None
        return listening(self.proc)

    # -- calls ------------------------------------------------------------------------
    def common(self, name: str, args: Mapping[str, Any] | None = None) -> Reply:
        return self.client.common(name, args)

    def middle(self, name: str, args: Mapping[str, Any] | None = None) -> Reply:
        return self.client.middle(name, args)

    def ext(self, name: str, args: Mapping[str, Any] | None = None) -> Reply:
        return self.client.ext(name, args)

    def servo(self, name: str, args: Mapping[str, Any] | None = None) -> Reply:
        return self.client.servo(name, args)

    def ok(self, reply: Reply) -> Reply:
        """``reply``, checked OK."""
        assert reply.id == ReturnCode.OK, f"{reply}\n{self.explain()}"
        return reply

    def call_ok(self, interface: Interface, name: str, args: Mapping[str, Any] | None = None) -> Reply:
        """``name`` of ``interface`` called, its reply checked OK."""
        reply = self.client.call(interface, name, args)
        assert reply.id == ReturnCode.OK, f"{name}: {reply}\n{self.explain()}"
        return reply

    def clear(self, timeout: float = 5.0) -> Reply:
        """clearAlarms until it says OK (a cause may take a moment to go)."""
        return wait_until(lambda: (r := self.common(OP.clearAlarms)).id == ReturnCode.OK and r, timeout, 0.05,
                          "clearAlarms to succeed",
                          explain=lambda: f"{self.common(OP.clearAlarms)}\n{self.log_tail()}")

    # -- where the arm is -------------------------------------------------------------
    def state(self) -> int:
        return int(self.common(OP.getState)["state"])

    def joints(self) -> np.ndarray:
        return np.asarray(self.common(OP.getFeedbackPosJoint)["pos"])

    def cartesian(self) -> CarPosWithElbow:
        """``getFeedbackPosCartesian``: the control point's pose, elbow and posture bits."""
        pos: CarPosWithElbow = self.middle(OP.getFeedbackPosCartesian)["pos"]
        return pos

    def pose(self) -> np.ndarray:
        """The control point's pose (4 x 4) as ``getFeedbackPosCartesian`` gives it."""
        pose = np.eye(4)
        pose[:3] = np.asarray(self.cartesian().carPos)
        return pose

    def fk(self, q: Any = None) -> np.ndarray:
        """Flange pose (4 x 4, arm frame, identity offsets) at joints ``q`` (default: the joint feedback now)."""
        return self.kin.fk(np.asarray(self.joints() if q is None else q)[: self.n]).homogeneous

    def points(self, q: np.ndarray) -> np.ndarray:
        """Flange positions (N, 3) [m] (identity offsets) of joint samples (N, dof)."""
        return np.array([self.kin.fk(x[: self.n]).translation for x in q])

    def target(self) -> np.ndarray:
        """The joints the servo holds the arm at: where a motion or a low-level stream starts.

        From a status the servo stamped after this call began: one still in transit may be
        from before a servoON, which holds the arm where its brakes held it, not at the old target.
        """
        now = time.time()
        self.held = self.status.wait(lambda st: st.tm.to_seconds() >= now, "a servo status stamped now", 2.0)
        return np.array(self.held.target)

    def wait_status(self, what: str, predicate: Callable[[messages.ServoStatus], Any],
                    timeout: float = 10.0) -> messages.ServoStatus:
        """A servo status (the newest, polled) for which ``predicate`` holds."""
        return self.status.wait(predicate, what, timeout)

    def pid(self, service: Service) -> int:
        """The pid of the newest process of ``service`` the launcher started."""
        assert self.proc is not None
        return [int(m[3]) for line in list(self.proc.lines)
                if (m := _STARTED.search(line)) and m[1] == service.value][-1]

    # -- waits ------------------------------------------------------------------------
    def idle(self, timeout: float = 60.0) -> None:
        """Until the arm neither moves nor has motions queued, or is paused, or has an alarm
        (``Arm.wait_idle``)."""
        self.client.wait_idle(timeout)

    def wait_rest(self, timeout: float = 10.0) -> None:
        """Until bit 0x02 is clear: the arm at rest, nothing queued, whatever else the state says."""
        if type(self).common is not LiveArm.common:  # a rig without the command service: no ``state`` published
            wait_until(lambda: not self.state() & StateBit.MOVING, timeout, what="the arm at rest")
            return
        try:
            self.client.wait_state(lambda s: not s & StateBit.MOVING, timeout)
        except StateTimeout as exc:
            raise AssertionError(f"timed out after {timeout} s waiting for the arm at rest: {exc}\n{self.explain()}")

    # -- the starting point -----------------------------------------------------------
    def reset(self) -> None:
        """Back to where the live tests start: nothing moving, no alarm, servo on, identity offsets, the hard
        limits as soft limits, speed ratios 100 %, at the ready pose (home)."""
        state = self.state()
        if state & StateBit.MOVING:
            self.middle(OP.stop)
            self.idle()
            state = self.state()
        if state & StateBit.ALARM:
            self.common(OP.clearAlarms)
        # Independent of each other: asked at once, one round trip instead of six (a reset before each of
        # ~400 live tests). setHome comes after the soft limits: a home outside the old ones is refused.
        asked = [_CALLS.submit(call, name, args) for call, name, args in (
            (self.common, OP.servoON, None),
            (self.middle, OP.setBaseOffset, {"offset": hg_matrix()}),
            (self.middle, OP.setControlPointOffset, {"offset": hg_matrix()}),
            (self.common, OP.setSoftLimitJoint, {"softLimit": self.model.hard_limits}),
            (self.middle, OP.setSpeedJoint, {"spdRatio": 100}),
            (self.middle, OP.setSpeedCartesian, {"spdRatio": 100}))]
        joints = _CALLS.submit(self.joints)
        for reply in asked:
            self.ok(reply.result())
        self.ok(self.middle(OP.setHome, {"jointPoint": self.model.ready_pose}))
        ready = np.asarray(self.model.ready_pose)
        if np.abs(joints.result()[:len(ready)] - ready).max() > AT_HOME:  # a goHome costs a plan and a handover
            self.home()

    def home(self) -> None:
        self.ok(self.middle(OP.goHome))
        self.idle()

    # -- what a failure report needs ----------------------------------------------------
    def log_tail(self, lines: int = 30, keys: Sequence[str] = (), proc: Proc | None = None) -> str:
        """The last ``lines`` of ``proc``'s output (default: this arm's process), the servo's loop timing
        reports left out; only those with one of ``keys`` if given."""
        proc = proc or self.proc
        if proc is None:
            return ""
        kept = [line for line in list(proc.lines)
                if "servo loop:" not in line and (not keys or any(k in line for k in keys))]
        return "\n".join(kept[-lines:])

    def explain(self, lines: int = 40) -> str:
        """The state, the active alarms and the last log lines."""
        try:
            state = f"state 0x{self.state():02x}, alarms {self.common(OP.getActiveAlarm)['alarms']}"
        except Exception as exc:  # the report must not hide the failure it explains
            state = f"state unknown ({exc})"
        return f"{state}\n{self.log_tail(lines)}"


class RecordingArm(LiveArm):
    """A ``LiveArm`` that records every feedback sample; ``record()`` (and ``reset()``) forgets them."""

    #: Record the servo's blocks (``Recorder``), where a client gateway relays the samples to the others. A rig
    #: whose test talks to the servo directly records the samples: there a subscriber of the blocks would leave
    #: every subscriber of the samples (``ServoTime``) without any, as the servo then builds blocks only.
    BLOCKS = True

    def __init__(self, session: zenoh.Session, robot_name: str = "iiwa", arm: str = "arm0",
                 proc: Proc | None = None) -> None:
        super().__init__(session, robot_name, arm, proc)
        key = self.keys.pos_feedback_block if self.BLOCKS else self.keys.pos_feedback
        self.fb = Recorder(session, key, explain=self.log_tail)

    def reset(self) -> None:
        super().reset()
        self.record()

    def record(self) -> None:
        """Forget the feedback recorded so far, that still on its way included: what follows is recorded."""
        self.fb.clear()

    def recorded(self) -> np.ndarray:
        """The joints of every feedback sample since the last read."""
        return self.fb.timed()[1]

    def recorded_timed(self) -> tuple[np.ndarray, np.ndarray]:
        """``(tm [s], joints)`` of every feedback sample since the last read."""
        return self.fb.timed()

    def recorded_through(self, t: float, timeout: float = 5.0) -> tuple[np.ndarray, np.ndarray]:
        """``(tm [s], joints)`` since the last read, up to (at least) a sample the servo stamped ``t`` [s] or
        later."""
        return self.fb.through(t, timeout)
