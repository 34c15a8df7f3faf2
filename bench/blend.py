"""Blending: cycle time of a pick-and-place sequence with blend distance d = 0, 5 mm and 20 mm.

    python bench/blend.py [--robot iiwa] [--repeat 3] [--distances 0,5,20]

The whole system (``jara-arm up``) on a private port. One cycle is 10 motions
from the point above the pick (LIN and CIRC mixed, absolute targets around the
ready pose, the orientation kept): down to the pick, up, a CIRC over to the
place, down, up, a LIN aside, a CIRC back, down, up, and a LIN to the start.
The pick and place points are exact stops whatever d is (the motion leaving
them is queued with ``Ext/setBlendDistance`` 0, as one would program a gripper
stop); every other corner is blended with d. All 10 motions are queued back to
back, then the arm runs the cycle.

Reported per d, from the servo's joint feedback (its ``tm`` stamps) and FK of
the flange: the cycle time [s] (first sample moving to the last sample before
rest; mean and best of ``--repeat``), the time saved against d = 0, the largest
distance from a blended corner [mm] (for each corner the closest the flange
came to it, the largest of those; 0 for exact stops), and the lowest flange
speed within d of a blended corner [m/s] (above 0: it never stopped there).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import zenoh

sys.path.insert(0, str(Path(__file__).parent))
from _system import client, launched_system  # noqa: E402

from jara_arm.kinematics import Kinematics  # noqa: E402
from jara_arm.client import Arm  # noqa: E402
from jara_arm.robots import robot  # noqa: E402
from jara_arm.schema import codec  # noqa: E402
from jara_arm.schema import wire_types as w  # noqa: E402
from jara_arm.schema.codes import ReturnCode  # noqa: E402
from jara_arm.schema.keys import Service  # noqa: E402
from jara_arm.schema.operations import OP, Interface  # noqa: E402
from jara_arm.schema.types import CarPosWithElbow, hg_matrix  # noqa: E402

REST = 1e-6  # [rad] joints closer than this to the resting joints count as at rest
SETTLE = 0.2  # [s] after the arm is idle, for the last feedback samples to arrive


@dataclass(frozen=True)
class Step:
    """One motion of the cycle: a LIN to ``target``, or a CIRC through ``via`` to it (offsets [m] from
    the ready pose's flange, robot frame); ``stop``: an exact stop at its target (pick, place)."""

    target: tuple[float, float, float]
    via: tuple[float, float, float] | None = None
    stop: bool = False


A_UP, A_DOWN = (0.10, -0.15, 0.0), (0.10, -0.15, -0.08)  # above the pick, the pick
B_UP, B_DOWN = (0.10, 0.15, 0.0), (0.10, 0.15, -0.08)  # above the place, the place
C_UP, D_UP, D_DOWN = (-0.02, 0.15, 0.0), (-0.02, -0.15, 0.0), (-0.02, -0.15, -0.06)
START = A_UP
CYCLE = (
    Step(A_DOWN, stop=True), Step(A_UP), Step(B_UP, via=(0.15, 0.0, 0.03)), Step(B_DOWN, stop=True), Step(B_UP),
    Step(C_UP), Step(D_UP, via=(-0.05, 0.0, 0.04)), Step(D_DOWN), Step(D_UP), Step(A_UP),
)


@dataclass(frozen=True)
class Run:
    cycle: float  # [s]
    largest: float  # [m] the largest distance from a blended corner (the closest the flange came to each)
    slowest: float  # [m/s] the lowest speed within d of a blended corner (inf: none blended)


class Bench:
    """The system's client, its feedback and the cycle's poses."""

    def __init__(self, session: zenoh.Session, robot_name: str) -> None:
        self.client = Arm(session)
        self.model = robot(robot_name)
        self.kin = Kinematics(self.model)
        self.fb = session.declare_subscriber(self.client.keys.pos_feedback, zenoh.handlers.FifoChannel(1 << 18))

    def ok(self, reply: codec.Reply, what: str) -> codec.Reply:
        if reply.id != ReturnCode.OK:
            raise SystemExit(f"{what}: {ReturnCode(reply.id).name}: {reply.comment}")
        return reply

    def prepare(self) -> None:
        c = self.client
        c.wait_alive((Service.SERVO, Service.PLANNER, Service.COMMAND))
        self.ok(c.call(Interface.COMMON, OP.servoON), OP.servoON)
        self.ok(c.call(Interface.MIDDLE, OP.setSpeedJoint, {"spdRatio": 100}), OP.setSpeedJoint)
        self.ok(c.call(Interface.MIDDLE, OP.setSpeedCartesian, {"spdRatio": 100}), OP.setSpeedCartesian)
        self.ok(c.call(Interface.MIDDLE, OP.goHome), OP.goHome)
        c.wait_idle()
        pos = c.call(Interface.MIDDLE, OP.getFeedbackPosCartesian)["pos"]
        carpos = np.asarray(pos.carPos)
        self.origin, self.rotation, self.elbow = carpos[:, 3].copy(), carpos[:, :3].copy(), float(pos.elbow)

    def car(self, offset: tuple[float, float, float]) -> CarPosWithElbow:
        return CarPosWithElbow(hg_matrix(self.rotation, self.origin + np.asarray(offset)), self.elbow, 0)

    def point(self, offset: tuple[float, float, float]) -> np.ndarray:
        return self.origin + np.asarray(offset)

    def distance(self, d: float) -> None:
        self.ok(self.client.call(Interface.EXT, OP.setBlendDistance, {"distance": d}), OP.setBlendDistance)

    def to_start(self) -> None:
        self.distance(0.0)
        self.ok(self.client.call(Interface.MIDDLE, OP.moveLinearCartesianAbs, {"carPoint": self.car(START)}),
                "to the start")
        self.client.wait_idle()

    def drain(self) -> None:
        while self.fb.try_recv() is not None:
            pass

    def feedback(self) -> tuple[np.ndarray, np.ndarray]:
        """``(t [s], joints)`` of every feedback sample since the last drain."""
        msgs = [codec.decode_message(w.TIMED_JOINT_POS, s.payload.to_bytes()) for s in iter(self.fb.try_recv, None)]
        return np.array([m.tm.to_seconds() for m in msgs]), np.array([m.pos for m in msgs])

    def cycle(self, d: float) -> Run:
        """One cycle with blend distance ``d`` [m], from rest at the start to rest there again."""
        self.to_start()
        time.sleep(SETTLE)
        self.drain()
        previous_stop = True  # the corner before the first motion: the start, at rest
        for step in CYCLE:
            # the corner before a motion is blended with the distance that motion is accepted with
            self.distance(0.0 if previous_stop else d)
            if step.via is None:
                reply = self.client.call(Interface.MIDDLE, OP.moveLinearCartesianAbs,
                                         {"carPoint": self.car(step.target)})
            else:
                reply = self.client.call(Interface.MIDDLE, OP.moveCircularCartesianAbs,
                                         {"carPointR": self.car(step.via), "carPointT": self.car(step.target)})
            self.ok(reply, f"the motion to {step.target}")
            previous_stop = step.stop
        self.client.wait_idle()
        time.sleep(SETTLE)
        t, q = self.feedback()
        n = self.model.axis_num
        arm = q[:, :n]
        moving = np.flatnonzero(np.abs(arm - arm[0]).max(axis=1) > REST)
        resting = np.flatnonzero(np.abs(arm - arm[-1]).max(axis=1) > REST)
        if not moving.size or moving[0] == 0 or resting[-1] == len(t) - 1:
            raise SystemExit("the feedback does not show the cycle from rest to rest")
        cycle = float(t[resting[-1] + 1] - t[moving[0] - 1])
        pts = np.array([self.kin.fk(qi).translation for qi in arm])
        dt = np.diff(t)
        speed = np.linalg.norm(np.diff(pts, axis=0), axis=1) / np.where(dt > 0, dt, np.nan)  # a repeated tm: no speed
        # The cycle starts and ends at rest at A_UP, itself a blended corner mid-cycle: only the run counts.
        running = np.zeros(len(speed), dtype=bool)
        running[moving[0]:resting[-1]] = True
        largest, slowest = 0.0, float("inf")
        for before in CYCLE[:-1]:  # the corner after each motion but the last
            if before.stop or d == 0.0:
                continue
            gap = np.linalg.norm(pts - self.point(before.target), axis=1)
            near = np.flatnonzero((gap[:-1] <= d) & running & np.isfinite(speed))
            # Each passage within d of the corner apart; A_UP is also where the cycle leaves and ends at
            # rest (exact stops, not this corner's blend): passages touching the cycle's ends do not count.
            for passage in np.split(near, np.flatnonzero(np.diff(near) > 1) + 1):
                if not passage.size or passage[0] <= moving[0] or passage[-1] >= resting[-1] - 1:
                    continue
                closest, low = float(gap[passage].min()), float(speed[passage].min())
                largest, slowest = max(largest, closest), min(slowest, low)
                if os.environ.get("BLEND_CORNERS"):
                    print(f"d {d * 1e3:.0f} mm, corner {before.target}: closest {closest * 1e3:.2f} mm, "
                          f"slowest {low:.4f} m/s over {passage.size} samples", file=sys.stderr)
        return Run(cycle, largest, slowest)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--robot", default="iiwa", help="the robot model (default: iiwa)")
    ap.add_argument("--repeat", type=int, default=3, help="cycles per blend distance (default: 3)")
    ap.add_argument("--distances", default="0,5,20", help="blend distances [mm], comma-separated (default: 0,5,20)")
    args = ap.parse_args()
    distances = [float(x) * 1e-3 for x in args.distances.split(",")]
    results: dict[float, list[Run]] = {}
    with launched_system(robot=args.robot) as port, client(port) as session:
        b = Bench(session, args.robot)
        b.prepare()
        for d in distances:
            results[d] = [b.cycle(d) for _ in range(args.repeat)]
        b.distance(0.0)
    base = float(np.mean([r.cycle for r in results[distances[0]]]))
    print(f"blend: {args.robot}, {len(CYCLE)} motions a cycle (LIN, CIRC; pick and place exact stops), "
          f"{args.repeat} cycles each, speed ratios 100 %")
    print(f"| d [mm] | cycle mean [s] | best [s] | vs d = {distances[0] * 1e3:g} mm "
          "| closest approach to a blended corner, the largest [mm] | lowest speed within d of one [m/s] |")
    print("| --- | --- | --- | --- | --- | --- |")
    for d, runs in results.items():
        mean = float(np.mean([r.cycle for r in runs]))
        slowest = min(r.slowest for r in runs)
        print(f"| {d * 1e3:g} | {mean:.3f} | {min(r.cycle for r in runs):.3f} | {100 * (mean / base - 1):+.1f} % | "
              f"{max(r.largest for r in runs) * 1e3:.2f} | {'—' if slowest == float('inf') else f'{slowest:.3f}'} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
