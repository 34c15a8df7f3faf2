"""The early start (issue 15, part 5): a LIN / CIRC from rest runs its checked head while the rest is planned.

In-process: ``MotionPlanner.head`` (what it checks, when there is none, its samples are the whole motion's
first ones bit for bit) and the hand-over to the servo's interpolator (``Handover``, ``LocalServo``) through
every way a head can end: accepted while it runs, after a late rest slowed it down, slowed down, refused,
paused, stopped. Live (``test_live_*``, a servo and a planner
process): the first command goes out before the reply, and a LIN refused for a box in the middle of its path
stops within the head's reach, at rest, with no alarm.

``docs/decisions.md`` ("First command and acceptance") gives the decision.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Iterator

import numpy as np
import pytest

from jara_arm.robots import Obstacle, robot
from jara_arm.schema.codes import ReturnCode
from jara_arm.schema.operations import OP
from jara_arm.schema.planner import ControlAction
from jara_arm.schema.types import Time
from jara_arm.services.planner.early import EARLY_OPS
from jara_arm.services.planner.handover import Handover
from jara_arm.services.planner.planning import MotionPlanner
from jara_arm.services.planner.request import PlanRefused, PlanRequest
from jara_arm.services.planner.trajectory import PlannedMotion

from .support import car, motion_settings, plan_request
from .local_servo import LocalServo
from .planner_rig import PlannerRig, start_rig

pytestmark = pytest.mark.timeout(120)
IIWA = robot("iiwa")
DT = IIWA.cmd_cycle
Q0 = np.array(IIWA.ready_pose)
LIN_Y = 0.4  # [m] the LIN of most tests: from the ready pose along +y
REACH = 2e-3  # [m] the head's reach stays below this (1.31 mm at the settings of these tests)


def _pose(planner: MotionPlanner, q: np.ndarray, dp: tuple[float, float, float]) -> np.ndarray:
    T = planner.kin.control_point(q[:planner.n]).homogeneous.copy()
    T[:3, 3] += dp
    return T


def _lin(planner: MotionPlanner, q: np.ndarray, dp: tuple[float, float, float], **settings: object) -> PlanRequest:
    return plan_request(OP.moveLinearCartesianAbs, {"carPoint": car(_pose(planner, q, dp))},
                        motion_settings(planner.model, **settings))


def _circ(planner: MotionPlanner, q: np.ndarray, r: float) -> PlanRequest:
    """A half circle of radius ``r`` [m] in the horizontal plane, from the pose at ``q``."""
    return plan_request(OP.moveCircularCartesianAbs, {"carPointR": car(_pose(planner, q, (r, r, 0.0))),
                                                      "carPointT": car(_pose(planner, q, (0.0, 2 * r, 0.0)))},
                        motion_settings(planner.model))


@pytest.fixture(scope="module")
def planner() -> MotionPlanner:
    return MotionPlanner(IIWA)


# ---------------------------------------------------------------------------------------------- the head


@pytest.mark.parametrize("name", ["iiwa", "panda"])
def test_the_whole_motion_begins_with_the_head_bit_for_bit(name):
    """Seeded LINs in random directions and CIRCs: every accepted one had a head, its samples are the whole
    motion's first ones exactly, and braking from its last sample ends on the checked part of the path."""
    model = robot(name)
    pl = MotionPlanner(model)
    q0 = np.array(list(model.ready_pose) + ([model.gripper_limits.upper] if model.has_gripper else []))
    rng = np.random.default_rng(15)
    checked = 0
    for k in range(8):
        if k % 2:
            req = _circ(pl, q0, float(rng.uniform(0.05, 0.12)))
        else:
            d = rng.normal(size=3)
            req = _lin(pl, q0, tuple(float(x) for x in d / np.linalg.norm(d) * rng.uniform(0.05, 0.25)))
        try:
            whole = pl.plan(req, q0)
        except PlanRefused:
            continue  # out of reach: the head may exist or not, the whole decides
        head = pl.head(req, q0)
        assert head is not None, req
        q = head.motion.q
        assert len(q) == round(pl.early_start / DT) + 1 and len(whole.q) > len(q)
        np.testing.assert_array_equal(whole.q[:len(q)], q)
        stop = head.motion.profile.stop_at((len(q) - 1) * DT)
        assert stop.s_end <= head.motion.path.s[-1]  # type: ignore[attr-defined]
        assert 0.0 < head.reach < REACH, head.reach
        checked += 1
    assert checked >= 6, checked


def test_no_head_where_the_start_cannot_tell(planner):
    """No early start for a PTP, with the early start off, for an unreachable target or one in a box:
    those refusals move nothing."""
    assert planner.head(_lin(planner, Q0, (0.0, LIN_Y, 0.0)), Q0) is not None
    ptp = plan_request(OP.movePTPJointAbs, {"jointPoints": tuple(Q0 + 0.1)}, motion_settings(IIWA))
    assert OP.movePTPJointAbs not in EARLY_OPS and planner.head(ptp, Q0) is None
    off = MotionPlanner(IIWA, early_start=0.0)
    assert off.head(_lin(off, Q0, (0.0, LIN_Y, 0.0)), Q0) is None
    too_high = _lin(planner, Q0, (0.0, 0.0, 0.8))
    assert planner.head(too_high, Q0) is None
    with pytest.raises(PlanRefused, match="unreachable"):
        planner.plan(too_high, Q0)
    target = _pose(planner, Q0, (0.0, LIN_Y, 0.0))[:3, 3]
    boxed = MotionPlanner(IIWA, obstacles=(Obstacle(tuple(target), (0.03, 0.03, 0.03)),))
    assert boxed.head(_lin(boxed, Q0, (0.0, LIN_Y, 0.0)), Q0) is None


def test_a_contact_past_the_samples_sent_still_starts_early_and_the_whole_refuses(planner):
    """A box the LIN reaches about 2 mm along (inside the first knot interval, up to which the head is solved,
    and past the samples sent, which with braking cover 1.3 mm): the head starts (its samples are clear; the
    servo never runs past them), the whole is refused for the contact, and the head's samples stay clear."""
    direction = np.array([0.0, 1.0, 0.0])
    half = (0.01, 0.002, 0.05)
    p0 = planner.kin.control_point(Q0[:planner.n]).translation
    full = planner.collisions.full(Q0[None, :])[0]
    own = len(planner.collisions.pairs)  # the box's pairs come after the arm's own

    def boxed(gap: float) -> MotionPlanner:
        return MotionPlanner(IIWA, obstacles=(Obstacle(tuple(p0 + direction * gap), half),))

    far = 0.1
    clearance = float(boxed(far).collisions.clearances(full)[own:].min())  # [m] beyond the margin
    assert 5e-3 < clearance < far, clearance
    near = boxed(far - clearance + 2e-3)  # a straight LIN moves the last link's surface as the point
    req = _lin(near, Q0, tuple(direction * LIN_Y))
    head = near.head(req, Q0)
    assert head is not None
    assert near.collisions.check(head.motion.q) is None
    assert head.reach < REACH <= 2e-3, head.reach
    with pytest.raises(PlanRefused, match="obstacle 1"):
        near.plan(req, Q0)


# ---------------------------------------------------------------------------------------------- the hand-over


@dataclasses.dataclass
class _Started:
    servo: LocalServo
    handover: Handover
    head: PlannedMotion
    whole: PlannedMotion
    epoch: int
    reach: float


def _started(planner: MotionPlanner, req: PlanRequest) -> _Started:
    """A servo at rest at the start, the head of ``req`` handed over early, and the whole motion."""
    servo = LocalServo(IIWA, Q0)
    h = servo.handover()
    start, epoch = h.start_point()
    np.testing.assert_array_equal(start, Q0)
    assert h.can_start_early()
    head = planner.head(req, start)
    assert head is not None and h.start_early(head.motion, epoch)
    assert not h.can_start_early()  # one at a time
    return _Started(servo, h, head.motion, planner.plan(req, start), epoch, head.reach)


def _smooth(q: np.ndarray, planner: MotionPlanner) -> None:
    """No joint speed step beyond two periods of the joints' acceleration limit (2 v / accel time): no jolt."""
    model = planner.model
    accel = 2.0 * np.array(model.rated_speed[:planner.n]) / model.min_accel_time
    dv = np.abs(np.diff(np.diff(q[:, :planner.n], axis=0), axis=0)) / DT
    assert np.all(dv <= accel * DT * 2.0), (dv / (accel * DT)).max()


def _no_dip(q: np.ndarray, planner: MotionPlanner) -> None:
    """The control point's speed rises to its peak and falls from it once: no slowing down and speeding
    up again on the way (what braking on a head and starting again would show)."""
    p = np.array([planner.kin.control_point(x[:planner.n]).translation for x in q])
    v = np.linalg.norm(np.diff(p, axis=0), axis=1) / DT
    peak = int(np.argmax(v))
    rising, falling = v[:peak + 1], v[peak:]
    tol = 1e-3 * v[peak]
    assert np.all(np.diff(rising) >= -tol), np.diff(rising).min() / v[peak]
    assert np.all(np.diff(falling) <= tol), np.diff(falling).max() / v[peak]


def test_accepted_while_running_the_commands_are_the_whole_motion(planner):
    s = _started(planner, _lin(planner, Q0, (0.0, LIN_Y, 0.0)))
    sent = s.servo.run(10)
    motion, progress = s.handover.confirm_early(s.whole, s.epoch)
    assert motion == 1 and progress.queued == (1,)
    sent += s.servo.run()
    q = np.vstack([Q0[None, :], sent])
    np.testing.assert_array_equal(q[-1], s.whole.end)
    _smooth(q, planner)
    _no_dip(q, planner)
    # On the motion's own samples, only slower at first (the head runs slowed down until its rest comes).
    p = np.array([planner.kin.control_point(x[:planner.n]).translation for x in q])
    a, b = p[0], planner.kin.control_point(s.whole.end[:planner.n]).translation
    d = (b - a) / np.linalg.norm(b - a)
    assert np.linalg.norm((p - a) - np.outer((p - a) @ d, d), axis=1).max() < 1e-6


def test_a_late_rest_slows_the_head_down_it_never_passes_it_and_goes_on_once_accepted(planner):
    s = _started(planner, _lin(planner, Q0, (0.0, LIN_Y, 0.0)))
    sent = s.servo.run(2000)  # the rest is very late: the head slows down towards its last sample
    assert s.servo.interp.tau <= len(s.head.q) - 1
    held = sent[-1]
    assert np.linalg.norm(planner.kin.control_point(held[:planner.n]).translation
                          - planner.kin.control_point(Q0[:planner.n]).translation) <= s.reach + 1e-9
    assert s.handover.progress().queued == ()  # not accepted: no id given to the client yet
    motion, _ = s.handover.confirm_early(s.whole, s.epoch)
    sent += s.servo.run()
    q = np.vstack([Q0[None, :], sent])
    np.testing.assert_array_equal(q[-1], s.whole.end)
    _smooth(q, planner)


def test_refused_after_the_start_it_stops_on_the_head_and_nothing_is_queued(planner):
    s = _started(planner, _lin(planner, Q0, (0.0, LIN_Y, 0.0)))
    sent = s.servo.run(20)
    comment = s.handover.cancel_early()
    assert "started early" in comment and "stops" in comment, comment
    sent += s.servo.run()
    q = np.vstack([Q0[None, :], sent])
    np.testing.assert_allclose(q[-1], q[-2], atol=1e-6)
    _smooth(q, planner)
    p0 = planner.kin.control_point(Q0[:planner.n]).translation
    moved = max(np.linalg.norm(planner.kin.control_point(x[:planner.n]).translation - p0) for x in q)
    assert moved <= s.reach + 1e-9, (moved, s.reach)
    progress = s.handover.progress()
    assert progress.queued == () and progress.running == 0
    assert s.handover.confirm_early(s.whole, s.epoch) is None  # nothing left to accept


def test_slowed_down_it_continues_from_the_head_without_a_stop(planner):
    req = _lin(planner, Q0, (0.0, LIN_Y, 0.0))
    s = _started(planner, req)
    slower = planner.plan(dataclasses.replace(req, settings=dataclasses.replace(req.settings,
                                                                                spdRatioCartesian=40)), Q0)
    assert slower.profile.limits != s.head.profile.limits
    sent = s.servo.run(25)
    assert s.handover.confirm_early(slower, s.epoch) is not None
    sent += s.servo.run()
    q = np.vstack([Q0[None, :], sent])
    np.testing.assert_allclose(q[-1], slower.end, atol=1e-12)
    _smooth(q, planner)
    speed = np.linalg.norm(np.diff(q[:, :planner.n], axis=0), axis=1)
    assert speed[25:-50].min() > 0.0  # never stopped on the way


def test_a_pause_during_the_head_holds_the_accepted_motion_until_resume(planner):
    s = _started(planner, _lin(planner, Q0, (0.0, LIN_Y, 0.0)))
    sent = s.servo.run(20)
    assert s.handover.control(ControlAction.PAUSE)[1].startswith("OK: pausing")
    sent += s.servo.run()
    motion, progress = s.handover.confirm_early(s.whole, s.epoch)
    assert progress.paused and progress.queued == (motion,) and s.servo.run() == []
    s.handover.control(ControlAction.RESUME)
    sent += s.servo.run()
    q = np.vstack([Q0[None, :], sent])
    np.testing.assert_array_equal(q[-1], s.whole.end)
    _smooth(q, planner)


def test_a_stop_during_the_head_discards_it_and_the_motion_is_planned_again(planner):
    s = _started(planner, _lin(planner, Q0, (0.0, LIN_Y, 0.0)))
    s.servo.run(20)
    s.handover.control(ControlAction.STOP)
    assert s.servo.run()  # slowing down to rest
    assert s.handover.confirm_early(s.whole, s.epoch) is None  # the epoch moved: plan again


# ---------------------------------------------------------------------------------------------- live


@pytest.fixture(scope="module")
def boxed_rig() -> Iterator[PlannerRig]:
    """A servo and a planner process with a box across the middle of the LIN (+y from the ready pose)."""
    free = MotionPlanner(IIWA)
    a = free.kin.control_point(Q0).translation
    box = Obstacle(tuple(a + (0.0, LIN_Y / 2, 0.0)), (0.02, 0.02, 0.02)).argument()
    yield from start_rig("iiwa", ("--obstacle", box), ("--obstacle", box))


def test_live_the_first_command_goes_out_before_the_reply(boxed_rig: PlannerRig):
    """A LIN from rest clear of the box (-y): its first commands arrive before its reply; it arrives, straight."""
    rig = boxed_rig
    rig.reset()
    a = rig.fk(rig.joints())
    b = a.copy()
    b[1, 3] -= 0.15
    t0 = time.time()
    reply = rig.plan_ok(OP.moveLinearCartesianAbs, {"carPoint": car(b)})
    t_reply = time.time()
    rig.wait_idle()
    rec = rig.drain()
    assert len(rec.cmd) and rec.cmd_t[0] < t_reply, (rec.cmd_t[0] - t0, t_reply - t0)
    reached = rig.fk(rig.joints())
    assert np.abs(reached[:3, 3] - b[:3, 3]).max() < 1e-4, reached
    d = b[:3, 3] - a[:3, 3]
    rel = rig.points(rec.cmd) - a[:3, 3]
    off = np.linalg.norm(rel - np.outer(rel @ d / (d @ d), d), axis=1)
    assert off.max() < 1e-6, off.max()
    assert reply.duration > 0.5


def test_live_a_box_mid_path_refuses_the_lin_and_it_stops_within_the_head(boxed_rig: PlannerRig):
    rig = boxed_rig
    rig.reset()
    q0 = rig.joints()
    p0 = rig.fk(q0)[:3, 3]
    b = rig.fk(q0)
    b[1, 3] += LIN_Y
    reply = rig.plan(OP.moveLinearCartesianAbs, {"carPoint": car(b)})
    assert reply.id == ReturnCode.VALUE_ERR and "obstacle 1" in reply.comment, reply
    assert "% of the path" in reply.comment, reply
    progress = rig.wait_idle()
    assert progress.queued == () and progress.running == 0
    rec = rig.drain()
    if len(rec.cmd):  # it had started early (the usual case): braked on the head
        assert "started early" in reply.comment, reply
        moved = np.linalg.norm(rig.points(rec.fb) - p0, axis=1).max()
        assert moved < REACH, moved
        np.testing.assert_allclose(rec.cmd[-1], rec.cmd[-2], atol=1e-6)  # the last command at rest
    assert not any(st.alarm for st in rec.status)
    assert np.linalg.norm(rig.fk(rig.joints())[:3, 3] - p0) < REACH


@pytest.mark.parametrize("late", [False, True], ids=["in-time", "late"])
def test_after_an_early_start_the_next_motion_still_blends(planner, late):
    """A head accepted while it runs, or once it has slowed down for a late rest: the next LIN's blend is
    planned against, and cuts into, what the servo buffers."""
    s = _started(planner, _lin(planner, Q0, (0.0, 0.15, 0.0)))
    sent = s.servo.run(500 if late else 10)
    s.handover.confirm_early(s.whole, s.epoch)
    start, epoch = s.handover.start_point()
    np.testing.assert_array_equal(start, s.whole.end)
    previous = s.handover.last_motion()
    assert previous is not None and previous.motion == 1
    nxt = plan_request(OP.moveLinearCartesianAbs, {"carPoint": car(_pose(planner, s.whole.end, (0.15, 0.0, 0.0)))},
                       motion_settings(IIWA, blendDistance=0.02))
    second = planner.plan(nxt, start, previous)
    assert second.blend is not None and second.blend.previous == 1
    assert s.handover.submit(second, epoch) is not None
    sent += s.servo.run()
    q = np.vstack([Q0[None, :], sent])
    np.testing.assert_allclose(q[-1], second.end, atol=1e-12)
    _smooth(q, planner)
    corner = planner.kin.control_point(s.whole.end[:planner.n]).translation
    closest = min(np.linalg.norm(planner.kin.control_point(x[:planner.n]).translation - corner) for x in q)
    assert 1e-3 < closest <= 0.02 + 1e-6, closest  # it cut the corner: no stop there


def test_the_start_point_listens_for_a_status_before_it_says_there_is_none():
    """The planner's receiving threads held up (a saturated machine): the start point waits up to
    ``STATUS_LISTEN`` for a status before it refuses; a servo that stays silent is still refused."""
    from jara_arm.services.runtime.timing import STATUS_LISTEN

    servo = LocalServo(IIWA, Q0)
    late = iter([None] * 5)  # five polls find nothing yet, then the status comes
    h = Handover(IIWA.dof, servo.dt, servo.ask_trajectory, servo.ask_control, lambda _p: None,
                 lambda: next(late, None) or servo.status(), servo.progress)
    start, _epoch = h.start_point()
    np.testing.assert_array_equal(start, Q0)
    silent = Handover(IIWA.dof, servo.dt, servo.ask_trajectory, servo.ask_control, lambda _p: None,
                      lambda: None, servo.progress)
    t0 = time.monotonic()
    with pytest.raises(PlanRefused, match="no status from the servo"):
        silent.start_point()
    assert time.monotonic() - t0 >= STATUS_LISTEN


def test_the_start_point_goes_by_the_callers_status_where_it_is_newer():
    """A servoON's reply reaches the command before the servo's publication reaches the planner: the command's
    status (``MotionRequest.servo``), newer by its number, is gone by; an older one changes nothing (a CI run
    refused a move "the servo is off" right after servoON answered OK)."""
    import dataclasses as dc

    servo = LocalServo(IIWA, Q0)
    started = Time.from_seconds(time.time())
    heard = dc.replace(servo.status(), servoOn=False, started=started, seq=7)  # the planner's newest: off
    h = Handover(IIWA.dof, servo.dt, servo.ask_trajectory, servo.ask_control, lambda _p: None,
                 lambda: heard, servo.progress)
    with pytest.raises(PlanRefused, match="the servo is off"):
        h.start_point()
    with pytest.raises(PlanRefused, match="the servo is off"):
        h.start_point(dc.replace(heard, servoOn=True, seq=6))  # older than what the planner heard
    start, _epoch = h.start_point(dc.replace(heard, servoOn=True, seq=8))  # the servoON's reply
    np.testing.assert_array_equal(start, Q0)
