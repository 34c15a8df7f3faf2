"""The planner's planning in-process, no process: the frames of the base and control point offsets, a LIN
slowed down for the joint speed limits, each family's rules for Cartesian motions, and a planning method
per motion operation."""

from __future__ import annotations

import inspect

import numpy as np
import pytest

from jara_arm.kinematics import as_se3
from jara_arm.robots import RobotModel, robot
from jara_arm.schema.codes import ReturnCode
from jara_arm.schema.operations import OP
from jara_arm.services.planner.planning import MotionPlanner
from jara_arm.services.planner.request import PlanRefused

from .support import car, motion_settings, plan_request, pose, rot_z, segment_distance

DT = 1e-3
PLANNED_TOL = 1e-6  # [m] planned path (FK of the samples) vs the ideal path


def _start(model: RobotModel) -> np.ndarray:
    grip = [model.gripper_limits.upper] if model.has_gripper else []
    return np.array(list(model.ready_pose) + grip)


def test_frames_base_offset_and_control_point_offset():
    """Commands are in the robot frame (T_arm = B · T_robot); the controlled pose is T_flange · C."""
    model = robot("iiwa")
    planner = MotionPlanner(model)
    B = pose([0.3, -0.2, 0.1], rot_z(0.5))  # robot frame seen from the arm frame
    C = pose([0.0, 0.0, 0.12])  # a 12 cm tool
    s = motion_settings(model, baseOffset=B[:3], controlPointOffset=C[:3])
    q0 = _start(model)
    T0 = np.linalg.inv(B) @ planner.kin.control_point(q0, as_se3(C)).homogeneous  # start, robot frame
    T1 = pose(T0[:3, 3] + [0.05, 0.1, -0.05], T0[:3, :3])
    m = planner.plan(plan_request(OP.moveLinearCartesianAbs, {"carPoint": car(T1)}, s), q0)
    pts = np.array([(np.linalg.inv(B) @ planner.kin.control_point(q, as_se3(C)).homogeneous)[:3, 3] for q in m.q])
    assert segment_distance(pts, T0[:3, 3], T1[:3, 3]).max() < PLANNED_TOL
    end = np.linalg.inv(B) @ planner.kin.control_point(m.end, as_se3(C)).homogeneous
    assert np.abs(end - T1).max() < 1e-6
    up_and_turn = {"carPoint": car(pose([0, 0, 0.05], rot_z(0.2)))}
    rel = planner.plan(plan_request(OP.movePTPCartesianRel, up_and_turn, s), m.end)
    end2 = np.linalg.inv(B) @ planner.kin.control_point(rel.end, as_se3(C)).homogeneous
    assert np.abs(end2[:3, 3] - (T1[:3, 3] + [0, 0, 0.05])).max() < 1e-6  # added in the robot frame
    assert np.abs(end2[:3, :3] - rot_z(0.2) @ T1[:3, :3]).max() < 1e-6  # R_rel · R_start


def test_lin_is_slowed_down_for_the_joint_speed_limits():
    model = robot("iiwa")
    planner = MotionPlanner(model)
    q0 = _start(model)
    T0 = planner.kin.control_point(q0).homogeneous
    args = {"carPoint": car(pose(T0[:3, 3] + [0.0, 0.2, 0.0], T0[:3, :3]))}
    fast = planner.plan(plan_request(OP.moveLinearCartesianAbs, args, motion_settings(model)), q0)
    vmax = np.full(7, 0.2)  # [rad/s]
    slow = planner.plan(plan_request(OP.moveLinearCartesianAbs, args,
                                     motion_settings(model, maxSpeedJoint=tuple(vmax))), q0)
    assert slow.duration > fast.duration
    assert (np.abs(np.diff(slow.q, axis=0)) / DT).max(axis=0).max() <= 0.2 * (1 + 1e-9)
    with pytest.raises(PlanRefused) as refused:
        planner.plan(plan_request(OP.moveLinearCartesianAbs, args,
                                  motion_settings(model, maxSpeedJoint=(1e-4,) * 7)), q0)
    assert refused.value.code == ReturnCode.VALUE_ERR and "lowest speed" in refused.value.comment


@pytest.mark.parametrize("name, op, code", [
    ("cartesian1", OP.moveLinearCartesianRel, ReturnCode.NG),
    ("cartesian1", OP.moveCircularCartesianRel, ReturnCode.NG),
    ("cartesian2", OP.movePTPCartesianRel, ReturnCode.NG),
    ("cartesian2", OP.moveCircularCartesianRel, ReturnCode.OK),
    ("cartesian3", OP.moveLinearCartesianRel, ReturnCode.NG),
    ("cartesian3", OP.moveCircularCartesianRel, ReturnCode.OK),
    ("scara4", OP.moveLinearCartesianRel, ReturnCode.OK),
    ("scara4", OP.moveCircularCartesianRel, ReturnCode.OK),
    ("arm5", OP.moveLinearCartesianRel, ReturnCode.OK),
    ("arm6", OP.moveCircularCartesianRel, ReturnCode.OK),
])
def test_family_rules(name: str, op: str, code: ReturnCode):
    """SPEC.md §7: gantries refuse LIN / PTP-Cartesian; rotations the family cannot do are ignored."""
    model = robot(name)
    planner = MotionPlanner(model)
    tilt = np.array([[1.0, 0.0, 0.0], [0.0, np.cos(0.3), -np.sin(0.3)], [0.0, np.sin(0.3), np.cos(0.3)]])
    if op == OP.moveCircularCartesianRel:
        args = {"carPointR": car(pose([0.03, 0.03, 0.01], tilt)),
                "carPointT": car(pose([0.0, 0.06, 0.02], tilt))}
    else:
        args = {"carPoint": car(pose([0.0, 0.05, -0.02], rot_z(0.2) @ tilt))}
    q0 = _start(model)
    try:
        m = planner.plan(plan_request(op, args, motion_settings(model)), q0)
    except PlanRefused as exc:
        assert exc.code == code and code == ReturnCode.NG and "Cartesian robot cannot" in exc.comment
        return
    assert code == ReturnCode.OK
    T0 = planner.kin.control_point(q0[:model.axis_num]).homogeneous
    T1 = planner.kin.control_point(m.end[:model.axis_num]).homogeneous
    target = np.array(args["carPointT" if "carPointT" in args else "carPoint"]["carPos"])[:, 3]
    if name == "cartesian2":
        target[2] = 0.0  # J1 = X, J2 = Y: Z ignored
    assert np.abs(T1[:3, 3] - (T0[:3, 3] + target)).max() < 1e-5
    if name.startswith("cartesian"):
        assert np.abs(T1[:3, :3] - T0[:3, :3]).max() < 1e-9  # every rotation ignored
    if name == "scara4":  # only the rotation about Z counts (the CIRC target has none)
        yaw = 0.0 if op == OP.moveCircularCartesianRel else 0.2
        assert np.abs(T1[:3, :3] - rot_z(yaw) @ T0[:3, :3]).max() < 1e-5


def test_the_planner_has_a_method_per_motion_operation():
    """``MotionPlanner.plan`` calls the method named after the IDL operation: one for every motion."""
    from jara_arm.schema.operations import MIDDLE
    from jara_arm.services.planner.planning import MotionPlanner

    motions = sorted(op.name for op in MIDDLE.values() if op.motion)
    assert len(motions) == 12
    for name in motions:
        params = list(inspect.signature(getattr(MotionPlanner, name)).parameters)
        assert params == ["self", "req", "start", *(p.name for p in MIDDLE[name].inputs)], name
