"""``Arm``: one arm over Zenoh, every operation a typed method, motions as handles.

    from jara_arm.client import Arm, rel

    with Arm.connect() as arm:                   # tcp/127.0.0.1:7447, arm0
        arm.servoON()
        arm.setSpeedJoint(40)
        arm.movePTPJointRel([0.3, 0, 0, 0, 0, 0, 0])           # returns once the arm arrived
        lin = arm.moveLinearCartesianRel(rel(dz=-0.05), wait=False)
        print(lin.fate, lin.progress)                            # waiting, queued, running, done, ...; 0.0 .. 1.0
        lin.wait(timeout=10)                                     # MotionFailed says why, if it did not end

Every call raises :class:`~.errors.Refused` (code and comment) for any RETURN_ID but OK, and
:class:`~.errors.NoAnswer` when nobody answers: a script never goes on past a refusal unnoticed.
"""

from __future__ import annotations

import contextlib
import threading
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from types import TracebackType
from typing import Any

import zenoh

from jara_arm.schema import codec
from jara_arm.schema.codes import ReturnCode, StateBit
from jara_arm.schema.keys import DEFAULT_ARM, ArmKeys, Service, parse_alive
from jara_arm.schema.operations import Interface, operation
from jara_arm.schema.planner import accepted_motion
from jara_arm.schema.types import Alarm, CarPosWithElbow, TimedJointPos, hg_matrix
from jara_arm.schema.wire_types import TIMED_JOINT_POS
from jara_arm.services.runtime.ask import Asker, Silence
from jara_arm.services.runtime.wire import decode_sample
from jara_arm.services.runtime.zenoh_args import default_endpoint, zenoh_config

from .errors import ArmError, NoAnswer, Refused, StateTimeout
from .motion import Motion, Tracker
from .operations import Operations


#: An arm's services, in the order a missing one is named (the servo first: nothing runs without it).
ARM_SERVICES = (Service.SERVO, Service.PLANNER, Service.COMMAND, Service.ALARM_MONITOR)
#: [s] A wait for a state asks ``getState`` when the command publishes a change (``state``), and at least this
#: often: a change that was not heard (a subscription still on its way, a role that may not read ``state``)
#: delays the answer by this much at most. Polled every 20 ms instead, a wait cost the arm's processes and the
#: client about 0.09 core (``getState`` at 50 Hz, measured on an idle arm).
STATE_RECHECK = 0.25
#: [s] How often a wait looks at its own channel of published changes (local: no traffic).
_CHANGE_LOOK = 0.005


def rel(dx: float = 0.0, dy: float = 0.0, dz: float = 0.0) -> CarPosWithElbow:
    """A relative Cartesian target: a translation [m], no rotation, elbow and posture unchanged."""
    return CarPosWithElbow(hg_matrix(None, (dx, dy, dz)), 0.0, 0)


class Arm(Operations):
    """One arm (``arm``) on a Zenoh session: the specification's operations by their IDL names
    (:class:`~.operations.Operations`), each query answered within ``timeout`` [s]."""

    def __init__(self, session: zenoh.Session, arm: str = DEFAULT_ARM, *, timeout: float = 10.0) -> None:
        self.session = session
        self.keys = ArmKeys(arm)
        self.timeout = timeout
        self._askers: dict[str, Asker] = {}
        self._lock = threading.Lock()
        self._tracker = Tracker(session, self.keys)
        self._changes = session.declare_subscriber(self.keys.state, zenoh.handlers.RingChannel(1))
        self._own_session = False

    @classmethod
    def connect(cls, endpoint: str | None = None, arm: str = DEFAULT_ARM, *, timeout: float = 10.0,
                secure: str | None = None, identity: str | None = None) -> Arm:
        """A session of its own, a client of ``endpoint`` (default: the launcher's on this host), trying to
        join for up to ``timeout`` [s]; :meth:`close` closes it. ``secure``/``identity``: a secure cell's
        directory and the certificate to present (``jara-arm certs``)."""
        where = endpoint or default_endpoint(secure)
        config = zenoh_config("client", connect=[where], secure=secure, identity=identity, join_within=timeout)
        try:
            session = zenoh.open(config)
        except zenoh.ZError as exc:
            raise NoAnswer(f"cannot join the Zenoh network at {where}: {exc}") from None
        arm_ = cls(session, arm, timeout=timeout)
        arm_._own_session = True
        return arm_

    def close(self) -> None:
        """Undeclare what this arm declared; close the session if :meth:`connect` opened it."""
        with self._lock:
            for asker in self._askers.values():
                asker.close()
            self._askers.clear()
        self._tracker.close()
        self._changes.undeclare()
        if self._own_session:
            self.session.close()

    def __enter__(self) -> Arm:
        return self

    def __exit__(self, kind: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()

    def wait_alive(self, services: Sequence[Service] = ARM_SERVICES, timeout: float = 30.0) -> None:
        """Until the liveliness token of each of the arm's ``services`` is up (:func:`wait_alive`)."""
        wait_alive(self.session, self.keys, services, timeout)

    # -- the calls ------------------------------------------------------------------------

    def _asker(self, key: str) -> Asker:
        with self._lock:  # one querier per key, whichever thread asks first
            asker = self._askers.get(key)
            if asker is None:
                asker = self._askers[key] = Asker(self.session, key, self.timeout)
            return asker

    def call(self, interface: Interface, name: str, args: Mapping[str, Any] | None = None, *,
             servo: bool = False) -> codec.Reply:
        """``name`` of ``interface`` by name, its reply whatever its RETURN_ID (for a tool that shows a refusal
        as it came; the typed methods raise :class:`~.errors.Refused` instead). ``servo=True`` asks the low
        level (``Servo/Common``) instead of the command service. :class:`~.errors.NoAnswer` when nobody answers."""
        op = operation(interface, name)
        key = self.keys.servo_common(name) if servo else self.keys.interface(interface, name)
        got = self._asker(key).ask(codec.encode_request(op, args))
        if isinstance(got, Silence):
            raise NoAnswer(f"{name}: {got.why}")
        return codec.decode_reply(op, got.payload, got.encoding)

    def wait_idle(self, timeout: float = 60.0) -> float:
        """Until the arm neither moves nor has queued motions (or is paused, or alarmed); the time waited [s].
        :class:`~.errors.ArmError` if it still moves after ``timeout`` [s]. A motion, jog, pause, resume or stop
        shows in ``getState`` as soon as its reply has come (the command takes in the queue the planner's reply
        carries), so the first look is at once (then :meth:`wait_state`)."""
        t0 = time.monotonic()
        try:
            self.wait_state(lambda s: not s & StateBit.MOVING or bool(s & (StateBit.PAUSED | StateBit.ALARM)),
                            timeout)
        except StateTimeout as exc:
            raise ArmError(f"the arm still moves after {timeout:g} s (state 0x{exc.state:02x})") from None
        return time.monotonic() - t0

    def wait_state(self, until: Callable[[int], bool], timeout: float = 60.0) -> int:
        """Until ``until(getState())`` holds; that state (``jara_arm.schema.codes.StateBit``). It asks when the
        command publishes a change, and at least every :data:`STATE_RECHECK` [s]; :class:`~.errors.ArmError`
        after ``timeout`` [s]."""
        deadline = time.monotonic() + timeout
        while True:
            while self._changes.try_recv() is not None:  # published before this getState: nothing newer
                pass
            state = self.state
            if until(state):
                return state
            now = time.monotonic()
            if now > deadline:
                raise StateTimeout(state, timeout)
            recheck = min(now + STATE_RECHECK, deadline)
            while self._changes.try_recv() is None and time.monotonic() < recheck:
                time.sleep(_CHANGE_LOOK)

    def _reply(self, interface: Interface, name: str, args: Mapping[str, Any]) -> codec.Reply:
        reply = self.call(interface, name, args)
        if not reply.ok:
            raise Refused(name, _code(reply.id), reply.comment)
        return reply

    def _call(self, interface: Interface, name: str, args: Mapping[str, Any]) -> tuple[Any, ...]:
        reply = self._reply(interface, name, args)
        return tuple(reply[p.name] for p in operation(interface, name).outputs)

    def _move(self, interface: Interface, name: str, args: Mapping[str, Any], wait: bool,
              timeout: float | None) -> Motion:
        reply = self._reply(interface, name, args)
        motion_id = accepted_motion(reply.comment)
        if motion_id is None:
            raise ArmError(f"{name} was accepted, but its reply names no motion to follow: {reply.comment!r}")
        motion = Motion(self._tracker, motion_id, name, self._alarm_texts)
        if wait:
            motion.wait(timeout)
        return motion

    def _alarm_texts(self) -> tuple[str, ...]:
        try:
            return tuple(f"0x{a.code:02x} {a.type.value} {a.description}" for a in self.getActiveAlarm())
        except ArmError as exc:
            return (f"the active alarms could not be read: {exc}",)

    # -- what a script reads most ------------------------------------------------------------

    @property
    def state(self) -> int:
        """``getState``'s bits (``jara_arm.schema.codes.StateBit``)."""
        return self.getState()

    @property
    def alarms(self) -> tuple[Alarm, ...]:
        """``getActiveAlarm``: the active alarms, none when the arm is clear."""
        return self.getActiveAlarm()

    @property
    def joints(self) -> tuple[float, ...]:
        """``getFeedbackPosJoint`` [rad or m]: J1..Jn, then the gripper if fitted."""
        return self.getFeedbackPosJoint()

    @contextlib.contextmanager
    def feedback(self, capacity: int = 1000) -> Iterator[Iterator[TimedJointPos]]:
        """The 1 kHz ``Servo/posFeedback`` while inside: an iterator of samples, blocking for the next.
        A reader slower than the stream loses the oldest beyond ``capacity`` samples (never the arm's)."""
        sub = self.session.declare_subscriber(self.keys.pos_feedback, zenoh.handlers.RingChannel(capacity))

        def samples() -> Iterator[TimedJointPos]:
            for sample in sub:
                yield decode_sample(TIMED_JOINT_POS, sample)

        try:
            yield samples()
        finally:
            sub.undeclare()


def alive_services(session: zenoh.Session, keys: ArmKeys, timeout: float = 1.0) -> set[str]:
    """The services of the arm whose liveliness token is up (one query for all of them)."""
    return {parse_alive(str(reply.ok.key_expr))[1]
            for reply in session.liveliness().get(keys.alive(), timeout=timeout) if reply.ok is not None}


def wait_alive(session: zenoh.Session, keys: ArmKeys, services: Sequence[Service] = ARM_SERVICES,
               timeout: float = 30.0) -> None:
    """Until the liveliness token of each of the arm's ``services`` is up: they have started and answer
    (connectivity, not health: ``getActiveAlarm`` says that). :class:`~.errors.NoAnswer` after ``timeout`` [s],
    naming the services not up."""
    deadline = time.monotonic() + timeout
    while True:
        up = alive_services(session, keys, timeout=max(0.1, min(1.0, deadline - time.monotonic())))
        missing = [s.value for s in services if s.value not in up]
        if not missing:
            return
        if time.monotonic() > deadline:
            nor = f" (nor {', '.join(missing[1:])})" if len(missing) > 1 else ""
            raise NoAnswer(f"{missing[0]} of {keys.arm} is not running{nor}: no liveliness token within "
                           f"{timeout:g} s")
        time.sleep(0.1)


def _code(value: int) -> ReturnCode:
    try:
        return ReturnCode(value)
    except ValueError:
        return ReturnCode.NG


__all__ = ["Arm", "rel"]
