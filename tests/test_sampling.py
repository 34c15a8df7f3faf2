"""LIN / CIRC joints from IK at knots and a Hermite spline (``services/planner/sampling.py``): pure, no processes.

Every 1 ms sample of a planned motion is checked here with Pinocchio forward
kinematics (not the planner's own batched FK): on the ideal path within
1e-6 m and 1e-5 rad, inside the joint soft limits, under the joint speed limits.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np
import pinocchio as pin
import pytest

from jara_arm.kinematics import Kinematics, as_se3
from jara_arm.robots import robot
from jara_arm.schema.operations import OP
from jara_arm.schema.planner import MotionSettings
from jara_arm.schema.types import LimitValue
from jara_arm.services.planner import sampling
from jara_arm.services.planner.planning import MotionPlanner
from jara_arm.services.planner.sampling import BatchFk, HermiteSpline, batch_arm_angle, batch_log3

from .support import car, motion_settings, plan_request, pose

DT = 1e-3
PLANNED_POS = 1e-6  # [m] every planned sample vs the ideal pose at its path parameter
PLANNED_ROT = 1e-5  # [rad]


def rot(axis: Any, angle: float) -> np.ndarray:
    return pin.exp3(np.asarray(axis, dtype=float) / np.linalg.norm(axis) * angle)




@pytest.fixture(scope="module")
def iiwa() -> MotionPlanner:
    return MotionPlanner(robot("iiwa"))


def counting(monkeypatch: pytest.MonkeyPatch) -> list[sampling.PathJoints]:
    """The PathJoints built while planning (to read their knot and IK counts)."""
    made: list[sampling.PathJoints] = []
    init = sampling.PathJoints.__init__

    def spy(self: sampling.PathJoints, *a: Any, **k: Any) -> None:
        init(self, *a, **k)
        made.append(self)

    monkeypatch.setattr(sampling.PathJoints, "__init__", spy)
    return made


def check_samples(planner: MotionPlanner, motion: Any, path_pose, s: MotionSettings,
                  base: np.ndarray | None = None, tool: np.ndarray | None = None) -> tuple[float, float]:
    """Every sample on the ideal path (Pinocchio FK), in the soft limits, under the speed limits.

    ``path_pose(s)``: the ideal pose (robot frame) at path parameter s. Returns the worst errors.
    """
    n = planner.n
    B = np.eye(4) if base is None else base
    C = None if tool is None else as_se3(tool)
    samples = motion.profile.sample(DT)
    assert len(samples.s) == len(motion.q)
    worst_p = worst_r = 0.0
    for sk, q in zip(samples.s, motion.q):
        T = np.linalg.inv(B) @ planner.kin.control_point(q[:n], C).homogeneous
        ideal = path_pose(sk)
        worst_p = max(worst_p, float(np.linalg.norm(T[:3, 3] - ideal[:3, 3])))
        worst_r = max(worst_r, float(np.linalg.norm(pin.log3(ideal[:3, :3] @ T[:3, :3].T))))
    assert worst_p <= PLANNED_POS, worst_p
    assert worst_r <= PLANNED_ROT, worst_r
    lo = np.array([x.lower for x in s.softLimitJoint])
    hi = np.array([x.upper for x in s.softLimitJoint])
    assert np.all(motion.q[:, :n] >= lo) and np.all(motion.q[:, :n] <= hi)
    vmax = np.minimum(s.maxSpeedJoint, planner.model.rated_speed)
    assert np.all(np.abs(np.diff(motion.q[:, :n], axis=0)) / DT <= vmax * (1 + 1e-9))
    assert np.array_equal(motion.q[0], motion.start)
    return worst_p, worst_r


# ----------------------------------------------------------------------------- building blocks


@pytest.mark.parametrize("name", ["iiwa", "panda", "arm5", "arm6", "scara4", "cartesian3"])
def test_batch_fk_agrees_with_pinocchio(name: str):
    model = robot(name)
    kin = Kinematics(model, seed_table=0)
    fk = BatchFk(kin)
    rng = np.random.default_rng(3)
    q = kin.lower + (kin.upper - kin.lower) * rng.random((50, model.axis_num))
    tool = as_se3(pose([0.01, -0.02, 0.15], rot([1, 2, 3], 0.4)))
    for C in (None, tool):
        pts, R, sew = fk.run(q, C)
        for k in range(len(q)):
            T = kin.control_point(q[k], C).homogeneous
            assert np.abs(T[:3, 3] - pts[k]).max() < 1e-12
            assert np.abs(T[:3, :3] - R[k]).max() < 1e-12
    if kin.has_elbow:
        psi = batch_arm_angle(sew)
        for k in range(len(q)):
            assert np.allclose(np.stack(kin.elbow_points(q[k])), sew[:, k], atol=1e-12)
            assert abs(math.remainder(psi[k] - kin.elbow_angle(q[k]), 2 * math.pi)) < 1e-9
    else:
        assert sew is None


def test_batch_log3_small_large_and_near_pi():
    rng = np.random.default_rng(5)
    angles = [0.0, 1e-12, 1e-8, 1e-7, 1e-3, 0.5, 2.0, 3.0, 3.1, math.pi - 1e-6, math.pi]
    Ra, Rb = [], []
    for a in angles:
        R0 = rot(rng.normal(size=3), rng.uniform(0, 3))
        Ra.append(rot(rng.normal(size=3), a) @ R0)
        Rb.append(R0)
    wv = batch_log3(np.array(Ra), np.array(Rb))
    for k, a in enumerate(angles):
        ref = pin.log3(Ra[k] @ Rb[k].T)
        if a < math.pi - 1e-3:
            assert np.abs(wv[k] - ref).max() < 1e-12 + 1e-9 * a, (a, wv[k], ref)
        assert abs(np.linalg.norm(wv[k]) - np.linalg.norm(ref)) < 1e-9


def test_hermite_spline_is_exact_at_knots_and_for_cubics():
    ks = np.array([0.0, 0.3, 0.35, 1.0])
    f = lambda s: np.stack([1 + 2 * s - s**2 + 0.5 * s**3, -s**3], axis=1)  # noqa: E731
    df = lambda s: np.stack([2 - 2 * s + 1.5 * s**2, -3 * s**2], axis=1)  # noqa: E731
    sp = HermiteSpline(ks, f(ks), df(ks))
    s = np.linspace(0.0, 1.0, 1001)
    assert np.abs(sp(s) - f(s)).max() < 1e-14
    assert np.array_equal(sp(ks), f(ks))  # bit-exact at the knots
    sp.insert(0.6, f(np.array([0.6]))[0], df(np.array([0.6]))[0])
    assert list(sp.s) == [0.0, 0.3, 0.35, 0.6, 1.0]
    assert np.abs(sp(s) - f(s)).max() < 1e-14


# ----------------------------------------------------------------------------- planned motions


def test_lin_half_metre_every_sample_on_the_line(iiwa: MotionPlanner, monkeypatch: pytest.MonkeyPatch):
    made = counting(monkeypatch)
    model, kin = iiwa.model, iiwa.kin
    q0 = np.array(model.ready_pose)
    T0 = kin.control_point(q0).homogeneous
    a = T0[:3, 3] + [-0.1, -0.25, 0.0]
    s = motion_settings(model)
    first = iiwa.plan(plan_request(OP.moveLinearCartesianAbs, {"carPoint": car(pose(a, T0[:3, :3]))}, s), q0)
    T1 = pose(a + [0.0, 0.5, 0.0], rot([0, 0, 1], 0.3) @ T0[:3, :3])  # 0.5 m and a turn
    Ta = kin.control_point(first.end).homogeneous
    m = iiwa.plan(plan_request(OP.moveLinearCartesianAbs, {"carPoint": car(T1)}, s), first.end)
    path = made[-1]
    omega = pin.log3(Ta[:3, :3].T @ T1[:3, :3])
    worst_p, worst_r = check_samples(iiwa, m, lambda u: pose(Ta[:3, 3] + u * (T1[:3, 3] - Ta[:3, 3]),
                                                            Ta[:3, :3] @ pin.exp3(u * omega)), s)
    assert len(m.q) > 2000
    assert path.ik_solves < len(m.q) / 20  # IK at knots, not at every sample
    end = kin.control_point(m.end).homogeneous
    assert np.linalg.norm(end[:3, 3] - T1[:3, 3]) < 1e-7 and np.linalg.norm(end[:3, :3] - T1[:3, :3]) < 1e-6
    # The arm angle moves linearly along the path (start's to target's: both the start's here).
    psi = np.array([kin.elbow_angle(q) for q in m.q[::50]])
    assert np.abs(psi - kin.elbow_angle(first.end)).max() < 2e-4
    print(f"LIN: {len(m.q)} samples, {path.ik_solves} IK solves, worst {worst_p:.2e} m, {worst_r:.2e} rad")


def test_circ_half_circle_every_sample_on_the_circle(iiwa: MotionPlanner, monkeypatch: pytest.MonkeyPatch):
    made = counting(monkeypatch)
    model, kin = iiwa.model, iiwa.kin
    q0 = np.array(model.ready_pose)
    T0 = kin.control_point(q0).homogeneous
    p0, R0 = T0[:3, 3], T0[:3, :3]
    r = 0.15
    c = p0 + [0.0, -r, 0.0]
    via, target = c + [r, 0.0, 0.0], c + [0.0, -r, 0.0]
    R1 = rot([1, 0, 0], 0.2) @ R0
    s = motion_settings(model)
    m = iiwa.plan(plan_request(OP.moveCircularCartesianAbs,
                               {"carPointR": car(pose(via, R0)), "carPointT": car(pose(target, R1))}, s), q0)
    omega = pin.log3(R0.T @ R1)

    def ideal(u: float) -> np.ndarray:  # from +y about -z (through +x) to -y: half a circle
        ang = u * math.pi
        return pose(c + r * np.array([math.sin(ang), math.cos(ang), 0.0]), R0 @ pin.exp3(u * omega))

    worst_p, worst_r = check_samples(iiwa, m, ideal, s)
    assert made[-1].ik_solves < len(m.q) / 20
    pts = np.array([kin.control_point(q[:7]).translation for q in m.q])
    radial = np.linalg.norm(pts[:, :2] - c[:2], axis=1) - r
    assert np.hypot(radial, pts[:, 2] - c[2]).max() < PLANNED_POS
    print(f"CIRC: {len(m.q)} samples, {made[-1].ik_solves} IK solves, worst {worst_p:.2e} m, {worst_r:.2e} rad")


def test_lin_with_frames_and_tight_soft_limits(iiwa: MotionPlanner):
    """Base and tool offsets; soft limits hugging the joint path: every sample stays inside."""
    model, kin = iiwa.model, iiwa.kin
    B = pose([0.3, -0.2, 0.1], rot([0, 0, 1], 0.5))
    C = pose([0.0, 0.02, 0.12], rot([1, 0, 0], 0.3))
    s = motion_settings(model, baseOffset=B[:3], controlPointOffset=C[:3])
    q0 = np.array(model.ready_pose)
    T0 = np.linalg.inv(B) @ kin.control_point(q0, as_se3(C)).homogeneous
    T1 = pose(T0[:3, 3] + [0.1, 0.15, -0.1], rot([1, 1, 0], 0.4) @ T0[:3, :3])
    req = plan_request(OP.moveLinearCartesianAbs, {"carPoint": car(T1)}, s)
    free = iiwa.plan(req, q0)
    omega = pin.log3(T0[:3, :3].T @ T1[:3, :3])

    def ideal(u: float) -> np.ndarray:
        return pose(T0[:3, 3] + u * (T1[:3, 3] - T0[:3, 3]), T0[:3, :3] @ pin.exp3(u * omega))

    check_samples(iiwa, free, ideal, s, B, C)
    # Soft limits at the swept range of each joint, widened by 1e-6 rad: the same path must fit.
    lo, hi = free.q.min(axis=0) - 1e-6, free.q.max(axis=0) + 1e-6
    tight = tuple(LimitValue(upper=float(h), lower=float(lo_)) for lo_, h in zip(lo, hi))
    s2 = dataclasses.replace(s, softLimitJoint=tight)
    m = iiwa.plan(dataclasses.replace(req, settings=s2), q0)
    check_samples(iiwa, m, ideal, s2, B, C)


def test_slowdown_reuses_the_joint_path(iiwa: MotionPlanner, monkeypatch: pytest.MonkeyPatch):
    """A profile slowed down for the joint speed limits samples the same q(s): no new IK round."""
    made = counting(monkeypatch)
    model, kin = iiwa.model, iiwa.kin
    q0 = np.array(model.ready_pose)
    T0 = kin.control_point(q0).homogeneous
    T1 = pose(T0[:3, 3] + [0.0, 0.2, 0.0], T0[:3, :3])
    s = motion_settings(model, maxSpeedJoint=(0.2,) * 7)
    m = iiwa.plan(plan_request(OP.moveLinearCartesianAbs, {"carPoint": car(T1)}, s), q0)
    assert len(made) == 1  # one joint path for every slowdown round
    assert m.duration > 0.2 / 0.25 + model.min_accel_time_cartesian  # it was slowed down
    check_samples(iiwa, m, lambda u: pose(T0[:3, 3] + u * (T1[:3, 3] - T0[:3, 3]), T0[:3, :3]), s)


@pytest.mark.parametrize("name", ["arm5", "arm6", "scara4", "panda"])
def test_other_families_every_sample_on_the_line(name: str):
    """Masked tasks (5 axes: rx free, SCARA: yaw only) and a gripper column kept as it is."""
    model = robot(name)
    planner = MotionPlanner(model)
    grip = [model.gripper_limits.upper] if model.has_gripper else []
    q0 = np.array(list(model.ready_pose) + grip)
    n = model.axis_num
    T0 = planner.kin.control_point(q0[:n]).homogeneous
    a, b = T0[:3, 3], T0[:3, 3] + [0.03, 0.08, -0.03]
    s = motion_settings(model)
    m = planner.plan(plan_request(OP.moveLinearCartesianRel, {"carPoint": car(pose(b - a))}, s), q0)
    pts = np.array([planner.kin.control_point(q[:n]).translation for q in m.q])
    d = b - a
    u = np.clip((pts - a) @ d / (d @ d), 0.0, 1.0)
    assert np.linalg.norm(pts - (a + u[:, None] * d), axis=1).max() < PLANNED_POS
    assert np.linalg.norm(pts[-1] - b) < 1e-7
    if model.has_gripper:
        assert np.all(m.q[:, n] == q0[n])
