"""Kinematics on Pinocchio: FK against PyBullet, Jacobian, IK, frames, arm angle, task masks."""

from __future__ import annotations

import math

import numpy as np
import pinocchio as pin
import pybullet as pb
import pytest

from jara_arm.kinematics import (
    FULL_MASK,
    POSITION_MASK,
    IkResult,
    Kinematics,
    KinematicsError,
    arm_angle,
    arm_to_robot,
    as_se3,
    hg_to_se3,
    pose_error,
    robot_to_arm,
    se3_to_hg,
)
from jara_arm.robots import ROBOTS, Family
from jara_arm.schema.errors import JaraArmError

ARMS7 = ("iiwa", "panda")


@pytest.fixture(scope="module")
def kins() -> dict[str, Kinematics]:
    return {}


def kin_of(kins: dict[str, Kinematics], name: str) -> Kinematics:
    if name not in kins:
        kins[name] = Kinematics(ROBOTS[name])
    return kins[name]


def uniform(kin: Kinematics, rng: np.random.Generator, margin: float = 0.0) -> np.ndarray:
    lo, hi = kin.lower + margin, kin.upper - margin
    return lo + (hi - lo) * rng.random(kin.axis_num)


def random_pose(rng: np.random.Generator, scale: float = 0.2) -> pin.SE3:
    return pin.exp6(pin.Motion(rng.normal(0, scale, 6)))


def wrap(a: float) -> float:
    return math.remainder(a, 2 * math.pi)


def task_mask(kin: Kinematics) -> tuple[bool, ...]:
    """A mask every model of the catalogue can satisfy at any reachable pose."""
    robot = kin.robot
    if kin.axis_num >= 6:
        return FULL_MASK
    if robot.family is Family.SCARA:
        return (True, True, True, False, False, True)
    if robot.family is Family.CARTESIAN:
        J = kin.jacobian(np.array(robot.ready_pose))
        return tuple(i < 3 and bool(np.abs(J[i]).max() > 1e-9) for i in range(6))
    return (True, True, True, False, True, True)  # 5 axes: rotation about base x free


# ---------------------------------------------------------------- forward kinematics


def pybullet_flange(robot, qs: list[np.ndarray]) -> list[np.ndarray]:
    """Flange poses from PyBullet (DIRECT), expressed in the URDF base link frame."""
    cid = pb.connect(pb.DIRECT)
    try:
        body = pb.loadURDF(str(robot.urdf), useFixedBase=True, physicsClientId=cid)
        joints, links = {}, {}
        for i in range(pb.getNumJoints(body, physicsClientId=cid)):
            info = pb.getJointInfo(body, i, physicsClientId=cid)
            joints[info[1].decode()] = i
            links[info[12].decode()] = i
        # PyBullet reports the base's inertial frame; recover the base link frame.
        com_p, com_o = pb.getBasePositionAndOrientation(body, physicsClientId=cid)
        dyn = pb.getDynamicsInfo(body, -1, physicsClientId=cid)
        inv_p, inv_o = pb.invertTransform(dyn[3], dyn[4])
        base_p, base_o = pb.multiplyTransforms(com_p, com_o, inv_p, inv_o)
        ib_p, ib_o = pb.invertTransform(base_p, base_o)
        out = []
        for q in qs:
            for name, v in zip(robot.arm_joints, q):
                pb.resetJointState(body, joints[name], float(v), physicsClientId=cid)
            st = pb.getLinkState(body, links[robot.flange_frame], computeForwardKinematics=True,
                                 physicsClientId=cid)
            p, o = pb.multiplyTransforms(ib_p, ib_o, st[4], st[5])
            T = np.eye(4)
            T[:3, :3] = np.array(pb.getMatrixFromQuaternion(o)).reshape(3, 3)
            T[:3, 3] = p
            out.append(T)
        return out
    finally:
        pb.disconnect(cid)


@pytest.mark.parametrize("name", sorted(ROBOTS))
def test_fk_matches_pybullet(kins, name):
    kin = kin_of(kins, name)
    rng = np.random.default_rng(1)
    qs = [uniform(kin, rng) for _ in range(20)]
    for q, T_pb in zip(qs, pybullet_flange(kin.robot, qs)):
        T = kin.fk(q).homogeneous
        assert T.shape == (4, 4)
        np.testing.assert_allclose(T, T_pb, atol=1e-6)


def test_reduced_model_is_the_arm(kins):
    kin = kin_of(kins, "panda")
    assert kin.pin_model.nq == kin.axis_num == 7
    assert [kin.pin_model.names[j] for j in range(1, 8)] == list(ROBOTS["panda"].arm_joints)
    np.testing.assert_allclose(kin.lower, [lim.lower for lim in ROBOTS["panda"].hard_limits])


@pytest.mark.parametrize("name", ARMS7)
def test_jacobian_finite_difference(kins, name):
    kin = kin_of(kins, name)
    rng = np.random.default_rng(2)
    h = 1e-6
    for _ in range(5):
        q = uniform(kin, rng, 0.01)
        tool = random_pose(rng)
        J = kin.jacobian(q, tool)
        assert J.shape == (6, kin.axis_num)
        for k in range(kin.axis_num):
            dq = np.zeros(kin.axis_num)
            dq[k] = h
            Tp, Tm = kin.control_point(q + dq, tool).homogeneous, kin.control_point(q - dq, tool).homogeneous
            lin = (Tp[:3, 3] - Tm[:3, 3]) / (2 * h)
            ang = pin.log3(Tp[:3, :3] @ Tm[:3, :3].T) / (2 * h)  # along the base axes
            np.testing.assert_allclose(J[:3, k], lin, atol=1e-6)
            np.testing.assert_allclose(J[3:, k], ang, atol=1e-6)


# ---------------------------------------------------------------- frames


def test_hg_matrix_round_trip():
    rng = np.random.default_rng(3)
    T = random_pose(rng)
    hg = se3_to_hg(T)
    assert hg.shape == (3, 4)
    np.testing.assert_array_equal(hg_to_se3(hg).homogeneous, T.homogeneous)
    with pytest.raises(KinematicsError):
        hg_to_se3(np.eye(4))
    with pytest.raises(KinematicsError):
        se3_to_hg(np.eye(3))


@pytest.mark.parametrize("name", ARMS7)
def test_base_and_control_point_offsets_compose(kins, name):
    """DECISIONS.md Frames: controlled pose T_flange · C; robot frame pose inv(B) · T_arm."""
    kin = kin_of(kins, name)
    rng = np.random.default_rng(4)
    q = uniform(kin, rng)
    B, C = random_pose(rng, 0.5), random_pose(rng, 0.3)
    T_cp = kin.control_point(q, C)
    np.testing.assert_allclose(T_cp.homogeneous, kin.fk(q).homogeneous @ C.homogeneous, atol=1e-12)
    np.testing.assert_allclose(kin.control_point(q).homogeneous, kin.fk(q).homogeneous, atol=1e-15)
    T_robot = arm_to_robot(T_cp, B)
    np.testing.assert_allclose(T_robot.homogeneous, np.linalg.inv(B.homogeneous) @ T_cp.homogeneous, atol=1e-12)
    np.testing.assert_allclose(robot_to_arm(T_robot, B).homogeneous, T_cp.homogeneous, atol=1e-12)
    np.testing.assert_allclose(arm_to_robot(T_cp).homogeneous, T_cp.homogeneous, atol=0)
    # IK of a robot-frame target with a tool: back through B, forward through C.
    target_robot = arm_to_robot(kin.control_point(uniform(kin, rng), C), B)
    res = kin.ik(robot_to_arm(target_robot, B), q, tool=C)
    assert res.success
    pe, re = pose_error(arm_to_robot(kin.control_point(res.q, C), B), target_robot)
    assert pe < 1e-5 and re < 1e-5
    # 3x4 HgMatrix from the wire accepted for targets and tools, through as_se3
    res2 = kin.ik(as_se3(se3_to_hg(robot_to_arm(target_robot, B))), q, tool=as_se3(se3_to_hg(C)))
    np.testing.assert_allclose(res2.q, res.q, atol=1e-12)


# ---------------------------------------------------------------- inverse kinematics


@pytest.mark.parametrize("name", ARMS7)
def test_ik_round_trip_from_random_seeds(kins, name):
    kin = kin_of(kins, name)
    rng = np.random.default_rng(5)
    for _ in range(200):
        q_goal, q_seed = uniform(kin, rng), uniform(kin, rng)
        target = kin.fk(q_goal)
        res = kin.ik(target, q_seed, tol_pos=1e-5, tol_rot=1e-5)
        assert isinstance(res, IkResult)
        assert res.success, res
        assert kin.within_limits(res.q)
        pe, re = pose_error(kin.fk(res.q), target)
        assert pe <= 1e-5 and re <= 1e-5
        assert res.pos_err == pytest.approx(pe, abs=1e-12) and res.rot_err == pytest.approx(re, abs=1e-9)


@pytest.mark.parametrize("name", ARMS7)
def test_ik_prefers_the_solution_near_the_seed(kins, name):
    kin = kin_of(kins, name)
    rng = np.random.default_rng(6)
    for _ in range(50):
        q_goal = uniform(kin, rng, 0.1)
        seed = q_goal + rng.normal(0, 0.02, kin.axis_num)
        res = kin.ik(kin.fk(q_goal), seed)
        assert res.success
        # a redundant arm has a curve of solutions: the one found is no farther from the seed
        assert np.linalg.norm(res.q - seed) <= 1.01 * np.linalg.norm(q_goal - seed)


@pytest.mark.parametrize("name", ARMS7)
def test_ik_respects_narrower_limits(kins, name):
    kin = kin_of(kins, name)
    rng = np.random.default_rng(7)
    mid = (kin.lower + kin.upper) / 2
    half = (kin.upper - kin.lower) / 4
    lower, upper = mid - half, mid + half
    for _ in range(20):
        q_goal = lower + (upper - lower) * rng.random(kin.axis_num)
        res = kin.ik(kin.fk(q_goal), kin.lower + (kin.upper - kin.lower) * rng.random(kin.axis_num),
                     lower=lower, upper=upper)
        assert res.success
        assert np.all(res.q >= lower) and np.all(res.q <= upper)
    with pytest.raises(KinematicsError):
        kin.ik(kin.fk(mid), mid, lower=kin.lower - 1.0, upper=kin.upper)


def test_ik_is_reproducible(kins):
    kin = kin_of(kins, "panda")
    rng = np.random.default_rng(14)
    problems = [(kin.fk(uniform(kin, rng)), uniform(kin, rng)) for _ in range(20)]
    first = [kin.ik(t, s) for t, s in problems]
    fresh = Kinematics(ROBOTS["panda"])
    again = [fresh.ik(t, s) for t, s in problems[:10]] + [kin.ik(t, s) for t, s in problems[10:]]
    for a, b in zip(first, again):
        np.testing.assert_array_equal(a.q, b.q)
        assert a.iterations == b.iterations


def test_ik_unreachable_fails_within_limits(kins):
    kin = kin_of(kins, "iiwa")
    target = pin.SE3(np.eye(3), np.array([3.0, 0.0, 0.5]))  # 3 m away: out of reach
    res = kin.ik(target, np.zeros(7), max_iter=200)
    assert not res.success
    assert res.iterations == 200
    assert kin.within_limits(res.q)
    assert res.pos_err > 1.0


@pytest.mark.parametrize("name", ARMS7)
def test_ik_position_only_mask(kins, name):
    kin = kin_of(kins, name)
    rng = np.random.default_rng(8)
    for _ in range(50):
        target = kin.fk(uniform(kin, rng))
        target.rotation = random_pose(rng, 3.0).rotation  # orientation is free: anything goes
        res = kin.ik(target, uniform(kin, rng), mask=POSITION_MASK)
        assert res.success and res.rot_err == 0.0
        assert np.linalg.norm(kin.fk(res.q).translation - target.translation) <= 1e-5


def test_ik_mask_frees_rotation_about_a_base_axis(kins):
    """With rx free, the reached orientation is the target turned about the base x axis."""
    kin = kin_of(kins, "iiwa")
    rng = np.random.default_rng(9)
    mask = (True, True, True, False, True, True)
    for _ in range(50):
        target = kin.fk(uniform(kin, rng))
        target.rotation = pin.exp3(np.array([rng.uniform(-1, 1), 0, 0])) @ target.rotation
        res = kin.ik(target, uniform(kin, rng), mask=mask)
        assert res.success
        T = kin.fk(res.q).homogeneous
        target = target.homogeneous
        w = pin.log3(target[:3, :3] @ T[:3, :3].T)
        assert abs(w[1]) <= 1e-5 and abs(w[2]) <= 1e-5
        assert np.linalg.norm(T[:3, 3] - target[:3, 3]) <= 1e-5


@pytest.mark.parametrize("name", sorted(set(ROBOTS) - set(ARMS7)))
def test_ik_other_models_with_their_task_mask(kins, name):
    kin = kin_of(kins, name)
    mask = task_mask(kin)
    rng = np.random.default_rng(10)
    for _ in range(30):
        target = kin.fk(uniform(kin, rng))
        res = kin.ik(target, uniform(kin, rng), mask=mask)
        assert res.success, res
        assert kin.within_limits(res.q)
        T, target = kin.fk(res.q).homogeneous, target.homogeneous
        err = np.concatenate((target[:3, 3] - T[:3, 3], pin.log3(target[:3, :3] @ T[:3, :3].T)))
        assert np.all(np.abs(err[list(mask)]) <= 1e-5)
    assert kin.elbow_angle(np.array(kin.robot.ready_pose)) == 0.0


# ---------------------------------------------------------------- arm angle


def rotate_about(p: np.ndarray, origin: np.ndarray, axis: np.ndarray, angle: float) -> np.ndarray:
    return origin + pin.exp3(axis / np.linalg.norm(axis) * angle) @ (p - origin)


def test_arm_angle_definition():
    s, w = np.array([0.0, 0.0, 0.3]), np.array([0.5, 0.0, 0.6])
    up = np.array([0.2, 0.0, 0.7])  # above the line, in the vertical plane through it
    assert arm_angle(s, up, w) == pytest.approx(0.0, abs=1e-12)
    down = np.array([0.3, 0.0, 0.3])
    assert abs(arm_angle(s, down, w)) == pytest.approx(math.pi, abs=1e-12)
    for a in (0.3, -1.0, 2.5):  # right-handed about S->W
        assert arm_angle(s, rotate_about(up, s, w - s, a), w) == pytest.approx(a, abs=1e-12)
    # vertical shoulder-wrist line: measured from the plane containing base x
    wv = np.array([0.0, 0.0, 1.0])
    assert arm_angle(s, np.array([0.1, 0.0, 0.5]), wv) == pytest.approx(0.0, abs=1e-12)
    assert arm_angle(s, np.array([0.0, 0.1, 0.5]), wv) == pytest.approx(math.pi / 2, abs=1e-12)
    # turning everything about the base z axis leaves the angle unchanged
    z = np.array([0.0, 0.0, 1.0])
    e = rotate_about(up, s, w - s, 0.7)
    rot = [rotate_about(p, np.zeros(3), z, 1.1) for p in (s, e, w)]
    assert arm_angle(*rot) == pytest.approx(0.7, abs=1e-12)


@pytest.mark.parametrize("name", ARMS7)
def test_elbow_angle_of_the_arm(kins, name):
    kin = kin_of(kins, name)
    assert kin.has_elbow
    rng = np.random.default_rng(11)
    for _ in range(20):
        q = uniform(kin, rng)
        assert kin.elbow_angle(q) == pytest.approx(arm_angle(*kin.elbow_points(q)), abs=1e-12)
        # J1 turns the whole arm about the base z axis: the arm angle does not change
        q1 = q.copy()
        q1[0] = rng.uniform(kin.lower[0], kin.upper[0])
        assert wrap(kin.elbow_angle(q1) - kin.elbow_angle(q)) == pytest.approx(0.0, abs=1e-9)
    # the shoulder, elbow and wrist points are the joint origins of J2, J4, J6
    q = uniform(kin, rng)
    model = pin.buildModelFromUrdf(str(kin.robot.urdf))
    data = model.createData()
    qf = pin.neutral(model)
    qf[:7] = q
    pin.forwardKinematics(model, data, qf)
    for p, j in zip(kin.elbow_points(q), (2, 4, 6)):
        np.testing.assert_allclose(p, data.oMi[model.getJointId(kin.robot.arm_joints[j - 1])].translation)


@pytest.mark.parametrize("name", ARMS7)
def test_elbow_angle_is_continuous_and_its_gradient_right(kins, name):
    kin = kin_of(kins, name)
    rng = np.random.default_rng(12)
    a, b = uniform(kin, rng, 0.3), uniform(kin, rng, 0.3)
    prev = kin.elbow_angle(a)
    for s in np.linspace(0.0, 1.0, 2001)[1:]:  # steps of about 1e-3 rad per joint
        psi = kin.elbow_angle(a + s * (b - a))
        assert abs(wrap(psi - prev)) < 0.05
        prev = psi
    h = 1e-6
    for _ in range(10):
        q = uniform(kin, rng, 0.01)
        g = kin.elbow_jacobian(q)
        fd = [wrap(kin.elbow_angle(q + h * e) - kin.elbow_angle(q - h * e)) / (2 * h) for e in np.eye(7)]
        np.testing.assert_allclose(g, fd, atol=1e-6)


@pytest.mark.parametrize("name", ARMS7)
def test_ik_reaches_the_commanded_elbow(kins, name):
    kin = kin_of(kins, name)
    rng = np.random.default_rng(13)
    for _ in range(50):  # the arm angle of a random configuration, from a random seed
        q_goal = uniform(kin, rng)
        target, psi = kin.fk(q_goal), kin.elbow_angle(q_goal)
        res = kin.ik(target, uniform(kin, rng), elbow=psi)
        assert res.success
        assert kin.within_limits(res.q)
        pe, re = pose_error(kin.fk(res.q), target)
        assert pe <= 1e-5 and re <= 1e-5
        assert abs(wrap(kin.elbow_angle(res.q) - psi)) <= 1e-3
    ok = 0
    for _ in range(50):  # moving the elbow by 0.2 rad; joint limits may forbid a few
        q_goal = uniform(kin, rng)
        target, psi = kin.fk(q_goal), wrap(kin.elbow_angle(q_goal) + 0.2)
        res = kin.ik(target, q_goal, elbow=psi)
        if res.success:
            ok += 1
            pe, re = pose_error(kin.fk(res.q), target)
            assert pe <= 1e-5 and re <= 1e-5
            assert abs(wrap(kin.elbow_angle(res.q) - psi)) <= 1e-3
    assert ok >= 40


# ---------------------------------------------------------------- errors


def test_errors(kins):
    kin = kin_of(kins, "iiwa")
    assert issubclass(KinematicsError, JaraArmError)
    with pytest.raises(KinematicsError):
        kin.fk(np.zeros(6))
    with pytest.raises(KinematicsError):
        kin.ik(np.eye(3), np.zeros(7))
    with pytest.raises(KinematicsError):
        kin.ik(pin.SE3.Identity(), np.zeros(7), mask=(True, True, True))
    with pytest.raises(KinematicsError):
        kin.ik(pin.SE3.Identity(), np.zeros(7), mask=(False,) * 6)
    with pytest.raises(KinematicsError):
        Kinematics(ROBOTS["iiwa"], elbow_joints=(3, 1, 5))
    six = kin_of(kins, "arm6") if "arm6" in ROBOTS else None
    if six is not None:
        assert not six.has_elbow
        with pytest.raises(KinematicsError):
            six.elbow_points(np.zeros(6))
