"""The servo's interpolator (``services/servo/interpolator.py``) in microseconds: no Zenoh, no world.

What a user would check of a buffered motion: it arrives; pause, resume, stop and the speed override keep
it on its path; the scale changes within the axes' acceleration; a head never runs past its last sample;
and what the planner gets back when it is late or stale.
"""

from __future__ import annotations

import numpy as np
import pytest

from jara_arm.schema.motion import MotionAction, TrajectoryRefusal
from jara_arm.schema.types import Time
from jara_arm.services.servo.interpolator import RATE_MAX, Interpolator, head_cap, prepare

DT = 1e-3
AMAX = np.array([2.0, 3.0])  # [rad/s²]


def _rest_to_rest(a: np.ndarray, b: np.ndarray, duration: float) -> np.ndarray:
    """Smooth samples from ``a`` to ``b`` [rad], at rest at both ends (a quintic), one per DT."""
    t = np.linspace(0.0, 1.0, int(round(duration / DT)) + 1)
    s = 10 * t**3 - 15 * t**4 + 6 * t**5
    return a + s[:, None] * (b - a)


def _run(it: Interpolator, plan: dict[int, tuple[MotionAction, float]] | None = None,
         limit: int = 100_000) -> np.ndarray:
    out = []
    plan = plan or {}
    k = 0
    while it.active and k < limit:
        if k in plan:
            it.control(*plan[k])
        if not it.holding:
            out.append(it.next())
        k += 1
    return np.array(out)


def _on_polyline(q: np.ndarray, rows: np.ndarray) -> float:
    """[rad] the largest distance of a command from the polyline through ``rows`` (2 axes)."""
    worst = 0.0
    for x in q:
        d = rows[1:] - rows[:-1]
        t = np.clip(np.einsum("ij,ij->i", x - rows[:-1], d) / np.maximum(np.einsum("ij,ij->i", d, d), 1e-30), 0, 1)
        worst = max(worst, float(np.min(np.linalg.norm(rows[:-1] + t[:, None] * d - x, axis=1))))
    return worst


def _buffered(rows: np.ndarray, motion: int = 1, final: bool = True) -> Interpolator:
    it = Interpolator(2, DT)
    refusal, why = it.submit(prepare(motion, rows, final, DT, AMAX), it.epoch, 0, -1, rows[0], True)
    assert refusal is None, why
    return it


def test_a_buffered_motion_runs_its_samples_exactly_and_arrives():
    rows = _rest_to_rest(np.zeros(2), np.array([0.5, -0.3]), 0.8)
    it = _buffered(rows)
    q = _run(it)
    np.testing.assert_array_equal(q, rows[1:])
    assert it.last_done == 1 and not it.active


@pytest.mark.parametrize("seed", range(5))
def test_override_changes_keep_the_path_and_the_acceleration_bound(seed):
    """Random override changes at random times: every command on the planned path; the scale's change adds
    at most the axes' rated acceleration (``AMAX``) to the planned one; the motion arrives."""
    rng = np.random.default_rng(seed)
    rows = _rest_to_rest(np.zeros(2), rng.uniform(-1.0, 1.0, 2), rng.uniform(0.5, 1.5))
    it = _buffered(rows)
    plan = {int(k): (MotionAction.OVERRIDE, float(r)) for k, r in zip(rng.integers(0, 1500, 6), rng.uniform(0, 1, 6))}
    plan[1600] = (MotionAction.OVERRIDE, 1.0)
    q = _run(it, plan)
    np.testing.assert_array_equal(q[-1], rows[-1])
    assert _on_polyline(q, rows) < 1e-9
    planned = np.abs(np.diff(rows, 2, axis=0)).max(axis=0) / DT**2
    acc = np.abs(np.diff(q, 2, axis=0)) / DT**2
    assert np.all(acc <= planned + AMAX * 1.05), (acc.max(axis=0), planned + AMAX)


def test_override_100_30_0_100_holds_at_0_and_goes_on():
    rows = _rest_to_rest(np.zeros(2), np.array([1.0, 0.5]), 3.0)
    it = _buffered(rows)
    first = _run(it, limit=500)
    it.control(MotionAction.OVERRIDE, 0.3)
    slow = _run(it, limit=600)  # the scale changes within the axes' acceleration: ~0.55 s here
    assert it.scale == pytest.approx(0.3)
    it.control(MotionAction.OVERRIDE, 0.0)
    stopping = _run(it, limit=600)
    assert it.scale == 0.0 and not it.paused
    held = _run(it, limit=100)
    assert np.ptp(held, axis=0).max() == 0.0  # 0 %: holds on the path
    it.control(MotionAction.OVERRIDE, 1.0)
    rest = _run(it)
    q = np.vstack([first, slow, stopping, held, rest])
    np.testing.assert_array_equal(q[-1], rows[-1])
    assert _on_polyline(q, rows) < 1e-9


def test_pause_holds_resume_goes_on_stop_discards():
    rows = _rest_to_rest(np.zeros(2), np.array([1.0, 0.5]), 1.0)
    it = _buffered(rows)
    _run(it, limit=300)
    assert it.control(MotionAction.PAUSE).startswith("OK: pausing")
    _run(it, limit=1000)
    assert it.holding and it.active
    assert it.control(MotionAction.PAUSE) == "OK: ignored, already paused"
    it.control(MotionAction.RESUME)
    _run(it, limit=100)
    epoch = it.epoch
    assert it.control(MotionAction.STOP).startswith("OK: stopping")
    assert it.epoch == epoch + 1  # a motion planned against the old queue is refused from now on
    q = _run(it)
    assert not it.active and it.last_discarded == 1 and it.last_done == 0
    assert _on_polyline(q, rows) < 1e-9
    refusal, _ = it.submit(prepare(2, rows, True, DT, AMAX), epoch, 1, -1, q[-1], True)
    assert refusal is TrajectoryRefusal.STALE


def test_a_splice_after_its_sample_is_late_and_a_wrong_start_is_refused():
    rows = _rest_to_rest(np.zeros(2), np.array([1.0, 0.5]), 0.5)
    it = _buffered(rows)
    _run(it, limit=100)
    nxt = prepare(2, _rest_to_rest(rows[50], np.array([0.0, 1.0]), 0.5), True, DT, AMAX)
    assert it.submit(nxt, it.epoch, 1, 50, rows[-1], True)[0] is TrajectoryRefusal.LATE
    off = prepare(2, _rest_to_rest(rows[-1] + 0.01, np.array([0.0, 1.0]), 0.5), True, DT, AMAX)
    assert it.submit(off, it.epoch, 1, -1, rows[-1], True)[0] is TrajectoryRefusal.START
    assert it.submit(off, it.epoch, 7, -1, rows[-1], True)[0] is TrajectoryRefusal.STALE  # 7 is not last


def test_from_rest_only_a_motion_planned_from_the_held_target_is_taken():
    """One planned from an older hold (before a servoON) is stale, however close: never a step of the command."""
    held = np.array([0.1, -0.2])
    it = Interpolator(2, DT)
    for gap in (1e-3, 3.5e-5, 2e-6):
        old = prepare(1, _rest_to_rest(held + gap, np.array([0.5, 0.5]), 0.5), True, DT, AMAX)
        refusal, why = it.submit(old, it.epoch, 0, -1, held, True)
        assert refusal is TrajectoryRefusal.STALE and "older hold" in why, gap
        assert not it.active
    exact = prepare(1, _rest_to_rest(held, np.array([0.5, 0.5]), 0.5), True, DT, AMAX)
    assert it.submit(exact, it.epoch, 0, -1, held, True)[0] is None
    assert np.max(np.abs(it.next() - held)) < 1e-6  # the first target is a sample of the path away from the hold


@pytest.mark.parametrize("seed", range(5))
def test_a_head_never_runs_past_its_last_sample(seed):
    """Whatever its length and speed, a head whose rest never comes slows down before its end."""
    rng = np.random.default_rng(seed)
    rows = _rest_to_rest(np.zeros(2), rng.uniform(-0.5, 0.5, 2), rng.uniform(0.2, 1.0))
    head = rows[:int(rng.integers(10, 60))]
    it = _buffered(head, final=False)
    q = _run(it, limit=5000)
    assert it.tau <= len(head) - 1 and it.ran_out == 0
    assert _on_polyline(q, head) < 1e-12


@pytest.mark.parametrize("seed", range(5))
def test_a_jogs_stop_is_replaced_from_the_end_and_a_head_that_ends_at_rest_runs_as_planned(seed):
    """A jog's head ends in its stop and its last sample again (``rests``): run at scale 1 to that end (no cap)
    and held there without a 'ran out'; a splice counted from the end (-k) replaces its stop by more path."""
    rng = np.random.default_rng(seed)
    goal = rng.uniform(-0.5, 0.5, 2)
    rows = _rest_to_rest(np.zeros(2), goal, rng.uniform(0.2, 0.6))
    half = len(rows) // 2
    stop = _rest_to_rest(rows[half], rows[half] + 1e-3 * np.sign(goal), 0.05)  # a short stop after the half
    head = np.vstack([rows[:half + 1], stop[1:], stop[-1:]])
    it = _buffered(head, final=False)
    assert it.queue[0].rests
    _run(it, limit=half - 20)
    assert it.scale == 1.0, "capped though it ends at rest"
    more = np.vstack([rows[half:], rows[-1:]])
    back = len(head) - 1 - half  # the stop's first sample, counted from the end
    refusal, why = it.submit(prepare(1, more, True, DT, AMAX), it.epoch, 1, -1 - back, head[-1], False)
    assert refusal is None, why
    q = _run(it)
    assert np.allclose(q[-1], goal) and _on_polyline(q, rows) < 1e-12 and it.ran_out == 0
    # Not replaced: it stops on its samples and holds at their end, no ran-out.
    it = _buffered(head, final=False)
    q = _run(it, limit=len(head) + 50)
    assert np.allclose(q[-1], stop[-1]) and it.ran_out == 0 and it.tau == len(head) - 1
    assert it.submit(prepare(1, head[-1:], True, DT, AMAX), it.epoch, 1, -1, head[-1], False)[0] is None
    _run(it)
    assert not it.active and it.last_done == 1


def test_head_cap_is_zero_at_the_end_and_grows_with_what_is_left():
    assert head_cap(0.0, RATE_MAX) == 0.0
    caps = [head_cap(r, 5.0) for r in (0.001, 0.01, 0.1, 1.0)]
    assert caps == sorted(caps) and caps[-1] > 1.0


def test_the_running_share_grows_from_0_to_1_along_a_motion_and_is_0_when_idle():
    """``MotionProgress.runningShare`` is ``tau`` over the running motion's last sample index: 0 before and
    after, growing every cycle it runs, held while paused; a change of it alone is no new state (``seq``)."""
    rows = _rest_to_rest(np.zeros(2), np.array([0.5, -0.3]), 2.0)
    it = Interpolator(2, DT)

    def share() -> float:
        return it.progress(it.state(rows[0]), Time.now(), 1).runningShare

    assert share() == 0.0  # idle
    assert it.submit(prepare(1, rows, True, DT, AMAX), it.epoch, 0, -1, rows[0], True)[0] is None
    assert share() == 0.0
    state = it.state(rows[0])
    shares, held = [], []
    for k in range(10_000):
        if k == 100:
            it.control(MotionAction.PAUSE)
        if k == 1500:
            it.control(MotionAction.RESUME)
        if it.holding:
            held.append(share())
        else:
            it.next()
        if not it.active:
            break
        assert k >= 100 or it.state(rows[0]) == state  # the pause is a new state; the share alone never is
        shares.append(share())
        assert shares[-1] == pytest.approx(it.tau / (len(rows) - 1))
    assert not it.active and it.last_done == 1
    assert shares == sorted(shares) and 0.0 < shares[0] < 0.01 and 0.99 < shares[-1] < 1.0
    assert len(held) > 100 and 0.1 < min(held) == max(held) < 0.9  # holding paused: the share holds too
    assert share() == 0.0  # done: nothing runs


def test_a_heads_share_is_of_its_samples_so_far_and_falls_when_its_rest_joins():
    rows = _rest_to_rest(np.zeros(2), np.array([0.5, -0.3]), 1.0)
    it = _buffered(rows[:200], final=False)
    _run(it, limit=100)
    head = it.progress(it.state(rows[0]), Time.now(), 1).runningShare
    assert head == pytest.approx(it.tau / 199) and head > 0.1
    refusal, why = it.submit(prepare(1, rows[199:], True, DT, AMAX), it.epoch, 1, 199, rows[0], True)
    assert refusal is None, why
    whole = it.progress(it.state(rows[0]), Time.now(), 1).runningShare
    assert whole == pytest.approx(it.tau / (len(rows) - 1)) and whole < head
