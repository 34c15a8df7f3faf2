"""The jerk-limited speed profile along a path (Ruckig), and the PTP / LIN / CIRC timing rules."""

from __future__ import annotations

import math

import numpy as np
import pinocchio
import pytest

from jara_arm.schema.errors import JaraArmError
from jara_arm.services.planner.paths import CartesianArc, CartesianLine
from jara_arm.services.planner.profile import (
    PathProfile,
    ProfileError,
    ProfileLimits,
    ProfileSamples,
    cartesian_path_speed,
    move_profile,
    plan_cartesian,
    plan_joint_ptp,
    resume_profile,
    stop_profile,
)

from .support import pose

DT = 1e-3  # [s] servo period
REL = 1e-9  # relative tolerance on limits


def assert_within_limits(samples: ProfileSamples, limits: ProfileLimits) -> None:
    """Forward only, never above v, a, j (jerk from finite differences of the piecewise-linear sdd)."""
    assert np.all(np.diff(samples.s) >= 0.0)
    assert np.all(samples.sd >= 0.0)
    assert np.max(samples.sd) <= limits.velocity * (1 + REL)
    assert np.max(np.abs(samples.sdd)) <= limits.acceleration * (1 + REL)
    # the last interval may end early (at the duration): skip it for the jerk estimate
    jerk = np.abs(np.diff(samples.sdd[:-1])) / samples.dt
    assert np.all(jerk <= limits.jerk * (1 + 1e-6))


def assert_rest_to_rest(p: PathProfile, samples: ProfileSamples) -> None:
    assert samples.s[0] == p.s_start and samples.s[-1] == p.s_end
    assert samples.sd[0] == 0.0 and samples.sd[-1] == 0.0
    assert samples.sdd[0] == 0.0 and samples.sdd[-1] == 0.0
    assert np.allclose(np.diff(samples.t), samples.dt)


def random_cases(seed: int, n: int):
    """(d, v, T, f) with d >= v*T so that a cruise phase exists."""
    rng = np.random.default_rng(seed)
    for _ in range(n):
        v = 10 ** rng.uniform(-2, 0.5)  # [1/s]
        T = 10 ** rng.uniform(-2, 0)  # [s]
        d = v * T * 10 ** rng.uniform(0, 1.5)
        f = rng.choice([1.0, 0.5, 0.2])
        yield float(d), float(v), float(T), float(f)


# --------------------------------------------------------------------------- timing law


def test_limits_reach_speed_in_exactly_accel_time() -> None:
    for f in (1.0, 0.7, 0.3, 1e-3):
        lim = ProfileLimits.from_accel_time(0.8, 0.25, f)
        assert lim.accel_time == pytest.approx(0.25, rel=1e-15)
    s_curve = ProfileLimits.from_accel_time(0.8, 0.25)
    assert s_curve.acceleration == pytest.approx(2 * 0.8 / 0.25)
    assert s_curve.jerk == pytest.approx(4 * 0.8 / 0.25**2)


def test_duration_is_distance_over_speed_plus_accel_time() -> None:
    for d, v, T, f in random_cases(10, 300):
        p = move_profile(d, ProfileLimits.from_accel_time(v, T, f))
        assert abs(p.duration - (d / v + T)) <= 1e-9 * (d / v + T), (d, v, T, f)
    # exactly at the boundary d = vT: no cruise, still d/v + T = 2T
    p = move_profile(0.5 * 0.2, ProfileLimits.from_accel_time(0.5, 0.2))
    assert p.duration == pytest.approx(0.4, rel=1e-9)


@pytest.mark.parametrize(
    ("d", "v", "T", "f"), [(1.0, 0.5, 0.2, 1.0), (0.3, 0.25, 0.5, 1.0), (2.0, 1.0, 0.35, 0.5)]
)
def test_sampled_accel_and_decel_times_equal_accel_time(d: float, v: float, T: float, f: float) -> None:
    p = move_profile(d, ProfileLimits.from_accel_time(v, T, f))
    smp = p.sample(DT)
    assert_rest_to_rest(p, smp)
    assert_within_limits(smp, p.limits)
    at_speed = np.flatnonzero(smp.sd >= v * (1 - 1e-9))
    assert at_speed.size > 0
    t_reach = smp.t[at_speed[0]]  # first sample at cruise speed
    t_leave = smp.t[at_speed[-1]]  # last sample at cruise speed
    assert T - 1e-12 <= t_reach < T + DT
    assert p.duration - T - DT < t_leave <= p.duration - T + 1e-12
    assert np.max(smp.sd) == pytest.approx(v, rel=1e-12)
    assert smp.s[-1] == d


def test_short_moves_are_symmetric_and_time_optimal() -> None:
    rng = np.random.default_rng(11)
    for _ in range(40):
        v, T = 10 ** rng.uniform(-1, 0.3), 10 ** rng.uniform(-1.5, -0.3)
        d = v * T * rng.uniform(0.01, 0.99)
        lim = ProfileLimits.from_accel_time(v, T)  # pure S-curve
        p = move_profile(d, lim)
        # never reaches v, hence never reaches a either: four jerk phases of tau each
        tau = (d / (2 * lim.jerk)) ** (1 / 3)
        assert p.duration == pytest.approx(4 * tau, rel=1e-9)
        assert p.duration < 2 * T  # shorter than the shortest move that reaches v (d = vT)
        ts = np.linspace(0.0, p.duration, 41)
        fwd = np.array([p.at(t) for t in ts])
        bwd = np.array([p.at(p.duration - t) for t in ts])
        assert np.allclose(fwd[:, 1], bwd[:, 1], rtol=0, atol=1e-9 * v)  # speed mirror-symmetric
        assert np.allclose(fwd[:, 2], -bwd[:, 2], rtol=0, atol=1e-9 * lim.acceleration)
        assert np.max(fwd[:, 1]) < v
    # with a constant-acceleration share, short moves are still symmetric
    p = move_profile(0.05, ProfileLimits.from_accel_time(1.0, 0.2, 0.4))
    half = p.duration / 2
    for t in np.linspace(0, half, 17):
        assert p.at(t)[1] == pytest.approx(p.at(p.duration - t)[1], abs=1e-9)


def test_profiles_are_monotonic_rest_to_rest_within_limits() -> None:
    for d, v, T, f in list(random_cases(12, 12)) + [(0.01, 1.0, 0.3, 1.0), (1e-6, 0.5, 0.2, 1.0)]:
        p = move_profile(d, ProfileLimits.from_accel_time(v, T, f))
        smp = p.sample(DT)
        assert_rest_to_rest(p, smp)
        assert_within_limits(smp, p.limits)
        assert smp.t[-1] >= p.duration - 1e-12 and smp.t[-1] < p.duration + DT


def test_sample_count_and_zero_length() -> None:
    p = move_profile(1.0, ProfileLimits.from_accel_time(0.5, 0.2))  # 2.2 s
    smp = p.sample(DT)
    assert len(smp.t) == 2201  # k = 0 … 2200, no extra sample from rounding
    still = move_profile(1.0, ProfileLimits.from_accel_time(0.5, 0.2), s_start=1.0)
    assert still.duration == 0.0 and still.at(0.0) == (1.0, 0.0, 0.0)
    assert len(still.sample(DT).t) == 1


# --------------------------------------------------------------------------- joint PTP


def test_joint_ptp_synchronised_to_slowest_axis() -> None:
    rng = np.random.default_rng(20)
    for _ in range(5):
        n = 6
        q0, q1 = rng.uniform(-2, 2, n), rng.uniform(-2, 2, n)
        q1[2] = q0[2]  # an axis that does not move
        vmax = rng.uniform(0.5, 3.0, n)
        ratio, T = float(rng.uniform(0.1, 1.0)), float(rng.uniform(0.05, 0.5))
        m = plan_joint_ptp(q0, q1, vmax, ratio, T)
        dq = np.abs(q1 - q0)
        axis_time = np.where(dq > 0, dq / (ratio * vmax), 0.0)  # cruise time each axis would need alone
        slowest = int(np.argmax(axis_time))
        v = m.profile.limits.velocity
        assert v == pytest.approx(ratio * vmax[slowest] / dq[slowest], rel=1e-15)
        if 1.0 >= v * T:  # cruise exists
            assert m.duration == pytest.approx(axis_time[slowest] + T, rel=1e-9)
        smp, q = m.sample(DT)
        # per-axis speed and acceleration from the single profile
        peak_axis_speed = dq * np.max(smp.sd)
        assert np.all(peak_axis_speed <= ratio * vmax * (1 + REL))
        if 1.0 >= v * T:
            assert peak_axis_speed[slowest] == pytest.approx(ratio * vmax[slowest], rel=1e-9)
        assert np.all(dq * np.max(np.abs(smp.sdd)) <= 2 * ratio * vmax / T * (1 + REL))
        # numerical differentiation of the executed joint samples agrees
        qd = np.diff(q, axis=0) / DT
        assert np.all(np.max(np.abs(qd), axis=0) <= ratio * vmax * (1 + 1e-6))
        # all moving axes start and stop at the same sample
        moving = dq > 0
        changed = np.abs(q - q0) > 0
        not_there = np.abs(q - q1) > 0
        first = [np.flatnonzero(changed[:, i])[0] for i in np.flatnonzero(moving)]
        last = [np.flatnonzero(not_there[:, i])[-1] for i in np.flatnonzero(moving)]
        assert len(set(first)) == 1 and first[0] == 1
        assert len(set(last)) == 1 and last[0] == len(q) - 2
        assert np.all(q[:, 2] == q0[2])
        assert np.array_equal(q[0], q0) and np.array_equal(q[-1], q1)
        # on the joint-space line
        d = (q1 - q0) / np.linalg.norm(q1 - q0)
        rel = q - q0
        assert np.max(np.abs(rel - np.outer(rel @ d, d))) < 1e-12


def test_joint_ptp_no_motion_and_bad_arguments() -> None:
    m = plan_joint_ptp([0.1, 0.2], [0.1, 0.2], [1.0, 1.0], 0.5, 0.2)
    assert m.duration == 0.0
    smp, q = m.sample(DT)
    assert len(q) == 1 and np.array_equal(q[0], [0.1, 0.2])
    for kwargs in (
        dict(speed_ratio=0.0),
        dict(speed_ratio=1.01),
        dict(accel_time=0.0),
        dict(max_speed=[1.0, -1.0]),
        dict(max_speed=[1.0]),
    ):
        args = dict(q0=[0.0, 0.0], q1=[1.0, 1.0], max_speed=[1.0, 1.0], speed_ratio=0.5, accel_time=0.2)
        args |= kwargs
        with pytest.raises(ProfileError) as info:
            plan_joint_ptp(**args)
        assert isinstance(info.value, JaraArmError)


# --------------------------------------------------------------------------- Cartesian


@pytest.mark.parametrize(
    ("dp", "angle", "governs"),
    [
        ([0.3, 0.4, 0.0], 0.5, "translation"),  # 0.5 m at 0.25 m/s vs 0.5 rad at 1 rad/s
        ([0.05, 0.0, 0.0], 1.5, "rotation"),
        ([0.0, 0.0, 0.0], 0.8, "rotation"),  # pure rotation
        ([0.0, 0.2, 0.0], 0.0, "translation"),  # pure translation
    ],
)
def test_cartesian_line_slower_part_sets_duration(dp, angle: float, governs: str) -> None:
    vt, vr, ratio, T = 0.25, 1.0, 0.8, 0.15
    R1 = pinocchio.exp3(np.array([0.0, angle, 0.0]))
    T0 = pose([0.4, 0.0, 0.3])
    T1 = pose(np.array([0.4, 0.0, 0.3]) + dp, R1)
    line = CartesianLine(T0, T1)
    m = plan_cartesian(line, vt, vr, ratio, T)
    L, th = line.translation_length, line.rotation_angle
    t_trans, t_rot = L / (ratio * vt), th / (ratio * vr)
    assert (t_trans > t_rot) == (governs == "translation")
    assert m.duration == pytest.approx(max(t_trans, t_rot) + T, rel=1e-9)
    smp, poses = m.sample(DT)
    assert_within_limits(smp, m.profile.limits)
    # translation and rotation speeds stay under their ratio x max; the governing one reaches it
    assert L * np.max(smp.sd) <= ratio * vt * (1 + REL)
    assert th * np.max(smp.sd) <= ratio * vr * (1 + REL)
    if governs == "translation":
        peak = L * np.max(smp.sd) / (ratio * vt)
    else:
        peak = th * np.max(smp.sd) / (ratio * vr)
    assert peak == pytest.approx(1.0, rel=1e-9)
    # every executed point lies on the segment; ends exactly on the target
    p0, p1 = T0[:3, 3], T1[:3, 3]
    ideal = p0 + np.outer(smp.s, p1 - p0)
    assert np.max(np.linalg.norm(poses[:, :3, 3] - ideal, axis=1)) < 1e-9
    assert np.array_equal(poses[0], T0) and np.array_equal(poses[-1], T1)


def test_cartesian_no_motion_and_speed_rule() -> None:
    T0 = pose([0.4, 0.0, 0.3])
    m = plan_cartesian(CartesianLine(T0, T0), 0.25, 1.0, 1.0, 0.1)
    assert m.duration == 0.0 and np.array_equal(m.sample(DT)[1][0], T0)
    line = CartesianLine(T0, pose([0.4, 0.5, 0.3]))
    assert cartesian_path_speed(line, 0.25, 1.0, 0.5) == pytest.approx(0.25)
    with pytest.raises(ProfileError):
        cartesian_path_speed(line, 0.0, 1.0, 0.5)


def test_cartesian_arc_motion_stays_on_circle_and_meets_via() -> None:
    c, r = np.array([0.5, 0.0, 0.4]), 0.15
    R = pinocchio.exp3(np.array([0.3, 0.2, -0.1]))

    def on_circle(deg: float) -> np.ndarray:
        a = math.radians(deg)
        return c + r * (R @ np.array([math.cos(a), math.sin(a), 0.0]))

    T0 = pose(on_circle(0.0))
    T1 = pose(on_circle(90.0), pinocchio.exp3(np.array([0.0, 0.0, 0.6])))
    arc = CartesianArc(T0, on_circle(200.0), T1)  # far-side via: 270° arc
    vt, vr, ratio, T = 0.25, 1.0, 0.5, 0.2
    m = plan_cartesian(arc, vt, vr, ratio, T)
    assert arc.sweep_angle == pytest.approx(1.5 * math.pi, abs=1e-12)
    assert m.duration == pytest.approx(arc.translation_length / (ratio * vt) + T, rel=1e-9)
    smp, poses = m.sample(DT)
    p = poses[:, :3, 3]
    assert np.max(np.abs(np.linalg.norm(p - c, axis=1) - r)) < 1e-9
    assert np.array_equal(poses[0], T0) and np.array_equal(poses[-1], T1)
    step = ratio * vt * DT  # [m] longest distance between samples
    assert np.min(np.linalg.norm(p - on_circle(200.0), axis=1)) <= step / 2 + 1e-12
    assert np.max(np.linalg.norm(np.diff(p, axis=0), axis=1)) <= step * (1 + 1e-6)


# --------------------------------------------------------------------------- pause, stop, resume


def test_stop_from_cruise_brakes_along_path_in_accel_time() -> None:
    d, v, T = 1.0, 0.5, 0.2
    p = move_profile(d, ProfileLimits.from_accel_time(v, T))
    t_stop = 1.0  # mid-cruise
    s, sd, sdd = p.at(t_stop)
    assert sd == pytest.approx(v) and sdd == pytest.approx(0.0, abs=1e-12)
    stop = p.stop_at(t_stop)
    assert stop.at(0.0) == (s, sd, sdd)  # continuous with the running profile
    assert stop.duration == pytest.approx(T, rel=1e-9)  # braking mirrors acceleration
    assert stop.s_end == pytest.approx(s + v * T / 2, rel=1e-12)
    assert stop.s_end < d
    smp = stop.sample(DT)
    assert_within_limits(smp, p.limits)
    assert smp.sd[-1] == 0.0 and smp.sdd[-1] == 0.0 and smp.s[-1] == stop.s_end
    assert np.all(np.diff(smp.sd[:-1]) <= 1e-12)  # only slows down


def test_stop_from_any_state_stays_within_limits_and_path() -> None:
    rng = np.random.default_rng(30)
    for d, v, T, f in list(random_cases(31, 6)) + [(0.05, 1.0, 0.3, 1.0)]:
        p = move_profile(d, ProfileLimits.from_accel_time(v, T, f))
        for t in list(rng.uniform(0.0, p.duration, 5)) + [DT, p.duration - DT, p.duration - T / 2]:
            stop = p.stop_at(float(t))
            assert stop.s_start <= stop.s_end <= d
            assert stop.duration <= max(p.duration - t, 0.0) + 1e-6  # never later than the original end
            smp = stop.sample(DT)
            assert np.all(np.diff(smp.s) >= 0.0) and np.all(smp.sd >= 0.0)
            assert np.max(np.abs(smp.sdd)) <= p.limits.acceleration * (1 + REL)
            jerk = np.abs(np.diff(smp.sdd[:-1])) / DT
            assert np.all(jerk <= p.limits.jerk * (1 + 1e-6))


def test_pause_then_resume_reaches_exact_end() -> None:
    rng = np.random.default_rng(40)
    for d, v, T, f in random_cases(41, 6):
        p = move_profile(d, ProfileLimits.from_accel_time(v, T, f))
        t_pause = float(rng.uniform(0.0, p.duration))
        first = p.sample(DT)
        k = int(t_pause / DT)  # the executor pauses on a sample
        stop = p.stop_at(float(first.t[k]))
        resumed = stop.resume()
        assert resumed.at(0.0) == (stop.s_end, 0.0, 0.0)
        assert resumed.at(resumed.duration) == (d, 0.0, 0.0)
        s_all = np.concatenate([first.s[: k + 1], stop.sample(DT).s[1:], resumed.sample(DT).s[1:]])
        assert s_all[-1] == d
        assert np.all(np.diff(s_all) >= 0.0)
        assert_within_limits(resumed.sample(DT), p.limits)
        # a second pause during the resumed motion works the same way
        again = resumed.stop_at(resumed.duration / 2).resume()
        assert again.at(again.duration)[0] == d and again.sample(DT).s[-1] == d


def test_stop_from_a_state_that_cannot_brake_in_time_lands_on_the_end() -> None:
    lim = ProfileLimits.from_accel_time(0.5, 0.2)  # braking from 0.5 needs 0.05
    stop = stop_profile(1.0, 0.99, 0.5, 0.0, lim)
    assert stop.s_end == 1.0 and stop.at(stop.duration) == (1.0, 0.0, 0.0)
    assert stop.resume().duration == 0.0


def test_stop_and_resume_edge_states() -> None:
    lim = ProfileLimits.from_accel_time(0.5, 0.2)
    at_rest = stop_profile(1.0, 0.3, 0.0, 0.0, lim)
    assert at_rest.duration == 0.0 and at_rest.s_end == 0.3
    assert resume_profile(1.0, 1.0, lim).duration == 0.0
    p = move_profile(1.0, lim)
    done = p.stop_at(p.duration + 1.0)
    assert done.duration == 0.0 and done.s_end == 1.0 and done.resume().duration == 0.0
    with pytest.raises(ProfileError):
        stop_profile(1.0, 0.5, -0.1, 0.0, lim)
    with pytest.raises(ProfileError):
        stop_profile(1.0, 1.5, 0.1, 0.0, lim)
