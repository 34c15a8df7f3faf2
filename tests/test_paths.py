"""Geometry of the planner's paths: joint line, Cartesian line, Cartesian arc."""

from __future__ import annotations

import math

import numpy as np
import pinocchio
import pytest

from jara_arm.schema.errors import JaraArmError
from jara_arm.services.planner.paths import (
    ARC_TOLERANCE,
    CartesianArc,
    CartesianLine,
    JointLine,
    Path,
    PathGeometryError,
)

from .support import pose


def random_rotation(rng: np.random.Generator) -> np.ndarray:
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    return pinocchio.Quaternion(q[0], q[1], q[2], q[3]).matrix()  # (w, x, y, z)


def rotation_angle(Ra: np.ndarray, Rb: np.ndarray) -> float:
    return float(np.linalg.norm(pinocchio.log3(Ra.T @ Rb)))


def circumcircle(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> tuple[np.ndarray, float, np.ndarray]:
    """Centre, radius and unit normal by a linear solve (independent of the code under test)."""
    n = np.cross(b - a, c - a)
    A = np.array([2 * (b - a), 2 * (c - a), n])
    rhs = np.array([b @ b - a @ a, c @ c - a @ a, n @ a])
    centre = np.linalg.solve(A, rhs)
    return centre, float(np.linalg.norm(a - centre)), n / np.linalg.norm(n)


# --------------------------------------------------------------------------- JointLine


def test_joint_line_endpoints_exact_and_points_collinear() -> None:
    rng = np.random.default_rng(1)
    q0, q1 = rng.uniform(-3, 3, 7), rng.uniform(-3, 3, 7)
    line = JointLine(q0, q1)
    assert isinstance(line, Path)
    assert line.length == 1.0
    assert np.array_equal(line.at(0.0), q0) and np.array_equal(line.at(1.0), q1)
    s = np.linspace(0.0, 1.0, 1001)
    q = line.sample(s)
    assert q.shape == (1001, 7)
    d = (q1 - q0) / np.linalg.norm(q1 - q0)
    rel = q - q0
    off_line = rel - np.outer(rel @ d, d)
    assert np.max(np.abs(off_line)) < 1e-12
    assert np.allclose(rel @ d, s * np.linalg.norm(q1 - q0), atol=1e-12)


def test_joint_line_rejects_bad_input() -> None:
    with pytest.raises(PathGeometryError):
        JointLine([0.0, 1.0], [0.0, 1.0, 2.0])
    with pytest.raises(PathGeometryError):
        JointLine([0.0, math.nan], [0.0, 1.0])
    line = JointLine([0.0], [1.0])
    with pytest.raises(PathGeometryError):
        line.at(1.1)
    assert line.at(1.0 + 1e-12)[0] == 1.0  # rounding noise is clamped, not an error


# --------------------------------------------------------------------------- CartesianLine


def test_cartesian_line_points_on_segment_and_slerp() -> None:
    rng = np.random.default_rng(2)
    for _ in range(20):
        T0 = pose(rng.uniform(-1, 1, 3), random_rotation(rng))
        T1 = pose(rng.uniform(-1, 1, 3), random_rotation(rng))
        line = CartesianLine(T0, T1)
        p0, p1 = T0[:3, 3], T1[:3, 3]
        assert line.translation_length == pytest.approx(np.linalg.norm(p1 - p0), abs=1e-15)
        theta = rotation_angle(T0[:3, :3], T1[:3, :3])
        assert line.rotation_angle == pytest.approx(theta, abs=1e-12)
        assert np.array_equal(line.at(0.0), T0) and np.array_equal(line.at(1.0), T1)

        u = np.linspace(0.0, 1.0, 257)
        T = line.sample(u)
        assert T.shape == (257, 4, 4)
        assert np.array_equal(T[:, 3], np.tile([0.0, 0.0, 0.0, 1.0], (257, 1)))
        ideal = p0 + np.outer(u, p1 - p0)
        assert np.max(np.linalg.norm(T[:, :3, 3] - ideal, axis=1)) < 1e-9
        q0, q1 = pinocchio.Quaternion(T0[:3, :3]), pinocchio.Quaternion(T1[:3, :3])
        for k in range(0, 257, 16):
            R = T[k, :3, :3]
            assert np.max(np.abs(R.T @ R - np.eye(3))) < 1e-12
            assert np.allclose(R, q0.slerp(u[k], q1).matrix(), atol=1e-9)
            # constant angular speed along the geodesic
            assert rotation_angle(T0[:3, :3], R) == pytest.approx(u[k] * theta, abs=1e-9)
            assert rotation_angle(R, T1[:3, :3]) == pytest.approx((1 - u[k]) * theta, abs=1e-9)


def test_cartesian_line_pure_rotation_and_pure_translation() -> None:
    R1 = pinocchio.exp3(np.array([0.0, 0.0, 1.2]))
    rot = CartesianLine(pose([0.3, 0.1, 0.5]), pose([0.3, 0.1, 0.5], R1))
    assert rot.translation_length == 0.0
    assert rot.rotation_angle == pytest.approx(1.2, abs=1e-14)
    mid = rot.at(0.5)
    assert np.allclose(mid[:3, :3], pinocchio.exp3(np.array([0.0, 0.0, 0.6])), atol=1e-14)
    tr = CartesianLine(pose([0, 0, 0]), pose([0.3, 0.4, 0.0]))
    assert tr.translation_length == pytest.approx(0.5, abs=1e-15) and tr.rotation_angle == 0.0
    assert np.allclose(tr.at(0.5)[:3, :3], np.eye(3), atol=0.0)


def test_cartesian_line_accepts_hgmatrix_and_rejects_non_rotations() -> None:
    T = pose([1.0, 2.0, 3.0])
    line = CartesianLine(T[:3], T)
    assert np.array_equal(line.T0, T)
    bad = pose([0, 0, 0], np.diag([1.0, 1.0, 2.0]))
    with pytest.raises(PathGeometryError, match="rotation"):
        CartesianLine(bad, T)
    with pytest.raises(PathGeometryError):
        CartesianLine(np.eye(3), T)


# --------------------------------------------------------------------------- CartesianArc


def test_arc_random_points_on_circle_through_via() -> None:
    rng = np.random.default_rng(3)
    for _ in range(30):
        p0, pv, p1 = (rng.uniform(-0.8, 0.8, 3) for _ in range(3))
        T0 = pose(p0, random_rotation(rng))
        T1 = pose(p1, random_rotation(rng))
        arc = CartesianArc(T0, pose(pv, random_rotation(rng)), T1)
        centre, r, n = circumcircle(p0, pv, p1)
        assert np.allclose(arc.center, centre, atol=1e-9) and arc.radius == pytest.approx(r, abs=1e-9)
        assert np.array_equal(arc.at(0.0), T0) and np.array_equal(arc.at(1.0), T1)

        N = 2000
        u = np.linspace(0.0, 1.0, N + 1)
        T = arc.sample(u)
        p = T[:, :3, 3]
        assert np.max(np.abs(np.linalg.norm(p - centre, axis=1) - r)) < 1e-9
        assert np.max(np.abs((p - centre) @ n)) < 1e-9
        # uniform in arc length: equal chords between consecutive samples
        chords = np.linalg.norm(np.diff(p, axis=0), axis=1)
        assert np.ptp(chords) < 1e-9
        assert arc.translation_length == pytest.approx(r * arc.sweep_angle, rel=1e-12)
        assert chords.sum() == pytest.approx(arc.translation_length, rel=1e-5)
        # passes through the via point: exactly at via_fraction, and within half a step on a grid
        assert np.linalg.norm(arc.at(arc.via_fraction)[:3, 3] - pv) < 1e-9
        step = arc.translation_length / N
        assert np.min(np.linalg.norm(p - pv, axis=1)) <= step / 2 + 1e-12
        # orientation: slerp R0 -> R1 with the arc fraction, via orientation ignored
        q0, q1 = pinocchio.Quaternion(T0[:3, :3]), pinocchio.Quaternion(T1[:3, :3])
        for k in (0, 500, 1000, 1700, 2000):
            assert np.allclose(T[k, :3, :3], q0.slerp(u[k], q1).matrix(), atol=1e-9)


@pytest.mark.parametrize(
    ("via_deg", "end_deg", "sweep_deg", "via_fraction"),
    [
        (45.0, 90.0, 90.0, 0.5),  # via on the near side: quarter circle
        (10.0, 90.0, 90.0, 1.0 / 9.0),
        (225.0, 90.0, 270.0, 0.5),  # via on the far side: the long way round (> 180°)
        (-90.0, 90.0, 270.0, 1.0 / 3.0),
        (180.0, 90.0, 270.0, 2.0 / 3.0),
        (359.0, 359.9, 359.9, 359.0 / 359.9),  # nearly a full circle
        (1.0, 359.9, 359.9, 1.0 / 359.9),
    ],
)
def test_arc_direction_contains_via(
    via_deg: float, end_deg: float, sweep_deg: float, via_fraction: float
) -> None:
    # circle of radius 0.4 in a tilted plane, centre off the origin; angles in its plane from p0
    R = pinocchio.exp3(np.array([0.4, -0.3, 0.2]))
    c = np.array([0.5, -0.2, 0.3])

    def on_circle(deg: float) -> np.ndarray:
        a = math.radians(deg)
        return c + 0.4 * (R @ np.array([math.cos(a), math.sin(a), 0.0]))

    p0, pv, p1 = on_circle(0.0), on_circle(via_deg), on_circle(end_deg)
    arc = CartesianArc(pose(p0), pv, pose(p1))
    assert math.degrees(arc.sweep_angle) == pytest.approx(sweep_deg, abs=1e-9)
    assert arc.via_fraction == pytest.approx(via_fraction, abs=1e-12)
    assert arc.radius == pytest.approx(0.4, abs=1e-12)
    # the samples run monotonically from p0 round to p1 the way that contains the via point
    u = np.linspace(0.0, 1.0, 721)
    local = (arc.positions(u) - c) @ R  # into the circle's own frame
    ang = np.unwrap(np.arctan2(local[:, 1], local[:, 0]))
    assert np.allclose(np.abs(ang), u * math.radians(sweep_deg), atol=1e-9)
    assert np.max(np.abs(local[:, 2])) < 1e-9


def test_arc_half_circle_both_sides() -> None:
    p0, p1 = np.array([1.0, 0.0, 0.0]), np.array([-1.0, 0.0, 0.0])
    for via in ([0.0, 1.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, 1.0]):
        arc = CartesianArc(pose(p0), via, pose(p1))
        assert arc.sweep_angle == pytest.approx(math.pi, abs=1e-12)
        assert np.allclose(arc.at(0.5)[:3, 3], via, atol=1e-12)
        assert arc.translation_length == pytest.approx(math.pi, abs=1e-12)


def test_arc_rotation_interpolated_with_arc_fraction() -> None:
    R1 = pinocchio.exp3(np.array([0.0, 0.0, 1.0]))
    arc = CartesianArc(pose([1.0, 0.0, 0.0]), [0.0, 1.0, 0.0], pose([-1.0, 0.0, 0.0], R1))
    assert arc.rotation_angle == pytest.approx(1.0, abs=1e-14)
    T = arc.at(0.25)
    assert np.allclose(T[:3, 3], [math.cos(math.pi / 4), math.sin(math.pi / 4), 0.0], atol=1e-12)
    assert np.allclose(T[:3, :3], pinocchio.exp3(np.array([0.0, 0.0, 0.25])), atol=1e-14)


@pytest.mark.parametrize(
    ("p0", "pv", "p1", "why"),
    [
        ([0, 0, 0], [0.5, 0.5, 0.5], [1, 1, 1], "collinear"),
        ([0, 0, 0], [2, 2, 2], [1, 1, 1], "collinear"),  # via beyond the target, still on the line
        ([0, 0, 0], [0.5, 0.5 + 0.5 * ARC_TOLERANCE, 0], [1, 1, 0], "collinear"),
        ([0, 0, 0], [0, 0, 0], [1, 0, 0], "coincide"),
        ([0, 0, 0], [1, 0, 0], [1, 0, 0], "coincide"),
        ([0, 0, 0], [1, 0, 0], [0, 0, 0], "coincide"),  # full circle: start == target
        ([0, 0, 0], [1, 0, 0], [0, 0.5 * ARC_TOLERANCE, 0], "coincide"),
    ],
)
def test_degenerate_arcs_raise(p0, pv, p1, why: str) -> None:
    with pytest.raises(PathGeometryError, match=why) as info:
        CartesianArc(pose(np.array(p0, float)), np.array(pv, float), pose(np.array(p1, float)))
    assert isinstance(info.value, JaraArmError)


def test_arc_just_above_tolerance_is_accepted() -> None:
    arc = CartesianArc(pose([0.0, 0.0, 0.0]), [0.5, 0.5 + 1e-3, 0.0], pose([1.0, 1.0, 0.0]))
    centre, r, _ = circumcircle(np.zeros(3), np.array([0.5, 0.5 + 1e-3, 0.0]), np.array([1.0, 1.0, 0.0]))
    p = arc.positions(np.linspace(0, 1, 101))
    assert np.max(np.abs(np.linalg.norm(p - centre, axis=1) - r)) < 1e-9 * max(1.0, r)
