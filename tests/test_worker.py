"""The planning process (``services/planner/worker.py``): the motion through the pipe, then its preview. Pure:
a child process, no services."""

from __future__ import annotations

import pickle

import numpy as np
import pytest

from jara_arm.robots import robot
from jara_arm.schema.operations import OP
from jara_arm.schema.planner import MotionRequest
from jara_arm.services.planner.planning import MotionPlanner, PlanRefused
from jara_arm.services.planner.worker import PlanningProcess

from .support import car
from .support import motion_settings as settings


@pytest.fixture(scope="module")
def child():
    p = PlanningProcess(robot("iiwa"), "WARNING")
    yield p
    p.close()


def lin(planner: MotionPlanner, dy: float) -> tuple[MotionRequest, np.ndarray]:
    model = planner.model
    q0 = np.array(model.ready_pose)
    T = planner.kin.control_point(q0).homogeneous
    T[1, 3] += dy
    return MotionRequest(OP.moveLinearCartesianAbs, {"carPoint": car(T)}, settings(model)), q0


def test_the_child_plans_what_the_parent_would_and_the_preview_follows(child: PlanningProcess):
    planner = MotionPlanner(robot("iiwa"))
    req, q0 = lin(planner, 0.2)
    here = planner.plan(req, q0)
    there = child.plan(req, q0)
    assert len(there.preview) == 0  # left out of the motion: it comes after
    assert np.array_equal(there.q, here.q)
    assert np.array_equal(there.path.joints(there.profile.sample(there.dt).s), here.q)
    assert there.duration == here.duration
    assert np.array_equal(child.preview(), here.preview)
    assert len(child.preview()) == 0  # read once


def test_an_unread_preview_does_not_answer_the_next_plan(child: PlanningProcess):
    planner = MotionPlanner(robot("iiwa"))
    req, q0 = lin(planner, 0.1)
    child.plan(req, q0)  # its preview never read (a motion not queued)
    req2, _ = lin(planner, -0.1)
    second = child.plan(req2, q0)
    assert np.array_equal(second.q, planner.plan(req2, q0).q)
    far, _ = lin(planner, 5.0)
    with pytest.raises(PlanRefused):
        child.plan(far, q0)
    assert len(child.preview()) == 0  # a refusal has none: nothing waits on the pipe


def test_a_cartesian_motion_pickles_its_samples_once():
    planner = MotionPlanner(robot("iiwa"))
    req, q0 = lin(planner, 0.2)
    motion = planner.plan(req, q0, preview=False)
    assert motion.path.q is motion.q  # the table is the samples
    data = pickle.dumps(motion, protocol=pickle.HIGHEST_PROTOCOL)
    assert len(data) < 1.2 * motion.q.nbytes + motion.path.s.nbytes
    back = pickle.loads(data)
    assert back.path.q is back.q and np.array_equal(back.q, motion.q)
