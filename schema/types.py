"""The IDL data types as Python values (SPEC.md §4).

Structs are frozen dataclasses with the IDL member names; sequences are tuples
of floats; ``HgMatrix`` is a read-only ``numpy`` array of shape (3, 4). The
wire form of each is defined in :mod:`jara_arm.schema.wire_types`.
"""

from __future__ import annotations

import dataclasses
import time as _time
from collections.abc import Sequence

import numpy as np

from .codes import AlarmType

JointPos = tuple[float, ...]  # [rad or m] per axis, J1..Jn then gripper
DoubleSeq = tuple[float, ...]
HgMatrix = np.ndarray  # (3, 4): rotation in columns 0-2, translation [m] in column 3


@dataclasses.dataclass(frozen=True)
class Time:
    """``RTC::Time``: wall-clock Unix time of a sample."""

    sec: int  # [s]
    nsec: int  # [ns], 0 .. 999 999 999

    @classmethod
    def from_ns(cls, ns: int) -> "Time":
        """From ``ns`` [ns] since the epoch."""
        return cls(ns // 1_000_000_000, ns % 1_000_000_000)

    @classmethod
    def from_seconds(cls, t: float) -> "Time":
        return cls.from_ns(int(round(t * 1e9)))

    @classmethod
    def now(cls) -> "Time":
        return cls.from_ns(_time.time_ns())

    def to_ns(self) -> int:
        """[ns] since the epoch: exact, for ordering (``to_seconds`` rounds)."""
        return self.sec * 1_000_000_000 + self.nsec

    def to_seconds(self) -> float:
        return self.sec + self.nsec * 1e-9


@dataclasses.dataclass(frozen=True)
class LimitValue:
    upper: float  # [rad, m]
    lower: float  # [rad, m]


@dataclasses.dataclass(frozen=True)
class TimedJointPos:
    tm: Time
    pos: JointPos  # [rad or m]


@dataclasses.dataclass(frozen=True)
class Alarm:
    code: int
    type: AlarmType
    description: str


@dataclasses.dataclass(frozen=True)
class ManipInfo:
    manufactur: str  # IDL spelling
    type: str
    axisNum: int  # axes without the gripper
    cmdCycle: int  # [ms] period of the low-level position commands
    isGripper: bool


@dataclasses.dataclass(frozen=True)
class CarPosWithElbow:
    carPos: HgMatrix  # (3, 4) [m, rad]
    elbow: float  # [rad] 7-axis arm angle; 0 for 1-6 axes
    structFlag: int  # model-specific posture bits; 0 = nearest solution

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, CarPosWithElbow):
            return NotImplemented
        return (
            np.array_equal(self.carPos, other.carPos)
            and self.elbow == other.elbow
            and self.structFlag == other.structFlag
        )

    __hash__ = None  # type: ignore[assignment]  # holds an array


@dataclasses.dataclass(frozen=True)
class CartesianSpeed:
    translation: float  # [m/s]
    rotation: float  # [rad/s]


def hg_matrix(rotation: np.ndarray | None = None,
              translation: Sequence[float] | np.ndarray = (0.0, 0.0, 0.0)) -> HgMatrix:
    """A read-only ``HgMatrix`` from a 3x3 rotation [-] and a translation [m]."""
    m = np.zeros((3, 4))
    m[:, :3] = np.eye(3) if rotation is None else rotation
    m[:, 3] = translation
    m.flags.writeable = False
    return m


IDENTITY = hg_matrix()
