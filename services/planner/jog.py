"""Jogging: ``Ext/jogJoint``, ``Ext/jogCartesian`` and ``Ext/jogStop``, a motion that goes on while its lease is renewed.

A jog is one motion of the servo's interpolator that this module keeps extending: it is handed over as a head
(``final`` false, as an early start's), and what the servo holds of it always ends **at rest, by the lease's
end plus** :data:`GRACE`: the jog's samples, then their stop. While the lease runs, the jog thread replaces that
stop with more of the jog and a new stop (a splice at the stop's first sample, at least :data:`LEAD` ahead of
the servo), every renewal and every :data:`TICK`, keeping about :data:`HORIZON` of path ahead. The ways it ends:

* **The lease lapses**: nothing replaces the stop. The arm is at rest by the lease's end plus ``GRACE`` (in
  planned time: at 100 % override), on the samples the servo holds: this process may be frozen or gone, the
  dead-man holds. A lapse is logged, not alarmed.
* **``jogStop``**: the servo is told to stop (``MotionAction.STOP``): it brakes on the buffered path at once,
  jerk-limited, and holds; the queue is discarded.
* **A limit ahead**: every extension is checked before it is handed over *with its stop* (joint soft limits,
  a Cartesian jog's nearness to a singularity (``jog_path.SINGULAR``), the Cartesian soft-limit box, the
  obstacles). An extension that fails is cut to its longest passing beginning and its stop (``final``): the
  arm stops before the limit, never past it, and the reply to the next renewal names the limit. A joint jog
  runs to its soft limit exactly (the profile's target is the limit).

A jog goes no faster than it can stop within half its lease (plus ``GRACE``, less ``TICK`` and ``LEAD``):
renewed at least twice per lease, it never begins the stop it holds. Renewed later, within the lease, it
slows down and goes on. The path and the speed along it: ``jog_path.py``; the speed override scales a jog in
the servo, as any motion.

No I/O but through :class:`~.handover.Handover`; tests: ``tests/test_jog.py``.

Over 500 lines on purpose: the ways a jog starts, is renewed, extended, cut before a limit, stopped and lapses
all read and change the one :class:`_Jog` under one lock, racing the client's renewals against the jog thread;
kept together, each rule about the lease is seen beside the others. What stands alone is outside: the path
and the speed along it (``jog_path.py``), the request (``jog_request.py``), the checks (``checks.py``).
"""

from __future__ import annotations

import dataclasses
import logging
import threading
import time
from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

from jara_arm.kinematics import Kinematics
from jara_arm.robots import Family, Obstacle, RobotModel
from jara_arm.schema.codes import ReturnCode
from jara_arm.schema.errors import WireError
from jara_arm.schema.motion import TrajectoryRefusal
from jara_arm.schema.operations import JOG_AXES, OP
from jara_arm.schema.planner import ControlAction, MotionSettings
from jara_arm.services.runtime.threads import LoopThread

from . import families
from .checks import Checks
from .collision import DEFAULT_MARGIN, PathChecker
from .frames import Frames
from .handover import Handover
from .jog_path import CartesianPath, JointPath, Track, speed_to_stop_within
from .jog_request import JogCommand
from .profile import ProfileLimits
from .request import PlanRefused
from .sampling import BatchFk
from .trajectory import Joints

log = logging.getLogger(__name__)

#: The jog thread looks at the lease and extends the jog this often [s].
TICK = 0.01
#: Path kept buffered ahead of the servo before the stop [s of planned time], for a long lease.
HORIZON = 0.3
#: A jog's first samples [s of planned time]; the jog thread adds the rest of HORIZON within a tick or two.
#: Planning 0.3 s of a Cartesian jog took 0.2 s beside two busy loops: its lease had nearly run out before the
#: reply left.
START = 0.1
#: The stop the servo holds ends this long after the lease [s]: the issue's bound is 50 ms; the other 30 ms
#: are for the renewal's way to this process (the lease runs from its arrival) and a late servo cycle.
GRACE = 0.02
#: A splice is sent this far ahead of the servo [s]: a tick's lateness and the way to the servo.
LEAD = 0.02
#: A joint jog stops this far inside its soft limit [rad or m]: the servo refuses a command outside it.
LIMIT_MARGIN = 1e-6
#: A jog that could move no joint more than this before a limit is refused, naming it [rad or m]: it is there.
#: From rest a jog may creep closer than it stopped from speed (its stop is shorter), and again, each time by
#: less: below a milliradian (about a millimetre at the tool) it is refused instead.
CREEP = 1e-3
#: A Cartesian jog along a straight line (or about an axis) goes at most this far [m or rad] in one go: the
#: profile's target, far enough never to be reached while jogging by hand.
CARTESIAN_REACH = 10.0


@dataclasses.dataclass
class _Jog:
    """The jog that runs: what was asked, its path, and what the servo holds of it. Indices count the motion's
    samples from its first [samples]."""

    cmd: JogCommand
    settings: MotionSettings
    path: JointPath | CartesianPath
    track: Track
    speed: float  # [rad/s or m/s] the speed asked for along s (the ratio of the max speed, or what stops in time)
    motion: int  # the servo's motion id
    epoch: int
    q_end: Joints  # the jog's last sample before its stop: where the next extension joins
    cruise_end: int  # its index
    end: int  # the index of the last sample the servo holds (its stop's, at rest)
    q_last: Joints  # that sample
    lease_until: float  # [monotonic s]
    stop_by: float = 0.0  # [monotonic s] the stop the servo holds ends by then (the lease it was planned for)
    pos: float = 0.0  # [samples] where the servo was along the motion at ``pos_at``
    pos_at: float = 0.0  # [monotonic s]
    full: bool = False  # the last extension stopped where the lease does, not at HORIZON: none until renewed
    ended: str = ""  # why the last extension was the end (a limit ahead), "" while it goes on


class Jogger:
    """The jog of one arm (module docstring): requests from ``Planner/jog``, extensions on a thread of its own."""

    def __init__(self, model: RobotModel, handover: Handover, obstacles: tuple[Obstacle, ...] = (),
                 collision_margin: float = DEFAULT_MARGIN) -> None:
        self.model = model
        self.dt = model.cmd_cycle
        self.handover = handover
        self._obstacles, self._margin = obstacles, collision_margin
        self._tools: tuple[Checks, PathChecker, BatchFk] | None = None  # built by the jog thread as it starts
        self._lock = threading.RLock()
        self._jog: _Jog | None = None
        #: The last jog that stopped by itself before a limit, why, and its motion: renewals of it while that
        #: motion still brakes are refused naming the limit.
        self._ended: tuple[JogCommand, str, int] | None = None
        #: The last jog whose lease lapsed, its motion and when [monotonic s]: a late renewal of it while it
        #: stops is told so.
        self._lapsed: tuple[JogCommand, int, float] | None = None
        #: When the newest call arrived, and the newest served [monotonic s]: one between them waits for the lock.
        self._arrived = self._served = 0.0
        self._cost = 5e-4  # [s] an extension's time per sample, the last one's (a Cartesian 7-axis jog's here)
        self._began = threading.Event()  # a jog began: the thread, asleep while none runs, ticks again
        self._loop = LoopThread(self._run, "planner-jog", wake=self._began.set)

    # ------------------------------------------------------------------ life cycle
    def start(self) -> None:
        self._loop.start()

    def close(self) -> None:
        self._loop.stop()

    @property
    def alive(self) -> bool:
        return self._loop.alive

    @property
    def active(self) -> bool:
        """A jog runs (its motion may still be braking in the servo after that)."""
        return self._jog is not None

    def _kit(self) -> tuple[Checks, PathChecker, BatchFk]:
        if self._tools is None:
            kin = Kinematics(self.model)
            fk = BatchFk(kin)
            # A work area of its own: the plan worker's thread uses the heads' (kinematics are not thread-safe).
            self._tools = (Checks(self.model, kin, fk), PathChecker(self.model, self._obstacles, self._margin), fk)
        return self._tools

    # ------------------------------------------------------------------ requests
    def jog(self, cmd: JogCommand, settings: MotionSettings, start: Callable[[], tuple[Joints, int]]
            ) -> tuple[ReturnCode, str]:
        """Start ``cmd``, or renew the jog it continues; ``start()`` gives where a new one starts and the
        servo's epoch (raising PlanRefused). Raises PlanRefused."""
        # A renewal is judged by when it arrived: the jog thread may hold the lock for a long extension, and it
        # does not call the lease lapsed while a call waits (``_tick``).
        arrival = self._arrived = time.monotonic()
        with self._lock:
            try:
                return self._call(cmd, settings, start, arrival)
            finally:
                self._served = max(self._served, arrival)

    def _call(self, cmd: JogCommand, settings: MotionSettings, start: Callable[[], tuple[Joints, int]],
              arrival: float) -> tuple[ReturnCode, str]:
        """:meth:`jog`'s work, under the lock, for a call that arrived at ``arrival`` [monotonic s]."""
        jog = self._jog
        if jog is not None:
            if not jog.cmd.same_jog(cmd):
                raise PlanRefused(ReturnCode.STATUS_ERR, f"{cmd.op} refused: jogging {jog.cmd.describe()}; "
                                  f"{OP.jogStop} first (or let its lease lapse)")
            if arrival > jog.lease_until:  # lapsed: the jog thread stops it, a late call does not revive it
                raise PlanRefused(ReturnCode.STATUS_ERR, f"{cmd.op} refused: the lease of jog "
                                  f"{jog.cmd.describe()} lapsed {(arrival - jog.lease_until) * 1e3:.0f} ms "
                                  "before this call: it brakes; call again once it holds")
            jog.cmd, jog.lease_until = cmd, time.monotonic() + cmd.lease
            jog.speed = self._speed(cmd, jog.settings, jog.track.limits)
            return ReturnCode.OK, f"OK: jogging {self._describe(jog)}"
        ended, lapsed = self._ended, self._lapsed
        if ended is not None and ended[0].same_jog(cmd) and ended[2] in self.handover.progress().queued:
            raise PlanRefused(ReturnCode.VALUE_ERR, f"{cmd.op} refused: stopping before the limit: {ended[1]}")
        if lapsed is not None and lapsed[0].same_jog(cmd) and lapsed[1] in self.handover.progress().queued:
            raise PlanRefused(ReturnCode.STATUS_ERR, f"{cmd.op} refused: the lease of jog {cmd.describe()} "
                              f"lapsed {(time.monotonic() - lapsed[2]) * 1e3:.0f} ms ago: it stops on its "
                              "path; call again once it holds")
        checks, _, _ = self._kit()
        try:
            checks.settings(settings)
        except WireError as exc:
            raise PlanRefused(ReturnCode.VALUE_ERR, str(exc)) from None
        q0, epoch = start()
        jog = self._begin(cmd, settings, q0, epoch)
        if jog.ended:  # the head already stops before a limit: nothing to renew
            self._ended = (cmd, jog.ended, jog.motion)
            log.info("jog %s: stopping before the limit: %s", cmd.describe(), jog.ended)
            return ReturnCode.OK, f"OK: jogging {cmd.describe()}, stopping before the limit: {jog.ended}"
        self._jog = jog
        self._began.set()
        log.info("jog %s started (motion %d, lease %.0f ms)", self._describe(jog), jog.motion, cmd.lease * 1e3)
        return ReturnCode.OK, f"OK: jogging {self._describe(jog)} (motion {jog.motion})"

    def stop(self, why: str) -> str:
        """End the jog now: the servo brakes on its path. What it did, for the reply."""
        with self._lock:
            jog, self._jog = self._jog, None
        if jog is None:
            return f"OK: {OP.jogStop} ignored: no jog runs"
        code, comment, _ = self.handover.control(ControlAction.STOP)
        log.info("jog %s: %s: %s", jog.cmd.describe(), why, comment)
        return f"OK: {why}: braking" if code == ReturnCode.OK else f"{why}: {comment}"

    def _top(self, cmd: JogCommand, s: MotionSettings) -> float:
        """The max speed along a jog of ``cmd``'s kind [rad/s or m/s]: the joint's, or the Cartesian one."""
        if cmd.joint >= 0:
            checks, _, _ = self._kit()
            return float(checks.vmax(s)[cmd.joint])
        return s.maxSpeedCartesian.rotation if cmd.axis >= 3 else s.maxSpeedCartesian.translation

    def _speed(self, cmd: JogCommand, s: MotionSettings, limits: ProfileLimits) -> float:
        """The speed along the jog [rad/s or m/s]: the share asked for of the max, at most what stops within
        half the lease (module docstring)."""
        return min(cmd.ratio * self._top(cmd, s), speed_to_stop_within(cmd.lease / 2 + GRACE - TICK - LEAD, limits))

    def _describe(self, jog: _Jog) -> str:
        asked = jog.cmd.ratio * self._top(jog.cmd, jog.settings)
        if jog.speed >= asked * (1.0 - 1e-9):
            return f"{jog.cmd.describe()} at {jog.cmd.ratio * 100:.0f} %"
        return (f"{jog.cmd.describe()} at {jog.speed / asked * jog.cmd.ratio * 100:.0f} % of the "
                f"{jog.cmd.ratio * 100:.0f} % asked: what stops within half its {jog.cmd.lease * 1e3:.0f} ms lease")

    def _path(self, cmd: JogCommand, s: MotionSettings, q0: Joints) -> tuple[JointPath | CartesianPath, Track]:
        """The path of ``cmd`` from ``q0`` and the track along it (from rest); raises PlanRefused."""
        checks, _, _ = self._kit()
        top = self._top(cmd, s)
        if cmd.joint >= 0:
            lo, hi = checks.soft_limits(s)
            i = cmd.joint
            room = (hi[i] - LIMIT_MARGIN - q0[i]) if cmd.sign > 0 else (q0[i] - lo[i] - LIMIT_MARGIN)
            if room <= 1e-6:
                bound = f"upper {hi[i]:.6g}" if cmd.sign > 0 else f"lower {lo[i]:.6g}"
                raise PlanRefused(ReturnCode.VALUE_ERR, f"{cmd.op} refused: J{i + 1} is at its joint soft limit "
                                  f"({bound}): jog the other way")
            return JointPath(q0, i, cmd.sign), Track(self.dt, room, ProfileLimits.from_accel_time(
                top, s.accelTimeJoint))
        mask = self._mask(cmd, checks, q0)
        path = CartesianPath(checks, Frames.of(s), q0, cmd.frame, cmd.axis, cmd.sign, checks.vmax(s), self.dt,
                             s.accelTimeJoint, mask)
        moved = np.concatenate([path.direction, np.zeros(3)] if not path.rotation else [np.zeros(3), path.direction])
        if np.abs(moved[~mask]).max(initial=0.0) > 1e-6:
            held = ", ".join(n for n, m in zip(JOG_AXES, mask) if m)
            raise PlanRefused(ReturnCode.NG, f"{cmd.op} refused: a {self.model.axis_num}-axis "
                              f"{self.model.family.value} arm moves {held} only; {cmd.frame} "
                              f"{JOG_AXES[cmd.axis]} is not among them here")
        return path, Track(self.dt, CARTESIAN_REACH, ProfileLimits.from_accel_time(top, s.accelTimeCartesian))

    def _mask(self, cmd: JogCommand, checks: Checks, q0: Joints) -> NDArray[np.bool_]:
        """The pose components a Cartesian jog holds (x .. rz, arm base frame); raises PlanRefused (NG)."""
        rule = families.rule(self.model, families.CartesianKind.LINEAR)
        if isinstance(rule, families.CartesianRule) and all(rule.mask) \
                and rule.orientation is families.Orientation.FULL:
            return np.ones(6, dtype=bool)  # 6 and 7 axes: the whole pose
        if self.model.family is Family.ARTICULATED:
            raise PlanRefused(ReturnCode.NG, f"{cmd.op} refused: a {self.model.axis_num}-axis arm cannot hold "
                              "the five components of the pose a Cartesian jog does not move")
        # A SCARA or a gantry moves a fixed set of the pose's components whatever its joints: the rows of its
        # Jacobian that are not zero (a SCARA never tilts its tool, a gantry never turns it).
        J = checks.kin.jacobian(q0[:checks.n])
        return np.abs(J).max(axis=1) > 1e-9

    def _begin(self, cmd: JogCommand, s: MotionSettings, q0: Joints, epoch: int) -> _Jog:
        path, track = self._path(cmd, s, q0)
        now = time.monotonic()
        jog = _Jog(cmd, s, path, track, self._speed(cmd, s, track.limits), 0, epoch, q0.copy(), 0, 0, q0.copy(),
                   now + cmd.lease)
        rows, moved, ended = self._extend(jog, int(round(START / self.dt)), (cmd.lease + GRACE) / self.dt)
        if ended and np.abs(rows[-1] - q0).max() < CREEP:  # at the limit already: nothing left to jog
            raise PlanRefused(ReturnCode.VALUE_ERR, f"{cmd.op} refused: {ended}")
        head = np.vstack([q0[None, :], rows])
        jog.motion, reply = self.handover.jog_start(head, epoch, final=bool(ended))
        handed = time.monotonic()
        jog.cruise_end, jog.end, jog.q_last = moved, len(head) - 1, head[-1].copy()
        # The lease runs from the reply, as a renewal's does; the head stops by what it was planned for (earlier):
        # the first tick replans it.
        jog.lease_until, jog.stop_by = handed + cmd.lease, now + cmd.lease + GRACE
        jog.pos, jog.pos_at = 0.0, handed
        jog.ended = ended
        return jog

    # ------------------------------------------------------------------ extensions
    def _extend(self, jog: _Jog, count: int, budget: float) -> tuple[NDArray[np.float64], int, str]:
        """At most ``count`` samples of the jog after ``jog.q_end``, each with a stop that ends within ``budget``
        samples of it (advancing the track, the path and ``q_end``), then that stop, and the last sample again
        (at rest: ``interpolator.Buffered.rests``); how many are the jog's; and why the jog ends there ("" if
        it does not). The samples are checked with their stop; where they fail, the longest of their first
        samples that still passes, then its stop, and why."""
        before_q, before_s, before_p = jog.q_end.copy(), jog.track.state, jog.path.state()
        states: list[tuple[tuple[float, float, float], object]] = []
        chunk, why = self._try(jog, count, budget, states)
        if not why:
            if len(chunk):
                jog.q_end = chunk[-1]
            if jog.track.finished and jog.cmd.joint >= 0:
                lim = "upper" if jog.cmd.sign > 0 else "lower"
                why = f"J{jog.cmd.joint + 1} reached its joint soft limit ({lim})"
            return self._with_stop(jog, chunk), len(chunk), why
        # A limit ahead: bisect for the last sample from which the arm still stops in time (the samples before
        # the one that fails are checked in order: a limit comes nearer along the jog). The stop from where
        # the servo holds was checked with the extension before, so none passing still has one. A try of the
        # first ``mid`` samples is ``chunk[:mid]`` from the state after them: only its checks are redone.
        checks, collisions, fk = self._kit()
        good, bad = 0, len(chunk)
        best: tuple[NDArray[np.float64], tuple[float, float, float], object] | None = None
        while bad - good > 1:
            mid = (good + bad) // 2
            track_state, path_state = states[mid - 1]
            jog.track.restore(track_state)
            jog.path.restore(path_state)
            if self._check(jog, chunk[:mid], checks, collisions, fk):
                bad = mid
            else:
                good, best = mid, (chunk[:mid], track_state, path_state)
        jog.track.restore(best[1] if best is not None else before_s)
        jog.path.restore(best[2] if best is not None else before_p)
        kept = best[0] if best is not None else chunk[:0]
        jog.q_end = kept[-1] if len(kept) else before_q
        return self._with_stop(jog, kept), len(kept), why

    def _with_stop(self, jog: _Jog, chunk: NDArray[np.float64]) -> NDArray[np.float64]:
        """``chunk``, the stop from its end (from the track's and the path's state, left as they are), and the
        last sample again."""
        stop = self._braking(jog, jog.q_end)
        parts = [p for p in (chunk, stop) if len(p)]
        rows = np.vstack(parts) if parts else jog.q_end[None, :]
        return np.vstack([rows, rows[-1:]])

    def _try(self, jog: _Jog, count: int, budget: float,
             states: list[tuple[tuple[float, float, float], object]]) -> tuple[NDArray[np.float64], str]:
        """Up to ``count`` samples on from ``jog.q_end`` whose stop ends within ``budget`` samples (advancing the
        track and the path; their states after each sample into ``states``), and why they fail the checks or ""."""
        checks, collisions, fk = self._kit()
        rows = []
        q = jog.q_end
        for i in range(count):
            before = jog.track.state, jog.path.state()
            q_next = jog.path.at(q, jog.track.step(*jog.path.limits(q, jog.speed)))
            if i + 1 + max(jog.track.stop_time(), jog.path.stop_time()) / self.dt > budget:
                jog.track.restore(before[0])  # its stop would end after the lease: the stop begins here
                jog.path.restore(before[1])
                break
            q = q_next
            rows.append(q)
            states.append((jog.track.state, jog.path.state()))
            if jog.track.finished:
                break
        if not rows:
            return np.empty((0, self.model.dof)), ""
        chunk = np.array(rows)
        return chunk, self._check(jog, chunk, checks, collisions, fk)

    def _braking(self, jog: _Jog, q: Joints) -> NDArray[np.float64]:
        if isinstance(jog.path, CartesianPath):
            stop = jog.path.stop(q)
            return stop if np.any(stop != q) else stop[:0]
        rows = []
        for s in jog.track.braking():
            q = jog.path.at(q, float(s))
            rows.append(q)
        return np.array(rows) if rows else np.empty((0, self.model.dof))

    def _check(self, jog: _Jog, chunk: NDArray[np.float64], checks: Checks, collisions: PathChecker,
               fk: BatchFk) -> str:
        """Why ``chunk`` and the braking after it would not do ("" if they would)."""
        s0, sd, _ = jog.track.state
        stop = jog.track.braking()
        ds = float(stop[-1] - s0) if len(stop) else 0.0
        last = chunk[-1]
        ahead = np.vstack([chunk, last + jog.path.rate(last) * ds]) if ds > 0.0 else chunk
        n = self.model.axis_num
        lo, hi = checks.soft_limits(jog.settings)
        if isinstance(jog.path, CartesianPath) and len(chunk) >= 2:
            # Where each sample's stop ends (``CartesianPath.stop``): near a singularity the joints lag the line, and
            # a wrist axis spun fast stops further than the line's stop says. Every sample's (as the servo checks).
            v = np.diff(chunk[:, :n], axis=0) / self.dt
            reach = chunk[1:, :n] + v * np.max(np.abs(v) / jog.path.amax, axis=1, keepdims=True) / 2.0
            ahead = np.vstack([ahead, np.hstack([reach, chunk[1:, n:]])])
        bad = np.argwhere((ahead[:, :n] < lo - 1e-9) | (ahead[:, :n] > hi + 1e-9))
        if bad.size:
            i = int(bad[0][1])
            return f"J{i + 1} would pass its joint soft limit [{lo[i]:.6g}, {hi[i]:.6g}]"
        if isinstance(jog.path, CartesianPath):
            stop = jog.path.stop(last)  # the stop the servo will hold
            near = jog.path.too_singular(jog.q_end, np.vstack([chunk, stop]))
            if near:
                return near
        frames = Frames.of(jog.settings)
        positions = frames.to_robot(fk.run(ahead[:, :n], frames.tool)[0])
        try:
            checks.box(jog.settings, positions, jog.cmd.op)
        except PlanRefused as exc:
            return exc.comment.split(": ", 1)[-1]
        contact = collisions.check(np.vstack([jog.q_end[None, :], ahead]))
        if contact is not None:
            return f"it would come too close to an obstacle: {contact.describe()}"
        return ""

    # ------------------------------------------------------------------ the thread
    def _run(self, stop: threading.Event) -> None:
        with self._lock:  # built here, not at the first jog (0.25 s) nor in the service's start
            self._kit()
        while not stop.is_set():
            if self._jog is None:  # no jog: no tick (100 wakes a second for nothing)
                self._began.wait()
                self._began.clear()
                continue
            if stop.wait(TICK):
                return
            try:
                self._tick()
            except Exception:  # a jog that cannot go on stops; the thread goes on for the next one
                log.exception("jog: extension failed; stopping the jog")
                self.stop("the jog failed")

    def _tick(self) -> None:
        with self._lock:
            jog = self._jog
            if jog is None:
                return
            now = time.monotonic()
            if now <= jog.lease_until:
                self._go_on(jog, now)
                return
            if jog.lease_until >= self._arrived > self._served:
                return  # a call that came within the lease waits for the lock: it may renew it
            # Lapsed: the servo holds the stop, at rest by the lease's end plus GRACE; no more after it.
            self._jog = None
            self._lapsed = (jog.cmd, jog.motion, jog.lease_until)
        reply = self.handover.jog_extend(jog.motion, jog.epoch, jog.q_last[None, :], final=True)
        silent = (now - jog.lease_until + jog.cmd.lease) * 1e3
        log.info("jog %s: the lease lapsed (%.0f ms without a renewal): stopping on its path%s", jog.cmd.describe(),
                 silent, "" if reply.id == ReturnCode.OK else f" ({reply.comment})")

    def _go_on(self, jog: _Jog, now: float) -> None:
        """Replace the stop the servo holds by more of the jog and a new stop, if there is more to give."""
        pos = min(float(jog.end), jog.pos + (now - jog.pos_at) / self.dt)  # where the servo is, at full speed
        renewed = jog.lease_until + GRACE > jog.stop_by
        stop_by = pos + (jog.lease_until + GRACE - now) / self.dt  # [samples]
        if jog.cruise_end >= pos + LEAD / self.dt:
            at = jog.cruise_end  # the stop has not begun: it is replaced
        elif renewed:
            # Renewed after its stop began: the jog goes on from where that stop ends, at rest.
            at = jog.end
            try:
                jog.path, jog.track = self._path(jog.cmd, jog.settings, jog.q_last)
            except PlanRefused as exc:  # it stopped on a limit: nothing more to jog this way
                self._jog = None
                log.info("jog %s ended: %s", jog.cmd.describe(), exc.comment)
                return
            jog.q_end = jog.q_last.copy()
        else:
            return  # stopping as the lease says, unless renewed
        count = int(pos + HORIZON / self.dt - at)
        if at == jog.cruise_end:  # handed over before the servo reaches the splice: half the time left
            room = (at - pos) * self.dt - LEAD
            count = min(count, max(int(round(TICK / self.dt)), int(room / 2.0 / self._cost)))
        if count <= 0 or not renewed and (jog.full or count < int(round(TICK / self.dt))):
            return  # nothing more to give until a renewal, or until the servo has taken some
        before = jog.q_end.copy(), jog.track.state, jog.path.state()
        rows, moved, ended = self._extend(jog, count, stop_by - at)
        self._cost = (time.monotonic() - now) / max(len(rows), 1)
        jog.full = moved < count
        if moved == 0 and not ended and at == jog.cruise_end:
            return  # the same stop again
        reply = self.handover.jog_extend(jog.motion, jog.epoch, np.vstack([before[0][None, :], rows]),
                                         final=bool(ended), splice=at - jog.end - 1)
        if reply.refusal == TrajectoryRefusal.LATE.value:  # the servo passed the splice: the next tick goes on
            jog.q_end, _, _ = before
            jog.track.restore(before[1])
            jog.path.restore(before[2])
            jog.pos, jog.pos_at = float(jog.cruise_end), now
            return
        if reply.id != ReturnCode.OK:
            log.info("jog %s ended: the servo did not take its extension: %s", jog.cmd.describe(), reply.comment)
            self._jog = None
            return
        jog.cruise_end, jog.end = at + moved, at + len(rows)
        jog.q_last, jog.stop_by = rows[-1].copy(), jog.lease_until + GRACE
        p = reply.progress
        if p.running == jog.motion:
            jog.pos, jog.pos_at = jog.end - p.runningLeft, time.monotonic()
        if ended:  # the stop before a limit is buffered: the jog is over, its motion ends at rest
            self._jog = None
            self._ended = (jog.cmd, ended, jog.motion)
            log.info("jog %s: stopping before the limit: %s", jog.cmd.describe(), ended)


__all__ = ["GRACE", "HORIZON", "Jogger", "LEAD", "START", "TICK"]
