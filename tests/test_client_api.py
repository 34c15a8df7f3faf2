"""``jara_arm.client``: the public Python API, against a live system (conftest's ``live``/``arm``), as a
user's script would drive it: typed calls, refusals as exceptions, blocking and asynchronous moves,
motions that do not reach their end reported with the reason. ``test_the_generated_methods_are_current``
needs no system."""

from __future__ import annotations

import threading
from collections.abc import Iterator

import numpy as np
import pytest

from jara_arm.client import Arm as ClientArm
from jara_arm.client import Fate, MotionFailed, NoAnswer, Refused, rel
from jara_arm.client.generate import main as generate
from jara_arm.schema.codes import ReturnCode, StateBit
from jara_arm.schema.operations import ALL
from jara_arm.schema.types import CartesianSpeed

from .harness import LiveArm
from .support import endpoint, free_port, wait_until


@pytest.fixture(scope="module", params=["iiwa"])
def robot_name(request: pytest.FixtureRequest) -> str:
    return str(request.param)


@pytest.fixture
def api(arm: LiveArm) -> Iterator[ClientArm]:
    with ClientArm.connect(arm.endpoint, timeout=10.0) as client:
        yield client


def test_the_generated_methods_are_current() -> None:
    """``client/operations.py`` is what ``python -m jara_arm.client.generate`` writes from the schema, and has
    every operation by its IDL name."""
    assert generate(["--check"]) == 0
    assert all(callable(getattr(ClientArm, op.name, None)) for op in ALL)


def test_no_router_is_a_no_answer_within_the_timeout() -> None:
    with pytest.raises(NoAnswer, match="cannot join"):
        ClientArm.connect(endpoint(free_port()), timeout=0.5)


def test_live_wait_alive_sees_the_services_and_names_one_that_is_not_there(api: ClientArm) -> None:
    api.wait_alive(timeout=10.0)
    other = ClientArm(api.session, "nosucharm", timeout=1.0)
    try:
        with pytest.raises(NoAnswer, match="servo of nosucharm is not running"):
            other.wait_alive(timeout=0.3)
    finally:
        other.close()


def test_live_an_arm_left_open_without_moving_still_answers(arm: LiveArm, monkeypatch: pytest.MonkeyPatch) -> None:
    """Nobody asks a motion's fate for longer than the progress channel holds (4,096 reports, 7 min; 8 here):
    the tracker's thread keeps it empty, so the session's thread never blocks on it and calls are answered."""
    from jara_arm.client import motion

    monkeypatch.setattr(motion, "_FIFO", 8)
    seen = threading.Semaphore(0)
    counter = arm.session.declare_subscriber(arm.keys.planner_progress, lambda _s: seen.release())
    try:
        with ClientArm.connect(arm.endpoint, timeout=5.0) as idle:
            for _ in range(40):  # five times what the channel holds, published 10 a second at rest
                assert seen.acquire(timeout=5.0), "no Planner/progress report within 5 s"
            assert idle.getState() & StateBit.SERVO_ON
    finally:
        counter.undeclare()


def test_live_typed_calls_and_a_refusal_with_its_code(api: ClientArm, arm: LiveArm) -> None:
    info = api.getManipInfo()
    assert info.axisNum == arm.model.axis_num and api.state & StateBit.SERVO_ON
    api.setMaxSpeedCartesian(CartesianSpeed(0.2, 0.8))
    assert api.getMaxSpeedCartesian() == CartesianSpeed(0.2, 0.8)
    x, y, z = api.getSoftLimitCartesian()
    assert x.upper > x.lower and y.upper > y.lower and z.upper > z.lower
    with pytest.raises(Refused) as refused:
        api.setSpeedJoint(101)  # a ratio is 0 .. 100 %
    assert refused.value.code == ReturnCode.VALUE_ERR and "spdRatio" in refused.value.comment
    api.setMaxSpeedCartesian(CartesianSpeed(0.25, 1.0))


def test_live_a_blocking_move_returns_once_arrived(api: ClientArm, arm: LiveArm) -> None:
    api.setSpeedJoint(60)
    start = np.array(api.joints[:arm.model.axis_num])
    delta = np.zeros(arm.model.axis_num)
    delta[0] = 0.3
    motion = api.movePTPJointRel(delta.tolist())
    assert motion.done and motion.fate is Fate.DONE
    np.testing.assert_allclose(api.joints[:arm.model.axis_num], start + delta, atol=1e-3)


def test_live_an_asynchronous_move_runs_while_the_script_goes_on(api: ClientArm, arm: LiveArm) -> None:
    api.setSpeedCartesian(50)
    z0 = api.getFeedbackPosCartesian().carPos[2, 3]
    first = api.moveLinearCartesianRel(rel(dz=-0.05), wait=False)
    second = api.moveLinearCartesianRel(rel(dz=0.05), wait=False)
    assert second.id > first.id
    wait_until(lambda: first.fate in (Fate.RUNNING, Fate.DONE), 5, what="the first LIN running")
    assert not second.done
    second.wait(timeout=20)
    assert first.done and second.done
    assert abs(api.getFeedbackPosCartesian().carPos[2, 3] - z0) < 1e-3


def test_live_a_motion_discarded_by_a_stop_fails_its_wait(api: ClientArm, arm: LiveArm) -> None:
    api.setSpeedJoint(20)
    delta = [0.0] * arm.model.axis_num
    delta[0] = 0.6
    motion = api.movePTPJointRel(delta, wait=False)
    wait_until(lambda: motion.fate is Fate.RUNNING, 5, what="the motion running")
    api.stop()
    with pytest.raises(MotionFailed) as failed:
        motion.wait(timeout=10)
    assert failed.value.motion == motion.id and motion.fate is Fate.DISCARDED and not motion.done
    assert api.alarms == ()  # a client's stop is no alarm


def test_live_the_feedback_iterates_the_1khz_samples(api: ClientArm) -> None:
    with api.feedback() as samples:
        got = [next(samples) for _ in range(50)]
    times = np.array([s.tm.to_seconds() for s in got])
    assert np.all(np.diff(times) > 0) and len(got[0].pos) == len(api.joints)
