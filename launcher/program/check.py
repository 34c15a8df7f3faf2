"""``jara-arm program check``: whether every motion of a program can be planned on a live arm, moving nothing.

The arm's robot model and world (``Servo/world``), its settings (the getters) and where it is now are read
from the live arm; each motion of the program, loops unrolled, is then planned in this process by the
planner's own code (``services/planner/planning.py``: the same checks as the planner service: reachable,
within the soft limits, no posture change in a LIN, no collision), from where the motion before it ends.
A motion that cannot be planned is a :class:`~jara_arm.schema.program.Mistake` at its step's line and
column, with the planner's reason.
"""

from __future__ import annotations

import dataclasses
import time
from typing import Any

import numpy as np
import zenoh

from jara_arm.client import Arm, NoAnswer
from jara_arm.robots import Obstacle, robot
from jara_arm.schema import codec
from jara_arm.schema.codec import encode_args
from jara_arm.schema.encoding import Encoding
from jara_arm.schema.messages import SERVO_WORLD, ServoWorld
from jara_arm.schema.operations import MIDDLE, OP
from jara_arm.schema.planner import MOTION_SETTINGS, MotionRequest, MotionSettings
from jara_arm.schema.program import Mistake, Program, Step, Target, resolve
from jara_arm.schema.types import CarPosWithElbow

#: How long the arm's world may take to answer [s].
WORLD_TIMEOUT = 5.0
#: How long to wait for the command service's settings (published every 0.25 s) [s].
SETTINGS_TIMEOUT = 2.0


@dataclasses.dataclass(frozen=True)
class Motion:
    """One motion of a program as the arm is asked for it: the operation and its arguments."""

    step: Step
    op: str
    args: dict[str, Any]
    #: where it must arrive: joints [rad or m] (a joint target) or a position [m] (a Cartesian one, robot frame)
    joints: np.ndarray | None
    position: np.ndarray | None


def motion_of(program: Program, step: Step) -> Motion | Mistake:
    """The operation ``step`` asks for, or why it cannot ask for one (a point without what it needs)."""
    targets = [resolve(program, t) for t in step.targets]

    def car(t: Target) -> CarPosWithElbow | Mistake:
        if t.pose is None:
            return Mistake(t.where, f"{step.kind}: {t.describe()} has no pose (joints only): teach it again")
        return CarPosWithElbow(np.array(t.pose, dtype=float), t.elbow, t.posture)

    if step.kind == "ptp":
        t = targets[0]
        if t.joints is not None:
            return Motion(step, OP.movePTPJointAbs, {"jointPoints": t.joints}, np.array(t.joints), None)
        c = car(t)
        if isinstance(c, Mistake):
            return c
        return Motion(step, OP.movePTPCartesianAbs, {"carPoint": c}, None, np.asarray(c.carPos)[:, 3])
    if step.kind == "lin":
        c = car(targets[0])
        if isinstance(c, Mistake):
            return c
        return Motion(step, OP.moveLinearCartesianAbs, {"carPoint": c}, None, np.asarray(c.carPos)[:, 3])
    via, end = car(targets[0]), car(targets[1])
    if isinstance(via, Mistake):
        return via
    if isinstance(end, Mistake):
        return end
    return Motion(step, OP.moveCircularCartesianAbs, {"carPointR": via, "carPointT": end}, None,
                  np.asarray(end.carPos)[:, 3])


def world_of(arm: Arm) -> ServoWorld:
    """The arm's robot model and obstacles, as its servo says (``Servo/world``); NoAnswer if it does not."""
    for reply in arm.session.get(arm.keys.servo_world, zenoh.handlers.FifoChannel(4), payload=b"{}",
                                 timeout=WORLD_TIMEOUT):
        if reply.ok is not None:
            world: ServoWorld = codec.decode_message(SERVO_WORLD, reply.ok.payload.to_bytes(), Encoding.JSON)
            return world
    raise NoAnswer(f"no answer on {arm.keys.servo_world}: is the arm's servo running?")


def settings_of(arm: Arm) -> MotionSettings:
    """The arm's settings now: the command service's snapshot (``Command/settings``, what every motion is
    planned with, published every 0.25 s); NoAnswer if none comes."""
    with arm.session.declare_subscriber(arm.keys.command_settings, zenoh.handlers.RingChannel(1)) as sub:
        sample = None
        deadline = time.monotonic() + SETTINGS_TIMEOUT
        while sample is None and time.monotonic() < deadline:  # no recv with a timeout in zenoh-python
            sample = sub.try_recv()
            if sample is None:
                time.sleep(0.02)
    if sample is None:
        raise NoAnswer(f"nothing on {arm.keys.command_settings} within {SETTINGS_TIMEOUT:g} s: is the arm's command "
                       "service running?")
    settings: MotionSettings = codec.decode_message(MOTION_SETTINGS, sample.payload.to_bytes(),
                                                    Encoding.of(sample.encoding))
    return settings


def check(program: Program, arm: Arm, cycles: int = 1) -> list[Mistake]:
    """Every mistake of ``program`` on ``arm`` as it is now (none: every motion can be planned)."""
    from jara_arm.services.planner.planning import MotionPlanner  # heavy: only when checking
    from jara_arm.services.planner.request import PlanRefused, PlanRequest

    world = world_of(arm)
    model = robot(world.robot)
    obstacles = tuple(Obstacle(tuple(b.position), tuple(b.halfExtents)) for b in world.obstacles)  # type: ignore[arg-type]
    planner = MotionPlanner(model, obstacles=obstacles)
    settings = settings_of(arm)
    start = np.array(arm.getFeedbackPosJoint(), dtype=float)
    mistakes: list[Mistake] = []
    seen: set[tuple[int, int]] = set()
    # The speed ratios the run will have at each step: the arm's, as each step's ``speed`` sets them (run.py).
    joint, cartesian = settings.spdRatioJoint, settings.spdRatioCartesian
    for step in program.flat(cycles):
        if step.kind == "wait":
            continue
        if step.speed is not None:
            joint, cartesian = (step.speed, cartesian) if step.kind == "ptp" else (joint, step.speed)
        motion = motion_of(program, step)
        if isinstance(motion, Mistake):
            mistakes.append(motion)
            continue
        ratio = joint if step.kind == "ptp" else cartesian
        if ratio <= 0.0:
            key = (step.where.line, step.where.column)
            if key not in seen:
                seen.add(key)
                which = "setSpeedJoint" if step.kind == "ptp" else "setSpeedCartesian"
                mistakes.append(Mistake(step.where, f"{step.describe()}: the arm's speed ratio is 0 % when it runs "
                                        f"({which}): give it a speed"))
            continue
        s = dataclasses.replace(settings, spdRatioJoint=joint, spdRatioCartesian=cartesian)
        try:
            req = PlanRequest.decode(MotionRequest(motion.op, encode_args(MIDDLE[motion.op], motion.args), s))
            planned = planner.plan(req, start, None, preview=False)
        except PlanRefused as exc:
            key = (step.where.line, step.where.column)
            if key not in seen:  # a loop's step fails each time round: once is enough
                seen.add(key)
                mistakes.append(Mistake(step.where, f"{step.describe()}: {exc.comment}"))
            continue
        start = np.array(planned.end, dtype=float)
    return mistakes


__all__ = ["Motion", "check", "motion_of", "settings_of", "world_of"]
