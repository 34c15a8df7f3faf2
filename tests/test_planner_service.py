"""The planner service as a real process, handing its motions to a real servo process.

A servo and a planner per robot, started once per test class (``planner_rig.py``); the test
session is a peer of both. Motions go to ``Planner/plan`` as the command service would send
them (``MotionRequest`` with a settings snapshot); the commands the servo followed
(``Servo/posTarget``) and its feedback are recorded and checked with forward kinematics.
"""

from __future__ import annotations

import os
import signal
import time
from collections.abc import Iterator

import numpy as np
import pytest

from jara_arm.schema import codec
from jara_arm.schema import wire_types as w
from jara_arm.schema.codes import ReturnCode, StateBit
from jara_arm.schema.operations import OP
from jara_arm.schema.planner import (
    MOTION_REQUEST,
    ControlAction,
    MotionRequest,
)
from jara_arm.schema.types import CarPosWithElbow, LimitValue

from .planner_rig import Answer, PlannerRig, start_rig
from .support import busy_loops, car, pose, rot_z, segment_distance, wait_until

pytestmark = pytest.mark.timeout(120)
DT = 1e-3
EXECUTED_TOL = 0.5e-3  # [m] executed path (FK of feedback) vs the ideal path
PLANNED_TOL = 1e-6  # [m] commanded path (FK of posCmd) vs the ideal path
HOLD_WINDOW = 0.2  # [s] of the servo's own time in which a paused arm must not move (an observation window)
CAPACITY = 4  # [motions] the iiwa rig's planner queue (planner --queue-capacity)


def cycles(duration: float) -> int:
    """Commands of a motion of ``duration`` [s]: one per cycle, its start excluded."""
    return int(np.ceil(duration / DT - 1e-9))


@pytest.fixture(scope="class")
def iiwa_rig() -> Iterator[PlannerRig]:
    # The queue's capacity is the planner's: 4 here, the most any test of the class queues.
    yield from start_rig("iiwa", planner_args=("--queue-capacity", str(CAPACITY)))


@pytest.fixture
def rig(iiwa_rig: PlannerRig) -> PlannerRig:
    iiwa_rig.reset()
    return iiwa_rig


def _refused(rig: PlannerRig, reply: Answer, *words: str) -> None:
    assert reply.id == ReturnCode.VALUE_ERR, reply
    assert all(word in reply.comment for word in words), reply.comment


@pytest.fixture(scope="class")
def panda_rig() -> Iterator[PlannerRig]:
    yield from start_rig("panda")


class TestIiwa:
    """iiwa (7 axes, no gripper): one servo and one planner for the class."""

    # ----------------------------------------------------------------------------- PTP
    def test_ptp_joint_axes_start_and_stop_together_on_the_line(self, rig: PlannerRig):
        q0 = rig.target()
        target = np.array(rig.model.ready_pose) + np.array([0.4, -0.2, 0.3, 0.3, -0.2, 0.2, 0.5])
        reply = rig.plan_ok(OP.movePTPJointAbs, {"jointPoints": list(target)})
        assert np.allclose(reply.endJoints, target, atol=1e-12)
        rig.wait_idle()
        rec = rig.drain()
        cmd = rec.cmd
        assert len(cmd) == cycles(reply.duration)  # one command per cycle, start excluded
        assert np.array_equal(cmd[-1], target)
        # Every command on the joint-space line from the start to the target.
        delta = target - q0
        u = (cmd - q0) @ delta / (delta @ delta)
        assert np.abs(cmd - (q0 + u[:, None] * delta)).max() < 1e-9
        assert np.all(np.diff(u) >= -1e-12)
        # All axes start and stop within one cycle of each other.
        moving = np.abs(np.diff(np.vstack([q0, cmd]), axis=0)) > 1e-12
        starts = [int(np.argmax(moving[:, i])) for i in range(7)]
        stops = [len(moving) - 1 - int(np.argmax(moving[::-1, i])) for i in range(7)]
        assert max(starts) - min(starts) <= 1 and max(stops) - min(stops) <= 1, (starts, stops)
        # Executed: the feedback stays near the line and ends on the target.
        fb = rec.fb
        uf = np.clip((fb - q0) @ delta / (delta @ delta), 0, 1)
        assert np.abs(fb - (q0 + uf[:, None] * delta)).max() < 5e-3
        assert np.abs(rig.joints() - target).max() < 2e-3

    def test_duration_law_d_over_v_plus_accel_time(self, rig: PlannerRig):
        d, ratio, acl = 0.6, 40, 0.3  # [rad], [%], [s]
        v = ratio / 100 * rig.model.rated_speed[0]
        assert d >= v * acl  # long enough to cruise
        t0 = time.time()
        reply = rig.plan_ok(OP.movePTPJointRel, {"jointPoints": [d, 0, 0, 0, 0, 0, 0]}, spdRatioJoint=ratio,
                       accelTimeJoint=acl)
        assert reply.duration == pytest.approx(d / v + acl, rel=1e-9, abs=1e-9)
        rig.wait_idle()
        rec = rig.drain()
        assert len(rec.cmd) == cycles(reply.duration)
        speed = np.diff(rec.cmd[:, 0]) / DT
        assert speed.max() == pytest.approx(v, rel=1e-6)  # never above ratio x max speed
        # rest -> cruise in exactly aclTime: the speed is reached at t = acl, not before
        assert int(np.argmax(speed >= v * (1 - 1e-6))) * DT == pytest.approx(acl, abs=2e-3)
        # Executed: the feedback moves as long as the commands do (same threshold on both).

        def moving_span(x: np.ndarray, t: np.ndarray) -> tuple[float, float]:
            """Shortest and longest time [s] from leaving ``x[0]`` to arriving at ``x[-1]`` (beyond 1e-4)
            that the samples allow: a sample lost in transit (newest value wins) leaves a gap, and the
            crossing may lie anywhere in the gap on either side."""
            first = int(np.flatnonzero(np.abs(x - x[0]) > 1e-4)[0])
            last = int(np.flatnonzero(np.abs(x - x[-1]) > 1e-4)[-1])
            return t[last] - t[first], t[min(last + 1, len(t) - 1)] - t[max(first - 1, 0)]

        # The feedback by its own time stamps, the commands one per cycle.
        cmd_t = np.arange(len(rec.cmd)) * DT
        commanded = moving_span(rec.cmd[:, 0], cmd_t)[0]
        shortest, longest = moving_span(rec.fb[:, 0], rec.fb_tm)
        assert shortest - 0.01 <= commanded <= longest + 0.01, (commanded, shortest, longest, np.diff(rec.fb_tm).max())
        assert time.time() - t0 < reply.duration + 2.0

    def test_relative_moves_compose_through_the_queue(self, rig: PlannerRig):
        q0 = rig.target()
        dq = np.array([0.1, -0.05, 0.1, 0.1, 0.0, -0.1, 0.2])
        r1 = rig.plan_ok(OP.movePTPJointRel, {"jointPoints": list(dq)}, spdRatioJoint=30)
        r2 = rig.plan_ok(OP.movePTPJointRel, {"jointPoints": list(dq)}, spdRatioJoint=30)
        assert np.allclose(r1.endJoints, q0 + dq, atol=1e-4)  # from where the servo holds the arm
        assert np.allclose(r2.endJoints, np.array(r1.endJoints) + dq, atol=1e-12)  # from the end of r1
        p0 = rig.fk(r2.endJoints)[:3, 3]
        step = pose([0.0, 0.04, -0.03])
        r3 = rig.plan_ok(OP.moveLinearCartesianRel, {"carPoint": car(step)})
        r4 = rig.plan_ok(OP.moveLinearCartesianRel, {"carPoint": car(step)})
        p3, p4 = rig.fk(r3.endJoints)[:3, 3], rig.fk(r4.endJoints)[:3, 3]
        assert np.linalg.norm(p3 - (p0 + step[:3, 3])) < PLANNED_TOL
        assert np.linalg.norm(p4 - (p0 + 2 * step[:3, 3])) < PLANNED_TOL
        done = rig.wait_idle()
        assert done.lastDone == r4.motion
        rec = rig.drain()
        # Back to back: no cycle without a command between the motions (each command one cycle).
        assert len(rec.cmd) == sum(cycles(r.duration) for r in (r1, r2, r3, r4))
        assert np.linalg.norm(rig.fk(rig.joints())[:3, 3] - p4) < EXECUTED_TOL

    # ----------------------------------------------------------------------------- LIN / CIRC
    def test_lin_stays_on_the_line(self, rig: PlannerRig):
        T0 = rig.fk(rig.joints())
        T1 = pose(T0[:3, 3] + [-0.05, 0.2, -0.1], rot_z(0.3) @ T0[:3, :3])
        reply = rig.plan_ok(OP.moveLinearCartesianAbs, {"carPoint": car(T1)})
        rig.wait_idle()
        rec = rig.drain()
        a, b = T0[:3, 3], T1[:3, 3]
        planned = segment_distance(rig.points(rec.cmd), a, b)
        executed = segment_distance(rig.points(rec.fb), a, b)
        assert planned.max() < PLANNED_TOL, planned.max()
        assert executed.max() < EXECUTED_TOL, executed.max()
        end = rig.fk(reply.endJoints)
        assert np.linalg.norm(end[:3, 3] - b) < PLANNED_TOL
        assert np.linalg.norm(end[:3, :3] - T1[:3, :3]) < 1e-5
        # 0.25 m/s at 100 %: the translation (0.229 m) is the slower part
        length = np.linalg.norm(b - a)
        assert reply.duration == pytest.approx(length / 0.25 + rig.model.min_accel_time_cartesian, rel=1e-6)

    def test_circ_passes_the_via_point_on_the_circle(self, rig: PlannerRig):
        T0 = rig.fk(rig.joints())
        p0 = T0[:3, 3]
        via, target = p0 + [0.0, 0.1, 0.1], p0 + [0.0, 0.2, 0.0]  # half circle, radius 0.1 m, in y-z
        center, radius = p0 + [0.0, 0.1, 0.0], 0.1
        reply = rig.plan_ok(OP.moveCircularCartesianAbs, {"carPointR": car(pose(via, T0[:3, :3])),
                                                     "carPointT": car(pose(target, T0[:3, :3]))})
        assert reply.duration == pytest.approx(np.pi * radius / 0.25 + 0.2, rel=1e-6)
        rig.wait_idle()
        rec = rig.drain()

        def off_circle(p: np.ndarray) -> np.ndarray:
            radial = np.linalg.norm(p[:, 1:] - center[1:], axis=1) - radius
            return np.hypot(radial, p[:, 0] - center[0])

        planned, executed = rig.points(rec.cmd), rig.points(rec.fb)
        assert off_circle(planned).max() < PLANNED_TOL
        assert off_circle(executed).max() < EXECUTED_TOL
        assert np.linalg.norm(planned - via, axis=1).min() < 0.2e-3  # passes the via point (0.25 mm steps)
        assert np.all(planned[:, 2] >= p0[2] - PLANNED_TOL)  # the arc through the via, not the other half
        assert np.linalg.norm(planned[-1] - target) < PLANNED_TOL

    # ----------------------------------------------------------------------------- pause, stop
    def test_pause_stops_on_the_line_and_resume_reaches_the_target(self, rig: PlannerRig):
        T0 = rig.fk(rig.joints())
        a = T0[:3, 3]
        b = a + [0.0, 0.25, -0.1]
        reply = rig.plan_ok(OP.moveLinearCartesianAbs, {"carPoint": car(pose(b, T0[:3, :3]))})
        rig.wait_progress("motion running", lambda p: p.running == reply.motion)
        rig.wait_along(a, b, 0.25)
        t_request = time.time()
        answer = rig.control(ControlAction.PAUSE)
        assert answer["id"] == ReturnCode.OK and "pausing" in answer["comment"], answer
        paused = rig.wait_progress("paused at rest", lambda p: p.paused and not p.streaming, 5.0)
        assert paused.queued == (reply.motion,) and paused.running == 0
        wait_until(lambda: not rig.state() & StateBit.MOVING, 5.0, what="arm at rest")
        held = rig.fk(rig.joints())[:3, 3]
        assert 0.02 < np.linalg.norm(held - a) < np.linalg.norm(b - a) - 0.02  # stopped mid-way
        assert rig.control(ControlAction.PAUSE)["comment"].startswith("OK: ignored")
        rig.servo_time.passes(HOLD_WINDOW)  # paused: nothing may move the arm in this window
        assert np.linalg.norm(rig.fk(rig.joints())[:3, 3] - held) < 1e-5  # holds
        rec = rig.drain()
        # The servo slows down in the cycle it gets the pause: the first command slower than the one
        # before it follows the request by a query's trip (the figure: bench/motion.py).
        speed = np.linalg.norm(np.diff(rig.points(rec.cmd), axis=0), axis=1)
        slower = np.flatnonzero((rec.cmd_t[1:] > t_request - DT) & (np.r_[np.inf, speed[:-1]] > speed + 1e-12))
        latency = rec.cmd_t[1 + slower[0]] - t_request
        print(f"pause latency {latency * 1e3:.1f} ms")
        assert latency < 0.1, latency  # not how fast a busy machine delivers: that nothing ran on before it

        assert rig.control(ControlAction.RESUME)["id"] == ReturnCode.OK
        done = rig.wait_idle()
        assert done.lastDone == reply.motion and not done.paused
        rec2 = rig.drain()
        cmd = np.vstack([rec.cmd, rec2.cmd])
        assert segment_distance(rig.points(cmd), a, b).max() < 1e-6
        fb = np.vstack([rec.fb, rec2.fb])
        assert segment_distance(rig.points(fb), a, b).max() < EXECUTED_TOL
        assert np.linalg.norm(rig.points(cmd[-1:])[0] - b) < PLANNED_TOL
        assert np.linalg.norm(rig.fk(rig.joints())[:3, 3] - b) < EXECUTED_TOL

    def test_speed_override_100_30_0_100_keeps_the_lin_on_its_line(self, rig: PlannerRig):
        """The override slows the running LIN, holds it at 0 % and lets it go on at 100 %: on its line all
        the while (within 0.5 mm executed), and it arrives."""
        T0 = rig.fk(rig.joints())
        a = T0[:3, 3]
        b = a + [0.0, 0.3, -0.05]
        reply = rig.plan_ok(OP.moveLinearCartesianAbs, {"carPoint": car(pose(b, T0[:3, :3]))})
        try:
            rig.wait_along(a, b, 0.15)
            assert rig.control(ControlAction.OVERRIDE, 30.0)["id"] == ReturnCode.OK
            assert rig.progress().override == 30.0 or rig.wait_progress("override 30", lambda p: p.override == 30.0)
            rig.wait_along(a, b, 0.4)
            assert rig.control(ControlAction.OVERRIDE, 0.0)["id"] == ReturnCode.OK
            seen: list[tuple[float, ...]] = []
            held = rig.wait_status("the target standing still", lambda st: seen.append(st.target) or
                                   (len(seen) > 1 and seen[-2] == st.target), 5.0)
            rig.servo_time.passes(HOLD_WINDOW)
            assert np.abs(rig.target() - np.array(held.target)).max() == 0.0  # 0 %: holds
            p = rig.progress()
            assert p.queued == (reply.motion,) and not p.paused  # held, not paused
        finally:
            assert rig.control(ControlAction.OVERRIDE, 100.0)["id"] == ReturnCode.OK
        done = rig.wait_idle()
        assert done.lastDone == reply.motion
        rec = rig.drain()
        assert segment_distance(rig.points(rec.cmd), a, b).max() < 1e-6
        assert segment_distance(rig.points(rec.fb), a, b).max() < EXECUTED_TOL
        assert np.linalg.norm(rig.fk(rig.joints())[:3, 3] - b) < EXECUTED_TOL

    def test_a_planner_stopped_for_half_a_second_mid_motion_does_not_touch_the_motion(self, rig: PlannerRig):
        """Once buffered, a motion runs to its end whatever the planner does: a SIGSTOP of 0.5 s in its
        middle changes nothing, not one cycle."""
        T0 = rig.fk(rig.joints())
        a = T0[:3, 3]
        b = a + [0.0, 0.3, 0.0]
        reply = rig.plan_ok(OP.moveLinearCartesianAbs, {"carPoint": car(pose(b, T0[:3, :3]))})
        rig.wait_along(a, b, 0.2)
        os.kill(rig.planner_proc.popen.pid, signal.SIGSTOP)
        try:
            rig.servo_time.passes(0.5)
        finally:
            os.kill(rig.planner_proc.popen.pid, signal.SIGCONT)
        done = rig.wait_idle()
        assert done.lastDone == reply.motion and done.lastDiscarded < reply.motion
        rec = rig.drain()
        assert np.allclose(np.diff(rec.cmd_t), DT, atol=1e-6), "a cycle without a command mid-motion"
        assert segment_distance(rig.points(rec.cmd), a, b).max() < 1e-6
        assert np.linalg.norm(rig.fk(rig.joints())[:3, 3] - b) < EXECUTED_TOL
        assert not any(st.alarm for st in rec.status)

    def test_a_lin_from_rest_beside_a_busy_loop_has_no_speed_dip(self, rig: PlannerRig):
        """The early start's head, beside a busy loop on every core: the measured speed rises once and falls
        once; no braking on the head and starting again."""
        with busy_loops():
            for k in range(3):
                T0 = rig.fk(rig.joints())
                a = T0[:3, 3]
                b = a + [0.0, 0.2 * (-1) ** k, 0.0]
                rig.plan_ok(OP.moveLinearCartesianAbs, {"carPoint": car(pose(b, T0[:3, :3]))})
                rig.wait_idle()
                rec = rig.drain()
                # measured speed, over 10 ms windows (the feedback's tm: a lost sample leaves a gap)
                p = rig.points(rec.fb)
                t = rec.fb_tm
                win = np.arange(t[0], t[-1], 0.01)
                idx = np.unique(np.searchsorted(t, win))  # a gap longer than a window: one window
                v = np.linalg.norm(np.diff(p[idx], axis=0), axis=1) / np.diff(t[idx])
                reached = np.maximum.accumulate(v)
                dips = [i for i in np.flatnonzero((v < 0.5 * reached) & (reached > 0.02))
                        if v[i:].max() > v[i] + 0.25 * reached[i]]
                assert not dips, f"LIN {k}: speed fell to {v[dips[0]]:.3f} of {reached[dips[0]]:.3f} m/s and rose again"

    def test_stop_discards_the_queue(self, rig: PlannerRig):
        T0 = rig.fk(rig.joints())
        a = T0[:3, 3]
        b = a + [0.0, -0.25, 0.0]
        first = rig.plan_ok(OP.moveLinearCartesianAbs, {"carPoint": car(pose(b, T0[:3, :3]))})
        more = [rig.plan_ok(OP.movePTPJointRel, {"jointPoints": [0.1] + [0.0] * 6}) for _ in range(CAPACITY - 1)]
        # The planner owns the queue and its capacity: it refuses the motion that does not fit, and says its capacity.
        full = rig.plan(OP.movePTPJointRel, {"jointPoints": [0.1] + [0.0] * 6})
        assert full.id == ReturnCode.FULL_MOTION_QUEUE_ERR and f"{CAPACITY} of {CAPACITY}" in full.comment, full
        assert rig.progress().capacity == CAPACITY
        rig.wait_progress("motion running", lambda p: p.running == first.motion)
        rig.wait_along(a, b, 0.25)
        answer = rig.control(ControlAction.STOP)
        assert answer["id"] == ReturnCode.OK and "stopping" in answer["comment"], answer
        done = rig.wait_idle()
        assert done.lastDiscarded == more[-1].motion and done.queued == ()
        assert done.lastDone < first.motion
        rested = rig.fk(rig.joints())[:3, 3]
        assert 0.02 < np.linalg.norm(rested - a) < np.linalg.norm(b - a) - 0.02  # short of the target
        rec = rig.drain()
        assert segment_distance(rig.points(rec.cmd), a, b).max() < 1e-6  # braked along the line
        assert segment_distance(rig.points(rec.fb), a, b).max() < EXECUTED_TOL
        assert rig.control(ControlAction.STOP)["comment"].startswith("OK: ignored")
        assert rig.control(ControlAction.RESUME)["comment"].startswith("OK: ignored")
        # The next motion starts where the arm rests: the end of the braking.
        again = rig.plan_ok(OP.movePTPJointRel, {"jointPoints": [0.0] * 7})
        assert np.array_equal(again.endJoints, rec.cmd[-1])

    def test_servo_off_mid_motion_aborts(self, rig: PlannerRig):
        q0 = rig.target()
        reply = rig.plan_ok(OP.movePTPJointRel, {"jointPoints": [0.5, 0, 0, 0, 0, 0, 0]}, spdRatioJoint=20)
        queued = rig.plan_ok(OP.movePTPJointRel, {"jointPoints": [-0.5, 0, 0, 0, 0, 0, 0]})
        rig.wait_progress("motion running", lambda p: p.running == reply.motion)
        rig.wait_status("the arm under way (J1 0.05 rad on)", lambda st: st.target[0] - q0[0] > 0.05)
        assert rig.client.servo(OP.servoOFF).id == ReturnCode.OK
        p = rig.wait_progress("aborted", lambda p: not p.queued and not p.streaming, 2.0)
        assert p.lastDiscarded == queued.motion
        # A client's servoOFF is not an alarm: the servo says it in its log.
        rig.servo_proc.wait_for_line(f"servo off: motions [{reply.motion}, {queued.motion}] discarded before their end")
        refused = rig.plan(OP.movePTPJointRel, {"jointPoints": [0.1] + [0.0] * 6})
        assert refused.id == ReturnCode.NOT_SV_ON_ERR and "off" in refused.comment

    # ----------------------------------------------------------------------------- refusals
    def test_refusals_say_why_and_move_nothing(self, rig: PlannerRig):
        before = rig.progress()
        T0 = rig.fk(rig.joints())
        p0 = T0[:3, 3]
        limits = list(rig.model.hard_limits)
        limits[1] = LimitValue(upper=0.6, lower=-0.6)
        _refused(rig, rig.plan(OP.movePTPJointRel, {"jointPoints": [0, 0.3, 0, 0, 0, 0, 0]},
                               softLimitJoint=tuple(limits)), "J2", "soft limit")
        _refused(rig, rig.plan(OP.movePTPJointAbs, {"jointPoints": [0.0] * 6}), "jointPoints", "7")
        _refused(rig, rig.plan(OP.movePTPCartesianAbs, {"carPoint": car(pose(p0 + [1.2, 0, 0], T0[:3, :3]))}),
                 "unreachable")
        too_high = car(pose(p0 + [0.0, 0.0, 0.8], T0[:3, :3]))
        _refused(rig, rig.plan(OP.moveLinearCartesianAbs, {"carPoint": too_high}),
                 "unreachable")
        box = (LimitValue(1.0, -1.0), LimitValue(0.1, -0.1), LimitValue(1.5, 0.0))
        _refused(rig, rig.plan(OP.moveLinearCartesianRel, {"carPoint": car(pose([0.0, 0.2, 0.0]))},
                               softLimitCartesian=box), "Cartesian soft limits", "y =")
        _refused(rig, rig.plan(OP.moveCircularCartesianRel, {"carPointR": car(pose([0.0, 0.05, 0.0])),
                                                             "carPointT": car(pose([0.0, 0.1, 0.0]))}),
                 "collinear")
        _refused(rig, rig.plan(OP.moveCircularCartesianRel, {"carPointR": car(pose([0.0, 0.0, 0.0])),
                                                             "carPointT": car(pose([0.0, 0.1, 0.0]))}),
                 "coincide")
        flagged = w.CAR_POS_WITH_ELBOW.encode(CarPosWithElbow(pose([0.0, 0.01, 0.0])[:3], 0.0, 1))
        _refused(rig, rig.plan(OP.moveLinearCartesianRel, {"carPoint": flagged}), "structFlag")
        ng = rig.plan(OP.closeGripper)
        assert ng.id == ReturnCode.NG and "no gripper" in ng.comment
        # Every refusal was answered; a progress message published after them is relayed after them,
        # and whatever the servo followed before has arrived by then.
        answered = time.time()
        rig.wait_progress("a progress message after the refusals", lambda p: p.tm.to_seconds() > answered, 2.0)
        rec = rig.drain()
        assert len(rec.cmd) == 0  # nothing was sent
        after = rig.progress()
        assert after.queued == () and after.lastDone == before.lastDone

    def test_bad_requests_and_control_actions(self, rig: PlannerRig):
        for payload in (b"\xc1", codec.dumps({"motion": 1})):
            replies = list(rig.session.get(rig.keys.planner_plan, payload=payload, timeout=10.0))
            reply = codec.loads(replies[0].ok.payload.to_bytes())
            assert reply["id"] == ReturnCode.VALUE_ERR and reply["comment"], reply
        unknown = MotionRequest(OP.getState, {}, rig.settings())
        replies = list(rig.session.get(rig.keys.planner_plan, timeout=10.0,
                                       payload=codec.encode_message(MOTION_REQUEST, unknown)))
        assert codec.loads(replies[0].ok.payload.to_bytes())["id"] == ReturnCode.NOT_IMPLEMENTED
        replies = list(rig.session.get(rig.keys.planner_control, payload=codec.dumps({"action": "jump"}),
                                       timeout=10.0))
        reply = codec.loads(replies[0].ok.payload.to_bytes())
        assert reply["id"] == ReturnCode.VALUE_ERR and "pause" in reply["comment"]
        assert rig.control(ControlAction.PAUSE)["comment"] == "OK: ignored, not moving"
        as_json = rig.client.raw(rig.keys.planner_control, b'{"action": "resume"}', json=True)
        assert (as_json["id"], as_json["comment"]) == (0, "OK: ignored, not paused")
        assert as_json["progress"]["paused"] is False and as_json["progress"]["queued"] == []
        assert rig.control(ControlAction.ABORT)["id"] == ReturnCode.OK


class TestPanda:
    """Panda (7 axes and a gripper axis), after the iiwa processes have stopped."""

    def test_panda_gripper_open_close(self, panda_rig: PlannerRig):
        rig = panda_rig
        rig.reset()
        lim = rig.model.gripper_limits
        arm = rig.target()[:7]
        close = rig.plan_ok(OP.closeGripper)
        assert close.endJoints[7] == lim.lower and np.allclose(close.endJoints[:7], arm, atol=1e-6)
        half = rig.plan_ok(OP.moveGripper, {"angleRatio": 50})
        assert half.endJoints[7] == pytest.approx((lim.lower + lim.upper) / 2)
        assert rig.plan(OP.moveGripper, {"angleRatio": 101}).id == ReturnCode.VALUE_ERR
        rig.wait_idle()
        assert rig.joints()[7] == pytest.approx((lim.lower + lim.upper) / 2, abs=1e-3)
        rec = rig.drain()
        assert np.abs(rec.cmd[:, :7] - close.endJoints[:7]).max() == 0.0  # the arm held still
        assert np.abs(np.diff(rec.cmd[:, 7])).max() <= rig.model.gripper_speed * DT * (1 + 1e-9)
        opened = rig.plan_ok(OP.openGripper)
        assert opened.endJoints[7] == lim.upper
        # An arm move keeps the gripper where it is.
        lin = rig.plan_ok(OP.moveLinearCartesianRel, {"carPoint": car(pose([0.05, 0.0, 0.0]))})
        assert lin.endJoints[7] == lim.upper
        rig.wait_idle()
        assert rig.joints()[7] == pytest.approx(lim.upper, abs=1e-3)
