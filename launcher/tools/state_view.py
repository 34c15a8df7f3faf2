"""``jara-arm state``: one screen of an arm, refreshed in place: state bits, queue, joints, pose, alarms,
servo loop health, services.

The state bits, joints, pose and alarms are asked for (``getState``,
``getFeedbackPosJoint``, ``getFeedbackPosCartesian``, ``getActiveAlarm``) at
every refresh; the queue depth (``state``), the servo loop's timing
(``Servo/health``, about 1 Hz) and the services' heartbeats are taken from
their publications, drained from ring channels by the refresh loop.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
import threading
import time
from collections.abc import Mapping, Sequence
from typing import Any, TextIO

import numpy as np
import zenoh

from jara_arm.client import Arm, NoAnswer
from jara_arm.client.arm import alive_services
from jara_arm.schema import codec
from jara_arm.schema.alarms import HEARTBEAT, format_code
from jara_arm.schema.errors import JaraArmError
from jara_arm.schema.keys import Service, parse_heartbeat
from jara_arm.schema.messages import LOOP_HEALTH, LoopHealth
from jara_arm.schema.operations import OP, Interface
from jara_arm.schema.types import Alarm
from jara_arm.services.runtime.arguments import positive_float

from ..command import Command, setup_logging
from ..session import add_arm, add_client_zenoh_arguments, listening, no_answer
from .arm_state import format_state, read_state, sample_encoding

CLEAR = "\x1b[H\x1b[J"  #: cursor home, erase below: the ANSI redraw of a terminal
_RING = 64  #: publications held between two refreshes, per key
#: [s] a ``--once`` view waits at most this long for the servo's first loop report (about 1 Hz; later on a
#: busy machine) and a heartbeat of every service (10 Hz on one host, 5 Hz on a LAN): a service that is down
#: never beats, and the view then shows it without one.
ONCE_WAIT = 2.5


@dataclasses.dataclass(frozen=True)
class Beat:
    """The newest heartbeat of a service."""

    seq: int
    stuck: tuple[str, ...]
    age: float  # [s] since it arrived


@dataclasses.dataclass(frozen=True)
class Snapshot:
    """What one screen shows; ``None`` where nothing was learnt (``errors`` says why)."""

    arm: str
    taken: float  # [s] Unix time
    state: int | None = None
    queue: tuple[int, int | None] | None = None  # (motions queued, capacity), from the last ``state``
    joints: tuple[float, ...] | None = None  # [rad or m]
    axis_num: int | None = None  # axes without the gripper
    pose: np.ndarray | None = None  # (3, 4) [m, rad] control point in the robot frame
    alarms: tuple[Alarm, ...] | None = None
    health: LoopHealth | None = None
    health_age: float | None = None  # [s] since the loop report arrived
    beats: Mapping[str, Beat] = dataclasses.field(default_factory=dict)
    alive: frozenset[str] | None = None
    errors: tuple[str, ...] = ()


def rpy(rotation: np.ndarray) -> tuple[float, float, float]:
    """Roll, pitch, yaw [rad] (rotations about fixed X, then Y, then Z) of a 3x3 rotation."""
    r = np.asarray(rotation, dtype=float)
    return (math.atan2(r[2, 1], r[2, 2]), math.atan2(-r[2, 0], math.hypot(r[2, 1], r[2, 2])),
            math.atan2(r[1, 0], r[0, 0]))


def _seconds(s: float) -> str:
    """A short duration: ``80 us``, ``1.2 ms``, ``3.0 s``."""
    if s < 1e-3:
        return f"{s * 1e6:.0f} us"
    return f"{s * 1e3:.1f} ms" if s < 1.0 else f"{s:.1f} s"


def _num(x: float) -> str:
    """``+0.1235``; a value that rounds to zero is ``+0.0000``, never ``-0.0000``."""
    return f"{round(float(x), 4) + 0.0:+.4f}"


def _joints(joints: Sequence[float], axis_num: int | None) -> str:
    names = [f"J{i + 1}" if axis_num is None or i < axis_num else "grip" for i in range(len(joints))]
    return "  ".join(f"{n} {_num(q)}" for n, q in zip(names, joints))


def render(s: Snapshot) -> list[str]:
    """The lines of one screen (plain text; no escape sequences)."""
    stamp = time.strftime("%H:%M:%S", time.localtime(s.taken))
    lines = [f"arm {s.arm}   {stamp}"]
    lines.append(f"state     {format_state(s.state) if s.state is not None else '?'}")
    if s.queue is not None:
        lines.append(f"queue     {s.queue[0]} motion(s)" + (f" of {s.queue[1]}" if s.queue[1] is not None else ""))
    else:
        lines.append("queue     ? (published on the next state change)")
    lines.append(f"joints    [rad or m]  {_joints(s.joints, s.axis_num) if s.joints is not None else '?'}")
    if s.pose is not None:
        lines.append(f"pose      xyz [m] {' '.join(_num(v) for v in s.pose[:, 3])}   "
                     f"rpy [rad] {' '.join(_num(v) for v in rpy(s.pose[:, :3]))}")
    else:
        lines.append("pose      ?")
    if s.alarms is None:
        lines.append("alarms    ?")
    elif not s.alarms:
        lines.append("alarms    none")
    else:
        lines += [f"{'alarms' if i == 0 else '':<10}{format_code(a.code)} {a.type.value} {a.description}"
                  for i, a in enumerate(s.alarms)]
    lines.append(f"servo     {_health(s.health, s.health_age)}")
    lines.append(f"services  {_services(s.alive, s.beats)}")
    lines += [f"!         {e}" for e in s.errors]
    return lines


def _health(h: LoopHealth | None, age: float | None) -> str:
    if h is None:
        return "no loop report yet (Servo/health, about 1 Hz)"
    stale = f" (report {age:.1f} s old)" if age is not None and age > 3.0 else ""
    return (f"{h.cycles} cycles of {_seconds(h.period)}, late p50 {_seconds(h.latenessP50)} "
            f"p99 {_seconds(h.latenessP99)} max {_seconds(h.latenessMax)}, late cycles {h.lateCycles}, "
            f"overruns {h.overruns}, underruns {h.underruns}, FIFO {h.fifoDepth}{stale}")


def _services(alive: frozenset[str] | None, beats: Mapping[str, Beat]) -> str:
    parts = []
    for service in Service:
        up = "?" if alive is None else ("up" if service.value in alive else "DOWN")
        beat = beats.get(service.value)
        if beat is None:
            parts.append(f"{service.value} {up}")
            continue
        stuck = f" STUCK: {'; '.join(beat.stuck)}" if beat.stuck else ""
        parts.append(f"{service.value} {up}, beat {_seconds(beat.age)} ago{stuck}")
    return "; ".join(parts)


class Publications:
    """The newest ``state``, ``Servo/health`` and heartbeats of one arm, from ring channels."""

    def __init__(self, session: zenoh.Session, client: Arm) -> None:
        keys = client.keys
        self._subs = [session.declare_subscriber(k, zenoh.handlers.RingChannel(_RING))
                      for k in (keys.state, keys.servo_health, keys.heartbeat())]
        self._state_key, self._health_key = keys.state, keys.servo_health
        self.queue: tuple[int, int | None] | None = None
        self.health: LoopHealth | None = None
        self.health_at: float | None = None  # [s] monotonic
        self.beats: dict[str, tuple[int, tuple[str, ...], float]] = {}  # service -> (seq, stuck, monotonic)
        self.errors: list[str] = []

    @property
    def complete(self) -> bool:
        """Whether a loop report and a heartbeat of every service have come."""
        return self.health is not None and all(service.value in self.beats for service in Service)

    def drain(self) -> None:
        for sub in self._subs:
            while (sample := sub.try_recv()) is not None:
                try:
                    self._take(str(sample.key_expr), sample.payload.to_bytes(), sample.encoding)
                except JaraArmError as exc:  # anyone may publish: note it, keep the view going
                    self.errors = [f"undecodable sample on {sample.key_expr}: {exc}"]

    def _take(self, key: str, payload: bytes, encoding: Any) -> None:
        now = time.monotonic()
        if key == self._state_key:
            published = read_state(payload, encoding)
            if published.queue_length is not None:
                self.queue = (published.queue_length, published.queue_capacity)
        elif key == self._health_key:
            self.health = codec.decode_message(LOOP_HEALTH, payload, sample_encoding(payload, encoding))
            self.health_at = now
        else:
            beat = codec.decode_message(HEARTBEAT, payload, sample_encoding(payload, encoding))
            self.beats[parse_heartbeat(key)[1]] = (beat.seq, tuple(beat.stuck), now)

    def close(self) -> None:
        for sub in self._subs:
            sub.undeclare()


def snapshot(client: Arm, pubs: Publications, axis_num: int | None) -> Snapshot:
    """Ask for what is asked for, add the newest publications."""
    errors: list[str] = []
    values: dict[str, Any] = {}
    for name, interface, out in ((OP.getState, Interface.COMMON, "state"),
                                 (OP.getFeedbackPosJoint, Interface.COMMON, "pos"),
                                 (OP.getFeedbackPosCartesian, Interface.MIDDLE, "pos"),
                                 (OP.getActiveAlarm, Interface.COMMON, "alarms")):
        try:
            reply = client.call(interface, name, None)
        except JaraArmError as exc:
            errors.append(f"{name}: {exc}")
            continue
        if reply.ok:
            values[name] = reply[out]
        else:
            errors.append(f"{name}: {reply.comment} ({reply.id})")
    pubs.drain()
    now = time.monotonic()
    pose = values.get(OP.getFeedbackPosCartesian)
    return Snapshot(
        arm=client.keys.arm, taken=time.time(), state=values.get(OP.getState), queue=pubs.queue,
        joints=values.get(OP.getFeedbackPosJoint), axis_num=axis_num,
        pose=None if pose is None else np.asarray(pose.carPos), alarms=values.get(OP.getActiveAlarm),
        health=pubs.health, health_age=None if pubs.health_at is None else now - pubs.health_at,
        beats={s: Beat(seq, stuck, now - at) for s, (seq, stuck, at) in pubs.beats.items()},
        alive=frozenset(alive_services(client.session, client.keys, timeout=0.5)),
        errors=tuple(errors + pubs.errors))


def _axis_num(client: Arm) -> int | None:
    try:
        reply = client.call(Interface.COMMON, OP.getManipInfo)
    except JaraArmError:
        return None
    return int(reply["mInfo"].axisNum) if reply.ok else None


def run_state(client: Arm, stop: threading.Event, out: TextIO, *, once: bool, period: float,
              tty: bool) -> int:
    """Print the view every ``period`` [s] until ``stop`` (in place on a terminal), or once."""
    pubs = Publications(client.session, client)
    try:
        axis_num = _axis_num(client)
        if once:  # a view right after subscribing would miss what is published every 0.1-1 s
            deadline = time.monotonic() + ONCE_WAIT
            while not pubs.complete and time.monotonic() < deadline and not stop.wait(0.05):
                pubs.drain()
        while True:
            lines = render(snapshot(client, pubs, axis_num))
            text = (CLEAR if tty else "") + "\n".join(lines) + ("\n" if tty or once else "\n\n")
            try:
                out.write(text)
                out.flush()
            except BrokenPipeError:
                return 0
            if once or stop.wait(period):
                return 0
    finally:
        pubs.close()


def _arguments(parser: argparse.ArgumentParser) -> None:
    add_arm(parser)
    parser.add_argument("--once", action="store_true", help="print one view and exit")
    parser.add_argument("--period", type=positive_float, default=0.5, metavar="S",
                        help="refresh period [s] (default: 0.5)")
    add_client_zenoh_arguments(parser)


def _run(args: argparse.Namespace, parser: argparse.ArgumentParser) -> int:
    setup_logging("WARNING")
    with listening(args, parser) as (session, stop):
        client = Arm(session, args.arm, timeout=2.0)
        try:
            return run_state(client, stop, sys.stdout, once=args.once, period=args.period,
                             tty=sys.stdout.isatty())
        except NoAnswer as exc:
            return no_answer(args, parser, exc)
        finally:
            client.close()


COMMAND = Command(
    "state", arguments=_arguments, run=_run,
    help="a live one-screen view of an arm",
    description="State bits by name, queue depth, joints, Cartesian pose, active alarms, servo "
    "loop health and services, refreshed in place on a terminal (as repeated blocks otherwise).")
