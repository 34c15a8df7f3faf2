"""The alarm logic in-process, no system: the monitor's book of alarms, its detectors (a rating with
debounce, a limit crossing), the watch of a service's token and heartbeat, the timing profiles, which
of two alarm lists is newer, and the servo's braking and glide."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from jara_arm.robots import robot
from jara_arm.schema.codes import AlarmCode
from jara_arm.schema.keys import Service
from jara_arm.schema.types import LimitValue, Time
from jara_arm.services.runtime.timing import SAME_HOST

DT = robot("iiwa").cmd_cycle


def latched(alarm: object, present: bool, at: float = 100.0) -> object:
    """A servo latch of ``alarm`` as its status carries it, latched at ``at`` [s]."""
    from jara_arm.schema.messages import ServoLatch

    return ServoLatch(alarm, present, Time.from_seconds(at))  # type: ignore[arg-type]


def test_book_clears_only_what_has_no_cause():
    from jara_arm.schema.alarms import make_alarm
    from jara_arm.services.alarm_monitor.book import AlarmBook

    book = AlarmBook()
    estop = make_alarm(AlarmCode.EMERGENCY_STOP, "e-stop")
    jump = make_alarm(AlarmCode.OVERSPEED, "jump")
    assert book.raise_alarm(estop) and not book.raise_alarm(estop)  # one per code
    assert book.adopt([latched(jump, True), latched(estop, True, 101)]) == [jump]  # 0x01 was listed already
    cleared, kept = book.clear(lambda code: False)
    assert cleared == [] and kept == [estop, jump]  # the servo says both causes are present
    book.adopt([latched(jump, True), latched(estop, False, 101)])
    cleared, kept = book.clear(lambda code: code == AlarmCode.OVERSPEED)  # the monitor sees one
    assert cleared == [estop] and kept == [jump]
    book.adopt([latched(jump, False)])
    assert book.clear(lambda code: False) == ([jump], []) and book.alarms == ()


def test_rating_debounce_and_crossing():
    from jara_arm.services.alarm_monitor.detectors import AboveRating, Crossing

    over = AboveRating((10.0, 20.0), margin=1.0, samples=3)
    assert [over.update(v) for v in ((11, 0), (11, 0), (0, 0), (11, 0), (11, 25), (11, 25))] == \
        [None, None, None, None, None, 0]  # axis 0 trips on its third sample in a row, not before
    assert over.update((11, 0)) is None and over.present  # tripped once per episode
    over.update((0, 0))
    assert not over.present

    cross = Crossing(tolerance=0.01)
    cross.set_limits((LimitValue(1.0, -1.0),))
    assert cross.update((1.5,)) is None  # beyond already when the limits came: not a crossing
    assert cross.update((0.5,)) is None and not cross.present
    assert cross.update((1.005,)) is None  # within the tolerance
    assert cross.update((1.02,)) == 0 and cross.present
    cross.set_limits((LimitValue(2.0, -1.0),))  # widened: the arm is inside again
    assert cross.update((1.02,)) is None and not cross.present


def test_service_watch_lost_stalled_hung_and_stuck():
    from jara_arm.services.runtime.heartbeat import ServiceWatch
    from jara_arm.services.runtime.timing import Health

    health = Health("test", heartbeat_period=0.01, stall_after=0.05, hung_after=0.2, first_beat_grace=1.0)
    watch = ServiceWatch(Service.SERVO, health)
    assert not watch.token(True, now=10.0) and not watch.stale(10.1)
    # Up, never heard: the first beat may come late (subscriptions settling), so the grace.
    assert not watch.stale(10.3) and not watch.stale(10.99) and watch.stale(11.01)
    assert watch.heard(10.5) is None  # the first beat ends no stall
    assert watch.heard(10.54) is None and watch.stalls == 0  # within stall_after
    assert not watch.stale(10.7) and watch.stale(10.75)  # hung_after past the newest beat
    assert watch.heard(10.64) == pytest.approx(0.1) and watch.stalls == 1  # a stall, counted
    assert "silent for 100 ms" in watch.stall_line(0.1) and "hung above 200 ms" in watch.stall_line(0.1)
    assert "no heartbeat for 300 ms" in watch.why_hung(10.94)
    watch.heard(10.95, ("the servo loop has not turned for 250 ms (deadline 200 ms)",))
    assert watch.hung(10.95) and not watch.stale(10.95)  # stuck while beating
    assert "servo loop" in watch.why_hung(10.95)
    watch.heard(10.96)
    assert not watch.hung(10.97)
    assert watch.token(False, now=11.0) and not watch.stale(12.0) and not watch.hung(12.0)  # lost, not hung


def test_timing_profiles_and_their_arguments():
    import argparse

    from jara_arm.services.runtime.timing import LAN, Health, add_health_arguments, health, health_from_args

    assert SAME_HOST.hung_after < LAN.hung_after
    for profile in (SAME_HOST, LAN):  # ten beats per hung bound at least
        assert profile.hung_after >= 10 * profile.heartbeat_period
    parser = argparse.ArgumentParser()
    add_health_arguments(parser)
    assert health_from_args(parser.parse_args([])) == SAME_HOST
    assert health_from_args(parser.parse_args(["--timing", "lan"])) == LAN
    custom = health_from_args(parser.parse_args(["--hung-after", "0.3"]))
    assert custom.hung_after == 0.3 and custom.heartbeat_period < custom.stall_after < 0.3
    with pytest.raises(ValueError, match="same-host, lan"):
        health("wan")
    with pytest.raises(ValueError, match="hung_after"):
        Health("bad", heartbeat_period=0.1, stall_after=0.5, hung_after=0.4, first_beat_grace=1.0)


def test_newer_alarm_lists():
    from jara_arm.schema.alarms import AlarmList, is_newer

    a = AlarmList(Time(100, 0), Time(50, 0), ())
    later = AlarmList(Time(100, 1), Time(50, 0), ())
    restarted = AlarmList(Time(90, 0), Time(80, 0), ())  # a new monitor wins even if its clock lags
    assert is_newer(a, None) and is_newer(later, a) and not is_newer(a, later) and is_newer(restarted, later)


def test_braking_extrema_and_glide():
    from jara_arm.services.servo.braking import Braking, Glide

    rng = np.random.default_rng(3)
    for _ in range(50):
        a = rng.uniform(3, 15, 3)
        b = Braking(rng.normal(size=3), rng.uniform(-2, 2, 3), rng.uniform(-1, 1, 3) * a, a, a / 0.02, DT,
                    synchronized=bool(rng.integers(2)))
        low, high = b.extrema()
        samples = np.array([b._traj.at_time(t)[0] for t in np.arange(0.0, b.duration + 1e-4, 1e-4)])
        assert np.allclose(samples.min(axis=0), low, atol=1e-7) and np.allclose(samples.max(axis=0), high, atol=1e-7)
    glide = Glide(np.zeros(2), np.array([0.02, -0.01]), 0.2, DT)
    steps = [glide.next() for _ in range(200)]
    assert steps[-1][3] and np.allclose(steps[-1][0], [0.02, -0.01])
    acc = np.array([s[2] for s in steps])
    assert np.abs(acc).max() <= np.pi**2 / 2 * 0.02 / 0.2**2 + 1e-9  # a gentle half cosine


def servo_alarms(cause: dict[int, bool]) -> object:
    """A servo's ``AlarmState`` whose causes are ``cause`` (code -> present, mutable)."""
    import logging

    from jara_arm.services.servo.alarms import AlarmState

    return AlarmState(logging.LoggerAdapter(logging.getLogger("test")), lambda code: cause.get(code, False))


def test_every_status_carries_every_latch_and_the_monitor_that_cleared_a_latch_releases_it():
    """The servo's status carries each latch it holds, with its cause's presence when last looked at and the
    time it latched (the same in every status); ``changed`` asks for a status at once when a latch or its
    cause comes or goes. The monitor that listed a latch releases it by listing it no more: evidence, not a
    timer; a list that does not hold it yet (the monitor has not heard of it yet, or is new) does not."""
    from jara_arm.schema.alarms import AlarmList
    from jara_arm.schema.codes import AlarmType

    cause = {int(AlarmCode.EMERGENCY_STOP): True}
    state = servo_alarms(cause)
    stopped: list = []
    state.latch(AlarmCode.EMERGENCY_STOP, AlarmType.FAULT, "e-stop")
    [first_latch] = state.snapshot()
    assert first_latch.present and state.changed
    state.changed = False  # a status went out
    first, second = Time(100, 0), Time(200, 0)
    state.adopt(AlarmList(Time(101, 0), first, ()), stopped.append)  # made before it heard of the latch
    assert state.snapshot() == (first_latch,) and not state.changed
    listed = AlarmList(Time(102, 0), first, (first_latch.alarm,))
    state.adopt(listed, stopped.append)
    state.look()
    assert not state.changed  # nothing new to say
    cause.clear()  # the arm has stopped: the cause has gone
    state.look()
    assert state.changed and state.snapshot() == (dataclasses.replace(first_latch, present=False),)
    state.changed = False
    state.adopt(dataclasses.replace(listed, tm=Time(102, 5)), stopped.append)  # older than the one held
    assert not stopped  # the servo stopped for it already
    state.adopt(AlarmList(Time(50, 0), second, ()), stopped.append)  # a new monitor (its clock may lag)
    assert int(AlarmCode.EMERGENCY_STOP) in state.latches and not state.changed
    state.adopt(AlarmList(Time(51, 0), second, (first_latch.alarm,)), stopped.append)
    state.adopt(AlarmList(Time(52, 0), second, ()), stopped.append)  # the monitor that listed it cleared it
    assert not state.latches and state.snapshot() == () and state.changed
    state.latch(AlarmCode.EMERGENCY_STOP, AlarmType.FAULT, "e-stop again")
    assert state.snapshot()[0].latched.to_ns() > first_latch.latched.to_ns()  # a new latch, later


def test_a_lost_status_does_not_keep_an_alarm_and_an_old_one_does_not_raise_it_again():
    """The servo's alarms and the monitor's book together, the statuses (``drop``) lost or late as the test
    says: CI run 50 saw an e-stop kept "cause still present" from every clearAlarms for 5 s, its one "cause
    gone" report lost; a status made before a clear still carries the latch cleared."""
    from jara_arm.schema.alarms import AlarmList
    from jara_arm.schema.codes import AlarmType
    from jara_arm.services.alarm_monitor.book import AlarmBook

    book, started, tm = AlarmBook(), Time(100, 0), [0]
    cause = {int(AlarmCode.EMERGENCY_STOP): True}  # braking
    state = servo_alarms(cause)

    def publish() -> None:  # the monitor's list, on a change or LIST_PERIOD, adopted by the servo
        tm[0] += 1
        state.adopt(AlarmList(Time(100, tm[0]), started, book.alarms), lambda _a: None)

    state.latch(AlarmCode.EMERGENCY_STOP, AlarmType.FAULT, "e-stop")
    book.adopt(state.snapshot())
    publish()
    cause.clear()
    state.look()
    old = state.snapshot()  # the arm stopped: "cause gone", this status lost
    assert book.clear(lambda _c: False)[0] == []  # kept: the monitor still believes the cause present
    book.adopt(state.snapshot())  # the next status says again where the cause stands
    cleared, kept = book.clear(lambda _c: False)
    assert [a.code for a in cleared] == [AlarmCode.EMERGENCY_STOP] and kept == []
    assert book.adopt(old) == [] and book.alarms == ()  # made before the clear: a cleared latch, ignored
    publish()  # the servo releases its latch: the monitor that listed it no longer does
    assert not state.latches
    state.latch(AlarmCode.EMERGENCY_STOP, AlarmType.FAULT, "a new e-stop")
    assert book.adopt(state.snapshot()) and [a.code for a in book.alarms] == [AlarmCode.EMERGENCY_STOP]


def test_a_new_servo_process_voids_what_the_one_before_it_latched():
    """A servo that died while its e-stop latch said "cause present" (braking) must not keep 0x01 from every
    clear for good: the first status of the new servo says all that the servo holds, and that is nothing."""
    from jara_arm.schema.alarms import make_alarm
    from jara_arm.services.alarm_monitor.book import AlarmBook

    book = AlarmBook()
    estop = make_alarm(AlarmCode.EMERGENCY_STOP, "e-stop")
    book.adopt([latched(estop, True)])  # the old servo, braking
    assert book.clear(lambda _c: False)[0] == []
    book.adopt([])  # the new servo
    assert book.clear(lambda _c: False) == ([estop], [])
