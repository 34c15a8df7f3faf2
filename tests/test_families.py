"""Every robot family, black box: the whole system from `jara-arm up --robot NAME`.

One system per family per module (8 starts). What is checked is SPEC.md §7
"Per-family rules for Cartesian commands" and issue 5: getManipInfo, PTP joint,
soft limits, home, each Cartesian command accepted or refused (NG) per the
table, the components the table ignores really ignored, 2-axis CIRC in the X-Y
plane of the arm frame, per-family Cartesian feedback, the 7-axis elbow (arm
angle) reached, interpolated and reported, and the gripper where there is one.
The expectations are written from the specification, not read from
``families.TABLE``.
"""

from __future__ import annotations

import time

import numpy as np
import pinocchio as pin
import pytest

from jara_arm.schema.codes import ReturnCode, StateBit
from jara_arm.schema.operations import OP
from jara_arm.schema.types import CarPosWithElbow, LimitValue, hg_matrix

from .harness import RecordingArm

pytestmark = pytest.mark.timeout(240)

NAMES = ("cartesian1", "cartesian2", "cartesian3", "scara4", "arm5", "arm6", "iiwa", "panda")
#: SPEC.md §7 table: (LIN / PTP-Cartesian accepted, CIRC accepted).
ACCEPTS = {"cartesian1": (False, False), "cartesian2": (False, True), "cartesian3": (False, True),
           "scara4": (True, True), "arm5": (True, True), "arm6": (True, True),
           "iiwa": (True, True), "panda": (True, True)}
SEVEN = ("iiwa", "panda")
TOL_POS = 1e-4  # [m] reached position (feedback, settled), 1-6 axes
TOL_ROT = 1e-3  # [rad]
TOL_POSE_7 = 1e-5  # [m, rad] 7-axis pose (issue 5)
TOL_ELBOW = 1e-3  # [rad]
#: [s] observation window, of the servo's own time (harness.ServoTime): after a refusal was
#: answered, nothing may move in it.
QUIET_WINDOW = 0.1


def rot(axis, angle: float) -> np.ndarray:
    a = np.asarray(axis, dtype=float)
    return pin.exp3(a / np.linalg.norm(a) * angle)


def car(T: np.ndarray, elbow: float = 0.0) -> CarPosWithElbow:
    return CarPosWithElbow(hg_matrix(T[:3, :3], T[:3, 3]), float(elbow), 0)


def rel(d=(0.0, 0.0, 0.0), R: np.ndarray | None = None, elbow: float = 0.0) -> CarPosWithElbow:
    return CarPosWithElbow(hg_matrix(R, tuple(d)), float(elbow), 0)


def moved(T: np.ndarray, d=(0.0, 0.0, 0.0), R: np.ndarray | None = None) -> np.ndarray:
    """``T`` moved by ``d`` [m] and turned by ``R`` (robot frame axes)."""
    out = T.copy()
    out[:3, 3] += d
    if R is not None:
        out[:3, :3] = R @ T[:3, :3]
    return out


def rot_err(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.linalg.norm(pin.log3(a[:3, :3] @ b[:3, :3].T)))


class Arm(RecordingArm):
    """conftest's ``live`` client of one family: a ``RecordingArm`` whose motions run to their end, settled,
    home included."""

    def moving_time(self, name, args) -> float:
        """[s] of the servo's own time the arm moved in motion ``name`` (from leaving where it was to
        arriving): the motion itself, not the calls around it, which a busy machine stretches."""
        self.record()
        self.run(name, args)
        tm, q = self.recorded_timed()
        left = np.flatnonzero(np.abs(q - q[0]).max(axis=1) > 1e-5)
        arrived = np.flatnonzero(np.abs(q - q[-1]).max(axis=1) > 1e-5)
        assert left.size and arrived.size, "the arm did not move"
        return float(tm[arrived[-1]] - tm[left[0]])

    def run(self, name, args) -> None:
        """A motion that must be accepted; returns once the arm is idle and settled."""
        mark = len(self.proc.lines) if self.proc else 0
        self.ok(self.middle(name, args))
        self.client.wait_idle(60.0)
        self.settle()
        state = self.client.state
        assert not state & StateBit.ALARM, f"{name}: alarm (state 0x{state:02x})\n" + self.log()
        aborted = [ln for ln in (self.proc.lines[mark:] if self.proc else []) if "abort (" in ln or "ran dry" in ln]
        assert not aborted, f"{name}: the system aborted the motion (streaming, not a family rule):\n" + \
            "\n".join(aborted)

    def log(self, lines: int = 15) -> str:
        """The last lines of the system's log that say why a motion ended early."""
        return self.log_tail(lines, keys=("WARNING", "ERROR", "alarm", "abort", "refused", "servo o"))

    def settle(self, tol: float = 1e-7, timeout: float = 2.0) -> None:
        """Until the joint feedback stops changing (the servo has caught up with the last command), read every
        10 ms: it follows every motion of the module, and with reads 50 ms apart the module took 106.0 s alone
        against 99.1 s (2026-12-02)."""
        deadline = time.monotonic() + timeout
        last = self.joints()
        while time.monotonic() < deadline:
            time.sleep(0.01)
            q = self.joints()
            if np.abs(q - last).max() < tol:
                return
            last = q

    def home(self) -> None:
        self.run(OP.goHome, None)


@pytest.fixture(scope="module", params=NAMES)
def robot_name(request) -> str:
    """The robots of ``live`` and ``arm`` (conftest.py): one system each, with this module's ``Arm``."""
    return request.param


def only(*names: str):
    def check(arm: Arm) -> None:
        if arm.model.name not in names:
            pytest.skip(f"{arm.model.name}: not one of {names}")
    return check


# ---------------------------------------------------------------------- every family


def test_manip_info(arm: Arm):
    info = arm.common(OP.getManipInfo)["mInfo"]
    expected_axes = {"cartesian1": 1, "cartesian2": 2, "cartesian3": 3, "scara4": 4, "arm5": 5,
                     "arm6": 6, "iiwa": 7, "panda": 7}[arm.model.name]
    assert info.axisNum == expected_axes  # without the gripper
    assert info.isGripper == (arm.model.name in ("cartesian3", "panda"))
    assert info.manufactur == arm.model.manufacturer and info.type == arm.model.type
    assert len(arm.joints()) == expected_axes + (1 if info.isGripper else 0)


def test_ptp_joint_home_and_soft_limits(arm: Arm):
    n, q0 = arm.n, arm.joints()[: arm.n]
    assert np.abs(q0 - arm.model.ready_pose).max() < 1e-4  # goHome went to the ready pose
    lo = np.array([lim.lower for lim in arm.model.hard_limits])
    hi = np.array([lim.upper for lim in arm.model.hard_limits])
    delta = np.where(hi - q0 > q0 - lo, 1.0, -1.0) * np.minimum(0.1, 0.3 * (hi - lo))
    fast = arm.moving_time(OP.movePTPJointRel, {"jointPoints": tuple(delta)})
    assert np.abs(arm.joints()[:n] - (q0 + delta)).max() < 1e-4
    # The same move back at a tenth of the speed takes far longer (speeds work the same everywhere),
    # in the servo's time: wall time adds the calls, which a busy machine stretches (a fresh-clone CI
    # run beside two busy loops: 0.95 s against 0.83 s for cartesian2).
    arm.ok(arm.middle(OP.setSpeedJoint, {"spdRatio": 10}))
    slow = arm.moving_time(OP.movePTPJointAbs, {"jointPoints": tuple(q0)})
    arm.ok(arm.middle(OP.setSpeedJoint, {"spdRatio": 100}))
    assert slow > 1.5 * fast, (slow, fast)
    assert np.abs(arm.joints()[:n] - q0).max() < 1e-4
    # A soft limit that excludes the target refuses it and nothing moves.
    soft = [LimitValue(h, lo_) for lo_, h in zip(lo, hi)]
    soft[0] = LimitValue(q0[0] + 0.01, q0[0] - 0.01)
    arm.ok(arm.common(OP.setSoftLimitJoint, {"softLimit": tuple(soft)}))
    step = np.zeros(n)
    step[0] = 0.05
    assert arm.middle(OP.movePTPJointRel, {"jointPoints": tuple(step)}).id == ReturnCode.VALUE_ERR
    assert np.abs(arm.joints()[:n] - q0).max() < 1e-4
    # Wrong axis count: the gripper is not a joint point.
    assert arm.middle(OP.movePTPJointAbs, {"jointPoints": tuple(q0) + (0.0,)}).id != ReturnCode.OK


def _targets(arm: Arm) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Start pose (robot frame = arm frame here), a LIN target and CIRC via/target, all reachable."""
    T0 = arm.pose()
    z = 0.0 if arm.n == 2 else 0.01
    if arm.n == 5:  # stay in the arm's vertical plane (ready pose: J1 = 0), where the start orientation is reachable
        return T0, moved(T0, (0.03, 0.0, z)), moved(T0, (0.02, 0.0, 0.02)), moved(T0, (0.04, 0.0, 0.0))
    T1 = moved(T0, (0.03, -0.02, z))
    via = moved(T0, (0.02, 0.02, z))
    tgt = moved(T0, (0.04, 0.0, 0.0))
    return T0, T1, via, tgt


@pytest.mark.parametrize("op", [OP.moveLinearCartesianAbs, OP.movePTPCartesianAbs,
                                OP.moveLinearCartesianRel, OP.movePTPCartesianRel,
                                OP.moveCircularCartesianAbs, OP.moveCircularCartesianRel])
def test_cartesian_command_accepted_or_refused_per_table(arm: Arm, op: str):
    circ = "Circular" in op
    accepted = ACCEPTS[arm.model.name][1 if circ else 0]
    T0, T1, via, tgt = _targets(arm)
    relative = op.endswith("Rel")
    q0 = arm.joints()
    if circ:
        args = ({"carPointR": rel(via[:3, 3] - T0[:3, 3]), "carPointT": rel(tgt[:3, 3] - T0[:3, 3])}
                if relative else {"carPointR": car(via), "carPointT": car(tgt)})
        goal = tgt
    else:
        args = {"carPoint": rel(T1[:3, 3] - T0[:3, 3]) if relative else car(T1)}
        goal = T1
    mark = len(arm.proc.lines)
    reply = arm.middle(op, args)
    if not accepted:
        assert reply.id == ReturnCode.NG, reply
        arm.servo_time.passes(QUIET_WINDOW)  # a motion queued all the same would move the arm in it
        assert np.abs(arm.joints() - q0).max() < 1e-6  # nothing moved
        return
    assert reply.id == ReturnCode.OK, f"{reply}\n{arm.log()}"
    arm.client.wait_idle(60.0)
    arm.settle()
    aborted = [ln for ln in arm.proc.lines[mark:] if "abort (" in ln or "ran dry" in ln]
    assert not aborted, "the system aborted the motion (streaming, not a family rule):\n" + "\n".join(aborted)
    T = arm.pose()
    assert np.linalg.norm(T[:3, 3] - goal[:3, 3]) < TOL_POS, (T[:3, 3], goal[:3, 3], arm.log())
    assert rot_err(T, T0) < TOL_ROT  # the orientation was commanded unchanged


def test_ignored_components_are_ignored(arm: Arm):
    """Two targets that differ only in what the table ignores reach the same joints."""
    name = arm.model.name
    if name == "cartesian1":
        pytest.skip("every Cartesian command is refused")
    T0 = arm.pose()
    tilt = rot((1.0, -0.5, 0.2), 0.3)
    if name in ("cartesian2", "cartesian3"):  # CIRC: every rotation (and for 2 axes Z) ignored
        via, tgt = moved(T0, (0.02, 0.02, 0.0)), moved(T0, (0.04, 0.0, 0.0))
        dz = 0.05 if name == "cartesian2" else 0.0
        plain = (OP.moveCircularCartesianAbs, {"carPointR": car(via), "carPointT": car(tgt)})
        other = (OP.moveCircularCartesianAbs, {"carPointR": car(moved(via, (0, 0, -dz), tilt), 0.7),
                                               "carPointT": car(moved(tgt, (0, 0, dz), tilt.T), -0.4)})
    elif name == "scara4":  # rotation about X and Y ignored; about Z used
        yaw = rot((0, 0, 1), 0.2)
        T1 = moved(T0, (0.03, -0.02, 0.01), yaw)
        plain = (OP.moveLinearCartesianAbs, {"carPoint": car(T1)})
        # A rotation about a horizontal axis (any axis other than Z) on top: ignored.
        other = (OP.moveLinearCartesianAbs, {"carPoint": car(moved(T1, R=rot((1.0, 0.6, 0.0), 0.3)), 0.5)})
    elif name == "arm5":  # rotation about the arm-plane X axis (in the plane, across the approach) ignored
        p1 = T0[:3, 3] * [0.95, 0.95, 1.0] + [0.0, 0.0, 0.02]  # same azimuth: same arm plane
        n = np.cross([0.0, 0.0, 1.0], p1)
        n /= np.linalg.norm(n)
        x_p = np.cross(n, T0[:3, 2])  # approach = flange z
        T1 = moved(T0, p1 - T0[:3, 3])
        plain = (OP.moveLinearCartesianAbs, {"carPoint": car(T1)})
        other = (OP.moveLinearCartesianAbs, {"carPoint": car(moved(T1, R=rot(x_p, 0.25)), 0.5)})
    else:  # 6 and 7 axes: the full pose counts; 6 axes ignore the elbow
        T1 = moved(T0, (0.03, -0.02, 0.01), rot((0, 0, 1), 0.1))
        if name != "arm6":
            pytest.skip("7 axes use every component (see the elbow tests)")
        plain = (OP.moveLinearCartesianAbs, {"carPoint": car(T1, 0.0)})
        other = (OP.moveLinearCartesianAbs, {"carPoint": car(T1, 1.2)})
    arm.run(*plain)
    q_plain = arm.joints()
    T_plain = arm.pose()
    arm.home()
    arm.run(*other)
    assert np.abs(arm.joints() - q_plain).max() < 1e-4
    T = arm.pose()
    assert np.linalg.norm(T[:3, 3] - T_plain[:3, 3]) < TOL_POS and rot_err(T, T_plain) < TOL_ROT
    if name == "scara4":  # the rotation about Z was used
        assert abs(rot_err(T, T0) - 0.2) < TOL_ROT
        assert np.linalg.norm(T[:3, 3] - T1[:3, 3]) < TOL_POS
    if name == "arm5":  # the pose reached is the one asked without the ignored rotation
        assert np.linalg.norm(T[:3, 3] - T1[:3, 3]) < TOL_POS and rot_err(T, T0) < TOL_ROT
        # Sideways (the arm plane turns): the start orientation's approach axis is tilted into
        # the new plane by the least rotation; the position is reached exactly.
        arm.home()
        p2 = T0[:3, 3] + (0.0, 0.06, 0.0)
        arm.run(OP.moveLinearCartesianAbs, {"carPoint": car(moved(T0, p2 - T0[:3, 3]))})
        T = arm.pose()
        n2 = np.cross([0.0, 0.0, 1.0], p2)
        n2 /= np.linalg.norm(n2)
        a0 = T0[:3, 2]
        a_exp = a0 - (a0 @ n2) * n2
        assert np.linalg.norm(T[:3, 3] - p2) < TOL_POS
        assert np.linalg.norm(T[:3, 2] - a_exp / np.linalg.norm(a_exp)) < TOL_ROT
        assert abs(rot_err(T, T0) - np.arcsin(abs(a0 @ n2))) < TOL_ROT  # the least rotation


def test_cartesian_feedback_per_family(arm: Arm):
    name, n = arm.model.name, arm.n
    q = arm.joints()
    fb0 = arm.cartesian()
    T0 = arm.pose()
    if n < 7:
        assert fb0.elbow == 0.0
    step = np.full(n, 0.05)
    arm.run(OP.movePTPJointRel, {"jointPoints": tuple(step)})
    fb = arm.cartesian()
    T = arm.pose()
    q = arm.joints()
    if name == "cartesian1":  # reports its X
        assert abs(T[0, 3] - T0[0, 3] - 0.05) < 1e-5
        assert np.abs(T[1:3, 3] - T0[1:3, 3]).max() < 1e-9 and rot_err(T, T0) < 1e-9
    elif name == "cartesian2":  # X = J1, Y = J2 (+ constant offsets)
        assert np.abs(T[:2, 3] - T0[:2, 3] - 0.05).max() < 1e-5
        assert abs(T[2, 3] - T0[2, 3]) < 1e-9 and rot_err(T, T0) < 1e-9
    elif name == "cartesian3":
        assert np.abs(T[:3, 3] - T0[:3, 3] - 0.05).max() < 1e-5 and rot_err(T, T0) < 1e-9
    elif name == "scara4":  # rotation about Z only: Rz(J1 + J2 + J4)
        yaw = q[0] + q[1] + q[3]
        assert np.abs(T[:3, :3] - rot((0, 0, 1), yaw)).max() < 1e-6
    else:
        assert np.abs(T - arm.fk(q)).max() < 1e-6
    if n == 7:
        assert abs(fb.elbow - arm.kin.elbow_angle(q[:7])) < 1e-6
    else:
        assert fb.elbow == 0.0


def test_two_axis_circ_is_in_the_xy_plane_of_the_arm_frame(arm: Arm):
    only("cartesian2")(arm)
    p0 = arm.fk()[:3, 3]  # arm frame
    B = np.eye(4)
    B[:3, :3] = rot((0.2, 0.1, 1.0), 0.4)
    B[:3, 3] = (0.3, -0.2, 0.5)
    arm.ok(arm.middle(OP.setBaseOffset, {"offset": hg_matrix(B[:3, :3], B[:3, 3])}))
    via, tgt = np.eye(4), np.eye(4)
    via[:3, 3] = p0 + (0.1, 0.1, 0.3)  # Z ignored
    tgt[:3, 3] = p0 + (0.2, 0.0, -0.2)
    arm.record()
    arm.run(OP.moveCircularCartesianAbs, {"carPointR": car(via), "carPointT": car(tgt)})
    p = arm.fk()[:3, 3]
    assert np.abs(p[:2] - tgt[:2, 3]).max() < TOL_POS and abs(p[2] - p0[2]) < 1e-9
    pts = np.array([arm.fk(qi)[:3, 3] for qi in arm.recorded()])
    c, r = np.array([p0[0] + 0.1, p0[1]]), 0.1  # circle through (0,0), (0.1,0.1), (0.2,0)
    assert np.abs(np.linalg.norm(pts[:, :2] - c, axis=1) - r).max() < 0.5e-3
    assert np.max(pts[:, 1] - p0[1]) > 0.1 - 0.5e-3  # passed the via point's side
    # The feedback is in the robot frame: inv(B) · T_arm.
    assert np.abs(arm.pose() - np.linalg.inv(B) @ arm.fk()).max() < 1e-6


def test_gripper(arm: Arm):
    lim = arm.model.gripper_limits
    if lim is None:
        for op, args in ((OP.closeGripper, None), (OP.openGripper, None), (OP.moveGripper, {"angleRatio": 50})):
            assert arm.middle(op, args).id == ReturnCode.NG
        return
    q_arm = arm.joints()[: arm.n]
    arm.run(OP.closeGripper, None)
    assert abs(arm.joints()[arm.n] - lim.lower) < 2e-3
    arm.run(OP.moveGripper, {"angleRatio": 50})
    assert abs(arm.joints()[arm.n] - (lim.lower + lim.upper) / 2) < 2e-3
    arm.run(OP.openGripper, None)
    assert abs(arm.joints()[arm.n] - lim.upper) < 2e-3
    assert np.abs(arm.joints()[: arm.n] - q_arm).max() < 1e-4  # the arm held


# ---------------------------------------------------------------------- 7-axis elbow


def _elbow_check(arm: Arm, goal: np.ndarray, elbow: float) -> None:
    fb = arm.cartesian()
    T = arm.pose()
    assert abs(fb.elbow - elbow) < TOL_ELBOW, (fb.elbow, elbow)
    assert abs(arm.kin.elbow_angle(arm.joints()[:7]) - fb.elbow) < 1e-9  # reports the measured one
    assert np.linalg.norm(T[:3, 3] - goal[:3, 3]) < TOL_POSE_7, np.linalg.norm(T[:3, 3] - goal[:3, 3])
    assert rot_err(T, goal) < TOL_POSE_7, rot_err(T, goal)


@pytest.mark.parametrize("op", [OP.moveLinearCartesianAbs, OP.movePTPCartesianAbs, OP.moveLinearCartesianRel])
def test_elbow_reached_and_interpolated(arm: Arm, op: str):
    only(*SEVEN)(arm)
    T0 = arm.pose()
    e0 = arm.cartesian().elbow
    d, R = np.array([0.04, 0.05, -0.03]), rot((0.3, 1.0, 0.2), 0.15)
    goal = moved(T0, d, R)
    e1 = e0 + 0.4
    args = {"carPoint": rel(d, R, 0.4)} if op.endswith("Rel") else {"carPoint": car(goal, e1)}
    arm.record()
    arm.run(op, args)
    _elbow_check(arm, goal, e1)
    if op.startswith("moveLinear"):  # the arm angle moves with the path: e0 + s (e1 - e0)
        q = arm.recorded()[:, :7]
        s = np.array([(arm.fk(qi)[:3, 3] - T0[:3, 3]) @ d / (d @ d) for qi in q])
        e = np.array([arm.kin.elbow_angle(qi) for qi in q])
        assert np.abs(e - (e0 + s * (e1 - e0))).max() < 0.01


def test_elbow_on_circ(arm: Arm):
    only(*SEVEN)(arm)
    T0 = arm.pose()
    e0 = arm.cartesian().elbow
    via, goal = moved(T0, (0.04, 0.04, 0.0)), moved(T0, (0.08, 0.0, -0.02), rot((0, 0, 1), 0.2))
    e1 = e0 - 0.35
    arm.record()
    arm.run(OP.moveCircularCartesianAbs, {"carPointR": car(via, 3.0), "carPointT": car(goal, e1)})
    _elbow_check(arm, goal, e1)
    e = np.array([arm.kin.elbow_angle(qi) for qi in arm.recorded()[:, :7]])
    assert e.min() > e1 - 0.005 and e.max() < e0 + 0.005  # between the start's and the target's
    assert np.all(np.diff(e) < 1e-4)  # monotonic: interpolated, not swinging


def test_elbow_ignored_below_seven_axes_and_used_on_seven(arm: Arm):
    """The same pose with two elbows: the same joints on 1-6 axes, two postures on 7."""
    if not ACCEPTS[arm.model.name][0]:
        pytest.skip("no LIN on this family")
    T1 = moved(arm.pose(), (0.02, 0.0, 0.01))
    e = arm.cartesian().elbow if arm.n == 7 else 0.0
    arm.run(OP.movePTPCartesianAbs, {"carPoint": car(T1, e)})
    qa = arm.joints()
    arm.home()
    arm.run(OP.movePTPCartesianAbs, {"carPoint": car(T1, e + 0.5)})
    if arm.n == 7:
        assert abs(arm.cartesian().elbow - (e + 0.5)) < TOL_ELBOW
        assert np.abs(arm.joints() - qa).max() > 0.05
    else:
        assert np.abs(arm.joints() - qa).max() < 1e-4


def test_cartesian_soft_limits_refuse_a_path_that_leaves_the_box(arm: Arm):
    """The Cartesian box works the same on every family that moves in Cartesian space."""
    lin, circ = ACCEPTS[arm.model.name]
    if not (lin or circ):
        pytest.skip(f"{arm.model.name}: no Cartesian motion (NG per the table)")
    T0, T1, via, tgt = _targets(arm)
    p = T0[:3, 3]
    names = ("xLimit", "yLimit", "zLimit")
    # A box around the start that the target of the move leaves (by 5 mm in x).
    box = {n: LimitValue(p[i] + 0.2, p[i] - 0.2) for i, n in enumerate(names)}
    goal = tgt if circ and not lin else T1
    box["xLimit"] = LimitValue(goal[0, 3] - 0.005, p[0] - 0.2)
    q0 = arm.joints()
    arm.ok(arm.middle(OP.setSoftLimitCartesian, box))
    try:
        if lin:
            reply = arm.middle(OP.moveLinearCartesianRel, {"carPoint": rel(T1[:3, 3] - p)})
        else:
            reply = arm.middle(OP.moveCircularCartesianRel,
                               {"carPointR": rel(via[:3, 3] - p), "carPointT": rel(tgt[:3, 3] - p)})
        assert reply.id == ReturnCode.VALUE_ERR, reply
        arm.servo_time.passes(QUIET_WINDOW)  # a motion queued all the same would move the arm in it
        assert np.abs(arm.joints() - q0).max() < 1e-6  # nothing moved
    finally:
        wide = {n: LimitValue(10.0, -10.0) for n in names}
        arm.ok(arm.middle(OP.setSoftLimitCartesian, wide))
