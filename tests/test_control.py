"""The servo's control law without I/O (``services/servo/control.py``): every safety rule,
deterministic and fast. The live-process tests (``test_servo.py``, ``test_alarms_motion.py``)
check the same rules end to end."""

from __future__ import annotations

import numpy as np
import pytest

from jara_arm.robots import robot
from jara_arm.schema.codes import AlarmCode, AlarmType
from jara_arm.schema.types import LimitValue
from jara_arm.services.servo.control import (
    BRAKE_JERK_TIME,
    LIMIT_STOP_ACCEL,
    OVERSPEED_MARGIN,
    RAN_DRY,
    RELAX_TIME,
    RESUME_TOLERANCE,
    STOPPED,
    ControlLaw,
    Refusal,
)

IIWA = robot("iiwa")
PANDA = robot("panda")
DT = IIWA.cmd_cycle
VMAX = np.array(IIWA.rated_speed)
AMAX = VMAX / IIWA.min_accel_time


def law_at_ready(model=IIWA) -> ControlLaw:
    q0 = list(model.ready_pose) + ([model.gripper_limits.upper] if model.has_gripper else [])
    return ControlLaw(model, np.array(q0))


def ramp(law: ControlLaw, axis: int, speed: float, cycles: int) -> np.ndarray:
    """Follow ``cycles`` commands that bring ``axis`` from rest to ``speed`` [rad/s] and keep it there."""
    q = law.q.copy()
    accel = AMAX[axis] * 0.5
    v = 0.0
    for _ in range(cycles):
        v = min(speed, v + accel * DT)
        q = q.copy()
        q[axis] += v * DT
        assert law.follow(q) is None
    return q


def run_stop(law: ControlLaw) -> np.ndarray:
    """Advance until the stop in progress ends; the targets, one per cycle."""
    targets = [law.q.copy()]
    for _ in range(10_000):
        outcome = law.advance(False)
        targets.append(law.q.copy())
        if outcome == STOPPED:
            return np.array(targets)
    raise AssertionError("the stop did not end")


def test_a_smooth_stream_is_followed():
    law = law_at_ready()
    q = ramp(law, 0, 0.5, 400)
    assert np.array_equal(law.q, q)
    assert law.qd[0] == pytest.approx(0.5) and law.moving


def test_a_jump_is_refused_as_overspeed_and_not_applied():
    law = law_at_ready()
    before = law.q.copy()
    cmd = before.copy()
    cmd[3] += VMAX[3] * DT * OVERSPEED_MARGIN * 1.01
    refusal = law.follow(cmd)
    assert isinstance(refusal, Refusal)
    assert (refusal.code, refusal.kind) == (AlarmCode.OVERSPEED, AlarmType.FAULT)
    assert "J4" in refusal.description
    assert np.array_equal(law.q, before) and not law.moving
    cmd[3] = before[3] + VMAX[3] * DT * OVERSPEED_MARGIN * 0.99  # just below: followed
    assert law.follow(cmd) is None


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_a_non_finite_command_is_refused(bad):
    law = law_at_ready()
    cmd = law.q.copy()
    cmd[2] = bad
    refusal = law.follow(cmd)
    assert refusal is not None and (refusal.code, refusal.kind) == (AlarmCode.OVERSPEED, AlarmType.FAULT)
    assert np.all(np.isfinite(law.q))


def test_a_command_outside_the_soft_limits_is_refused_as_a_warning():
    law = law_at_ready()
    law.soft_limits = tuple(LimitValue(q + 0.1, q - 0.1) for q in IIWA.ready_pose)
    cmd = law.q.copy()
    cmd[5] += 0.1 + 1e-6
    refusal = law.follow(cmd)
    assert refusal is not None and (refusal.code, refusal.kind) == (AlarmCode.SOFT_LIMIT_JOINT, AlarmType.WARNING)
    assert "J6" in refusal.description and np.array_equal(law.q, np.array(IIWA.ready_pose))


def test_a_command_whose_stop_would_pass_a_soft_limit_is_refused():
    law = law_at_ready()
    limit = IIWA.ready_pose[0] + 0.2
    law.soft_limits = (LimitValue(limit, -2.9),) + IIWA.hard_limits[1:]
    speed = 0.8 * VMAX[0]
    stop_distance = speed**2 / (2 * AMAX[0] * LIMIT_STOP_ACCEL)
    refused = None
    for _ in range(2000):
        cmd = law.q.copy()
        cmd[0] += min(speed, law.qd[0] + 0.5 * AMAX[0] * DT) * DT
        refused = law.follow(cmd)
        if refused is not None:
            break
    assert refused is not None and refused.code == AlarmCode.SOFT_LIMIT_JOINT and "could not stop" in refused.description
    assert law.q[0] < limit - stop_distance * 0.5  # refused well before the limit, not at it
    law.brake(before_limit=True)
    assert run_stop(law)[:, 0].max() <= limit + 1e-9  # the stop from the last applied command ends inside


def test_every_stop_from_an_applied_command_ends_inside_the_soft_limits():
    """Seeded property: random streams towards random limits; whatever was applied, the
    shortest stop from it stays inside."""
    rng = np.random.default_rng(20261123)
    for _ in range(30):
        law = law_at_ready()
        axis = int(rng.integers(0, 7))
        sign = rng.choice([-1.0, 1.0])
        margin = rng.uniform(0.05, 0.5)
        lims = list(IIWA.hard_limits)
        q0 = IIWA.ready_pose[axis]
        lims[axis] = LimitValue(q0 + margin, -2.9) if sign > 0 else LimitValue(2.9, q0 - margin)
        law.soft_limits = tuple(lims)
        speed = rng.uniform(0.2, 1.0) * VMAX[axis]
        for _ in range(3000):
            cmd = law.q.copy()
            cmd[axis] += sign * min(speed, abs(law.qd[axis]) + 0.9 * AMAX[axis] * DT) * DT
            if law.follow(cmd) is not None:
                break
        law.brake(before_limit=True)
        path = run_stop(law)[:, axis]
        assert lims[axis].lower - 1e-9 <= path.min() and path.max() <= lims[axis].upper + 1e-9


def test_the_gripper_axis_is_clamped_not_refused():
    law = law_at_ready(PANDA)
    cmd = law.q.copy()
    cmd[7] = PANDA.gripper_limits.upper + 1e-5  # a hair beyond open
    assert law.follow(cmd) is None
    assert law.q[7] == PANDA.gripper_limits.upper


def test_a_stream_that_runs_dry_stops_smoothly_and_only_a_stream_from_rest_resumes():
    law = law_at_ready()
    ramp(law, 1, 0.6 * VMAX[1], 500)
    assert law.advance(True) == RAN_DRY  # nothing in the FIFO while moving
    assert law.braking is not None and law.interrupted
    path = run_stop(law)[:, 1]
    vel = np.diff(path) / DT
    acc = np.diff(vel) / DT
    assert np.abs(acc).max() <= AMAX[1] * (1 + 1e-6)  # within the limits: no jump
    jerk = np.diff(acc) / DT
    assert np.abs(jerk).max() <= AMAX[1] / BRAKE_JERK_TIME * 1.01
    assert abs(vel[-1]) < 1e-9 and not law.moving
    held = law.q.copy()
    stale = held.copy()
    stale[1] += 0.01  # the old stream, further on
    assert law.follow(stale) is None and law.stale == 1 and np.array_equal(law.q, held)
    fresh = held.copy()
    fresh[1] += RESUME_TOLERANCE / 2  # a stream that starts again where the arm stopped
    assert law.follow(fresh) is None and not law.interrupted and np.array_equal(law.q, fresh)
    assert not law.qd.any()  # taken up at rest: the tolerance corrects the position, it is no speed
    # ... and it goes on from rest: jerk-limited, every command followed
    for k in range(1, 200):
        nxt = fresh.copy()
        nxt[1] += 0.5 * AMAX[1] * (k * DT) ** 2 * min(1.0, k / 50)
        assert law.follow(nxt) is None and np.array_equal(law.q, nxt), k
    assert not law.interrupted


def test_a_dry_stream_that_goes_on_mid_motion_through_the_held_target_is_not_taken_up():
    """A stream late past the grace goes on where it would have been: one of its commands may land within
    RESUME_TOLERANCE of where the arm stopped, but the next one moves on at the stream's speed; taking it
    would step the velocity from zero in one cycle (375 rad/s² seen on the iiwa's J1, beside busy loops)."""
    law = law_at_ready()
    ramp(law, 1, 0.2 * VMAX[1], 500)
    assert law.advance(True) == RAN_DRY
    run_stop(law)
    held = law.q.copy()
    speed = 0.2 * VMAX[1]  # the stream goes on at its speed, through the held target
    for k in range(-5, 40):
        cmd = held.copy()
        cmd[1] += k * speed * DT + RESUME_TOLERANCE / 4
        before = law.q.copy()
        assert law.follow(cmd) is None
        assert np.abs(law.q - before).max() <= RESUME_TOLERANCE, (k, law.q - before)  # never a step at speed
    assert law.interrupted and law.stale >= 40


def test_a_disabled_law_does_not_take_from_the_fifo():
    law = law_at_ready()
    law.fifo.append(law.q + 1e-4)
    assert law.advance(False) is None
    assert len(law.fifo) == 1 and law.consumed == 0
    assert law.advance(True) is None
    assert len(law.fifo) == 0 and law.consumed == 1


def test_a_refused_command_from_the_fifo_comes_back_to_the_caller():
    law = law_at_ready()
    jump = law.q.copy()
    jump[0] += 1.0
    law.fifo.append(jump)
    outcome = law.advance(True)
    assert isinstance(outcome, Refusal) and outcome.code == AlarmCode.OVERSPEED


def test_a_blocked_arm_is_let_go_in_relax_time_and_a_following_one_is_not():
    law = law_at_ready()
    assert law.let_go(law.q.copy()) is None and law.braking is None
    measured = law.q.copy()
    measured[2] -= 0.05  # the arm stopped short of its target: blocked
    assert law.let_go(measured) == (2, pytest.approx(0.05))
    path = run_stop(law)
    assert len(path) - 1 == pytest.approx(RELAX_TIME / DT, abs=2)
    assert law.q[2] == pytest.approx(measured[2])


def test_hold_forgets_the_stream():
    law = law_at_ready()
    ramp(law, 0, 0.3, 100)
    law.fifo.append(law.q.copy())
    law.interrupted = True
    here = law.q + 0.001
    law.hold(here)
    assert np.array_equal(law.q, here) and not law.fifo and not law.moving and not law.interrupted
    assert not law.qd.any() and not law.qdd.any()


# -- the screen: what the interpolator's targets may skip ---------------------------------------
def _quintic(a: np.ndarray, b: np.ndarray, cycles: int) -> np.ndarray:
    t = np.linspace(0.0, 1.0, cycles + 1)
    s = 10 * t**3 - 15 * t**4 + 6 * t**5
    return a + s[:, None] * (b - a)


@pytest.mark.parametrize("model", [IIWA, PANDA], ids=["iiwa", "panda"])
def test_screened_targets_pass_every_check(model):
    """Seeded property: a law that takes the targets ``screen`` passed without checks applies exactly
    what a law checking every target applies, and every target the full checks refuse was left to them
    (random paths near, onto and past the soft limits, too fast ones, random overrides and pauses)."""
    from jara_arm.schema.motion import MotionAction
    from jara_arm.services.servo.interpolator import Interpolator, prepare

    rng = np.random.default_rng(20261126)
    dof, n = model.dof, model.axis_num
    q0 = np.array(list(model.ready_pose) + ([model.gripper_limits.upper] if model.has_gripper else []))
    hard = model.hard_limits
    screened_cycles = refused = 0
    for episode in range(25):
        fast, full = ControlLaw(model, q0), ControlLaw(model, q0)
        # Soft limits a little inside the hard ones, some of them around the path.
        limits = tuple(LimitValue(upper=lim.upper - rng.uniform(0, 0.3) * (lim.upper - lim.lower) * 0.5,
                                  lower=lim.lower + rng.uniform(0, 0.3) * (lim.upper - lim.lower) * 0.5)
                       for lim in hard)
        fast.soft_limits = full.soft_limits = limits
        lower = np.array([lim.lower for lim in limits])
        upper = np.array([lim.upper for lim in limits])
        start = q0.copy()
        start[:n] = np.clip(q0[:n], lower + 0.01, upper - 0.01)
        fast.hold(start)
        full.hold(start)
        goal = start.copy()
        # Goals inside, onto and past the limits; durations from comfortable to a jump.
        goal[:n] = rng.uniform(lower - 0.1 * (upper - lower), upper + 0.1 * (upper - lower))
        if model.has_gripper:
            goal[n] = rng.uniform(model.gripper_limits.lower - 0.01, model.gripper_limits.upper + 0.01)
        span = float(np.max(np.abs(goal - start)[:n] / np.array(model.rated_speed)))
        cycles = max(3, int(span / DT * rng.choice([0.3, 1.0, 1.5, 3.0])))
        rows = _quintic(start, goal, cycles)
        if rng.random() < 0.3:  # a jump in the middle: the segments on both sides of it
            j = int(rng.integers(2, min(len(rows) - 1, 300)))
            rows[j:, :n] += rng.choice([-1.0, 1.0]) * 1.5 * np.array(model.rated_speed) * DT
        b = prepare(1, rows, True, DT, fast.max_accel)
        b.screen(*fast.screen(b.q))
        it = Interpolator(dof, DT)
        assert it.submit(b, it.epoch, 0, -1, fast.q, True)[0] is None
        k = 0
        while it.active and k < 1500:  # the first 1.5 s of each: where limits and jumps show
            if rng.random() < 0.01:
                it.control(MotionAction.OVERRIDE, float(rng.uniform(0.2, 1.0)))
            elif rng.random() < 0.003:
                it.control(MotionAction.PAUSE if not it.paused else MotionAction.RESUME, 1.0)
            elif it.holding:
                it.control(MotionAction.RESUME, 1.0)
                continue
            target = it.next()
            k += 1
            screened = it.screened
            fast.fifo.append(target.copy())
            full.fifo.append(target.copy())
            a, c = fast.advance(True, screened), full.advance(True)
            if screened is not None:
                screened_cycles += 1
                assert a is None and c is None, (episode, k, c)
                np.testing.assert_allclose(fast.q, full.q, atol=0, rtol=0)
                np.testing.assert_allclose(fast.qd, full.qd, rtol=1e-12, atol=1e-12)
            if isinstance(c, Refusal):
                refused += 1
                break
            assert a is None or isinstance(a, Refusal)
            np.testing.assert_array_equal(fast.q, full.q)
    # The property is not empty: both sides happened.
    assert screened_cycles > 5_000 and refused >= 5, (screened_cycles, refused)
