"""``jara-arm demo``: a short, visible session over the public interface only (``jara_arm.client``).

Servo on, speeds, PTP, LIN, CIRC, pause and resume, home, servo off. Each step
prints the operation, its return code and comment, and what was measured
afterwards (feedback, not what was asked): every motion's arrival is checked
against its target, ``[FAILED]`` with the distance left when it fell short.
Exits 1 if a step that should succeed did not.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable
from typing import TextIO, TypeVar

import numpy as np

from jara_arm.client import Arm, ArmError, Motion, MotionFailed, Refused, rel
from jara_arm.robots import ROBOTS, Family, RobotModel
from jara_arm.schema.codes import ReturnCode, StateBit
from jara_arm.schema.keys import DEFAULT_ARM, Service
from jara_arm.services.runtime.stop_signals import StopSignals

from ..command import Command, setup_logging
from ..session import add_client_zenoh_arguments, arm_id, open_session

SPEED_JOINT = 40  # [%]
SPEED_CARTESIAN = 60  # [%] of 0.25 m/s by default
STEP = 0.08  # [m] size of the Cartesian moves
#: A motion counts as arrived with its feedback this close to its target [rad or m]: the simulated
#: drives settle within 1e-4 of it; a motion cut short misses it by far more.
ARRIVED = 1e-3
#: How long a demo motion may take to end [s]: the longest step (goHome at 40 %) takes about 3 s.
MOTION_TIMEOUT = 60.0

T = TypeVar("T")


class Demo:
    def __init__(self, arm: Arm, out: TextIO) -> None:
        self.arm = arm
        self.out = out
        self.failed: list[str] = []

    def say(self, text: str) -> None:
        print(text, file=self.out, flush=True)

    def _attempt(self, label: str, call: Callable[[], T]) -> tuple[bool, T | None]:
        """One call: ``[ok]`` (and its result), or ``[FAILED]`` with the code and comment of its refusal."""
        try:
            result = call()
        except Refused as exc:
            self.failed.append(label)
            self.say(f"[{'FAILED':>6}] {label:<52} -> {int(exc.code)} {exc.code.name}: {exc.comment}")
            return False, None
        except ArmError as exc:
            self.failed.append(label)
            self.say(f"[{'FAILED':>6}] {label:<52} -> {exc}")
            return False, None
        said = f"motion {result.id} accepted" if isinstance(result, Motion) else "OK"
        self.say(f"[{'ok':>6}] {label:<52} -> {int(ReturnCode.OK)} OK: {said}")
        return True, result

    def step(self, label: str, call: Callable[[], object]) -> bool:
        """One call that is not a motion; whether it was answered OK."""
        return self._attempt(label, call)[0]

    def start(self, label: str, call: Callable[[], Motion]) -> Motion | None:
        """One motion, not waited for; None if it was refused."""
        return self._attempt(label, call)[1]

    def check(self, label: str, passed: bool, detail: str) -> bool:
        """A measured outcome: ``[ok]`` or ``[FAILED]`` with what was measured."""
        if not passed:
            self.failed.append(label)
        self.say(f"[{'ok' if passed else 'FAILED':>6}] {label:<52} -> {detail}")
        return passed

    def position(self) -> np.ndarray:
        return np.asarray(self.arm.getFeedbackPosCartesian().carPos)[:, 3]

    def joints(self) -> np.ndarray:
        return np.asarray(self.arm.joints)

    def move(self, label: str, start: Callable[[], Motion], *, joints: np.ndarray | None = None,
             delta: np.ndarray | None = None) -> None:
        """One motion: accepted, ended, and arrived where it should: at ``joints`` [rad or m], or with the
        control point moved by ``delta`` [m]."""
        p0 = self.position() if delta is not None else None
        t0 = time.monotonic()
        motion = self.start(label, start)
        if motion is None:
            return
        try:
            motion.wait(MOTION_TIMEOUT)
        except MotionFailed as exc:
            self.check(f"{label}: arrived", False, f"state 0x{self.arm.state:02x}; active alarms: "
                       + ("; ".join(exc.alarms) or "none"))
            return
        except ArmError as exc:
            self.check(f"{label}: arrived", False, str(exc))
            return
        dt = time.monotonic() - t0
        if delta is not None:
            assert p0 is not None
            d = self.position() - p0
            left = float(np.linalg.norm(d - delta))
            self.check(f"{label}: arrived", left <= ARRIVED,
                       f"after {dt:.2f} s the control point moved ({d[0]:+.4f}, {d[1]:+.4f}, {d[2]:+.4f}) m"
                       + ("" if left <= ARRIVED else f"; {left:.4f} m short of its target"))
        elif joints is not None:
            q = self.joints()[:len(joints)]
            left = float(np.max(np.abs(q - joints)))
            self.check(f"{label}: arrived", left <= ARRIVED,
                       f"after {dt:.2f} s joints {np.round(q, 4).tolist()}"
                       + ("" if left <= ARRIVED else f"; {left:.4f} rad / m short of the target"))


def run_demo(arm: Arm, out: TextIO) -> int:
    """The sequence; returns the number of steps that did not do what they should."""
    d = Demo(arm, out)
    arm.wait_alive((Service.SERVO, Service.PLANNER, Service.COMMAND))
    info = arm.getManipInfo()
    d.say(f"arm {arm.keys.arm}: {info.manufactur} {info.type}, {info.axisNum} axes"
          f"{' + gripper' if info.isGripper else ''}, cycle {info.cmdCycle} ms")
    model: RobotModel | None = next((r for r in ROBOTS.values() if r.type == info.type), None)
    if arm.state & StateBit.ALARM:
        d.step("clearAlarms", arm.clearAlarms)
    if not d.step("servoON", arm.servoON):
        d.say("demo stopped: every further step needs the servo on")
        return len(d.failed)
    d.step(f"setSpeedJoint({SPEED_JOINT} %)", lambda: arm.setSpeedJoint(SPEED_JOINT))
    d.step(f"setSpeedCartesian({SPEED_CARTESIAN} %)", lambda: arm.setSpeedCartesian(SPEED_CARTESIAN))
    home = np.asarray(arm.getHome())
    d.move("goHome", lambda: arm.goHome(wait=False), joints=home)
    delta = [0.0] * info.axisNum
    delta[0] = 0.3 if model is None or not model.prismatic[0] else 0.05
    d.move(f"movePTPJointRel(J1 {delta[0]:+})", lambda: arm.movePTPJointRel(delta, wait=False),
           joints=d.joints()[:info.axisNum] + delta)
    cartesian_lin = model is None or not (model.family is Family.CARTESIAN and model.axis_num < 3)
    if cartesian_lin:
        d.move(f"moveLinearCartesianRel(z {-STEP:+})", lambda: arm.moveLinearCartesianRel(rel(dz=-STEP), wait=False),
               delta=np.array([0.0, 0.0, -STEP]))
    if model is None or model.axis_num >= 2:
        d.move(f"moveCircularCartesianRel(via {STEP/2:+},{STEP/2:+}; to {STEP:+},0)",
               lambda: arm.moveCircularCartesianRel(rel(dx=STEP / 2, dy=STEP / 2), rel(dx=STEP), wait=False),
               delta=np.array([STEP, 0.0, 0.0]))
    if cartesian_lin:
        p0 = d.position()
        away = d.start(f"moveLinearCartesianRel(x {-2 * STEP:+})",
                      lambda: arm.moveLinearCartesianRel(rel(dx=-2 * STEP), wait=False))
        time.sleep(0.4)
        d.step("pause", arm.pause)
        time.sleep(0.5)
        held = d.position() - p0
        state = arm.state
        d.check("paused", bool(state & StateBit.PAUSED) and not state & StateBit.ALARM,
                f"state 0x{state:02x} (bit 0x10 {'set' if state & StateBit.PAUSED else 'NOT set'}) after "
                f"{held[0]:+.4f} m of {-2 * STEP:+} m")
        d.step("resume", arm.resume)
        try:
            if away is not None:
                away.wait(MOTION_TIMEOUT)
            moved = d.position()[0] - p0[0]
            d.check("resumed and arrived", abs(moved + 2 * STEP) < ARRIVED,
                    f"moved {moved:+.4f} m in x of {-2 * STEP:+} m"
                    + ("" if abs(moved + 2 * STEP) < ARRIVED else f"; {abs(moved + 2 * STEP):.4f} m short"))
        except ArmError as exc:
            d.check("resumed and arrived", False, str(exc))
    d.move("goHome", lambda: arm.goHome(wait=False), joints=home)
    d.step("servoOFF", arm.servoOFF)
    d.say("demo done" if not d.failed else f"demo: {len(d.failed)} step(s) failed: {', '.join(d.failed)}")
    return len(d.failed)


def _arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--arm", type=arm_id, default=DEFAULT_ARM, metavar="ID",
                        help=f"the arm to drive (default: {DEFAULT_ARM})")
    add_client_zenoh_arguments(parser)


def _run(args: argparse.Namespace, parser: argparse.ArgumentParser) -> int:
    setup_logging("WARNING")
    session = open_session(args, parser)
    StopSignals()  # SIGINT/SIGTERM noted, not obeyed: the demo runs to its end (servo off)
    with session:
        try:
            with Arm(session, args.arm) as arm:
                return 1 if run_demo(arm, sys.stdout) else 0
        except ArmError as exc:
            print(f"{parser.prog}: {exc}", file=sys.stderr)
            return 1


COMMAND = Command(
    "demo", arguments=_arguments, run=_run,
    help="drive a running arm through a short, visible sequence",
    description="Servo on, speeds, PTP, LIN, CIRC, pause/resume, home, servo off, over the "
    "public interface only; prints each step with its return code and what was measured.")
