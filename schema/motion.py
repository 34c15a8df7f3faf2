"""The internal contract between the planner and the servo's interpolator.

The planner hands the servo each accepted motion whole, as joint samples at
the servo's cycle (a *trajectory*); the servo interpolates it from its own
buffer, scaling time along it for pause, stop and the speed override
(``services/servo/interpolator.py``). Nothing of a motion in progress depends
on the planner or the network any more once it is buffered.
Everything here lives under ``JARA_ARM/<arm>/Servo/``.

* ``Servo/trajectory`` (queryable): ``Trajectory`` -> ``MotionReply``.
* ``Servo/motionControl`` (queryable): ``MotionControl`` -> ``MotionReply``.
* ``Servo/motion`` (publisher, on every change and at 10 Hz): ``MotionProgress``.

The servo numbers its buffers by *epoch*: a stop, an abort or the servo going
off discards every buffered motion and starts a new epoch. A trajectory planned
in an older epoch is refused (``TrajectoryRefusal.STALE``): the planner plans it again
from where the arm stopped.
"""

from __future__ import annotations

import dataclasses
import enum
from typing import Any, Protocol

import numpy as np

from . import wire_types as w
from .errors import WireError
from .types import Time
from .wire_types import StructType, struct, wire


class _SamplesType(w.WireType[np.ndarray]):
    """Joint samples, row after row: MessagePack binary of little-endian float64 (what the planner
    sends: 8 bytes a value, no per-value decoding), or a list of rows (JSON, generic tools)."""

    name = "Samples"

    def decode(self, value: Any, path: str) -> np.ndarray:
        if isinstance(value, (bytes, bytearray, memoryview)):
            if len(value) % 8:
                raise WireError(path, f"expected float64 values (8 bytes each), got {len(value)} bytes")
            a = np.frombuffer(value, dtype="<f8")
        elif isinstance(value, (list, tuple)):
            try:
                a = np.array(value, dtype=float).reshape(-1)
            except (TypeError, ValueError):
                raise WireError(path, "expected rows of numbers") from None
        else:
            raise WireError(path, f"expected binary float64 samples or a list of rows, got {type(value).__name__}")
        if not np.all(np.isfinite(a)):
            raise WireError(path, "a sample is not finite")
        return a

    def encode(self, value: np.ndarray) -> bytes:
        return np.ascontiguousarray(value, dtype="<f8").tobytes()

    def json_schema(self) -> dict[str, Any]:
        return {"description": "binary little-endian float64, row after row (MessagePack bin), or a list of rows"}


SAMPLES = _SamplesType()


class TrajectoryRefusal(enum.StrEnum):
    """Why ``Servo/trajectory`` refused a trajectory (``MotionReply.refusal``; "" when accepted)."""

    STALE = "stale"  # planned in another epoch, after a motion no longer last, or from an older hold: plan it again
    LATE = "late"  # its splice point is already behind the interpolator: send it without the splice
    START = "start"  # it does not start where the motion before it ends (at the splice)
    STATE = "state"  # the servo is off, has an alarm, or a low-level client's stream is moving the arm


class MotionAction(enum.StrEnum):
    PAUSE = "pause"  # slow down to 0 along the path and hold there
    RESUME = "resume"  # speed up again along the same path
    STOP = "stop"  # slow down to 0 along the path, then discard every buffered motion
    ABORT = "abort"  # discard every buffered motion now (the law brakes the arm)
    OVERRIDE = "override"  # the speed override, ``ratio``


@dataclasses.dataclass(frozen=True)
class Trajectory:
    """One motion, or the head of one (``final`` false), or the rest of a head (``motion == after``)."""

    motion: int = wire(w.ULONG)  # the id the planner gave the motion
    epoch: int = wire(w.ULONG)  # the servo's epoch it was planned in (MotionProgress.epoch)
    after: int = wire(w.ULONG)  # the motion it follows; 0: from rest where the servo holds the arm
    #: the sample of ``after`` at which it takes over (a blend's cut, a head's last sample); negative: counted
    #: from the end, -1 being the last (a jog's stop, replaced by more of the jog)
    splice: int = wire(w.LONG)
    final: bool = wire(w.BOOLEAN)  # False: a head whose rest follows (an early start)
    dof: int = wire(w.ULONG)  # values per sample
    samples: np.ndarray = wire(SAMPLES, "rad or m", "one per servo cycle; the first is where it takes over")

    def rows(self) -> np.ndarray:
        """The samples as a (N, dof) array; raises WireError if they do not fill whole rows."""
        if self.dof == 0 or self.samples.size % self.dof or self.samples.size < self.dof:
            raise WireError("samples", f"expected whole rows of {self.dof} values, at least one, "
                            f"got {self.samples.size} values")
        return self.samples.reshape(-1, self.dof)


@dataclasses.dataclass(frozen=True)
class MotionControl:
    action: str = wire(w.STRING, doc=" | ".join(a.value for a in MotionAction))
    ratio: float = wire(w.DOUBLE, "%", "OVERRIDE only: 0 (hold on the path) .. 100 (as planned)", default=100.0)


@dataclasses.dataclass(frozen=True)
class MotionProgress:
    """What the servo's interpolator is doing; motions complete strictly in the order buffered."""

    tm: Time = wire(w.TIME)
    epoch: int = wire(w.ULONG)
    running: int = wire(w.ULONG)  # motion id interpolated now, 0 when none
    queued: tuple[int, ...] = wire(w.SeqType("ULONGSeq", w.ULONG))  # buffered, running one first
    head: int = wire(w.ULONG)  # the last buffered motion if it is a head still waiting for its rest, else 0
    lastDone: int = wire(w.ULONG)  # id of the last motion that reached its end, 0 when none
    lastDiscarded: int = wire(w.ULONG)  # highest id discarded by stop/abort, 0 when none
    paused: bool = wire(w.BOOLEAN)
    moving: bool = wire(w.BOOLEAN)  # the interpolator commands the arm (a motion, or slowing down on one)
    stopping: bool = wire(w.BOOLEAN)  # slowing down for a stop: where it ends is not known yet
    override: float = wire(w.DOUBLE, "%")
    scale: float = wire(w.DOUBLE, "", "time along the path per time now: 0 holds, 1 runs as planned")
    #: where the next motion starts: the end of the last buffered one, or the held target; () while
    #: stopping or while a head is last
    tail: tuple[float, ...] = wire(w.DOUBLE_SEQ, "rad or m")
    started: Time = wire(w.TIME)  # when this servo process started: a restarted servo is newer
    seq: int = wire(w.ULONG)  # grows with every change of the members above but ``tm``, ``scale``
    runningShare: float = wire(w.DOUBLE, "", "0 .. 1: the share of the running motion's samples passed (tau over "
                               "its last sample's index), 0 when none runs; while it is a head (not final), of the "
                               "samples known so far (its rest makes it fall); not counted in seq", default=0.0)
    runningLeft: float = wire(w.DOUBLE, "samples", "what the running motion has left to its last sample buffered "
                              "so far (a jog keeps this ahead of the servo); 0 when none runs; not counted in seq",
                              default=0.0)


MOTION_PROGRESS = struct(MotionProgress, strict=False, doc="Internal: servo -> planner, Servo/motion.")


def is_newer(candidate: MotionProgress, current: MotionProgress | None) -> bool:
    """Whether ``candidate`` tells a later state than ``current`` (of a later servo, or later in it)."""
    if current is None:
        return True
    return (candidate.started.to_seconds(), candidate.seq) > (current.started.to_seconds(), current.seq)


class Numbered(Protocol):
    """A numbered snapshot: ``MotionProgress``, ``PlannerProgress``."""

    @property
    def tm(self) -> Time: ...
    @property
    def started(self) -> Time: ...
    @property
    def seq(self) -> int: ...


def refreshes(candidate: Numbered, current: Numbered | None) -> bool:
    """Whether ``candidate`` tells the same state as ``current`` (same ``started`` and ``seq``) later: its
    ``tm`` and the members ``seq`` does not count (e.g. ``scale``, ``runningShare``) are the newer ones."""
    return (current is not None and candidate.started == current.started and candidate.seq == current.seq
            and (candidate.tm.sec, candidate.tm.nsec) > (current.tm.sec, current.tm.nsec))


@dataclasses.dataclass(frozen=True)
class MotionReply:
    """``id``/``comment`` as RETURN_ID; ``refusal`` says which (``TrajectoryRefusal``), "" when accepted."""

    id: int = wire(w.LONG)
    comment: str = wire(w.STRING)
    refusal: str = wire(w.STRING)
    progress: MotionProgress = wire(MOTION_PROGRESS)  # as the call left it


TRAJECTORY = struct(Trajectory, doc="Internal: planner -> servo, Servo/trajectory.")
MOTION_CONTROL = struct(MotionControl, doc="Internal: planner -> servo, Servo/motionControl.")
MOTION_REPLY = struct(MotionReply, strict=False, doc="Internal: servo -> planner, the reply to both.")

MESSAGES: tuple[StructType[Any], ...] = (TRAJECTORY, MOTION_CONTROL, MOTION_REPLY, MOTION_PROGRESS)
