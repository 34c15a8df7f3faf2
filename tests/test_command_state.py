"""The command service's queue bookkeeping in-process, no process: ``StateTracker`` takes the planner's
newest message by its number, publishes the state only when it changes, and reads what arrived before
it says the servo is silent."""

from __future__ import annotations

import dataclasses
import threading
import time

from jara_arm.robots import robot
from jara_arm.schema import messages
from jara_arm.schema.codes import StateBit
from jara_arm.schema.planner import PlannerProgress
from jara_arm.schema.types import Time

from .support import wait_until

N = robot("iiwa").axis_num


def progress(queued=(), paused=False, seq=1, started=100.0, capacity=3) -> PlannerProgress:
    return PlannerProgress(Time.now(), queued[0] if queued else 0, tuple(queued), 0, 0, paused, bool(queued),
                           Time.from_seconds(started), seq, capacity=capacity)


def test_the_newest_planner_message_wins_by_its_number():
    from jara_arm.services.command.state import StateTracker

    published: list[tuple[int, int]] = []
    tracker = StateTracker(publish=lambda view: published.append((view.bits, view.queue_length)))
    tracker.on_progress(progress((1, 2, 3), seq=5))
    assert tracker.view().full and tracker.view().queue_length == 3
    tracker.on_progress(progress((1,), seq=4))  # older: on its way before the last
    tracker.on_progress(progress((1,), seq=5))  # the same number: nothing new
    assert tracker.view().queue_length == 3
    tracker.on_progress(progress((2, 3), paused=True, seq=6))
    assert (tracker.view().queue_length, tracker.view().paused, tracker.view().full) == (2, True, False)
    tracker.on_progress(None)  # the planner did not answer: nothing learnt
    assert tracker.view().queue_length == 2
    tracker.on_progress(progress((7,), seq=1, started=200.0))  # a restarted planner
    assert tracker.view().queue_length == 1 and not tracker.view().paused
    tracker.on_planner_gone()
    assert tracker.view().queue_length == 0
    tracker.on_progress(progress((7,), seq=2, started=200.0))  # still on its way from the gone one
    assert tracker.view().queue_length == 0
    tracker.on_progress(progress((), seq=1, started=300.0))
    tracker.on_progress(progress((4, 5), seq=2, started=300.0, capacity=2))  # the planner's capacity, not ours
    assert tracker.view().full and tracker.view().capacity == 2
    assert published == [(StateBit.MOVING | StateBit.BUFFER_FULL, 3), (StateBit.MOVING | StateBit.PAUSED, 2),
                         (StateBit.MOVING, 1), (0, 0), (StateBit.MOVING | StateBit.BUFFER_FULL, 2)]


def test_the_newest_servo_status_wins_by_its_number():
    """A ``Servo/power`` reply's status is taken in at once; a ``Servo/status`` publication made before it,
    arriving after it, changes nothing; a restarted servo's statuses are newer."""
    from jara_arm.services.command.state import StateTracker

    tracker = StateTracker(publish=lambda view: None)
    z = (0.0,) * N
    started = Time.from_seconds(100.0)
    off = messages.ServoStatus(Time.now(), False, False, False, 0, 0, 0, 0, z, z, z, started=started, seq=7)
    tracker.on_status(off)
    on = dataclasses.replace(off, servoOn=True, seq=9)  # the reply to servoON
    tracker.on_status(on)
    assert tracker.view().servo_on
    tracker.on_status(dataclasses.replace(off, seq=8, tm=Time.now()))  # published before the reply
    assert tracker.view().servo_on
    tracker.on_status(None)  # the servo did not answer: nothing learnt
    assert tracker.view().servo_on
    tracker.on_status(dataclasses.replace(off, started=Time.from_seconds(200.0), seq=1))  # a restarted servo
    assert not tracker.view().servo_on
    # Once the one held is stale, another servo process's status counts: one restarted after the wall clock
    # stepped back; an older one of the same process still does not (this process's threads were held up).
    tracker = StateTracker(publish=lambda view: None, stale_after=0.05)
    tracker.on_status(on)
    wait_until(lambda: not tracker.view().servo_heard, 2.0, what="the status stale")
    tracker.on_status(dataclasses.replace(off, seq=8))
    assert not tracker.view().servo_heard
    tracker.on_status(dataclasses.replace(off, started=Time.from_seconds(50.0), seq=1))
    assert tracker.view().servo_heard and not tracker.view().servo_on


def test_the_state_is_published_only_when_it_changes():
    from jara_arm.services.command.state import StateTracker

    published: list[int] = []
    tracker = StateTracker(publish=lambda view: published.append(view.bits))
    z = (0.0,) * N
    status = messages.ServoStatus(Time.now(), True, False, False, 0, 0, 0, 0, z, z, z)
    for _ in range(100):
        tracker.on_status(status)
        tracker.on_progress(progress(seq=1))
        tracker.tick()
    assert published == [StateBit.SERVO_ON]
    tracker.on_status(dataclasses.replace(status, moving=True))
    assert published == [StateBit.SERVO_ON, StateBit.SERVO_ON | StateBit.MOVING]


def test_what_arrived_together_is_judged_together():
    """A command service held up for longer than the staleness window finds the planner's progress and the
    servo's statuses waiting (``Watcher.drain``): the servo is not said off before its statuses are in. Judged
    after the progress alone it said 0x02, a moving arm whose servo is off (an 8-arm soak on 2 cores)."""
    from jara_arm.services.command.state import StateTracker

    published: list[int] = []
    tracker = StateTracker(publish=lambda view: published.append(view.bits), stale_after=0.5)
    z = (0.0,) * N
    status = messages.ServoStatus(Time.now(), True, False, False, 0, 0, 0, 0, z, z, z, seq=1)
    tracker.on_status(status)
    wait_until(lambda: not tracker.view().servo_heard, 2.0, what="the status stale")  # held up, unpublished
    tracker.catch_up = lambda: None  # a watcher drains (here: the test, in its order)
    tracker.on_progress(progress((1,), seq=1))
    tracker.on_status(dataclasses.replace(status, moving=True, seq=2, tm=Time.now()))
    tracker.tick()
    assert published == [StateBit.SERVO_ON, StateBit.SERVO_ON | StateBit.MOVING]
    wait_until(lambda: not tracker.view().servo_heard, 2.0, what="the status stale")
    tracker.tick()  # a drain that found nothing: the servo stays silent, now it is off
    assert published[-1] == StateBit.MOVING


def test_a_reply_to_a_command_held_up_waits_for_the_drain_to_say_the_servo_is_off():
    """A call's reply (the planner's progress) taken in while the servo's status is stale: with a watcher
    (``catch_up``) the servo's newer statuses may be waiting unread, so the next drain publishes the state, not
    the reply; a drain that finds the servo silent says it is off."""
    from jara_arm.services.command.state import StateTracker

    published: list[int] = []
    tracker = StateTracker(publish=lambda view: published.append(view.bits), stale_after=0.5)
    z = (0.0,) * N
    status = messages.ServoStatus(Time.now(), True, False, False, 0, 0, 0, 0, z, z, z, seq=1)
    tracker.on_status(status)
    waiting = [dataclasses.replace(status, moving=True, seq=2)]

    def drain() -> None:
        while waiting:
            tracker.on_status(dataclasses.replace(waiting.pop(), tm=Time.now()))
        tracker.tick()

    wait_until(lambda: not tracker.view().servo_heard, 2.0, what="the status stale")  # held up: not drained
    tracker.catch_up = drain
    tracker.on_progress(progress((1,), seq=1))  # a plan call's reply
    assert published == [StateBit.SERVO_ON], "a reply said the servo was off while its statuses waited unread"
    drain()
    assert published == [StateBit.SERVO_ON, StateBit.SERVO_ON | StateBit.MOVING]
    # A servo that stays silent: a drain (view() runs one once stale) says it is off.
    wait_until(lambda: tracker.view() is not None and published[-1] == StateBit.MOVING, 2.0,
               what="the silent servo said off")


def test_a_stale_view_first_takes_in_what_arrived():
    """A command service held up without a CPU has statuses waiting: the view reads them before it says
    "no status" (``StateTracker.catch_up``); with nothing waiting it still says so."""
    from jara_arm.services.command.state import StateTracker

    tracker = StateTracker(publish=lambda view: None, stale_after=0.05)
    z = (0.0,) * N
    status = messages.ServoStatus(Time.now(), True, False, False, 0, 0, 0, 0, z, z, z)
    tracker.on_status(status)
    assert tracker.view().servo_heard and tracker.view().servo_on
    waiting: list[messages.ServoStatus] = []
    tracker.catch_up = lambda: [tracker.on_status(s) for s in waiting] and waiting.clear()
    wait_until(lambda: not tracker.view().servo_heard, 2.0, what="the status stale")  # none waiting: stale
    waiting.append(status)
    view = tracker.view()  # stale, but one waits: taken in first
    assert view.servo_heard and view.servo_on and not waiting


def test_a_motion_request_listens_for_a_status_before_it_says_there_is_none():
    """A command service whose receiving threads were held up has no status yet: the view of a motion
    request waits up to ``listen`` for one (a status arriving meanwhile counts); a servo that stays
    silent is still "not heard", after ``listen``, not before."""
    from jara_arm.services.command.state import StateTracker

    tracker = StateTracker(publish=lambda view: None, stale_after=0.05)
    z = (0.0,) * N
    status = messages.ServoStatus(Time.now(), True, False, False, 0, 0, 0, 0, z, z, z)
    drains: list[float] = []
    tracker.catch_up = lambda: drains.append(time.monotonic())
    t0 = time.monotonic()
    view = tracker.view(listen=0.2)  # nothing ever came
    assert not view.servo_heard and time.monotonic() - t0 >= 0.2
    assert len(drains) >= 2  # what arrived meanwhile was looked for, not only once
    late = threading.Timer(0.1, tracker.on_status, (status,))
    late.start()
    try:
        view = tracker.view(listen=5.0)
    finally:
        late.join()
    assert view.servo_heard and view.servo_on
    wait_until(lambda: not tracker.view().servo_heard, 2.0, what="the status stale")
    drains.clear()
    assert not tracker.view().servo_heard  # a plain view (getState) looks once and does not wait
    assert len(drains) == 1


def test_the_measured_joints_first_take_in_what_arrived():
    """``getFeedbackPos*`` read the newest status that arrived, read by the watcher or not: right after a
    client learnt its motion ended, the end pose, not one from before it."""
    from jara_arm.services.command.state import StateTracker

    tracker = StateTracker(publish=lambda view: None)
    z = (0.0,) * N
    moving = messages.ServoStatus(Time.now(), True, True, False, 0, 0, 0, 0, z, z, z, seq=1, pos=(0.1,) * N)
    tracker.on_status(moving)
    ended = dataclasses.replace(moving, moving=False, seq=2, pos=(0.3,) * N)
    waiting = [ended]  # arrived, not read yet: the watcher's thread has not run

    def drain() -> None:
        while waiting:
            tracker.on_status(waiting.pop())

    tracker.catch_up = drain
    newest = tracker.measured_joints()
    assert newest is not None and newest[0] == ended.pos, newest
    tracker.catch_up = None  # no watcher (a test's tracker): the newest read so far
    assert tracker.measured_joints()[0] == ended.pos


def test_the_state_first_takes_in_what_arrived():
    """``getState`` right after a client learnt from ``Planner/progress`` that its motion ended: not MOVING
    from the reports this service read before, though its own status is fresh (not stale)."""
    from jara_arm.services.command.state import StateTracker

    tracker = StateTracker(publish=lambda view: None)
    z = (0.0,) * N
    moving = messages.ServoStatus(Time.now(), True, True, False, 0, 0, 0, 0, z, z, z, seq=1)
    tracker.on_status(moving)
    tracker.on_progress(progress(queued=(7,), seq=1))
    assert tracker.view().moving
    waiting: list = [progress(seq=2), dataclasses.replace(moving, moving=False, seq=2)]  # arrived, not read

    def drain() -> None:
        for message in waiting:
            (tracker.on_progress if isinstance(message, PlannerProgress) else tracker.on_status)(message)
        waiting.clear()

    tracker.catch_up = drain
    view = tracker.view()
    assert not view.moving and view.queue_length == 0 and view.servo_on, view


def test_after_a_motion_done_the_joints_come_from_a_status_made_after_it():
    """The planner's word that a motion is done and the servo's statuses take different paths: a status made
    before the end may be the newest here while those after it are still on their way (or dropped). The
    joints are read from one stamped at the word or later, waited for a moment (``ARRIVAL_LISTEN``)."""
    from jara_arm.services.command.state import StateTracker
    from jara_arm.services.runtime.timing import ARRIVAL_LISTEN

    tracker = StateTracker(publish=lambda view: None)
    z = (0.0,) * N
    before = messages.ServoStatus(Time.now(), True, True, False, 0, 0, 0, 0, z, z, z, pos=(0.1,) * N, seq=1)
    waiting: list[messages.ServoStatus] = []

    def drain() -> None:
        while waiting:
            tracker.on_status(waiting.pop())

    tracker.catch_up = drain
    tracker.on_status(before)
    assert tracker.measured_joints()[0] == before.pos  # no motion done yet: no wait
    time.sleep(0.01)
    tracker.on_progress(dataclasses.replace(progress(seq=2), lastDone=1))  # stamped now: after ``before``
    after = dataclasses.replace(before, tm=Time.now(), pos=(0.2,) * N, moving=False, seq=2)
    threading.Timer(0.1, lambda: waiting.append(after)).start()
    t0 = time.monotonic()
    assert tracker.measured_joints()[0] == after.pos, "the pose from before the motion's end"
    assert 0.08 < time.monotonic() - t0 < ARRIVAL_LISTEN
    # Read again: the status after the end is in, no wait.
    t0 = time.monotonic()
    assert tracker.measured_joints()[0] == after.pos and time.monotonic() - t0 < 0.05
    # None comes (a servo gone): the newest after the bound, not a hang.
    tracker.on_progress(dataclasses.replace(progress(seq=3), lastDone=2))
    t0 = time.monotonic()
    assert tracker.measured_joints()[0] == after.pos
    assert ARRIVAL_LISTEN - 0.01 < time.monotonic() - t0 < ARRIVAL_LISTEN + 0.2
