"""The planning process (``services/planner/worker.py``): the motion through the pipe, then its preview; the
typed request it is sent (``services/planner/request.py``). Pure: a child process, no services."""

from __future__ import annotations

import pickle

import numpy as np
import pytest

from jara_arm.robots import robot
from jara_arm.schema.codes import ReturnCode
from jara_arm.schema.operations import OP
from jara_arm.schema.types import CarPosWithElbow
from jara_arm.services.planner.planning import MotionPlanner
from jara_arm.services.planner.request import PlanRefused, PlanRequest
from jara_arm.services.planner.worker import PlanningProcess

from .support import car, plan_request
from .support import motion_settings as settings


@pytest.fixture(scope="module")
def child():
    p = PlanningProcess(robot("iiwa"), "WARNING")
    yield p
    p.close()


def lin(planner: MotionPlanner, dy: float) -> tuple[PlanRequest, np.ndarray]:
    model = planner.model
    q0 = np.array(model.ready_pose)
    T = planner.kin.control_point(q0).homogeneous
    T[1, 3] += dy
    return plan_request(OP.moveLinearCartesianAbs, {"carPoint": car(T)}, settings(model)), q0


def test_the_request_is_decoded_once_into_typed_values_that_pickle():
    """What the plan worker hands on (to the head and, pickled, to the child): the parameters as IDL values,
    no wire form left; a non-motion operation and a malformed parameter are refused as they come off the wire."""
    req, _ = lin(MotionPlanner(robot("iiwa")), 0.1)
    assert isinstance(req.args["carPoint"], CarPosWithElbow)
    back = pickle.loads(pickle.dumps(req, protocol=pickle.HIGHEST_PROTOCOL))
    assert back.op == req.op and back.settings.spdRatioCartesian == req.settings.spdRatioCartesian
    assert np.array_equal(back.args["carPoint"].carPos, req.args["carPoint"].carPos)
    model = robot("iiwa")
    with pytest.raises(PlanRefused) as refused:
        plan_request(OP.getState, {}, settings(model))
    assert refused.value.code == ReturnCode.NOT_IMPLEMENTED
    with pytest.raises(PlanRefused) as refused:
        plan_request(OP.moveLinearCartesianAbs, {"carPoint": {"carPos": [[1.0, 0.0]]}}, settings(model))
    assert refused.value.code == ReturnCode.VALUE_ERR and refused.value.comment.startswith("carPoint")


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
