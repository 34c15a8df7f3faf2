"""Every robot model loads in PyBullet and Pinocchio and is physically sound."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections.abc import Iterator

import numpy as np
import pinocchio as pin
import pybullet as p
import pytest

from jara_arm.robots import ROBOTS, Family, RobotModel

NAMES = list(ROBOTS)
_PB_TYPE = {p.JOINT_REVOLUTE: "revolute", p.JOINT_PRISMATIC: "prismatic"}


def expected_types(m: RobotModel) -> tuple[str, ...]:
    """Joint types each family must have (SPEC.md §1 families)."""
    if m.family is Family.CARTESIAN:
        return ("prismatic",) * m.axis_num
    if m.family is Family.SCARA:
        return ("revolute", "revolute", "prismatic", "revolute")
    return ("revolute",) * m.axis_num


class Sim:
    """One PyBullet DIRECT client with the robot loaded on a fixed base."""

    def __init__(self, m: RobotModel) -> None:
        self.c = p.connect(p.DIRECT)
        p.setGravity(0, 0, -9.81, physicsClientId=self.c)
        p.setTimeStep(0.001, physicsClientId=self.c)
        self.body = p.loadURDF(str(m.urdf), useFixedBase=True, physicsClientId=self.c)
        n = p.getNumJoints(self.body, physicsClientId=self.c)
        self.info = [p.getJointInfo(self.body, i, physicsClientId=self.c) for i in range(n)]
        self.joint = {i[1].decode(): i[0] for i in self.info}
        self.link = {i[12].decode(): i[0] for i in self.info}
        self.arm = [self.joint[j] for j in m.arm_joints]

    def reset(self, q: np.ndarray | tuple[float, ...]) -> None:
        for j, v in zip(self.arm, q):
            p.resetJointState(self.body, j, v, physicsClientId=self.c)

    def q(self) -> np.ndarray:
        return np.array([s[0] for s in p.getJointStates(self.body, self.arm, physicsClientId=self.c)])

    def link_pose(self, link: str) -> tuple[np.ndarray, np.ndarray]:
        s = p.getLinkState(self.body, self.link[link], computeForwardKinematics=True,
                           physicsClientId=self.c)
        return np.array(s[4]), np.array(p.getMatrixFromQuaternion(s[5])).reshape(3, 3)


@pytest.fixture(params=NAMES)
def model(request: pytest.FixtureRequest) -> RobotModel:
    return ROBOTS[request.param]


@pytest.fixture
def sim(model: RobotModel) -> Iterator[Sim]:
    s = Sim(model)
    yield s
    p.disconnect(s.c)


def pin_model(m: RobotModel) -> pin.Model:
    return pin.buildModelFromUrdf(str(m.urdf))


def pin_q(model: pin.Model, m: RobotModel, arm_q: tuple[float, ...]) -> np.ndarray:
    q = pin.neutral(model)
    for name, v in zip(m.arm_joints, arm_q):
        q[model.joints[model.getJointId(name)].idx_q] = v
    return q


def test_catalog_has_every_family() -> None:
    assert {"iiwa", "panda", "cartesian1", "cartesian2", "cartesian3", "scara4", "arm5",
            "arm6"} <= set(ROBOTS)
    assert [ROBOTS[f"cartesian{n}"].axis_num for n in (1, 2, 3)] == [1, 2, 3]


def test_family_axis_count(model: RobotModel) -> None:
    lo, hi = {Family.CARTESIAN: (1, 3), Family.SCARA: (4, 4), Family.ARTICULATED: (5, 7)}[model.family]
    assert lo <= model.axis_num <= hi


def test_joints_in_pybullet(model: RobotModel, sim: Sim) -> None:
    types = tuple(_PB_TYPE.get(sim.info[j][2]) for j in sim.arm)
    assert types == expected_types(model)
    for g in model.gripper_joints:
        assert sim.info[sim.joint[g]][2] == p.JOINT_PRISMATIC
    assert model.flange_frame in sim.link


def test_joints_in_pinocchio(model: RobotModel) -> None:
    pm = pin_model(model)
    for name, kind in zip(model.arm_joints, expected_types(model)):
        assert pm.existJointName(name)
        short = pm.joints[pm.getJointId(name)].shortname()
        assert ("JointModelP" if kind == "prismatic" else "JointModelR") in short, (name, short)
    assert pm.existFrame(model.flange_frame)


def test_ready_pose_and_ratings(model: RobotModel) -> None:
    for q, lim in zip(model.ready_pose, model.hard_limits):
        assert lim.lower < q < lim.upper
    assert all(v > 0 for v in model.rated_speed + model.rated_effort)
    assert model.min_accel_time > 0 and model.min_accel_time_cartesian > 0
    joints = {j.get("name"): j for j in ET.parse(model.urdf).getroot().iter("joint")}
    urdf_speed = [float(joints[j].find("limit").get("velocity")) for j in model.arm_joints]
    assert all(v <= u + 1e-9 for v, u in zip(model.rated_speed, urdf_speed))
    if model.has_gripper:
        g = model.gripper_limits
        assert g is not None and g.lower == 0.0 < g.upper  # 0 closed .. upper open
        assert model.gripper_speed > 0 and model.gripper_effort > 0


def test_manip_info(model: RobotModel) -> None:
    info = model.manip_info
    assert info.axisNum == len(model.arm_joints)
    assert not set(model.gripper_joints) & set(model.arm_joints)
    assert info.isGripper == bool(model.gripper_joints)
    assert info.cmdCycle == model.cmd_cycle_ms == 1
    assert model.dof == info.axisNum + info.isGripper


def test_gripper_flags() -> None:
    assert ROBOTS["cartesian3"].manip_info.isGripper and ROBOTS["panda"].manip_info.isGripper
    assert ROBOTS["cartesian3"].manip_info.axisNum == 3
    assert not any(ROBOTS[n].has_gripper for n in ("cartesian1", "cartesian2", "scara4", "arm5", "arm6"))


@pytest.mark.parametrize("name", [n for n in NAMES if ROBOTS[n].family is Family.CARTESIAN])
def test_gantry_axes_along_base_xyz(name: str) -> None:
    m, s = ROBOTS[name], Sim(ROBOTS[name])
    try:
        s.reset(m.ready_pose)
        p0, r0 = s.link_pose(m.flange_frame)
        for i in range(m.axis_num):
            q = np.array(m.ready_pose)
            q[i] += 0.05
            s.reset(q)
            p1, r1 = s.link_pose(m.flange_frame)
            np.testing.assert_allclose(p1 - p0, 0.05 * np.eye(3)[i], atol=1e-6)  # PyBullet is float32 here
            np.testing.assert_allclose(r1, r0, atol=1e-6)
    finally:
        p.disconnect(s.c)


def test_scara_axes_parallel_to_base_z() -> None:
    m = ROBOTS["scara4"]
    pm = pin_model(m)
    data = pm.createData()
    rng = np.random.default_rng(0)
    poses = [m.ready_pose] + [tuple(rng.uniform(lim.lower, lim.upper) for lim in m.hard_limits)
                              for _ in range(5)]
    for arm_q in poses:
        q = pin_q(pm, m, arm_q)
        pin.computeJointJacobians(pm, data, q)
        for name, prism in zip(m.arm_joints, m.prismatic):
            jid = pm.getJointId(name)
            jac = np.asarray(pin.getJointJacobian(pm, data, jid, pin.LOCAL_WORLD_ALIGNED)).reshape(6, -1)
            col = jac[:, pm.joints[jid].idx_v]  # (linear, angular)
            axis = col[:3] if prism else col[3:]
            np.testing.assert_allclose(axis, [0, 0, 1], atol=1e-9)


@pytest.mark.parametrize("name", [n for n in NAMES if ROBOTS[n].family is not Family.CARTESIAN])
def test_ready_pose_not_singular(name: str) -> None:
    m = ROBOTS[name]
    pm = pin_model(m)
    data = pm.createData()
    q = pin_q(pm, m, m.ready_pose)
    fid = pm.getFrameId(m.flange_frame)
    jac = np.asarray(pin.computeFrameJacobian(pm, data, q, fid, pin.LOCAL_WORLD_ALIGNED)).reshape(6, -1)
    cols = [pm.joints[pm.getJointId(j)].idx_v for j in m.arm_joints]
    if m.family is Family.SCARA:
        jac = jac[[0, 1, 2, 5]]  # x, y, z, rotation about z: the SCARA's task space
    assert np.linalg.svd(jac[:, cols], compute_uv=False).min() > 0.05


def test_holds_ready_pose_under_gravity(model: RobotModel, sim: Sim) -> None:
    sim.reset(model.ready_pose)
    p.setJointMotorControlArray(sim.body, sim.arm, p.POSITION_CONTROL, targetPositions=model.ready_pose,
                                forces=model.rated_effort, physicsClientId=sim.c)
    if model.has_gripper:
        g = [sim.joint[j] for j in model.gripper_joints]
        p.setJointMotorControlArray(sim.body, g, p.POSITION_CONTROL, targetPositions=[0.0] * len(g),
                                    forces=[model.gripper_effort] * len(g), physicsClientId=sim.c)
    worst = 0.0
    for _ in range(1000):
        p.stepSimulation(physicsClientId=sim.c)
        worst = max(worst, float(np.abs(sim.q() - model.ready_pose).max()))
    assert worst < 1e-3


def test_tracks_rated_speed(model: RobotModel, sim: Sim) -> None:
    """Rated efforts suffice to reach rated speed in the min accel time, commanded every 1 ms."""
    q0 = np.array(model.ready_pose)
    v = np.array(model.rated_speed)
    ta = model.min_accel_time
    # head for the farther limit; the accel phase covers v * ta / 2
    sign = np.array([1.0 if lim.upper - q > q - lim.lower else -1.0
                     for q, lim in zip(q0, model.hard_limits)])
    end = q0 + sign * v * ta / 2
    assert all(lim.lower < e < lim.upper for e, lim in zip(end, model.hard_limits))
    sim.reset(q0)
    worst = 0.0
    for k in range(1, round(ta / 1e-3) + 1):
        target = q0 + sign * v * 0.5 * (k * 1e-3) ** 2 / ta
        p.setJointMotorControlArray(sim.body, sim.arm, p.POSITION_CONTROL, targetPositions=target,
                                    forces=model.rated_effort, positionGains=[1.0] * len(sim.arm),
                                    physicsClientId=sim.c)
        p.stepSimulation(physicsClientId=sim.c)
        worst = max(worst, float(np.abs(sim.q() - target).max()))
    assert worst < 1e-3


def test_inertias_physical(model: RobotModel) -> None:
    for link in ET.parse(model.urdf).getroot().iter("link"):
        inertial = link.find("inertial")
        if inertial is None or float(inertial.find("mass").get("value")) == 0.0:
            continue  # massless frame
        a = {k: float(v) for k, v in inertial.find("inertia").attrib.items()}
        tensor = np.array([[a["ixx"], a["ixy"], a["ixz"]],
                           [a["ixy"], a["iyy"], a["iyz"]],
                           [a["ixz"], a["iyz"], a["izz"]]])
        ev = np.sort(np.linalg.eigvalsh(tensor))
        assert ev[0] > 0, link.get("name")
        assert ev[0] + ev[1] >= ev[2] * (1 - 1e-6), link.get("name")  # triangle inequality
    pm = pin_model(model)
    for inertia in pm.inertias[1:]:
        assert inertia.mass > 0 and np.linalg.eigvalsh(inertia.inertia).min() > 0


def test_own_models_have_mass_everywhere(model: RobotModel) -> None:
    if model.manufacturer != "JARA sim":
        pytest.skip("third-party model")
    for link in ET.parse(model.urdf).getroot().iter("link"):
        assert float(link.find("inertial/mass").get("value")) > 0, link.get("name")
        assert link.find("visual") is not None and link.find("collision") is not None
