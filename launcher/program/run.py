"""``jara-arm program run``: a program's steps, through the specification's operations, each arrival checked.

The program is checked first (``check.py``): one that has a mistake moves nothing. Then each step in turn,
loops unrolled, the whole ``--cycles`` times: the step's speed (``setSpeedJoint`` for a PTP,
``setSpeedCartesian`` for a LIN or a CIRC) and blend distance (``setBlendDistance``, 0 unless the step sets
one), then the motion. A motion is waited for and its arrival measured (feedback, not what was asked)
unless the next step blends into it; a ``wait`` waits for every motion before it, then its seconds.
``--step`` asks for Enter before each step. Pause, resume and stop from any client act as on any
motion: a paused motion is waited for; a stopped one ends the run, saying so (exit 1).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import TextIO

import numpy as np

from jara_arm.client import Arm, ArmError
from jara_arm.client.motion import Motion as ArmMotion
from jara_arm.schema.operations import OP
from jara_arm.schema.program import Program, Step

from .check import Motion, check, motion_of

#: An arrival: feedback joints this close to a joint target [rad or m], or the control point this close
#: to a Cartesian target [m] (the issue's 0.5 mm; the simulated drives settle within 0.1 mm).
ARRIVED_JOINTS = 1e-3
ARRIVED_POSITION = 5e-4
#: How long one motion may take to end [s], paused time included.
MOTION_TIMEOUT = 600.0


class Runner:
    def __init__(self, arm: Arm, out: TextIO, ask: Callable[[str], str] | None = None) -> None:
        """``ask``: asks for Enter before each step (``--step``), None: runs straight through."""
        self.arm, self.out, self.ask = arm, out, ask

    def say(self, text: str) -> None:
        print(text, file=self.out, flush=True)

    def run(self, program: Program, cycles: int = 1) -> int:
        """0 once every step ran and every checked motion arrived; 1 after the first that did not."""
        mistakes = check(program, self.arm, cycles)
        if mistakes:
            for m in mistakes:
                self.say(f"{program.path}:{m}")
            self.say(f"{len(mistakes)} mistake(s): nothing moved")
            return 1
        steps = program.flat(cycles)
        n = len(steps)
        running: tuple[int, Motion, ArmMotion] | None = None  # blended into by the step after it
        for k, step in enumerate(steps, 1):
            if self.ask is not None:
                if running is not None and not self._arrive(*running, n):
                    return 1
                running = None
                self.ask(f"step {k}/{n}: {step.describe()} (line {step.where.line}): Enter to run it ")
            if step.kind == "wait":
                if running is not None and not self._arrive(*running, n):
                    return 1
                running = None
                self.say(f"step {k}/{n}: {step.describe()}")
                time.sleep(step.seconds)
                continue
            motion = motion_of(program, step)
            assert isinstance(motion, Motion)  # check() found no mistake
            blends = step.blend is not None and step.blend > 0.0
            if running is not None and not blends and not self._arrive(*running, n):
                return 1
            try:
                self._settings(step)
                started = self._start(motion)
            except ArmError as exc:
                self.say(f"step {k}/{n}: {step.describe()}: FAILED: {exc}")
                return 1
            if running is not None and blends:
                self.say(f"step {running[0]}/{n}: {running[1].step.describe()}: blended into step {k}")
            self.say(f"step {k}/{n}: {step.describe()}: motion {started.id} accepted")
            running = (k, motion, started)
        if running is not None and not self._arrive(*running, n):
            return 1
        self.say(f"program done: {n} steps" + (f", {cycles} cycles" if cycles > 1 else ""))
        return 0

    def _settings(self, step: Step) -> None:
        if step.speed is not None:
            if step.kind == "ptp":
                self.arm.setSpeedJoint(step.speed)
            else:
                self.arm.setSpeedCartesian(step.speed)
        self.arm.setBlendDistance(step.blend or 0.0)

    def _start(self, motion: Motion) -> ArmMotion:
        a = self.arm
        if motion.op == OP.movePTPJointAbs:
            return a.movePTPJointAbs(motion.args["jointPoints"], wait=False)
        if motion.op == OP.movePTPCartesianAbs:
            return a.movePTPCartesianAbs(motion.args["carPoint"], wait=False)
        if motion.op == OP.moveLinearCartesianAbs:
            return a.moveLinearCartesianAbs(motion.args["carPoint"], wait=False)
        return a.moveCircularCartesianAbs(motion.args["carPointR"], motion.args["carPointT"], wait=False)

    def _arrive(self, k: int, motion: Motion, started: ArmMotion, n: int) -> bool:
        """Wait for ``started`` to end and measure where the arm is; whether it arrived."""
        what = f"step {k}/{n}: {motion.step.describe()}"
        try:
            started.wait(MOTION_TIMEOUT)
        except ArmError as exc:
            self.say(f"{what}: FAILED: {exc}")
            return False
        if motion.joints is not None:
            q = np.array(self.arm.getFeedbackPosJoint())[:len(motion.joints)]
            left = float(np.abs(q - motion.joints).max())
            ok, said = left < ARRIVED_JOINTS, f"{left:.2e} rad from its target"
        else:
            assert motion.position is not None
            p = np.asarray(self.arm.getFeedbackPosCartesian().carPos)[:, 3]
            left = float(np.linalg.norm(p - motion.position))
            ok, said = left < ARRIVED_POSITION, f"{left * 1e3:.3f} mm from its target"
        self.say(f"{what}: {'arrived' if ok else 'FAILED: did not arrive'}, {said}")
        return ok


__all__ = ["Runner"]
