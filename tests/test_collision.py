"""Collision-checked acceptance (issue 15, part 2): ``services/planner/collision.py`` through ``MotionPlanner``.

In-process, except ``test_live_ptp_through_a_box_is_refused_and_nothing_moves`` (the whole system with
``--obstacle``).
"""

from __future__ import annotations

import re

import numpy as np
import pytest

from jara_arm.kinematics import Kinematics
from jara_arm.robots import ROBOTS, Obstacle, RobotModel, robot
from jara_arm.schema.codes import ReturnCode, StateBit
from jara_arm.schema.operations import OP
from jara_arm.services.planner.collision import PathChecker
from jara_arm.services.planner.planning import MotionPlanner
from jara_arm.services.planner.request import PlanRefused

from .harness import ServoTime, launched
from .support import Client, client_session, motion_settings, plan_request

IIWA = robot("iiwa")
READY = np.array(IIWA.ready_pose)
#: iiwa J4 folded near its limit with J2 forward: the wrist (link 5) runs into the base (link 0).
FOLDED = (0.0, 2.0, 0.0, -2.0, 0.0, 0.0, 0.0)




def _start(model: RobotModel) -> np.ndarray:
    return np.array(list(model.ready_pose) + ([model.gripper_limits.upper] if model.has_gripper else []))


def _box_ahead() -> Obstacle:
    """A box on the circle the ready flange follows when J1 turns, 0.5 rad ahead (as alarm_system.py's box)."""
    x, y, z = Kinematics(IIWA, seed_table=0).fk(READY).translation
    r, a = float(np.hypot(x, y)), float(np.arctan2(y, x)) + 0.5
    return Obstacle((r * np.cos(a), r * np.sin(a), z), (0.05, 0.05, 0.15))


def _ptp(planner: MotionPlanner, target: tuple[float, ...]):
    return planner.plan(plan_request(OP.movePTPJointAbs, {"jointPoints": target}, motion_settings(planner.model)),
                        _start(planner.model))


def _percent(comment: str) -> float:
    found = re.search(r"at (\d+) % of the path", comment)
    assert found, comment
    return float(found.group(1))


TURN = (READY[0] + 1.0, *READY[1:])  # J1 on by 1 rad: the wrist sweeps through _box_ahead()


def test_ptp_through_a_box_is_refused_naming_the_box_a_link_and_where():
    planner = MotionPlanner(IIWA, obstacles=(_box_ahead(),))
    with pytest.raises(PlanRefused) as refused:
        _ptp(planner, TURN)
    exc = refused.value
    assert exc.code is ReturnCode.VALUE_ERR
    assert "movePTPJointAbs" in exc.comment and "obstacle 1 (box at" in exc.comment, exc.comment
    assert re.search(r"lbr_iiwa_link_\d", exc.comment), exc.comment
    assert 5.0 < _percent(exc.comment) < 95.0, exc.comment  # on the way, neither the start nor the target


def test_the_same_ptp_with_the_box_moved_away_is_accepted():
    box = _box_ahead()
    away = Obstacle((box.position[0], -box.position[1], box.position[2]), box.half_extents)  # behind the start
    motion = _ptp(MotionPlanner(IIWA, obstacles=(away,)), TURN)
    assert np.allclose(motion.end[:7], TURN)


def test_a_lin_into_a_box_is_refused():
    """Cartesian motions pass the same check (the one place every motion passes)."""
    planner = MotionPlanner(IIWA, obstacles=(_box_ahead(),))
    T = planner.kin.fk(READY)
    target = np.hstack([T.rotation, (T.translation + [0.0, 0.3, 0.0])[:, None]])
    req = plan_request(OP.moveLinearCartesianAbs, {"carPoint": {"carPos": target.tolist(), "elbow": 0.0,
                                                                "structFlag": 0}}, motion_settings(IIWA))
    with pytest.raises(PlanRefused) as refused:
        planner.plan(req, _start(IIWA))
    assert refused.value.code is ReturnCode.VALUE_ERR and "obstacle 1" in refused.value.comment


def test_the_first_contact_found_is_the_first_sample_in_contact():
    """The advancement between checks never steps over a sample closer than allowed: the sample it reports
    is the first of all samples checked one by one."""
    checker = PathChecker(IIWA, (_box_ahead(),))
    q = _ptp(MotionPlanner(IIWA), TURN).q
    contact = checker.check(q)
    assert contact is not None
    full = checker.full(q)
    every = [k for k in range(len(q)) if checker.clearances(full[k]).min() < 0.0]
    assert every and contact.sample == every[0], (contact, every[:3])


def test_a_self_colliding_target_is_refused_naming_two_links():
    planner = MotionPlanner(IIWA)
    with pytest.raises(PlanRefused) as refused:
        _ptp(planner, FOLDED)
    exc = refused.value
    assert exc.code is ReturnCode.VALUE_ERR and "collide" in exc.comment, exc.comment
    assert len(re.findall(r"lbr_iiwa_link_\d", exc.comment)) == 2 and "obstacle" not in exc.comment, exc.comment


def test_the_margin_refuses_a_near_miss_that_a_smaller_margin_accepts():
    """A wide slab 5 mm above the arm's highest point: J1 turning keeps every height, so the arm passes
    5 mm under it all the way."""
    top = PathChecker(IIWA, (Obstacle((0.0, 0.0, 5.0), (3.0, 3.0, 0.5)),), margin=0.0)
    to_slab = [k for k, (_, b) in enumerate(top.pairs) if b.startswith("obstacle")]
    highest = 4.5 - float(top.clearances(top.full(_start(IIWA)[None])[0])[to_slab].min())  # underside at 4.5
    slab = Obstacle((0.0, 0.0, highest + 0.005 + 0.5), (3.0, 3.0, 0.5))
    with pytest.raises(PlanRefused) as refused:
        _ptp(MotionPlanner(IIWA, obstacles=(slab,), collision_margin=0.01), TURN)
    assert "mm close" in refused.value.comment and "collision margin 10 mm" in refused.value.comment
    assert _ptp(MotionPlanner(IIWA, obstacles=(slab,), collision_margin=0.002), TURN).duration > 0.0


@pytest.mark.parametrize("name", list(ROBOTS))
def test_every_robot_builds_its_collision_model_and_its_ready_pose_is_clear(name: str):
    model = robot(name)
    far = Obstacle((5.0, 5.0, 5.0), (0.1, 0.1, 0.1))
    checker = PathChecker(model, (far,))
    assert checker.check(_start(model)[None]) is None
    bodies = {b for pair in checker.pairs for b in pair}
    assert any("obstacle 1" in b for b in bodies), checker.pairs  # every moving link is paired with the box
    assert all(e.reason for e in checker.excluded)
    if model.has_gripper:  # the gripper is checked too
        assert any("finger" in b for b in bodies), bodies


def test_adjacent_links_and_only_those_and_the_fingers_are_excluded_on_panda():
    checker = PathChecker(robot("panda"))
    reasons = {e.reason for e in checker.excluded}
    assert reasons <= {"adjacent links", "gripper fingers"}, reasons
    assert ("panda_link5", "panda_link7") in checker.pairs  # J6 between them: checked


def test_live_ptp_through_a_box_is_refused_and_nothing_moves():
    """The whole system with ``--obstacle``: the planner refuses the PTP, the servo's feedback does not move."""
    box = _box_ahead()
    with launched("--robot", "iiwa", "--obstacle", box.argument()) as (_proc, port), \
            client_session(port) as session:
        client = Client(session)
        servo = ServoTime(session, client.keys)
        assert client.common(OP.servoON).id == ReturnCode.OK
        assert client.middle(OP.setSpeedJoint, {"spdRatio": 50}).id == ReturnCode.OK
        before = servo.settled()
        reply = client.middle(OP.movePTPJointAbs, {"jointPoints": TURN})
        assert reply.id == ReturnCode.VALUE_ERR and "obstacle 1" in reply.comment, reply
        assert re.search(r"lbr_iiwa_link_\d", reply.comment) and "% of the path" in reply.comment, reply
        servo.passes(0.3)
        after = servo.sample()[1]
        assert np.abs(after - before).max() < 1e-6, (before, after)
        assert not client.state & StateBit.MOVING

