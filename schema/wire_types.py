"""How each IDL type looks on the wire, and how it is checked.

A :class:`WireType` turns a decoded MessagePack/JSON value into its Python
value (:mod:`jara_arm.schema.types`) and back, and describes itself as JSON
Schema. ``decode`` is strict, as WIRE.md "Bad input" demands: wrong types,
wrong lengths, NaN or infinity, non-rotations, out-of-range ULONGs, missing or
extra struct members all raise :class:`WireError` naming the field.
"""

from __future__ import annotations

import abc
import dataclasses
import enum
import math
from collections.abc import Mapping
from typing import Any, Generic, TypeVar

import numpy as np

from . import types as t
from .codes import ULONG_MAX, AlarmType
from .errors import WireError

T = TypeVar("T")
C = TypeVar("C", bound=enum.StrEnum)

#: Largest deviation of ``R^T R`` from identity (and of det R from 1) accepted
#: for the rotation block of an ``HgMatrix`` [-].
ROTATION_TOLERANCE = 1e-6


def _kind(value: Any) -> str:
    return "null" if value is None else type(value).__name__


class WireType(abc.ABC, Generic[T]):
    """One IDL type: its name, its strict decoder and encoder, its JSON Schema."""

    name: str

    @abc.abstractmethod
    def decode(self, value: Any, path: str) -> T:
        """The Python value of wire ``value``; raises WireError naming ``path``."""

    @abc.abstractmethod
    def encode(self, value: T) -> Any:
        """The wire (MessagePack/JSON-ready) form of ``value``."""

    @abc.abstractmethod
    def json_schema(self) -> dict[str, Any]:
        """This type as JSON Schema."""

    def __repr__(self) -> str:
        return self.name


class DoubleType(WireType[float]):
    name = "double"

    def decode(self, value: Any, path: str) -> float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise WireError(path, f"expected a number (double), got {_kind(value)}")
        x = float(value)
        if not math.isfinite(x):
            raise WireError(path, f"must be finite, got {value!r}")
        return x

    def encode(self, value: float) -> float:
        return float(value)

    def json_schema(self) -> dict[str, Any]:
        return {"type": "number"}


class IntegerType(WireType[int]):
    def __init__(self, name: str, lo: int, hi: int) -> None:
        self.name, self.lo, self.hi = name, lo, hi

    def decode(self, value: Any, path: str) -> int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise WireError(path, f"expected an integer ({self.name}), got {_kind(value)}")
        if not self.lo <= value <= self.hi:
            raise WireError(path, f"{value} is out of range {self.lo} .. {self.hi} ({self.name})")
        return value

    def encode(self, value: int) -> int:
        return int(value)

    def json_schema(self) -> dict[str, Any]:
        return {"type": "integer", "minimum": self.lo, "maximum": self.hi}


class BooleanType(WireType[bool]):
    name = "boolean"

    def decode(self, value: Any, path: str) -> bool:
        if not isinstance(value, bool):
            raise WireError(path, f"expected a boolean, got {_kind(value)}")
        return value

    def encode(self, value: bool) -> bool:
        return bool(value)

    def json_schema(self) -> dict[str, Any]:
        return {"type": "boolean"}


class StringType(WireType[str]):
    name = "string"

    def decode(self, value: Any, path: str) -> str:
        if not isinstance(value, str):
            raise WireError(path, f"expected a string, got {_kind(value)}")
        return value

    def encode(self, value: str) -> str:
        return str(value)

    def json_schema(self) -> dict[str, Any]:
        return {"type": "string"}


class AlarmTypeType(WireType[AlarmType]):
    name = "AlarmType"

    def decode(self, value: Any, path: str) -> AlarmType:
        try:
            return AlarmType(value)
        except ValueError:
            raise WireError(
                path, f"expected one of {[m.value for m in AlarmType]}, got {value!r}"
            ) from None

    def encode(self, value: AlarmType) -> str:
        return AlarmType(value).value

    def json_schema(self) -> dict[str, Any]:
        return {"enum": [m.value for m in AlarmType]}


class SeqType(WireType[tuple[Any, ...]]):
    """``sequence<item>``; a list on the wire, a tuple in Python."""

    def __init__(self, name: str, item: WireType[Any]) -> None:
        self.name, self.item = name, item
        self._doubles = type(item) is DoubleType

    def decode(self, value: Any, path: str) -> tuple[Any, ...]:
        if not isinstance(value, (list, tuple)):
            raise WireError(path, f"expected a list ({self.name}), got {_kind(value)}")
        if self._doubles and all(type(v) is float for v in value):
            # The usual joint vector, in a tenth of the time: a sum of finite doubles is finite
            # (or overflows, and then the item by item path below decides).
            doubles = tuple(value)
            if math.isfinite(sum(doubles)):
                return doubles
        return tuple(self.item.decode(v, f"{path}[{i}]") for i, v in enumerate(value))

    def encode(self, value: Any) -> list[Any]:
        return [self.item.encode(v) for v in value]

    def json_schema(self) -> dict[str, Any]:
        return {"type": "array", "items": {"$ref": f"#/$defs/{self.item.name}"}
                if isinstance(self.item, StructType) else self.item.json_schema()}


class HgMatrixType(WireType[np.ndarray]):
    """``double[3][4]``; the rotation block must be a proper rotation."""

    name = "HgMatrix"

    def decode(self, value: Any, path: str) -> np.ndarray:
        if not isinstance(value, (list, tuple)) or len(value) != 3:
            n = len(value) if isinstance(value, (list, tuple)) else _kind(value)
            raise WireError(path, f"expected 3 rows of 4 numbers, got {n} rows")
        rows = []
        for i, row in enumerate(value):
            if not isinstance(row, (list, tuple)) or len(row) != 4:
                n = len(row) if isinstance(row, (list, tuple)) else _kind(row)
                raise WireError(f"{path}[{i}]", f"expected a row of 4 numbers, got {n}")
            rows.append([DOUBLE.decode(x, f"{path}[{i}][{j}]") for j, x in enumerate(row)])
        m = np.array(rows)
        r = m[:, :3]
        err = np.abs(r.T @ r - np.eye(3)).max()
        if err > ROTATION_TOLERANCE or abs(np.linalg.det(r) - 1.0) > ROTATION_TOLERANCE:
            raise WireError(
                path,
                "columns 0-2 are not a rotation matrix (orthonormal, det +1) "
                f"within {ROTATION_TOLERANCE:g}: |R^T R - I| = {err:.3g}",
            )
        m.flags.writeable = False
        return m

    def encode(self, value: np.ndarray) -> list[Any]:
        return np.asarray(value, dtype=float).reshape(3, 4).tolist()

    def json_schema(self) -> dict[str, Any]:
        row = {"type": "array", "items": {"type": "number"}, "minItems": 4, "maxItems": 4}
        return {
            "type": "array", "items": row, "minItems": 3, "maxItems": 3,
            "description": "Homogeneous transform without its last row; rotation in "
            "columns 0-2 (must be orthonormal with det +1 within 1e-6), translation [m] in column 3.",
        }


@dataclasses.dataclass(frozen=True)
class Member:
    """A struct member or operation parameter: name, wire type, unit, meaning."""

    name: str
    type: WireType[Any]
    unit: str = ""
    doc: str = ""
    optional: bool = False  # may be left out: the dataclass field's default stands in

_WIRE = "jara_arm.wire"  # the dataclass field metadata key of wire()


def wire(type_: WireType[Any], unit: str = "", doc: str = "", **field: Any) -> Any:
    """A dataclass field declared with its wire type, unit and meaning, e.g.
    ``vel: tuple[float, ...] = wire(DOUBLE_SEQ, "rad/s or m/s")``: :func:`struct` reads it, so a
    message is declared once (``field`` passes on, e.g. ``default=False``)."""
    return dataclasses.field(metadata={_WIRE: (type_, unit, doc)}, **field)


class StructType(WireType[T]):
    """An IDL struct: a map keyed by member names, decoded into ``cls``.

    ``strict`` structs refuse members they do not define (requests); relaxed
    ones (published messages) ignore extra members so that they can grow.
    """

    def __init__(self, cls: type[T], members: tuple[Member, ...], *, strict: bool = True,
                 doc: str = "") -> None:
        self.cls, self.members, self.strict, self.doc = cls, members, strict, doc
        self.name = cls.__name__
        self._names = {m.name for m in members}
        self._paths: dict[str, tuple[str, ...]] = {}  # by path: each member's (decoded every cycle)

    def _member_paths(self, path: str) -> tuple[str, ...]:
        paths = self._paths.get(path)
        if paths is None:
            prefix = f"{path}." if path else ""
            paths = tuple(f"{prefix}{m.name}" for m in self.members)
            if len(self._paths) < 256:  # a struct inside a long sequence: its paths are not all kept
                self._paths[path] = paths
        return paths

    def decode(self, value: Any, path: str) -> T:
        if not isinstance(value, dict):
            raise WireError(path, f"expected a map ({self.name}), got {_kind(value)}")
        if self.strict:
            for key in value:
                if key not in self._names:
                    prefix = f"{path}." if path else ""
                    raise WireError(f"{prefix}{key}", f"unexpected member of {self.name}; "
                                    f"valid members: {', '.join(m.name for m in self.members)}")
        kwargs = {}
        for m, member_path in zip(self.members, self._member_paths(path)):
            if m.name not in value:
                if m.optional:
                    continue
                raise WireError(member_path, f"missing member of {self.name}")
            kwargs[m.name] = m.type.decode(value[m.name], member_path)
        return self.cls(**kwargs)

    def encode(self, value: T | Mapping[str, Any]) -> dict[str, Any]:
        if isinstance(value, Mapping):  # already in wire form, members by name
            return {m.name: m.type.encode(value[m.name]) for m in self.members}
        return {m.name: m.type.encode(getattr(value, m.name)) for m in self.members}

    def json_schema(self) -> dict[str, Any]:
        props = {}
        for m in self.members:
            s = ({"$ref": f"#/$defs/{m.type.name}"} if isinstance(m.type, StructType)
                 else m.type.json_schema())
            desc = " ".join(x for x in (m.doc, f"[{m.unit}]" if m.unit else "") if x)
            if desc:
                s = {**s, "description": desc}
            props[m.name] = s
        out: dict[str, Any] = {"type": "object", "properties": props,
                               "required": [m.name for m in self.members if not m.optional]}
        if self.strict:
            out["additionalProperties"] = False
        if self.doc:
            out["description"] = self.doc
        return out


DOUBLE = DoubleType()
ULONG = IntegerType("ULONG", 0, ULONG_MAX)
LONG = IntegerType("long", -(2**31), 2**31 - 1)
BOOLEAN = BooleanType()
STRING = StringType()
ALARM_TYPE = AlarmTypeType()
DOUBLE_SEQ = SeqType("DoubleSeq", DOUBLE)
JOINT_POS = SeqType("JointPos", DOUBLE)
HG_MATRIX = HgMatrixType()

def struct(cls: type[T], *, strict: bool = True, doc: str = "") -> StructType[T]:
    """The :class:`StructType` of a dataclass whose every field is declared with :func:`wire`,
    members in field order."""
    members = []
    for f in dataclasses.fields(cls):  # type: ignore[arg-type]
        if _WIRE not in f.metadata:
            raise TypeError(f"{cls.__name__}.{f.name}: declare its wire type with wire(...)")
        type_, unit, meaning = f.metadata[_WIRE]
        optional = f.default is not dataclasses.MISSING or f.default_factory is not dataclasses.MISSING
        members.append(Member(f.name, type_, unit, meaning, optional))
    return StructType(cls, tuple(members), strict=strict, doc=doc)


TIME = StructType(t.Time, (
    Member("sec", IntegerType("ULONG", 0, ULONG_MAX), "s"),
    Member("nsec", IntegerType("ULONG", 0, 999_999_999), "ns"),
))
LIMIT_VALUE = StructType(t.LimitValue, (
    Member("upper", DOUBLE, "rad or m"), Member("lower", DOUBLE, "rad or m"),
))
LIMIT_SEQ = SeqType("LimitSeq", LIMIT_VALUE)
TIMED_JOINT_POS = StructType(t.TimedJointPos, (
    Member("tm", TIME, doc="wall-clock Unix time of the sample"),
    Member("pos", JOINT_POS, "rad or m", "J1..Jn, then the gripper axis if fitted"),
), strict=False)
ALARM = StructType(t.Alarm, (
    Member("code", ULONG), Member("type", ALARM_TYPE), Member("description", STRING),
))
ALARM_SEQ = SeqType("AlarmSeq", ALARM)
MANIP_INFO = StructType(t.ManipInfo, (
    Member("manufactur", STRING, doc="IDL spelling"),
    Member("type", STRING),
    Member("axisNum", ULONG, doc="axes without the gripper"),
    Member("cmdCycle", ULONG, "ms", "period of the low-level position commands"),
    Member("isGripper", BOOLEAN, doc="a 1-axis gripper is fitted"),
))
CAR_POS_WITH_ELBOW = StructType(t.CarPosWithElbow, (
    Member("carPos", HG_MATRIX, "m, rad"),
    Member("elbow", DOUBLE, "rad", "7-axis arm angle; ignored / 0 for 1-6 axes"),
    Member("structFlag", ULONG, doc="model-specific posture bits; 0 = nearest solution"),
))
CARTESIAN_SPEED = StructType(t.CartesianSpeed, (
    Member("translation", DOUBLE, "m/s"), Member("rotation", DOUBLE, "rad/s"),
))

#: Every named type, for the generated JSON Schema ``$defs``.
NAMED_TYPES: tuple[WireType[Any], ...] = (
    TIME, LIMIT_VALUE, TIMED_JOINT_POS, ALARM, MANIP_INFO, CAR_POS_WITH_ELBOW, CARTESIAN_SPEED,
)


def choice(cls: type[C], value: str, path: str) -> C:
    """The member of the string enum ``cls`` whose value is ``value`` (an ``action`` member); WireError naming
    ``path`` and the valid values otherwise."""
    try:
        return cls(value)
    except ValueError:
        raise WireError(path, f"unknown {value!r}; valid: {', '.join(m.value for m in cls)}") from None
