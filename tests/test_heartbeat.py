"""The services' heartbeat (``services/runtime/heartbeat.py``) on a real Zenoh session.

The alarm monitor's side (silence and stuck loops raise the hung FAULTs) is
provoked for real in ``test_alarms_services.py``; here: what a heartbeat says.
"""

from __future__ import annotations

import collections
import contextlib
import logging
import os
import time
from collections.abc import Iterator

import pytest
import zenoh

from jara_arm.schema import codec
from jara_arm.schema.alarms import HEARTBEAT
from jara_arm.schema.keys import ArmKeys, Service, parse_heartbeat
from jara_arm.services.runtime.heartbeat import Heartbeat, Pulse
from jara_arm.services.runtime.timing import Health

from .support import endpoint, free_port, wait_until

#: Beats every 5 ms, so that these tests see many in little time.
FAST = Health("test", heartbeat_period=0.005, stall_after=0.05, hung_after=1.0, first_beat_grace=1.0)
#: [s] after close(): an observation window of ten heartbeat periods in which no beat may come.
#: (close() joins the heartbeat thread, and a subscriber of the publishing session gets each
#: beat within the put: nothing is on its way when the window starts.)
SILENT_WINDOW = 10 * FAST.heartbeat_period


@pytest.fixture
def session():
    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("listen/endpoints", f'["{endpoint(free_port())}"]')
    conf.insert_json5("scouting/multicast/enabled", "false")
    with zenoh.open(conf) as s:
        yield s


def test_beats_name_the_service_count_up_and_report_a_stuck_loop(session: zenoh.Session):
    keys = ArmKeys("hb-test")
    beats: collections.deque = collections.deque()
    sub = session.declare_subscriber(keys.heartbeat(), lambda s: beats.append(
        (str(s.key_expr), codec.decode_message(HEARTBEAT, s.payload.to_bytes()))))
    heartbeat = Heartbeat(session, keys, Service.PLANNER, health=FAST)
    pulse = heartbeat.pulse("the test loop", deadline=0.2)
    heartbeat.start()
    try:
        wait_until(lambda: len(beats) >= 10, 5.0, what="ten heartbeats")
        assert {parse_heartbeat(k) for k, _ in list(beats)} == {("hb-test", Service.PLANNER.value)}
        seqs = [b.seq for _, b in list(beats)]
        assert seqs == list(range(seqs[0], seqs[0] + len(seqs)))  # one per period, none skipped
        assert all(b.stuck == () for _, b in list(beats))  # never beaten yet: not judged

        # A loop that beats is healthy; one that stops is named once its deadline has passed.
        beats.clear()
        end = time.monotonic() + 0.3
        while time.monotonic() < end:
            pulse.beat()
            time.sleep(FAST.heartbeat_period / 2)
        assert beats and all(b.stuck == () for _, b in list(beats))
        stuck = wait_until(lambda: next((b.stuck for _, b in list(beats) if b.stuck), None), 2.0,
                           what="a heartbeat naming the stuck loop")
        assert len(stuck) == 1 and stuck[0].startswith("the test loop has not turned for ")
        assert "(deadline 200 ms)" in stuck[0]
        beats.clear()
        pulse.beat()
        # Beats come in order: once one names no stuck loop (judged after the beat above, the
        # loop being stuck until then, or after a stall of the heartbeat thread, which restarts
        # the judgement), none after it does.
        wait_until(lambda: any(b.stuck == () for _, b in list(beats)), 2.0,
                   what="a heartbeat judged after the loop turned")
        beats.clear()
        wait_until(lambda: len(beats) >= 3, 2.0, what="more heartbeats")
        assert all(b.stuck == () for _, b in list(beats))
    finally:
        heartbeat.close()
    try:
        # Beats sent before close() returned may still be on their way (under load, one was): wait for the last.
        sent = heartbeat._seq  # the number the next beat would have had
        wait_until(lambda: beats and beats[-1][1].seq == sent - 1, 2.0, what="the last beat sent before close()")
        n = len(beats)
        time.sleep(SILENT_WINDOW)  # the subscriber still listens: a beat after close() would show
        assert len(beats) == n  # closed: silent
    finally:
        sub.undeclare()


def test_pulse_deadline_must_be_positive():
    with pytest.raises(ValueError, match="positive"):
        Pulse("a loop", 0.0)


def test_leave_sends_one_last_beat_that_says_so_then_nothing(session: zenoh.Session):
    keys = ArmKeys("hb-leave")
    beats: collections.deque = collections.deque()
    sub = session.declare_subscriber(keys.heartbeat(), lambda s: beats.append(
        codec.decode_message(HEARTBEAT, s.payload.to_bytes())))
    heartbeat = Heartbeat(session, keys, Service.SERVO, health=FAST)
    heartbeat.start()
    try:
        wait_until(lambda: len(beats) >= 5, 5.0, what="five heartbeats")
        assert not any(b.leaving for b in list(beats))
        heartbeat.leave()
        wait_until(lambda: beats[-1].leaving, 1.0, what="the leaving beat")
        last = list(beats)
        assert [b.leaving for b in last].count(True) == 1 and last[-1].seq >= last[-2].seq
        heartbeat.leave()  # once only
        heartbeat.close()
        time.sleep(SILENT_WINDOW)  # observation window: a beat after leave() and close() would show
        assert len(beats) == len(last)
    finally:
        heartbeat.close()
        sub.undeclare()


def test_a_watch_forgives_a_service_that_said_it_leaves():
    from jara_arm.services.runtime.heartbeat import ServiceWatch

    watch = ServiceWatch(Service.PLANNER, Health("test", 0.005, 0.01, 0.03, 0.5))
    watch.token(True, now=1.0)
    watch.heard(1.01)
    assert watch.hung(1.05)  # silent
    watch.heard(1.06, leaving=True)
    assert not watch.hung(2.0)  # no more beats, token still up: it is on its way out
    assert watch.token(False, now=2.1) and watch.leaving  # gone, as announced
    watch.token(True, now=3.0)  # a new process of it
    assert not watch.leaving


def _deletions_waiting(presence) -> int:
    """Token deletions that arrived and were not drained yet."""
    return sum(1 for s in list(presence._box._samples) if s.kind == zenoh.SampleKind.DELETE)


def test_a_watcher_held_up_while_a_service_leaves_sees_a_departure_not_a_loss(session: zenoh.Session):
    """The leaving beat and the token's deletion both wait in the watcher (its thread held up, a busy machine):
    taken in arrival order, the deletion follows the beat that said it leaves (a CI run raised 0x402 for a
    launcher that stopped in order, draining tokens before beats). Without that beat, a loss; a new process
    of it after either comes up anew."""
    from jara_arm.services.runtime.heartbeat import ServiceWatch
    from jara_arm.services.runtime.presence import Change, Presence

    keys = ArmKeys("hb-presence")
    watches = {s: ServiceWatch(s, FAST) for s in (Service.COMMAND, Service.PLANNER)}
    with Presence(session, keys, watches) as presence:
        seen: list[tuple[Service, Change]] = []

        def drained() -> list[tuple[Service, Change]]:
            seen.extend((e.watch.service, e.change) for e in presence.drain(time.monotonic())
                        if e.change is not Change.STALL)
            return seen

        def start(service: Service):
            token = session.liveliness().declare_token(keys.alive(service))
            heartbeat = Heartbeat(session, keys, service, health=FAST)
            heartbeat.start()
            watch = watches[service]
            wait_until(lambda: drained() and watch.alive and watch.heard_at > watch.up_at, 5.0,
                       what=f"the {service.value}'s token and a beat")
            return token, heartbeat

        command, planner = start(Service.COMMAND), start(Service.PLANNER)
        assert seen == [(Service.COMMAND, Change.UP), (Service.PLANNER, Change.UP)]
        seen.clear()

        # Not drained from here on: the watcher is held up.
        command[1].leave()  # the leaving beat, then the token, as a service that stops in order
        command[0].undeclare()
        command[1].close()
        planner[1].close()  # the planner's process ends: no leaving beat
        planner[0].undeclare()
        wait_until(lambda: _deletions_waiting(presence) == 2, 5.0, what="both deletions waiting in the box")
        # Each service's own samples keep their order; two tokens' deletions need not (a CI run: the
        # planner's came first).
        assert sorted(drained()) == [(Service.COMMAND, Change.LEFT), (Service.PLANNER, Change.LOST)]
        seen.clear()

        command = start(Service.COMMAND)  # a new process of it: watched anew
        assert seen == [(Service.COMMAND, Change.UP)] and not watches[Service.COMMAND].leaving
        command[1].close()
        command[0].undeclare()


# -- starved or hung: the evidence of this host's kernel (services/runtime/starvation.py) ------------
def _child(code: str) -> "subprocess.Popen[bytes]":
    """A Python process running ``code``, returned once its interpreter has started: its start-up runs and
    waits for a CPU, evidence of life that is not what a test watches (under load it lasts past a bound)."""
    import subprocess
    import sys
    child = subprocess.Popen([sys.executable, "-c", "import sys; sys.stdout.write('up\\n'); sys.stdout.flush()\n"
                              + code], stdout=subprocess.PIPE)
    assert child.stdout is not None and child.stdout.readline() == b"up\n"
    return child


def _watch_of(pid: int, host: str | None = None):
    from jara_arm.services.runtime.heartbeat import ServiceWatch
    from jara_arm.services.runtime.starvation import THIS_HOST

    watch = ServiceWatch(Service.PLANNER, Health("test", 0.05, 0.1, 0.3, 1.0))
    watch.token(True, now=time.monotonic())
    # A child's main thread, as its heartbeat thread: its id is the process's.
    watch.heard(time.monotonic(), pid=pid, host=THIS_HOST if host is None else host, tid=pid)
    return watch


def _judged_after(watch, seconds: float) -> bool:
    """Ask ``watch.hung`` every 10 ms for ``seconds`` of real time (the watcher's own cadence),
    as the kernel's counters only move in real time; the last verdict."""
    end = time.monotonic() + seconds
    hung = False
    while time.monotonic() < end:
        hung = watch.hung(time.monotonic())
        time.sleep(0.01)
    return hung


def test_a_silent_sleeping_process_is_hung_at_the_bound():
    """Silent, its heartbeat thread neither runs nor waits (a deadlock, a blocked call): hung once silent
    past the bound, as before."""
    child = _child("import time; time.sleep(30)")
    try:
        watch = _watch_of(child.pid)
        assert _judged_after(watch, 0.8)
        assert "neither ran nor waited for a CPU" in watch.why_hung(time.monotonic())
        assert watch.evidence_line(time.monotonic()) is None
    finally:
        child.kill()
        child.wait()


def test_a_stopped_process_is_hung_at_the_bound_and_named_stopped():
    import signal

    child = _child("import time; time.sleep(30)")
    try:
        watch = _watch_of(child.pid)
        child.send_signal(signal.SIGSTOP)
        assert _judged_after(watch, 0.5)
        assert "stopped (SIGSTOP" in watch.why_hung(time.monotonic())
    finally:
        child.kill()
        child.wait()


def test_a_starved_process_is_not_hung_until_starved_max(monkeypatch):
    """Three busy processes on one core: each waits for the CPU two thirds of the time. Silent past
    the bound, the watched one is starved, not hung (and said so once); past STARVED_MAX it is hung."""

    from jara_arm.services.runtime import heartbeat, starvation

    monkeypatch.setattr(heartbeat, "STARVED_MAX", 1.2)  # the real 5 s, shortened for the test
    spin = "import os, time; os.sched_setaffinity(0, {0}); end = time.monotonic() + 10\nwhile time.monotonic() < end: pass"
    children = [_child(spin) for _ in range(3)]
    try:
        wait_until(lambda: all(os.sched_getaffinity(c.pid) == {0} for c in children), timeout=5)
        watch = _watch_of(children[0].pid)
        assert not _judged_after(watch, 0.8)  # past the 0.3 s bound: starved
        line = watch.evidence_line(time.monotonic())
        assert line is not None and "starved of the CPU" in line and watch.evidence_line(time.monotonic()) is None
        assert _judged_after(watch, 0.6)  # silent past STARVED_MAX (1.2 s here): hung all the same
        assert "starved" in watch.why_hung(time.monotonic())
    finally:
        for c in children:
            c.kill()
            c.wait()
    assert starvation.STARVED_MAX == 5.0


def test_a_process_that_beats_unheard_is_not_hung_until_starved_max(monkeypatch):
    """Its heartbeat thread runs every period and nothing arrives (the link or the watcher's reception
    stalls): not hung, said once; past STARVED_MAX hung all the same."""
    from jara_arm.services.runtime import heartbeat

    monkeypatch.setattr(heartbeat, "STARVED_MAX", 1.2)
    child = _child("import time\nwhile True: time.sleep(0.02)")
    try:
        watch = _watch_of(child.pid)
        assert not _judged_after(watch, 0.8)
        line = watch.evidence_line(time.monotonic())
        assert line is not None and "its beats do not arrive" in line
        assert _judged_after(watch, 0.6)
        assert "its beats did not arrive" in watch.why_hung(time.monotonic())
    finally:
        child.kill()
        child.wait()


def test_a_thread_woken_far_more_often_than_it_beats_is_hung():
    """A heartbeat thread that wakes every millisecond is not beating: it is a thread asking for a GIL
    that a hung thread holds (CPython asks every 5 ms). Hung at the bound, as a deadlock is."""
    # Real-time where permitted: a thread that waits for a CPU is starved, whatever else it does (two test
    # workers beside a busy loop per core judged this child starved), and this test is about the wakes.
    child = _child("import os, time\ntry: os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(30))\n"
                   "except OSError: pass\nwhile True: time.sleep(0.001)")
    try:
        watch = _watch_of(child.pid)
        assert _judged_after(watch, 0.8)
        assert watch.evidence_line(time.monotonic()) is None
    finally:
        child.kill()
        child.wait()


@contextlib.contextmanager
def _starved_child() -> "Iterator[subprocess.Popen[bytes]]":
    """A process whose main thread sleeps (as one waiting for a GIL does) while another of its threads
    waits for a CPU beside two busy processes, all on one core."""
    spin = "import os, time; os.sched_setaffinity(0, {0}); end = time.monotonic() + 10\nwhile time.monotonic() < end: pass"
    busy = [_child(spin) for _ in range(2)]
    child = _child("import os, threading, time\nos.sched_setaffinity(0, {0})\n"
                   "def spin():\n    end = time.monotonic() + 10\n    while time.monotonic() < end: pass\n"
                   "threading.Thread(target=spin, daemon=True).start()\ntime.sleep(30)")
    try:
        wait_until(lambda: all(os.sched_getaffinity(c.pid) == {0} for c in [*busy, child]), timeout=5)
        yield child
    finally:
        for c in [*busy, child]:
            c.kill()
            c.wait()


def test_a_process_whose_other_threads_wait_for_a_cpu_is_starved():
    """Its heartbeat thread sleeps, and another of its threads waits for a CPU: starved, not hung (8 arms
    on 2 cores: a false 0x412)."""
    with _starved_child() as child:
        watch = _watch_of(child.pid)  # its main thread, asleep, as the heartbeat thread
        assert not _judged_after(watch, 0.8)
        line = watch.evidence_line(time.monotonic())
        assert line is not None and "starved of the CPU" in line


def _stall_line_of(pid: int) -> str:
    """The warning a watcher logs when the service of ``pid`` (its main thread as the heartbeat thread)
    beats again after a silence watched past the stall bound."""
    from jara_arm.services.runtime.starvation import THIS_HOST

    watch = _watch_of(pid)
    _judged_after(watch, 0.2)  # the test profile: evidence kept from 75 ms of silence, a stall from 100 ms
    gap = watch.heard(time.monotonic(), pid=pid, host=THIS_HOST, tid=pid)
    assert gap is not None
    return watch.stall_line(gap)


def test_a_stall_of_a_starved_process_says_so():
    """A stall warning says whether the machine kept the service from a CPU: what a user reads first."""
    with _starved_child() as child:
        line = _stall_line_of(child.pid)
    assert "; starved of the CPU: its threads waited for a CPU" in line, line


def test_a_stall_of_a_process_that_stood_still_says_it_was_not_starved():
    child = _child("import time; time.sleep(30)")
    try:
        line = _stall_line_of(child.pid)
    finally:
        child.kill()
        child.wait()
    assert "; not starved of the CPU: its threads waited for a CPU 0 ms" in line, line


def test_a_stall_cause_needs_evidence():
    """Under ``STALL_EVIDENCE_MIN`` of counters nothing is claimed; a stopped thread is said stopped."""
    from jara_arm.services.runtime.starvation import STALL_EVIDENCE_MIN, ThreadSched, stall_cause

    before = ThreadSched(False, 1.0, 100, 2.0)
    assert stall_cause(before, ThreadSched(False, 1.02, 101, 2.02), STALL_EVIDENCE_MIN / 2) == "cause not measured"
    assert stall_cause(before, ThreadSched(False, 1.0, 100, 2.06), 0.2).startswith("starved of the CPU: ")
    assert stall_cause(before, ThreadSched(False, 1.0, 100, 2.04), 0.2).startswith("not starved of the CPU: ")
    assert stall_cause(before, ThreadSched(True, 1.0, 100, 2.0), 0.2).startswith("its process was stopped")


def test_a_beat_from_another_host_gives_no_evidence():
    """Another host's pid means nothing here: silence past the bound is hung, as before."""

    watch = _watch_of(os.getpid(), host="another-boot-id/pid:[1]")
    assert watch.pid == 0
    assert _judged_after(watch, 0.5)




def test_a_start_that_hangs_dumps_every_stack_and_one_that_ends_dumps_none(
        monkeypatch: pytest.MonkeyPatch, capfd: pytest.CaptureFixture[str],
        caplog: pytest.LogCaptureFixture) -> None:
    """The service framework's start watch: a service whose start hangs has every thread's stack on stderr
    (the hanging call named) after ``START_STUCK_AFTER``; a service that is up before it, none."""
    import argparse
    import threading

    from jara_arm.robots import robot
    from jara_arm.services.runtime import service

    release = threading.Event()

    class Fake(service.ArmService):
        SERVICE = Service.PLANNER

        def start(self, ctx: service.ServiceContext) -> None:
            self.hanging_start_step()
            ctx.up("fake up")

        def hanging_start_step(self) -> None:
            release.wait(10.0)

    @contextlib.contextmanager
    def serving() -> Iterator[None]:
        conf = zenoh.Config()
        conf.insert_json5("mode", '"peer"')
        conf.insert_json5("listen/endpoints", f'["{endpoint(free_port())}"]')
        conf.insert_json5("scouting/multicast/enabled", "false")
        stop = threading.Event()
        thread = threading.Thread(target=service._serve, args=(Fake(), conf, [("t1", robot("iiwa"))], FAST, stop,
                                                               argparse.Namespace(), 0))
        thread.start()
        try:
            yield
        finally:
            release.set()
            stop.set()
            thread.join(10.0)
        assert not thread.is_alive()

    err = ""

    def stderr_has(*texts: str) -> bool:
        nonlocal err
        err += capfd.readouterr().err
        return all(text in err for text in texts)

    # Every 0.2 s while stuck (a slow session open gets one too: it is a start not finished).
    monkeypatch.setattr(service, "START_STUCK_AFTER", 0.2)
    with serving():
        # A dump written while pytest empties its capture file may lose lines: the next one brings them.
        wait_until(lambda: stderr_has("Timeout", "in hanging_start_step", "in start"), 10.0, 0.05,
                   "the stacks of a hanging start", explain=lambda: err)
    release.set()  # the next start does not hang
    with caplog.at_level(logging.INFO, service.log.name), serving():
        wait_until(lambda: "fake up" in caplog.text, 10.0, 0.01, "the fake service up")
        err = ""
        capfd.readouterr()  # dumps of a slow session open, before it was up
        time.sleep(0.6)  # three periods: a dump not cancelled comes in this window
        assert not stderr_has("Timeout"), err
