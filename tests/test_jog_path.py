"""A Cartesian jog's path, without a system (``services/planner/jog_path.py``): it keeps its line and the arm
angle, its stop keeps the step's direction within its time bound, and it goes no nearer to a singularity than
``SINGULAR``. Seeded."""

from __future__ import annotations

import functools

import numpy as np
import pinocchio as pin
import pytest

from jara_arm.kinematics import Kinematics
from jara_arm.robots.catalog import robot
from jara_arm.schema.planner import MotionSettings
from jara_arm.services.planner.checks import Checks
from jara_arm.services.planner.frames import Frames
from jara_arm.services.planner.jog_path import SINGULAR, CartesianPath, Track
from jara_arm.services.planner.profile import ProfileLimits
from jara_arm.services.planner.sampling import BatchFk

from .support import motion_settings

DT = 0.001


@functools.cache
def _iiwa() -> tuple[Checks, MotionSettings]:
    model = robot("iiwa")
    kin = Kinematics(model)
    return Checks(model, kin, BatchFk(kin)), motion_settings(model)


def _path(q0: np.ndarray, axis: int = 2, sign: float = 1.0) -> CartesianPath:
    checks, s = _iiwa()
    return CartesianPath(checks, Frames.of(s), q0, "base", axis, sign, checks.vmax(s), DT, s.accelTimeJoint)


def _random_bent(rng: np.random.Generator) -> np.ndarray:
    """An iiwa pose well away from its singularities (elbow and wrist bent, wrist off the base axis)."""
    while True:
        q = rng.uniform(-1.2, 1.2, 7)
        q[3] = -rng.uniform(0.6, 1.4)
        q[5] = rng.uniform(0.4, 1.2)
        if _path(q).singular(q) > 0.05:
            return q


@pytest.mark.parametrize("seed", range(4))
def test_a_7_axis_cartesian_jog_keeps_its_line_and_its_arm_angle(seed: int) -> None:
    rng = np.random.default_rng(seed)
    q = _random_bent(rng)
    axis = int(rng.integers(0, 3))
    path = _path(q, axis, 1.0)
    kin, start, psi = path.kin, path.x0, path.kin.elbow_angle(q)
    track = Track(DT, 0.02, ProfileLimits.from_accel_time(0.1, 0.2))  # 20 mm at up to 0.1 m/s
    for i in range(1, 1001):
        q = path.at(q, track.step(0.1))
        x = kin.control_point(q, path.tool)
        moved = x.translation - start.translation
        assert np.linalg.norm(np.delete(moved, axis)) < 1e-4, f"off the line at sample {i}"
        assert np.linalg.norm(pin.log3(x.rotation @ start.rotation.T)) < 1e-4
        assert abs(kin.elbow_angle(q) - psi) < 1e-4
    assert moved[axis] == pytest.approx(0.02, abs=1e-5)


@pytest.mark.parametrize("seed", range(4))
def test_a_cartesian_jog_stop_keeps_the_step_direction_within_its_time_bound(seed: int) -> None:
    rng = np.random.default_rng(seed)
    q = _random_bent(rng)
    path = _path(q)
    step = rng.uniform(-1.0, 1.0, 7) * path.vmax * DT * 0.9
    path.restore(step)
    bound = path.stop_time()
    rows = path.stop(q)
    assert np.array_equal(path.state(), step)  # pure: the jogger goes on from the step before
    steps = np.diff(np.vstack([q, rows]), axis=0)
    assert len(rows) * DT <= bound + 1e-9
    assert np.allclose(steps[-1], 0.0)  # at rest at the end
    moving = steps[np.linalg.norm(steps, axis=1) > 1e-12]
    cosines = moving @ step / (np.linalg.norm(moving, axis=1) * np.linalg.norm(step))
    assert np.all(cosines > 1.0 - 1e-9)
    change = np.abs(np.diff(np.vstack([step, steps]), axis=0))
    assert np.all(change <= path.amax * DT * DT + 1e-12)  # no joint faster than its acceleration


def test_a_cartesian_jog_goes_no_nearer_to_a_singularity_but_may_leave() -> None:
    """The iiwa upright, elbow bent, jogging up toward the stretched elbow: its samples are refused once they
    fall below SINGULAR, naming the singularity; from there, the samples back down are not."""
    q = np.array([0.0, 0.3, 0.0, -0.6, 0.0, 0.3, 0.0])
    path = _path(q)
    rows, why = [q], ""
    for i in range(1, 20001):
        rows.append(path.at(rows[-1], 1e-5 * i))
        why = path.too_singular(rows[-2], np.array(rows[-1:]))
        if why:
            break
    assert "singularity" in why and f"below {SINGULAR}" in why, why
    near = rows[-2]  # the last sample that passed
    assert path.singular(near) >= SINGULAR and near[3] < 0.0
    back = _path(rows[-1], sign=-1.0)
    down = [rows[-1]]
    for i in range(1, 51):
        down.append(back.at(down[-1], 1e-5 * i))
    assert back.too_singular(down[0], np.array(down[1:])) == ""


def test_a_track_at_its_end_up_to_rounding_brakes_there() -> None:
    """Ruckig lands on the end up to rounding (7e-18 past it, a soft limit reached by a pendant's jog): the
    stop is the end's, not a ProfileError that fails the jog."""
    limits = ProfileLimits.from_accel_time(0.5, 0.2)
    track = Track(DT, 0.030022195988849365, limits)
    for past in (0.0, 7e-18, 1e-15):
        track.restore((track.end + past, 1e-9, 0.0))
        s = track.braking()
        assert len(s) and np.all(s <= track.end), past
