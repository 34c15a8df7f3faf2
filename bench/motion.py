"""Motion benchmark: a servo and a planner process (iiwa), driven over Zenoh as the command service would.

Measures, and prints one line each:

* reply -> motion: from the ``Planner/plan`` reply to the first feedback sample
  that has left the start (PTP from rest, 50 %), median / max over ``--n`` moves;
* request -> first position command (the first command the servo followed,
  ``Servo/posTarget``, by the time its cycle stands for) and request -> reply
  for a 0.5 m LIN and a half-circle CIRC (radius 0.15 m) at 0.25 m/s, from
  rest, ``--rounds`` times each (median, max): with the planner's early start
  the first command follows the head (its first knot interval), the reply the
  whole; ``--early-start-ms 0`` measures acceptance first. For each of them,
  whether the control point's commanded speed dipped on the way (fell below
  half the speed reached, then rose again: what braking on an early start's
  head and starting again shows), and how often the servo held a head at its
  last sample waiting for its rest (its log); Then the planner's own planning time (its log), and the same two
  motions planned in this process (``MotionPlanner.plan``, median wall and
  least CPU time of 9: the planning cost without the services and the
  machine's other load); ``bench/plan_stages.py`` splits that cost by stage;
* deviation of those moves from the ideal line / circle: planned (FK of the
  position commands) and executed (FK of the feedback);
* pause latency: from the ``pause`` request (and from its reply) to the first
  command the servo followed that is slower than the one before;
* PTP duration vs the time-optimal bound: Ruckig's synchronised time-optimal
  duration for the same per-axis speed, acceleration and jerk limits;
* the collision check's cost per motion (``services/planner/collision.py``,
  in this process, before the services start): a PTP (J1 by 1 rad), a 0.5 m
  LIN and a half-circle CIRC (radius 0.15 m) on iiwa and panda, median of 9,
  with one box in the world, clear of the paths.

    python bench/motion.py [--n 10] [--rounds 5] [--early-start-ms 0]
"""

from __future__ import annotations

import argparse
import os
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import ruckig
import zenoh

from jara_arm.robots import robot
from jara_arm.schema import codec, messages
from jara_arm.schema import wire_types as w
from jara_arm.schema.keys import ArmKeys, Service
from jara_arm.schema.operations import COMMON, OP
from jara_arm.schema.planner import (
    CONTROL_REQUEST,
    MOTION_REQUEST,
    PLAN_REPLY,
    PLANNER_PROGRESS,
    ControlAction,
    ControlRequest,
    MotionRequest,
    MotionSettings,
)
from jara_arm.schema.types import CarPosWithElbow, CartesianSpeed, LimitValue
from jara_arm.kinematics import Kinematics
from jara_arm.robots import Obstacle
from jara_arm.services.planner.planning import MotionPlanner
from jara_arm.services.planner.profile import ProfileLimits
from jara_arm.services.planner.request import PlanRequest
from jara_arm.services.runtime.zenoh_args import zenoh_config

sys.path.insert(0, str(Path(__file__).parent))
from _system import free_port  # noqa: E402

MODEL = robot("iiwa")
DT = MODEL.cmd_cycle


def spawn(service: Service, port: int, *extra: str) -> subprocess.Popen:
    argv = [sys.executable, "-m", f"jara_arm.services.{service.value}", "--robot", MODEL.name,
            "--listen", f"tcp/127.0.0.1:{port}", *extra]
    return subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            start_new_session=True)


class Bench:
    def __init__(self, session: zenoh.Session) -> None:
        self.session = session
        self.keys = ArmKeys()
        self.kin = Kinematics(MODEL)
        self.lock = threading.Lock()
        self.fbs: list[tuple[float, bytes]] = []
        self.statuses: list[bytes] = []
        self.cmds = session.declare_subscriber(self.keys.pos_target, zenoh.handlers.FifoChannel(1 << 18))
        session.declare_subscriber(self.keys.pos_feedback, lambda s: self._add(self.fbs, s))
        session.declare_subscriber(self.keys.servo_status, lambda s: self._add(self.statuses, s))
        self.progress = session.declare_subscriber(self.keys.planner_progress, zenoh.handlers.RingChannel(1))

    def _add(self, where: list, sample: zenoh.Sample) -> None:
        with self.lock:
            where.append((time.time(), sample.payload.to_bytes()))

    def drain(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, list[messages.ServoStatus]]:
        with self.lock:
            fbs, sts = self.fbs, self.statuses
            self.fbs, self.statuses = [], []
        dec = lambda b: codec.decode_message(w.TIMED_JOINT_POS, b)  # noqa: E731
        cmds = [dec(s.payload.to_bytes()) for s in iter(self.cmds.try_recv, None)]
        fb = [dec(b) for _, b in fbs]
        return (np.array([c.tm.to_seconds() for c in cmds]), np.array([c.pos for c in cmds]).reshape(-1, 7),
                np.array([f.tm.to_seconds() for f in fb]), np.array([f.pos for f in fb]),
                [codec.decode_message(messages.SERVO_STATUS, b) for _, b in sts])

    def settings(self, **kw) -> MotionSettings:
        s = dict(spdRatioJoint=50, spdRatioCartesian=100, maxSpeedJoint=MODEL.rated_speed,
                 maxSpeedCartesian=CartesianSpeed(0.25, 1.0), accelTimeJoint=MODEL.min_accel_time,
                 accelTimeCartesian=MODEL.min_accel_time_cartesian, softLimitJoint=MODEL.hard_limits,
                 softLimitCartesian=(LimitValue(2.0, -2.0),) * 3, baseOffset=np.eye(4)[:3],
                 controlPointOffset=np.eye(4)[:3], home=MODEL.ready_pose)
        s.update(kw)
        return MotionSettings(**s)

    def plan(self, op: str, args: dict | None = None, **kw):
        req = MotionRequest(op, args or {}, self.settings(**kw))
        r = list(self.session.get(self.keys.planner_plan, payload=codec.encode_message(MOTION_REQUEST, req),
                                  timeout=30.0))
        reply = codec.decode_message(PLAN_REPLY, r[0].ok.payload.to_bytes())
        assert reply.id == 0, reply
        return reply.motion, reply  # the id the planner's queue gave it

    def control(self, action: ControlAction) -> dict:
        r = list(self.session.get(self.keys.planner_control, payload=codec.encode_message(
            CONTROL_REQUEST, ControlRequest(action.value)), timeout=10.0))
        return codec.loads(r[0].ok.payload.to_bytes())

    def servo(self, op: str) -> None:
        body = codec.encode_request(COMMON[op], {})
        list(self.session.get(self.keys.servo_common(op), payload=body, timeout=5.0))

    def wait_done(self, motion: int, timeout: float = 30.0) -> None:
        deadline = time.time() + timeout
        while time.time() < deadline:
            s = self.progress.try_recv()
            if s is not None:
                p = codec.decode_message(PLANNER_PROGRESS, s.payload.to_bytes())
                if max(p.lastDone, p.lastDiscarded) >= motion and not p.streaming:
                    time.sleep(0.15)  # tracking settles
                    return
            time.sleep(0.005)
        raise TimeoutError(f"motion {motion} not done")

    def tcp(self, q: np.ndarray) -> np.ndarray:
        return np.array([self.kin.control_point(x[:7]).translation for x in np.atleast_2d(q)])


def car(p, R) -> dict:
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, p
    return w.CAR_POS_WITH_ELBOW.encode(CarPosWithElbow(T[:3], 0.0, 0))


def dipped(p: np.ndarray) -> bool:
    """Whether the speed along points ``p`` (one per cycle) fell below half the speed reached so far and
    then rose again by a quarter of it: a stop-and-go on the way, not the end of the motion."""
    return speed_dipped(np.linalg.norm(np.diff(p, axis=0), axis=1))


def speed_dipped(v: np.ndarray) -> bool:
    """Whether speeds ``v`` (in time order, any unit) fell below half the speed reached so far and then rose
    again by a quarter of it (``dipped``)."""
    reached = np.maximum.accumulate(v)
    low = np.flatnonzero((v < 0.5 * reached) & (reached > 0))
    return any(v[i:].max() > v[i] + 0.25 * reached[i] for i in low)


def line_dev(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> float:
    d = b - a
    u = np.clip((p - a) @ d / (d @ d), 0, 1)
    return float(np.linalg.norm(p - (a + u[:, None] * d), axis=1).max())


def reply_to_motion(b: Bench, n: int) -> str:
    lat = []
    for k in range(n):
        b.drain()
        time.sleep(0.05)
        _, _, _, fb0, _ = b.drain()
        rest = fb0[-20:].mean(axis=0)
        sign = 1 if k % 2 == 0 else -1
        motion, _ = b.plan(OP.movePTPJointRel, {"jointPoints": [sign * 0.2] + [0.0] * 6})
        t_reply = time.time()
        b.wait_done(motion)
        _, _, tf, fb, _ = b.drain()
        moved = np.flatnonzero(np.abs(fb[:, 0] - rest[0]) > 1e-6)
        lat.append(tf[moved[0]] - t_reply)
    lat_ms = np.array(lat) * 1e3
    return (f"reply -> first feedback that moved (> 1e-6 rad): median {np.median(lat_ms):.1f} ms, "
            f"max {lat_ms.max():.1f} ms over {n} PTP moves")


def cartesian(b: Bench, rounds: int) -> list[str]:
    """``rounds`` times: the 0.5 m LIN, the half circle from its end, an unmeasured LIN back."""
    out = []
    _, _, _, fb, _ = b.drain()
    q0 = np.array(MODEL.ready_pose)
    T0 = b.kin.control_point(q0)
    p0, R0 = T0.translation, T0.rotation
    # 0.5 m LIN, from the ready pose across the front of the robot
    a = p0 + [-0.1, -0.25, 0.0]
    bb = a + [0.0, 0.5, 0.0]
    # half circle, radius 0.15 m, in the x-y plane
    r = 0.15
    c = bb + [0.0, -r, 0.0]
    via, target = c + [r, 0.0, 0.0], c + [0.0, -r, 0.0]
    lin_args = {"carPoint": car(bb, R0)}
    circ_args = {"carPointR": car(via, R0), "carPointT": car(target, R0)}

    def circ_dev(p: np.ndarray) -> float:
        radial = np.linalg.norm(p[:, :2] - c[:2], axis=1) - r
        return float(np.hypot(radial, p[:, 2] - c[2]).max())

    measured: dict[str, list[tuple[float, float, float, float, float]]] = {"LIN": [], "CIRC": []}
    durations = {}
    for _ in range(rounds):
        m, _ = b.plan(OP.moveLinearCartesianAbs, {"carPoint": car(a, R0)})
        b.wait_done(m)
        for name, op, args, dev in (("LIN", OP.moveLinearCartesianAbs, lin_args,
                                     lambda p: line_dev(p, a, bb)),
                                    ("CIRC", OP.moveCircularCartesianAbs, circ_args, circ_dev)):
            b.drain()
            t0 = time.time()
            m, reply = b.plan(op, args)
            t_reply = time.time()
            b.wait_done(m)
            tc, cmd, _, fb, _ = b.drain()
            durations[name] = reply.duration
            measured[name].append((1e3 * (t_reply - t0), 1e3 * (tc[0] - t0), dev(b.tcp(cmd)), dev(b.tcp(fb)),
                                   float(dipped(b.tcp(cmd)))))
    for name, what in (("LIN", "LIN 0.5 m"), ("CIRC", "CIRC half circle r = 0.15 m")):
        reply_ms, first_ms, planned, executed, dips = np.array(measured[name]).T
        out.append(f"{what} at 0.25 m/s ({durations[name]:.2f} s), {rounds} times: request -> reply median "
                   f"{np.median(reply_ms):.1f} ms (max {reply_ms.max():.1f}), request -> first command median "
                   f"{np.median(first_ms):.1f} ms (min {first_ms.min():.1f}, max {first_ms.max():.1f}); deviation "
                   f"planned {planned.max() * 1e6:.3f} µm, executed {executed.max() * 1e6:.1f} µm; speed dips "
                   f"{int(dips.sum())} of {rounds}")
    out.append(in_process(b, q0, a, lin_args, circ_args))
    return out


def in_process(b: Bench, q0: np.ndarray, a: np.ndarray, lin_args: dict, circ_args: dict) -> str:
    """The LIN and the CIRC of :func:`cartesian` planned here, the LIN from a LIN ready pose -> its start."""
    planner = MotionPlanner(MODEL)
    R0 = b.kin.control_point(q0).rotation
    plan = lambda op, args, q: planner.plan(PlanRequest.decode(MotionRequest(op, args, b.settings())), q)  # noqa: E731
    qa = plan(OP.moveLinearCartesianAbs, {"carPoint": car(a, R0)}, q0).end
    qb = plan(OP.moveLinearCartesianAbs, lin_args, qa).end
    out = []
    for name, op, args, q in (("LIN", OP.moveLinearCartesianAbs, lin_args, qa),
                              ("CIRC", OP.moveCircularCartesianAbs, circ_args, qb)):
        wall, cpu = [], []
        for _ in range(9):
            t, c = time.perf_counter(), time.process_time()
            plan(op, args, q)
            wall.append(time.perf_counter() - t)
            cpu.append(time.process_time() - c)
        out.append(f"{name} median {1e3 * float(np.median(wall)):.1f} ms (CPU {1e3 * min(cpu):.1f} ms)")
    return "planned in this process: " + ", ".join(out)


def collision_cost() -> list[str]:
    """The collision check alone (``MotionPlanner.collisions.check``) on a PTP, a LIN and a CIRC per robot."""
    out = []
    for name in ("iiwa", "panda"):
        model = robot(name)
        box = Obstacle((-0.6, 0.0, 0.3), (0.1, 0.1, 0.3))  # behind the arm: every pair is computed, none hits
        planner = MotionPlanner(model, obstacles=(box,))
        start = np.array(list(model.ready_pose) + ([model.gripper_limits.upper] if model.has_gripper else []))
        s = MotionSettings(spdRatioJoint=50, spdRatioCartesian=100, maxSpeedJoint=model.rated_speed,
                           maxSpeedCartesian=CartesianSpeed(0.25, 1.0), accelTimeJoint=model.min_accel_time,
                           accelTimeCartesian=model.min_accel_time_cartesian, softLimitJoint=model.hard_limits,
                           softLimitCartesian=(LimitValue(2.0, -2.0),) * 3, baseOffset=np.eye(4)[:3],
                           controlPointOffset=np.eye(4)[:3], home=model.ready_pose)
        plan = lambda op, args, q: planner.plan(PlanRequest.decode(MotionRequest(op, args, s)), q)  # noqa: E731
        T = planner.kin.fk(np.array(model.ready_pose))
        at = lambda d: car(T.translation + np.array(d), T.rotation)  # noqa: E731
        q_a = plan(OP.moveLinearCartesianAbs, {"carPoint": at((0.0, -0.25, 0.0))}, start).end
        motions = (("PTP", plan(OP.movePTPJointRel, {"jointPoints": (1.0,) + (0.0,) * (model.axis_num - 1)},
                                start)),
                   ("LIN 0.5 m", plan(OP.moveLinearCartesianAbs, {"carPoint": at((0.0, 0.25, 0.0))}, q_a)),
                   ("CIRC", plan(OP.moveCircularCartesianAbs, {"carPointR": at((0.15, -0.1, 0.0)),
                                                               "carPointT": at((0.0, 0.05, 0.0))}, q_a)))
        costs = []
        for what, motion in motions:
            wall = []
            for _ in range(9):
                t = time.perf_counter()
                assert planner.collisions.check(motion.q) is None
                wall.append(time.perf_counter() - t)
            costs.append(f"{what} ({len(motion.q)} samples) {1e3 * float(np.median(wall)):.2f} ms")
        out.append(f"collision check, {name}: " + ", ".join(costs))
    return out


def pause_latency(b: Bench, n: int) -> str:
    """From the pause request (and its reply) to the first followed command slower than the one before."""
    from_request, from_reply = [], []
    for k in range(n):
        sign = 1 if k % 2 == 0 else -1
        m, _ = b.plan(OP.movePTPJointRel, {"jointPoints": [sign * 0.6] + [0.0] * 6}, spdRatioJoint=30)
        time.sleep(0.4)  # at its cruising speed
        b.drain()
        t_request = time.time()
        b.control(ControlAction.PAUSE)
        t_reply = time.time()
        time.sleep(0.4)
        b.control(ControlAction.RESUME)
        b.wait_done(m)
        tc, cmd, _, _, _ = b.drain()
        v = np.abs(np.diff(cmd[:, 0]))
        slower = np.flatnonzero((tc[1:] > t_request - DT) & (np.r_[np.inf, v[:-1]] - v > 1e-12))
        if len(slower):
            t = tc[1 + slower[0]]
            from_request.append(t - t_request)
            from_reply.append(t - t_reply)
    req_ms, rep_ms = np.array(from_request) * 1e3, np.array(from_reply) * 1e3
    if not len(req_ms):
        return "pause latency: no measurement"
    return (f"pause request -> first slower command followed by the servo: median {np.median(req_ms):.1f} ms, "
            f"max {req_ms.max():.1f} ms; reply -> it: median {np.median(rep_ms):.1f} ms, max {rep_ms.max():.1f} ms "
            f"over {len(req_ms)} pauses")


def ptp_optimality(b: Bench) -> str:
    rng = np.random.default_rng(1)
    ratios = []
    q = np.array(MODEL.ready_pose)
    for _ in range(5):
        dq = rng.uniform(-0.4, 0.4, 7)
        m, reply = b.plan(OP.movePTPJointRel, {"jointPoints": list(dq)}, spdRatioJoint=100)
        b.wait_done(m)
        vmax = np.array(MODEL.rated_speed)
        lim = [ProfileLimits.from_accel_time(v, MODEL.min_accel_time) for v in vmax]
        inp = ruckig.InputParameter(7)
        inp.current_position, inp.target_position = list(q), list(q + dq)
        inp.max_velocity = [x.velocity for x in lim]
        inp.max_acceleration = [x.acceleration for x in lim]
        inp.max_jerk = [x.jerk for x in lim]
        traj = ruckig.Trajectory(7)
        ruckig.Ruckig(7).calculate(inp, traj)
        ratios.append(reply.duration / traj.duration)
        q = q + dq
    return (f"PTP duration / time-optimal bound (Ruckig, same per-axis v, a, j; 5 random moves at 100 %): "
            + ", ".join(f"{r:.3f}" for r in ratios))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n", type=int, default=10, help="repetitions of the latency measurements")
    ap.add_argument("--rounds", type=int, default=5, help="repetitions of the LIN and the CIRC")
    ap.add_argument("--early-start-ms", type=float, default=None,
                    help="the planner's early start (default: its own; 0: acceptance first)")
    args = ap.parse_args()
    for line in collision_cost():
        print(line)
    sp, pp = free_port(), free_port()
    servo = spawn(Service.SERVO, sp, "--publish-targets")
    extra = ["--connect", f"tcp/127.0.0.1:{sp}"]
    early = ["--early-start-ms", str(args.early_start_ms)] if args.early_start_ms is not None else []
    planner = spawn(Service.PLANNER, pp, *extra, *early)
    try:
        time.sleep(1.0)
        with zenoh.open(zenoh_config("peer", connect=[f"tcp/127.0.0.1:{sp}", f"tcp/127.0.0.1:{pp}"])) as s:
            keys = ArmKeys()
            deadline = time.time() + 60
            while not (list(s.liveliness().get(keys.alive(Service.PLANNER), timeout=1.0))
                       and list(s.liveliness().get(keys.alive(Service.SERVO), timeout=1.0))):
                if time.time() > deadline:
                    raise TimeoutError("services not up")
            b = Bench(s)
            b.servo(OP.servoON)
            time.sleep(0.2)
            m, _ = b.plan(OP.goHome)
            b.wait_done(m)
            print(reply_to_motion(b, args.n))
            for line in cartesian(b, args.rounds):
                print(line)
            print(pause_latency(b, args.n))
            print(ptp_optimality(b))
    finally:
        for p in (planner, servo):
            os.killpg(p.pid, signal.SIGTERM)
        for p in (planner, servo):
            out, _ = p.communicate(timeout=10)
            if p is planner:
                for line in out.splitlines():
                    if "planned in" in line and ("Linear" in line or "Circular" in line) or "WARNING" in line:
                        print("planner log:", line.split(": ", 1)[-1])
                # The head's share of request -> first command; the rest is the hops and the servo's cycle.
                heads = np.array([[float(g) for g in m.groups()] for m in re.finditer(
                    r"head planned in ([0-9.]+) ms \(([0-9.]+) before it began, ([0-9.]+) planning it, "
                    r"([0-9.]+) handing it over\)", out)])
                if len(heads):
                    med = np.median(heads, axis=0)
                    print(f"planner log: head ready {med[0]:.1f} ms after the planner took the request (median of "
                          f"{len(heads)}, max {heads[:, 0].max():.1f}): {med[1]:.1f} before it began (the whole "
                          f"sent to the planning process), {med[2]:.1f} planning it, {med[3]:.1f} handing it over")
            else:
                held = [line for line in out.splitlines() if "held at its last sample" in line]
                print(f"servo log: an early start's head held at its last sample {len(held)} times")
                for line in out.splitlines():
                    if "WARNING" in line and "late by more than one period" not in line:
                        print("servo log:", line.split(": ", 1)[-1])
    return 0


if __name__ == "__main__":
    sys.exit(main())
