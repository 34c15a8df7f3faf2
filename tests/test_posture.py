"""Posture bits (``structFlag``, ``kinematics/posture.py``) on arm6, iiwa and panda.

In-process (``MotionPlanner.plan``, ``Kinematics``, ``CartesianFeedback``), except the
``test_live_*`` tests (the whole system from ``jara-arm up``). The postures a sample pose
surely has are built here independently of the planner, from the Euler dualities of a
spherical shoulder, elbow or wrist (``q_j -> -q_j``, its neighbours turned by pi), and
checked by forward kinematics.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np
import pytest

from jara_arm.kinematics import Kinematics, as_se3
from jara_arm.kinematics.posture import ELBOW, POSTURE_SET, SHOULDER, WRIST, Postures, describe
from jara_arm.robots import RobotModel, robot
from jara_arm.schema import wire_types as w
from jara_arm.schema.codes import ReturnCode, StateBit
from jara_arm.schema.operations import OP
from jara_arm.schema.types import CarPosWithElbow, LimitValue, hg_matrix
from jara_arm.services.command.cartesian import CartesianFeedback
from jara_arm.services.planner.planning import MotionPlanner
from jara_arm.services.planner.request import PlanRefused

from .harness import ServoTime, launched
from .support import Client, client_session, motion_settings, plan_request

POSE_TOL = 1e-6  # [m] and [rad]: a PTP's end against its Cartesian target

#: A sample configuration per robot, away from J1 = 0 and with the joints that the dualities
#: turn by pi far enough from 0 for the turned values to stay within the limits.
SAMPLE = {
    "arm6": (0.8, 0.2, 0.2, 0.6, 1.17, 0.4),
    "iiwa": (0.8, 0.5, 0.6, -1.5, 0.5, 1.0, 0.3),
    "panda": (0.8, -0.5, 0.6, -2.0, 0.5, 2.0, 0.3),
}


def _turn(x: float, lo: float, hi: float) -> float:
    return x - math.pi if x - math.pi >= lo else x + math.pi


def _dual(model: RobotModel, q: np.ndarray, j: int) -> np.ndarray:
    """The other Euler solution of the spherical joint group J(j-1), Jj, J(j+1): same pose, same arm angle."""
    out = q.copy()
    lim = model.hard_limits
    out[j] = -out[j]
    out[j - 1] = _turn(out[j - 1], lim[j - 1].lower, lim[j - 1].upper)
    out[j + 1] = _turn(out[j + 1], lim[j + 1].lower, lim[j + 1].upper)
    return out


def known_solutions(model: RobotModel, kin: Kinematics, q: np.ndarray) -> list[np.ndarray]:
    """Configurations with the pose (and arm angle) of ``q``, checked by FK here."""
    groups = {"arm6": [4], "iiwa": [1, 3, 5], "panda": [1]}[model.name]  # spherical groups about these joints
    out = [q]
    for j in groups:
        out += [_dual(model, x, j) for x in out]
    T = kin.fk(q)
    for x in out:
        assert kin.within_limits(x), x
        assert np.abs((kin.fk(x).inverse() * T).homogeneous - np.eye(4)).max() < 1e-9
        if kin.has_elbow:
            assert abs(math.remainder(kin.elbow_angle(x) - kin.elbow_angle(q), math.tau)) < 1e-9
    return out




def carpos(T: np.ndarray, elbow: float = 0.0, flag: int = 0) -> dict:
    return w.CAR_POS_WITH_ELBOW.encode(CarPosWithElbow(T[:3].copy(), elbow, flag))


def wire(model: RobotModel, q: np.ndarray) -> np.ndarray:
    """Wire joints: the arm's, plus an open gripper if fitted."""
    grip = [model.gripper_limits.upper] if model.gripper_limits is not None else []
    return np.array(list(q) + grip)


@dataclasses.dataclass
class Setup:
    model: RobotModel
    planner: MotionPlanner
    postures: Postures

    def plan(self, op: str, args: dict, start: np.ndarray, **changes: Any):
        request = plan_request(op, args, motion_settings(self.model, **changes))
        return self.planner.plan(request, wire(self.model, start))

    def refused(self, op: str, args: dict, start: np.ndarray, **changes: Any) -> PlanRefused:
        with pytest.raises(PlanRefused) as exc:
            self.plan(op, args, start, **changes)
        return exc.value


_SETUPS: dict[str, Setup] = {}


@pytest.fixture(params=["arm6", "iiwa", "panda"])
def arm(request: pytest.FixtureRequest) -> Setup:
    name = request.param
    if name not in _SETUPS:
        model = robot(name)
        planner = MotionPlanner(model)
        _SETUPS[name] = Setup(model, planner, Postures(planner.kin))
    return _SETUPS[name]


def _target(arm: Setup, q: np.ndarray, flag: int = 0) -> dict:
    kin = arm.planner.kin
    return {"carPoint": carpos(kin.fk(q).homogeneous, kin.elbow_angle(q), flag)}


# ---------------------------------------------------------------------------- reading the bits


def test_ready_poses_and_the_bit_rules():
    """The bits per robot as robots/catalog.py documents them, at the ready poses and by hand."""
    expected = {"arm6": 0x100, "iiwa": 0x102, "panda": 0x103}
    for name, flag in expected.items():
        model = robot(name)
        p = Postures(Kinematics(model, seed_table=0))
        assert p.of(model.ready_pose) == flag, (name, describe(p.of(model.ready_pose)))
    iiwa = Postures(Kinematics(robot("iiwa"), seed_table=0))
    assert abs(iiwa.elbow_reference) < 1e-9  # J4 = 0 is the stretched arm
    assert iiwa.of([0.3, -0.2, 0.1, 0.5, 0.1, -0.4, 0.0]) == POSTURE_SET | SHOULDER | WRIST
    arm6 = Postures(Kinematics(robot("arm6"), seed_table=0))
    q = np.array(robot("arm6").ready_pose)
    assert arm6.of(q + [0, 0, 0, 0, -2.0, 0]) == POSTURE_SET | WRIST
    assert arm6.of(q + [math.pi - 0.2, -0.4, 0, 0, 0, 0]) == POSTURE_SET  # J1 turns: the wrist stays in front
    assert arm6.of([0.0, -0.2, -3.1, 0.0, 1.0, 0.0]) == POSTURE_SET | SHOULDER | ELBOW  # leaning back over
    assert describe(0x105) == "0x105 (shoulder back, elbow up, wrist flipped)"


@pytest.mark.parametrize("name", ["arm6", "panda"])
def test_elbow_reference_is_the_stretched_arm(name: str):
    """At the reference the wrist point is farthest from the shoulder point (J2 and J5 / J6 origins)."""
    model = robot(name)
    kin = Kinematics(model, seed_table=0)
    p = Postures(kin)
    s, e, w_ = model.posture_joints

    def reach(angle: float) -> float:
        q = np.zeros(model.axis_num)
        q[e] = angle
        oMi = p._fk(q)
        jid = [kin.pin_model.getJointId(n) for n in model.arm_joints]
        return float(np.linalg.norm(oMi[jid[s]].translation - oMi[jid[w_]].translation))

    r = p.elbow_reference
    assert reach(r) > max(reach(r - 0.05), reach(r + 0.05))


def test_feedback_reports_the_posture():
    for name in ("arm6", "iiwa", "panda"):
        model = robot(name)
        kin = Kinematics(model, seed_table=0)
        fb = CartesianFeedback(model)
        for q in known_solutions(model, kin, np.array(SAMPLE[name])):
            pos = fb.pose(list(q), hg_matrix(), hg_matrix())
            assert pos.structFlag == Postures(kin).of(q) and pos.structFlag & POSTURE_SET
    arm5 = robot("arm5")
    assert CartesianFeedback(arm5).pose(list(arm5.ready_pose), hg_matrix(), hg_matrix()).structFlag == 0


# ---------------------------------------------------------------------------- PTP toward a posture


def test_ptp_reaches_every_posture_of_the_sample_pose(arm: Setup):
    """Each of the 8 flags: reached (pose and posture) or VALUE_ERR naming it; every known one reached."""
    kin = arm.planner.kin
    q = np.array(SAMPLE[arm.model.name])
    known = {arm.postures.of(x) for x in known_solutions(arm.model, kin, q)}
    assert len(known) == {"arm6": 2, "iiwa": 8, "panda": 2}[arm.model.name]
    start = np.array(arm.model.ready_pose)
    T = kin.fk(q)
    reached = set()
    for bits in range(8):
        flag = POSTURE_SET | bits
        try:
            m = arm.plan(OP.movePTPCartesianAbs, _target(arm, q, flag), start)
        except PlanRefused as exc:
            assert exc.code == ReturnCode.VALUE_ERR and describe(flag) in exc.comment, exc.comment
            continue
        end = m.end[:arm.model.axis_num]
        assert arm.postures.of(end) == flag
        assert np.abs((kin.fk(end).inverse() * T).homogeneous - np.eye(4)).max() < POSE_TOL
        if kin.has_elbow:
            assert abs(math.remainder(kin.elbow_angle(end) - kin.elbow_angle(q), math.tau)) < 1e-6
        reached.add(flag)
    assert known <= reached, (sorted(map(hex, known)), sorted(map(hex, reached)))


def test_ptp_posture_with_a_tool_and_relative(arm: Setup):
    """The posture holds with a control point offset, and for a relative target."""
    kin = arm.planner.kin
    q = np.array(SAMPLE[arm.model.name])
    C = np.eye(4)
    C[:3, 3] = (0.0, 0.02, 0.1)
    other = known_solutions(arm.model, kin, q)[1]
    flag = arm.postures.of(other)
    T = kin.control_point(q, as_se3(C[:3])).homogeneous
    m = arm.plan(OP.movePTPCartesianAbs, {"carPoint": carpos(T, kin.elbow_angle(q), flag)}, q,
                 controlPointOffset=C[:3])
    end = m.end[:arm.model.axis_num]
    assert arm.postures.of(end) == flag != arm.postures.of(q)
    assert np.abs(kin.control_point(end, as_se3(C[:3])).homogeneous - T).max() < POSE_TOL
    up = np.eye(4)
    up[2, 3] = 0.02
    rel = arm.plan(OP.movePTPCartesianRel, {"carPoint": carpos(up, 0.0, flag)}, q)
    end = rel.end[:arm.model.axis_num]
    assert arm.postures.of(end) == flag
    assert np.abs(kin.fk(end).translation - (kin.fk(q).translation + [0, 0, 0.02])).max() < POSE_TOL


def test_impossible_posture_is_refused(arm: Setup):
    """The wrist joint's soft limit kept on its unflipped side: no flipped posture exists."""
    q = np.array(SAMPLE[arm.model.name])
    j = arm.model.posture_joints[2]
    limits = list(arm.model.hard_limits)
    limits[j] = LimitValue(upper=min(limits[j].upper, math.pi), lower=0.0)
    flag = arm.postures.of(q) | WRIST
    exc = arm.refused(OP.movePTPCartesianAbs, _target(arm, q, flag), q, softLimitJoint=tuple(limits))
    assert exc.code == ReturnCode.VALUE_ERR and describe(flag) in exc.comment and "no IK solution" in exc.comment


def test_arm6_shoulder_back_straight_ahead_is_refused():
    """With no shoulder offset the wrist centre lies in the arm's plane: behind J1 needs J1 = +-pi, beyond +-2.967."""
    model = robot("arm6")
    planner = MotionPlanner(model)
    q = np.array([0.0, 0.2, 0.2, 0.6, 1.17, 0.4])
    args = {"carPoint": carpos(planner.kin.fk(q).homogeneous, 0.0, POSTURE_SET | SHOULDER | ELBOW)}
    with pytest.raises(PlanRefused) as exc:
        planner.plan(plan_request(OP.movePTPCartesianAbs, args, motion_settings(model)), q)
    assert exc.value.code == ReturnCode.VALUE_ERR and "0x103 (shoulder back, elbow down" in exc.value.comment


def test_struct_flag_zero_is_the_nearest_solution(arm: Setup):
    """Unchanged: the IK solution from the start joints, which keeps the start's posture nearby."""
    kin = arm.planner.kin
    q = np.array(SAMPLE[arm.model.name])
    for start in known_solutions(arm.model, kin, q):
        near = start + 0.05
        m = arm.plan(OP.movePTPCartesianAbs, _target(arm, q, 0), near)
        end = m.end[:arm.model.axis_num]
        assert np.abs(end - start).max() < 1e-5, (start, end)


def test_malformed_flags_and_robots_without_posture_bits():
    iiwa = robot("iiwa")
    planner = MotionPlanner(iiwa)
    q = np.array(SAMPLE["iiwa"])
    for flag in (0x1, 0x108, 0x300):
        with pytest.raises(PlanRefused) as exc:
            planner.plan(plan_request(OP.movePTPCartesianAbs, {"carPoint": carpos(planner.kin.fk(q).homogeneous,
                                                                                  0.0, flag)},
                                      motion_settings(iiwa)), q)
        assert exc.value.code == ReturnCode.VALUE_ERR and "structFlag" in exc.value.comment
    for name in ("arm5", "scara4"):
        model = robot(name)
        p = MotionPlanner(model)
        T = p.kin.fk(model.ready_pose).homogeneous
        with pytest.raises(PlanRefused) as exc:
            p.plan(plan_request(OP.movePTPCartesianAbs, {"carPoint": carpos(T, 0.0, POSTURE_SET)},
                                motion_settings(model)), np.array(model.ready_pose))
        assert exc.value.code == ReturnCode.VALUE_ERR and "defines no posture flags" in exc.value.comment


# ---------------------------------------------------------------------------- LIN / CIRC keep the posture


def test_lin_and_circ_keep_the_posture(arm: Setup):
    kin = arm.planner.kin
    q = np.array(SAMPLE[arm.model.name])
    own = arm.postures.of(q)
    T = kin.fk(q).homogeneous
    T1 = T.copy()
    T1[:3, 3] += (0.0, 0.03, -0.03)
    e = kin.elbow_angle(q)
    same = arm.plan(OP.moveLinearCartesianAbs, {"carPoint": carpos(T1, e, own)}, q)
    assert arm.postures.of(same.end[:arm.model.axis_num]) == own
    assert np.abs(kin.fk(same.end[:arm.model.axis_num]).homogeneous - T1).max() < POSE_TOL
    for flag in (own ^ WRIST, own ^ SHOULDER):
        exc = arm.refused(OP.moveLinearCartesianAbs, {"carPoint": carpos(T1, e, flag)}, q)
        assert exc.code == ReturnCode.VALUE_ERR and "a posture change needs a PTP" in exc.comment, exc.comment
        assert describe(flag) in exc.comment and describe(own) in exc.comment
    Tv = T.copy()
    Tv[:3, 3] += (0.0, 0.02, -0.01)
    circ = {"carPointR": carpos(Tv, e), "carPointT": carpos(T1, e, own ^ WRIST)}
    exc = arm.refused(OP.moveCircularCartesianAbs, circ, q)
    assert exc.code == ReturnCode.VALUE_ERR and "a posture change needs a PTP" in exc.comment
    circ["carPointT"] = carpos(T1, e, own)
    ok = arm.plan(OP.moveCircularCartesianAbs, circ, q)
    assert arm.postures.of(ok.end[:arm.model.axis_num]) == own


# ---------------------------------------------------------------------------- live


def test_live_posture_reached_reported_and_lin_across_refused():
    """The whole system on the iiwa: a PTP to the sample pose in another posture gets there and
    getFeedbackPosCartesian reports that posture; a LIN asking for the start's old posture is refused
    and the arm does not move."""
    model = robot("iiwa")
    kin = Kinematics(model, seed_table=0)
    postures = Postures(kin)
    q = np.array(SAMPLE["iiwa"])
    other = known_solutions(model, kin, q)[-1]  # every bit of the sample pose flipped
    flag = postures.of(other)
    with launched("--robot", "iiwa") as (_proc, port), client_session(port) as session:
        client = Client(session)
        servo = ServoTime(session, client.keys)
        assert client.common(OP.servoON).id == ReturnCode.OK
        assert client.middle(OP.setSpeedJoint, {"spdRatio": 100}).id == ReturnCode.OK
        assert client.middle(OP.setSpeedCartesian, {"spdRatio": 100}).id == ReturnCode.OK
        assert client.middle(OP.movePTPJointAbs, {"jointPoints": tuple(q)}).id == ReturnCode.OK
        client.wait_idle(60.0)
        assert client.middle(OP.getFeedbackPosCartesian)["pos"].structFlag == postures.of(q)
        T = kin.fk(q).homogeneous
        target = CarPosWithElbow(T[:3].copy(), kin.elbow_angle(q), flag)
        reply = client.middle(OP.movePTPCartesianAbs, {"carPoint": target})
        assert reply.id == ReturnCode.OK, reply
        client.wait_idle(60.0)
        reached = np.asarray(client.common(OP.getFeedbackPosJoint)["pos"])
        assert postures.of(reached) == flag
        pos = client.middle(OP.getFeedbackPosCartesian)["pos"]
        assert pos.structFlag == flag
        assert np.abs(np.asarray(pos.carPos) - T[:3]).max() < 1e-3
        before = servo.settled()
        T1 = T.copy()
        T1[2, 3] -= 0.05
        back = CarPosWithElbow(T1[:3].copy(), kin.elbow_angle(q), postures.of(q))
        reply = client.middle(OP.moveLinearCartesianAbs, {"carPoint": back})
        assert reply.id == ReturnCode.VALUE_ERR and "a posture change needs a PTP" in reply.comment, reply
        servo.passes(0.3)
        after = servo.sample()[1]
        assert np.abs(after - before).max() < 1e-6, (before, after)
        assert not client.state & StateBit.MOVING
