"""How far a motion has come, from the servo to the client, in-process: no Zenoh, no process.

The servo's interpolator counts the running motion's samples passed (``MotionProgress.runningShare``,
``tests/test_interpolator.py``); the planner relays it on ``Planner/progress`` (``PlannerProgress.runningShare``,
:class:`Handover`); the client's :class:`Motion` reads it as ``progress``. The share changes every cycle
without a new ``seq``: a report of the same number and a later ``tm`` carries a newer one.
"""

from __future__ import annotations

import pytest

from jara_arm.client.errors import MotionFailed
from jara_arm.client.motion import Fate, Motion, ProgressBook
from jara_arm.schema.motion import MOTION_PROGRESS, MotionProgress
from jara_arm.schema.planner import PLANNER_PROGRESS, PlannerProgress
from jara_arm.schema.types import Time

STARTED = Time.from_seconds(100.0)


def report(seq: int, running: int = 0, queued: tuple[int, ...] = (), done: int = 0, discarded: int = 0,
           share: float = 0.0, paused: bool = False, at: float = 0.0) -> PlannerProgress:
    """The planner's ``Planner/progress`` number ``seq``, sent at ``1000 + seq + at`` [s]."""
    return PlannerProgress(Time.from_seconds(1000.0 + seq + at), running, queued, done, discarded, paused,
                           bool(running), STARTED, seq, runningShare=share)


def test_a_motions_progress_is_0_queued_the_reported_share_running_1_done():
    book = ProgressBook()
    first = Motion(book, 5, "moveLinearCartesianRel", lambda: ())
    second = Motion(book, 6, "moveLinearCartesianRel", lambda: ())
    assert (first.fate, first.progress) == (Fate.WAITING, 0.0)
    book.offer(report(1, queued=(5, 6)))
    assert (first.fate, first.progress, second.progress) == (Fate.QUEUED, 0.0, 0.0)
    book.offer(report(2, running=5, queued=(5, 6), share=0.25))
    assert (first.fate, first.progress, second.progress) == (Fate.RUNNING, 0.25, 0.0)
    book.offer(report(2, running=5, queued=(5, 6), share=0.5, at=0.1))  # the same state, 100 ms later
    assert (first.fate, first.progress) == (Fate.RUNNING, 0.5)
    book.offer(report(2, running=5, queued=(5, 6), share=0.3, at=0.05))  # the same state, overtaken
    book.offer(report(1, queued=(5, 6), share=0.9, at=1.0))  # an older state, whatever its time
    assert (first.fate, first.progress) == (Fate.RUNNING, 0.5)
    book.offer(report(3, running=6, queued=(6,), done=5, share=0.1))
    assert (first.fate, first.progress, first.done) == (Fate.DONE, 1.0, True)
    assert (second.fate, second.progress) == (Fate.RUNNING, 0.1)


def test_a_paused_or_discarded_motion_keeps_the_share_it_had_reached():
    book = ProgressBook()
    motion = Motion(book, 8, "movePTPJointRel", lambda: ("0x21 error a test alarm",))
    book.offer(report(1, running=8, queued=(8,), share=0.4))
    book.offer(report(2, queued=(8,), paused=True))  # holding paused: the planner names no running motion
    assert (motion.fate, motion.progress) == (Fate.QUEUED, 0.4)
    book.offer(report(3, running=8, queued=(8,), share=0.6))
    book.offer(report(3, running=8, queued=(8,), share=0.7, at=0.1))
    book.offer(report(4, discarded=8))
    assert (motion.fate, motion.progress, motion.done) == (Fate.DISCARDED, 0.7, False)
    with pytest.raises(MotionFailed, match="a test alarm"):
        motion.wait(timeout=0.1)


def test_a_motion_followed_after_the_reports_that_named_it_is_judged_on_them():
    """The tracker's thread takes reports as they come, so the one that discarded a motion may come before
    the move's reply (and the ``follow``); a later motion done must not make it look done."""
    book = ProgressBook()
    book.offer(report(1, running=5, queued=(5,), share=0.3))
    book.offer(report(2, discarded=5))
    book.offer(report(3, running=6, queued=(6,)))
    book.offer(report(4, done=6, discarded=5))
    late = Motion(book, 5, "movePTPJointRel", lambda: ())
    assert (late.fate, late.progress) == (Fate.DISCARDED, 0.3)
    assert Motion(book, 6, "movePTPJointRel", lambda: ()).fate is Fate.DONE
    assert Motion(book, 7, "movePTPJointRel", lambda: ()).fate is Fate.WAITING  # not reported yet


def test_an_older_peer_without_the_share_still_decodes():
    progress = report(2, running=5, queued=(5,), share=0.5)
    wire = PLANNER_PROGRESS.encode(progress)
    assert PLANNER_PROGRESS.decode(wire, "") == progress
    del wire["runningShare"]
    assert PLANNER_PROGRESS.decode(wire, "").runningShare == 0.0
    servo = MotionProgress(Time.now(), 1, 5, (5,), 0, 0, 0, False, True, False, 100.0, 1.0, (), STARTED, 3, 0.5)
    wire = MOTION_PROGRESS.encode(servo)
    assert MOTION_PROGRESS.decode(wire, "") == servo
    del wire["runningShare"]
    assert MOTION_PROGRESS.decode(wire, "").runningShare == 0.0


def test_the_planner_relays_the_servos_share_without_a_new_number():
    """A ``Servo/motion`` of the same ``seq`` and a later ``tm`` renews the share the planner relays; an
    earlier one does not; a running motion held paused is none, and relays no share."""
    from jara_arm.services.planner.handover import Handover

    heard: list[MotionProgress] = []

    def servo(seq: int, share: float, at: float = 0.0, moving: bool = True, paused: bool = False) -> None:
        heard.append(MotionProgress(Time.from_seconds(1000.0 + seq + at), 1, 7, (7,), 0, 0, 0, paused, moving,
                                    False, 100.0, 1.0 if moving else 0.0, (0.0, 0.0), STARTED, seq, share))

    h = Handover(2, 1e-3, lambda _t: None, lambda _c: None, lambda _p: None, lambda: None,
                 lambda: heard.pop(0) if heard else None)
    servo(3, 0.2)
    first = h.progress()
    assert (first.running, first.runningShare) == (7, 0.2)
    servo(3, 0.6, at=0.1)
    second = h.progress()
    assert (second.running, second.runningShare, second.seq) == (7, 0.6, first.seq)
    servo(3, 0.1, at=0.05)
    assert h.progress().runningShare == 0.6
    servo(4, 0.6, moving=False, paused=True)
    held = h.progress()
    assert (held.running, held.runningShare, held.paused) == (0, 0.0, True) and held.seq > first.seq
