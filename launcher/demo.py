"""``jara-arm demo``: a short, visible session over the public interface only.

Servo on, speeds, PTP, LIN, CIRC, pause and resume, home, servo off. Each step
prints the operation, its return code and comment, and what was measured
afterwards (feedback, not what was asked): every motion's arrival is checked
against its target, ``[FAILED]`` with the distance left when it fell short.
Exits 1 if a step that should succeed did not.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping
from typing import Any, TextIO

import numpy as np

from jara_arm.robots import ROBOTS, Family, RobotModel
from jara_arm.schema.codec import Reply
from jara_arm.schema.codes import ReturnCode, StateBit
from jara_arm.schema.keys import Service
from jara_arm.schema.operations import OP
from jara_arm.schema.types import CarPosWithElbow, hg_matrix

from .client import ArmClient

SPEED_JOINT = 40  # [%]
SPEED_CARTESIAN = 60  # [%] of 0.25 m/s by default
STEP = 0.08  # [m] size of the Cartesian moves
#: A motion counts as arrived with its feedback this close to its target [rad or m]: the simulated
#: drives settle within 1e-4 of it; a motion cut short misses it by far more.
ARRIVED = 1e-3


def rel(dx: float = 0.0, dy: float = 0.0, dz: float = 0.0) -> CarPosWithElbow:
    """A relative Cartesian target: a translation [m], no rotation, elbow unchanged."""
    return CarPosWithElbow(hg_matrix(None, (dx, dy, dz)), 0.0, 0)


class Demo:
    def __init__(self, client: ArmClient, out: TextIO) -> None:
        self.client = client
        self.out = out
        self.failed: list[str] = []

    def say(self, text: str) -> None:
        print(text, file=self.out, flush=True)

    def step(self, label: str, call: Callable[[], Reply], expect: int = ReturnCode.OK) -> Reply:
        reply = call()
        mark = "ok" if reply.id == expect else "FAILED"
        if reply.id != expect:
            self.failed.append(label)
        self.say(f"[{mark:>6}] {label:<52} -> {reply.id} {ReturnCode(reply.id).name}: {reply.comment}")
        return reply

    def check(self, label: str, passed: bool, detail: str) -> bool:
        """A measured outcome: ``[ok]`` or ``[FAILED]`` with what was measured."""
        if not passed:
            self.failed.append(label)
        self.say(f"[{'ok' if passed else 'FAILED':>6}] {label:<52} -> {detail}")
        return passed

    def position(self) -> np.ndarray:
        return np.asarray(self.client.middle(OP.getFeedbackPosCartesian)["pos"].carPos)[:, 3]

    def joints(self) -> np.ndarray:
        return np.asarray(self.client.common(OP.getFeedbackPosJoint)["pos"])

    def move(self, label: str, name: str, args: Mapping[str, Any] | None = None, *,
             joints: np.ndarray | None = None, delta: np.ndarray | None = None) -> None:
        """One motion: accepted, then arrived where it should: at ``joints`` [rad or m], or with the
        control point moved by ``delta`` [m]."""
        p0 = self.position() if delta is not None else None
        t0 = time.monotonic()
        if self.step(label, lambda: self.client.middle(name, args)).id != ReturnCode.OK:
            return
        self.client.wait_idle()
        dt = time.monotonic() - t0
        state = self.client.state()
        if state & StateBit.ALARM or not state & StateBit.SERVO_ON:
            alarms = self.client.common(OP.getActiveAlarm)["alarms"]
            self.check(f"{label}: arrived", False, f"state 0x{state:02x}; active alarms: "
                       + ("; ".join(f"0x{a.code:02x} {a.type.value} {a.description}" for a in alarms) or "none"))
            return
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


def run_demo(client: ArmClient, out: TextIO) -> int:
    """The sequence; returns the number of steps that did not do what they should."""
    d = Demo(client, out)
    client.wait_alive((Service.SERVO, Service.PLANNER, Service.COMMAND))
    info = client.common(OP.getManipInfo)["mInfo"]
    d.say(f"arm {client.keys.arm}: {info.manufactur} {info.type}, {info.axisNum} axes"
          f"{' + gripper' if info.isGripper else ''}, cycle {info.cmdCycle} ms")
    model: RobotModel | None = next((r for r in ROBOTS.values() if r.type == info.type), None)
    if client.state() & StateBit.ALARM:
        d.step("clearAlarms", lambda: client.common(OP.clearAlarms))
    if d.step("servoON", lambda: client.common(OP.servoON)).id != ReturnCode.OK:
        d.say("demo stopped: every further step needs the servo on")
        return len(d.failed)
    d.step(f"setSpeedJoint({SPEED_JOINT} %)", lambda: client.middle(OP.setSpeedJoint, {"spdRatio": SPEED_JOINT}))
    d.step(f"setSpeedCartesian({SPEED_CARTESIAN} %)",
           lambda: client.middle(OP.setSpeedCartesian, {"spdRatio": SPEED_CARTESIAN}))
    home = np.asarray(client.middle(OP.getHome)["jointPoint"])
    d.move("goHome", OP.goHome, joints=home)
    delta = [0.0] * info.axisNum
    delta[0] = 0.3 if model is None or not model.prismatic[0] else 0.05
    d.move(f"movePTPJointRel(J1 {delta[0]:+})", OP.movePTPJointRel, {"jointPoints": delta},
           joints=d.joints()[:info.axisNum] + delta)
    cartesian_lin = model is None or not (model.family is Family.CARTESIAN and model.axis_num < 3)
    if cartesian_lin:
        d.move(f"moveLinearCartesianRel(z {-STEP:+})", OP.moveLinearCartesianRel, {"carPoint": rel(dz=-STEP)},
               delta=np.array([0.0, 0.0, -STEP]))
    if model is None or model.axis_num >= 2:
        d.move(f"moveCircularCartesianRel(via {STEP/2:+},{STEP/2:+}; to {STEP:+},0)",
               OP.moveCircularCartesianRel,
               {"carPointR": rel(dx=STEP / 2, dy=STEP / 2), "carPointT": rel(dx=STEP)},
               delta=np.array([STEP, 0.0, 0.0]))
    if cartesian_lin:
        p0 = d.position()
        d.step(f"moveLinearCartesianRel(x {-2 * STEP:+})",
               lambda: client.middle(OP.moveLinearCartesianRel, {"carPoint": rel(dx=-2 * STEP)}))
        time.sleep(0.4)
        d.step("pause", lambda: client.middle(OP.pause))
        time.sleep(0.5)
        held = d.position() - p0
        state = client.state()
        d.check("paused", bool(state & StateBit.PAUSED) and not state & StateBit.ALARM,
                f"state 0x{state:02x} (bit 0x10 {'set' if state & StateBit.PAUSED else 'NOT set'}) after "
                f"{held[0]:+.4f} m of {-2 * STEP:+} m")
        d.step("resume", lambda: client.middle(OP.resume))
        client.wait_idle()
        moved = d.position()[0] - p0[0]
        d.check("resumed and arrived", abs(moved + 2 * STEP) < ARRIVED,
                f"moved {moved:+.4f} m in x of {-2 * STEP:+} m"
                + ("" if abs(moved + 2 * STEP) < ARRIVED else f"; {abs(moved + 2 * STEP):.4f} m short"))
    d.move("goHome", OP.goHome, joints=home)
    d.step("servoOFF", lambda: client.common(OP.servoOFF))
    d.say("demo done" if not d.failed else f"demo: {len(d.failed)} step(s) failed: {', '.join(d.failed)}")
    return len(d.failed)

