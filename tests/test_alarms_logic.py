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


def test_book_clears_only_what_has_no_cause():
    from jara_arm.schema.alarms import AlarmReport, make_alarm
    from jara_arm.services.alarm_monitor.book import AlarmBook

    book = AlarmBook()
    estop = make_alarm(AlarmCode.EMERGENCY_STOP, "e-stop")
    jump = make_alarm(AlarmCode.OVERSPEED, "jump")
    assert book.raise_alarm(estop) and not book.raise_alarm(estop)  # one per code
    assert book.report(AlarmReport(jump, True, Service.SERVO.value))  # still braking
    assert book.report(AlarmReport(estop, True, Service.SERVO.value)) is False
    cleared, kept = book.clear(lambda code: False)
    assert cleared == [] and kept == [estop, jump]  # the servo says both causes are present
    book.report(AlarmReport(estop, False, Service.SERVO.value))
    cleared, kept = book.clear(lambda code: code == AlarmCode.OVERSPEED)  # the monitor sees one
    assert cleared == [estop] and kept == [jump]
    book.report(AlarmReport(jump, False, Service.SERVO.value))
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


def test_a_latch_is_reported_again_on_each_list_that_does_not_hold_it():
    """The servo's own alarm goes to the monitor when raised; a monitor list without it (the report was lost,
    or a new monitor) makes the servo report it again, a list that holds it does not, and the monitor that
    listed it releases it by listing it no more: evidence, not a timer."""
    import logging

    from jara_arm.schema.alarms import AlarmList, AlarmReport
    from jara_arm.schema.codes import AlarmType
    from jara_arm.services.servo.alarms import AlarmState

    class Reports:
        def __init__(self) -> None:
            self.sent: list[AlarmReport] = []

        def put_message(self, _kind: object, report: AlarmReport) -> None:
            self.sent.append(report)

    reports, stopped = Reports(), []
    state = AlarmState(reports, logging.LoggerAdapter(logging.getLogger("test")), lambda code: True)  # type: ignore[arg-type]
    state.latch(AlarmCode.EMERGENCY_STOP, AlarmType.FAULT, "e-stop")
    assert len(reports.sent) == 1
    first, second = Time(100, 0), Time(200, 0)
    state.adopt(AlarmList(Time(101, 0), first, ()), stopped.append)  # lost, or the list crossed the report
    assert len(reports.sent) == 2
    listed = AlarmList(Time(102, 0), first, (reports.sent[0].alarm,))
    state.adopt(listed, stopped.append)
    state.adopt(dataclasses.replace(listed, tm=Time(103, 0)), stopped.append)
    assert len(reports.sent) == 2 and not stopped  # held: said once, and the servo stopped for it already
    state.adopt(AlarmList(Time(50, 0), second, ()), stopped.append)  # a new monitor (its clock may lag)
    assert len(reports.sent) == 3 and int(AlarmCode.EMERGENCY_STOP) in state.latches
    state.adopt(AlarmList(Time(51, 0), second, (reports.sent[0].alarm,)), stopped.append)
    state.adopt(AlarmList(Time(52, 0), second, ()), stopped.append)  # the monitor that listed it cleared it
    assert len(reports.sent) == 3 and not state.latches

