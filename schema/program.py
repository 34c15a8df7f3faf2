"""Program files: named points and the steps that move the arm between them (``jara-arm program``).

A program is a YAML file with two keys (docs/programs.md shows one)::

    points:                      # what Ext/teach stores, by name
      pick:
        joints: [0.0, 0.6, 0.0, -1.2, 0.0, 1.3, 0.0]     # [rad or m] J1..Jn
        pose: [[1, 0, 0, 0.5], [0, -1, 0, 0.0], [0, 0, -1, 0.4]]   # [R | p] robot frame, control point [m]
        elbow: 0.0               # [rad] 7-axis arm angle
        posture: 0               # structFlag: the model's posture bits
    steps:
      - ptp: pick                # to the point's joints (a pose of its own: {pose: ..., elbow: .., posture: ..})
        speed: 50                # [%] setSpeedJoint before it (setSpeedCartesian for lin and circ)
      - lin: place               # to the point's pose, in a straight line
        blend: 0.02              # [m] setBlendDistance before it: it may leave the corner after it by that much
        posture: 1               # the target's posture bits, instead of the point's
      - circ: [via, end]         # through via to end
      - wait: 0.5                # [s] once every motion before it has ended
      - loop: 2                  # the steps below, twice
        steps:
          - ptp: pick

:func:`load` reads one, every mistake with its line and column (:class:`ProgramError`); :func:`teach` adds
or replaces a point, keeping the rest of the file as it is, comments included (ruamel.yaml's round trip).
Whether each motion can be planned (reachable, posture, collisions) is checked against a live arm by
``launcher/program/check.py``.
"""

from __future__ import annotations

import dataclasses
import io
import math
import os
import re
import tempfile
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

from ruamel.yaml import YAML
from ruamel.yaml.comments import CommentedMap, CommentedSeq
from ruamel.yaml.error import MarkedYAMLError

from .errors import JaraArmError

#: A point's name: what a step names it by.
NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_\-]*\Z")
MOTIONS = ("ptp", "lin", "circ")
#: The keys a step may have besides its kind.
_STEP_KEYS = {"speed", "blend", "posture"}


@dataclasses.dataclass(frozen=True)
class Where:
    """A place in the file: 1-based line and column."""

    line: int
    column: int

    def __str__(self) -> str:
        return f"{self.line}:{self.column}"


@dataclasses.dataclass(frozen=True)
class Mistake:
    where: Where
    message: str

    def __str__(self) -> str:
        return f"{self.where}: {self.message}"


class ProgramError(JaraArmError):
    """A program that does not load: every mistake found, each with its line and column."""

    def __init__(self, path: Path, mistakes: Sequence[Mistake]) -> None:
        self.path, self.mistakes = path, tuple(mistakes)
        super().__init__("\n".join(f"{path}:{m}" for m in self.mistakes))


@dataclasses.dataclass(frozen=True)
class Target:
    """Where a motion goes: a point's joints or pose, or a pose of its own."""

    where: Where
    point: str = ""  # the named point, "" for a pose of its own
    joints: tuple[float, ...] | None = None  # [rad or m]
    pose: tuple[tuple[float, ...], ...] | None = None  # 3 x 4 [R | p], robot frame [m]
    elbow: float = 0.0  # [rad]
    posture: int = 0  # structFlag

    def describe(self) -> str:
        return self.point or "a pose"


@dataclasses.dataclass(frozen=True)
class Step:
    """One step: a motion (``ptp``, ``lin``, ``circ``), a ``wait`` or a ``loop``."""

    kind: str
    where: Where
    targets: tuple[Target, ...] = ()  # one (ptp, lin) or two (circ: via, end)
    speed: int | None = None  # [%] before the motion; None: as the arm is set
    blend: float | None = None  # [m] before the motion; None: as the arm is set
    seconds: float = 0.0  # wait
    count: int = 0  # loop
    steps: tuple[Step, ...] = ()  # loop

    def describe(self) -> str:
        if self.kind == "wait":
            return f"wait {self.seconds:g} s"
        if self.kind == "loop":
            return f"loop x{self.count}"
        return f"{self.kind} {' via '.join(t.describe() for t in reversed(self.targets)) if self.kind == 'circ' else self.targets[0].describe()}"


@dataclasses.dataclass(frozen=True)
class Program:
    path: Path
    points: Mapping[str, Target]
    steps: tuple[Step, ...]

    def flat(self, cycles: int = 1) -> list[Step]:
        """Every motion and wait in the order they run, loops unrolled, the whole ``cycles`` times."""
        def unroll(steps: Sequence[Step]) -> Iterator[Step]:
            for s in steps:
                if s.kind == "loop":
                    for _ in range(s.count):
                        yield from unroll(s.steps)
                else:
                    yield s
        return [s for _ in range(cycles) for s in unroll(self.steps)]


# ---------------------------------------------------------------------------- reading


def _where(node: Any, key: Any = None) -> Where:
    """The place of ``node`` (or of its ``key``'s value), 1-based."""
    try:
        if key is not None and isinstance(node, CommentedMap):
            line, col = node.lc.value(key)
        elif key is not None and isinstance(node, CommentedSeq):
            line, col = node.lc.item(key)
        else:
            line, col = node.lc.line, node.lc.col
        return Where(line + 1, col + 1)
    except (AttributeError, KeyError, TypeError):
        return Where(1, 1)


class _Reader:
    def __init__(self, path: Path) -> None:
        self.path = path
        self.mistakes: list[Mistake] = []

    def wrong(self, where: Where, message: str) -> None:
        self.mistakes.append(Mistake(where, message))

    def number(self, node: Any, key: Any, what: str) -> float | None:
        value = node[key]
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            self.wrong(_where(node, key), f"{what}: a number, got {value!r}")
            return None
        return float(value)

    def numbers(self, node: Any, key: Any, what: str, size: int | None = None) -> tuple[float, ...] | None:
        value = node[key]
        if not isinstance(value, list) or (size is not None and len(value) != size):
            self.wrong(_where(node, key), f"{what}: a list of {size or 'some'} numbers, got {value!r}")
            return None
        out = [self.number(value, i, what) for i in range(len(value))]
        return None if any(v is None for v in out) else tuple(float(v) for v in out if v is not None)

    def target(self, node: Any, key: Any, what: str) -> Target | None:
        """A named point (a string) or a pose / joints of its own (a map)."""
        value = node[key]
        here = _where(node, key)
        if isinstance(value, str):
            return Target(here, point=value)
        if not isinstance(value, CommentedMap):
            self.wrong(here, f"{what}: a point's name or a map with pose or joints, got {value!r}")
            return None
        return self.point_body(value, here, what)

    def point_body(self, value: CommentedMap, here: Where, what: str, name: str = "") -> Target | None:
        unknown = set(value) - {"joints", "pose", "elbow", "posture"}
        for k in sorted(unknown, key=str):
            self.wrong(_where(value, k), f"{what}: unknown key {k!r} (joints, pose, elbow, posture)")
        joints = self.numbers(value, "joints", f"{what}.joints") if "joints" in value else None
        pose = None
        if "pose" in value:
            rows = value["pose"]
            if not isinstance(rows, list) or len(rows) != 3:
                self.wrong(_where(value, "pose"), f"{what}.pose: 3 rows of [r, r, r, p] (robot frame, m), "
                           f"got {rows!r}")
            else:
                got = [self.numbers(rows, i, f"{what}.pose row {i + 1}", 4) for i in range(3)]
                pose = None if any(r is None for r in got) else tuple(r for r in got if r is not None)
        if joints is None and pose is None and not unknown and "joints" not in value and "pose" not in value:
            self.wrong(here, f"{what}: needs joints or a pose")
        elbow = self.number(value, "elbow", f"{what}.elbow") if "elbow" in value else 0.0
        posture = value.get("posture", 0)
        if isinstance(posture, bool) or not isinstance(posture, int) or posture < 0:
            self.wrong(_where(value, "posture"), f"{what}.posture: a whole number >= 0, got {posture!r}")
            posture = 0
        return Target(here, name, joints, pose, elbow or 0.0, posture)

    def step(self, node: CommentedSeq, i: int) -> Step | None:
        value = node[i]
        here = _where(node, i)
        if not isinstance(value, CommentedMap):
            self.wrong(here, f"step {i + 1}: a map such as {{ptp: a_point}}, got {value!r}")
            return None
        kinds = [k for k in value if k in (*MOTIONS, "wait", "loop")]
        if len(kinds) != 1:
            self.wrong(here, f"step {i + 1}: exactly one of ptp, lin, circ, wait, loop, got {list(value)}")
            return None
        kind = str(kinds[0])
        allowed = {kind} | (_STEP_KEYS if kind in MOTIONS else {"steps"} if kind == "loop" else set())
        for k in value:
            if k not in allowed:
                self.wrong(_where(value, k), f"step {i + 1} ({kind}): unknown key {k!r}; it takes "
                           f"{', '.join(sorted(allowed - {kind})) or 'nothing else'}")
        where = _where(value, kind)
        if kind == "wait":
            seconds = self.number(value, "wait", "wait")
            if seconds is not None and seconds < 0:
                self.wrong(where, f"wait: seconds >= 0, got {seconds}")
            return Step("wait", where, seconds=seconds or 0.0)
        if kind == "loop":
            count = value["loop"]
            if isinstance(count, bool) or not isinstance(count, int) or count < 1:
                self.wrong(where, f"loop: a count of 1 or more, got {count!r}")
                count = 1
            inner = value.get("steps")
            if not isinstance(inner, CommentedSeq) or not inner:
                self.wrong(where, "loop: needs steps: a list of the steps to repeat")
                return None
            steps = [self.step(inner, j) for j in range(len(inner))]
            return Step("loop", where, count=count, steps=tuple(s for s in steps if s is not None))
        if kind == "circ":
            pair = value["circ"]
            if not isinstance(pair, CommentedSeq) or len(pair) != 2:
                self.wrong(where, f"circ: [via, end], two points or poses, got {pair!r}")
                return None
            targets = [self.target(pair, j, f"circ {'via' if j == 0 else 'end'}") for j in range(2)]
        else:
            targets = [self.target(value, kind, kind)]
        speed = value.get("speed")
        if speed is not None and (isinstance(speed, bool) or not isinstance(speed, int) or not 1 <= speed <= 100):
            self.wrong(_where(value, "speed"), f"speed: a whole percentage 1 .. 100, got {speed!r}")
            speed = None
        blend = self.number(value, "blend", "blend") if "blend" in value else None
        if blend is not None and blend < 0:
            self.wrong(_where(value, "blend"), f"blend: metres >= 0, got {blend}")
        posture = value.get("posture")
        if posture is not None:
            if isinstance(posture, bool) or not isinstance(posture, int) or posture < 0:
                self.wrong(_where(value, "posture"), f"posture: a whole number >= 0, got {posture!r}")
            else:
                targets = [dataclasses.replace(t, posture=posture) if t is not None else None for t in targets]
        if any(t is None for t in targets):
            return None
        return Step(kind, where, tuple(t for t in targets if t is not None), speed, blend)


def parse(text: str, path: Path) -> Program:
    """The program in ``text`` (read from ``path``); raises ProgramError with every mistake found."""
    r = _Reader(path)
    try:
        doc = YAML().load(text)
    except MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        where = Where(mark.line + 1, mark.column + 1) if mark is not None else Where(1, 1)
        raise ProgramError(path, [Mistake(where, f"not YAML: {exc.problem or exc.context}")]) from None
    if doc is None:
        doc = CommentedMap()
    if not isinstance(doc, CommentedMap):
        raise ProgramError(path, [Mistake(Where(1, 1), "a program is a map with points and steps")])
    for k in doc:
        if k not in ("points", "steps"):
            r.wrong(_where(doc, k), f"unknown key {k!r} (points, steps)")
    points: dict[str, Target] = {}
    raw_points = doc.get("points") or CommentedMap()
    if not isinstance(raw_points, CommentedMap):
        r.wrong(_where(doc, "points"), "points: a map of named points")
        raw_points = CommentedMap()
    for name in raw_points:
        here = _where(raw_points, name)
        if not isinstance(name, str) or not NAME.match(name):
            r.wrong(here, f"point name {name!r}: letters, digits, _ and -, not starting with a digit")
            continue
        body = raw_points[name]
        if not isinstance(body, CommentedMap):
            r.wrong(here, f"point {name}: a map with joints and pose, got {body!r}")
            continue
        point = r.point_body(body, here, f"point {name}", name)
        if point is not None:
            points[name] = point
    steps: list[Step] = []
    raw_steps = doc.get("steps") or CommentedSeq()
    if not isinstance(raw_steps, CommentedSeq):
        r.wrong(_where(doc, "steps"), "steps: a list of steps")
    else:
        steps = [s for s in (r.step(raw_steps, i) for i in range(len(raw_steps))) if s is not None]
    program = Program(path, points, tuple(steps))
    for step in program.flat():
        for t in step.targets:
            if t.point and t.point not in points:
                known = ", ".join(sorted(points)) or "none"
                r.wrong(t.where, f"unknown point {t.point!r} (points: {known})")
    if r.mistakes:
        raise ProgramError(path, sorted(set(r.mistakes), key=lambda m: (m.where.line, m.where.column)))
    return program


def resolve(program: Program, target: Target) -> Target:
    """``target`` with its point's joints and pose (its own posture, if the step set one)."""
    if not target.point:
        return target
    p = program.points[target.point]
    posture = target.posture if target.posture else p.posture
    return dataclasses.replace(p, where=target.where, point=target.point, posture=posture)


def load(path: str | os.PathLike[str]) -> Program:
    """The program in the file ``path``; raises ProgramError (also for a file that cannot be read)."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except OSError as exc:
        raise ProgramError(p, [Mistake(Where(1, 1), f"cannot read it: {exc.strerror or exc}")]) from None
    return parse(text, p)


# ---------------------------------------------------------------------------- writing


def teach(path: str | os.PathLike[str], name: str, joints: Sequence[float], pose: Sequence[Sequence[float]],
          elbow: float, posture: int) -> None:
    """Add point ``name`` to the program file ``path`` (made if absent), or replace it; the rest of the
    file stays as it was. Written whole to a temporary file, then renamed over it: never half written."""
    if not NAME.match(name):
        raise ValueError(f"name: letters, digits, _ and -, not starting with a digit, got {name!r}")
    p = Path(path)
    yaml = YAML()
    yaml.indent(mapping=2, sequence=4, offset=2)  # "  - step" under "steps:", as people write it
    yaml.width = 4096  # a point's joints, and its pose, on one line each
    doc = yaml.load(p.read_text(encoding="utf-8")) if p.exists() else None
    if doc is None:
        doc = CommentedMap()
    if not isinstance(doc, CommentedMap):
        raise ValueError(f"{p} is not a program (a map with points and steps)")
    points = doc.get("points")
    if not isinstance(points, CommentedMap):
        points = doc["points"] = CommentedMap()
    body = CommentedMap()
    body["joints"] = _flow([round(float(q), 9) + 0.0 for q in joints])  # + 0.0: no "-0.0" in the file
    body["pose"] = _flow([_flow([round(float(v), 9) + 0.0 for v in row]) for row in pose])
    body["elbow"] = round(float(elbow), 9) + 0.0
    body["posture"] = int(posture)
    points[name] = body
    if "steps" not in doc:
        doc["steps"] = CommentedSeq()
    out = io.StringIO()
    yaml.dump(doc, out)
    p.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{p.name}.", dir=p.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            f.write(out.getvalue())
        os.replace(tmp, p)
    except BaseException:
        os.unlink(tmp)
        raise


def _flow(items: list[Any]) -> CommentedSeq:
    seq = CommentedSeq(items)
    seq.fa.set_flow_style()  # [a, b, c] on one line: a point reads as a row of numbers
    return seq


__all__ = ["Mistake", "Program", "ProgramError", "Step", "Target", "Where", "load", "parse", "resolve", "teach"]
