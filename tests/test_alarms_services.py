"""Faults of the services themselves, for real: the whole system under ``jara-arm up``
(``alarm_system.py``), once for the module.

Each service killed (SIGKILL) or hung (SIGSTOP) in the middle of a motion, the alarm monitor
among them: the FAULT on both Common interfaces and as an event, the launcher's restart of a
killed service, the arm stopped without a jump and the queue discarded, and the way back to
work once the cause has gone (``alarm_system.py``'s checks). A restarted monitor takes the
active alarms over; its alarm list and the events tell one story.

Detection latency (cause -> alarm event received here, or the servo's state where no monitor
publishes one) is measured for each and printed at the end of the module (``pytest -s`` shows
it); the cause is the SIGKILL or the SIGSTOP.
"""

from __future__ import annotations

import contextlib
import os
import signal
import time
from collections.abc import Iterator

import pytest
import zenoh

from jara_arm.schema.alarms import ALARM_LIST, AlarmEventKind, format_code
from jara_arm.schema.codes import AlarmCode, AlarmType, ReturnCode, StateBit
from jara_arm.schema.keys import Service
from jara_arm.schema.messages import SERVO_STATUS, ServoLatch
from jara_arm.schema.operations import OP
from jara_arm.schema.types import Time
from jara_arm.services.runtime.timing import SAME_HOST
from jara_arm.services.runtime.wire import decode_sample

from .alarm_system import (
    N,
    AlarmArm,
    check_alarm,
    check_back_to_work,
    check_no_jump,
    check_queue_discarded,
    latency,
)
from .support import wait_alive, wait_until

pytestmark = pytest.mark.timeout(60)


@pytest.fixture
def arm(alarm_system: AlarmArm) -> AlarmArm:
    """conftest's ``alarm_system``, back at its starting point."""
    alarm_system.reset()
    return alarm_system


@contextlib.contextmanager
def stopped(pid: int) -> Iterator[None]:
    """SIGSTOP ``pid``; SIGCONT when the block ends, whatever happens."""
    os.kill(pid, signal.SIGSTOP)
    try:
        yield
    finally:
        os.kill(pid, signal.SIGCONT)


def start_long_motion(arm: AlarmArm, ratio: int = 20) -> int:
    """Two queued PTPs at ``ratio`` [%] of the joint speeds, the arm under way in the first; the index of the
    next alarm event."""
    arm.ok(arm.middle(OP.setSpeedJoint, {"spdRatio": ratio}))
    base = arm.consumed()
    arm.ok(arm.middle(OP.movePTPJointRel, {"jointPoints": (-0.6,) + (0.0,) * (N - 1)}))
    arm.ok(arm.middle(OP.movePTPJointRel, {"jointPoints": (0.3,) + (0.0,) * (N - 1)}))
    since = arm.mark()
    arm.under_way(base, 500)
    assert arm.state() & StateBit.MOVING, f"{arm.common(OP.getActiveAlarm)}\n{arm.log_tail()}"
    return since


def check_fault_without(arm: AlarmArm, service: Service, code: AlarmCode) -> None:
    """While ``service`` is down or stopped: the other Common interface lists the FAULT and sets bit 0x04."""
    common = arm.servo if service is Service.COMMAND else arm.common  # ask one that answers
    reply = common(OP.getActiveAlarm)  # forwarded to the monitor
    alarms = arm.ok(reply)["alarms"]
    assert [(a.code, a.type) for a in alarms[:1]] == [(code, AlarmType.FAULT)], reply
    # and, when the FAULT cut the queued motions short while the servo lived, the 0x420 WARNING naming them
    assert all(a.code == AlarmCode.MOTION_NOT_COMPLETED and a.type is AlarmType.WARNING
               and "discarded before their end" in a.description for a in alarms[1:]), reply
    wait_until(lambda: common(OP.getState)["state"] & StateBit.ALARM, 0.5, 0.005,
               f"bit 0x04 of the {'servo' if service is Service.COMMAND else 'command'}'s state")


def kill_mid_motion(arm: AlarmArm, service: Service, code: AlarmCode) -> float:
    """SIGKILL ``service`` while the arm moves; checks up to its restart. The time of the kill [s]."""
    since = start_long_motion(arm)
    pid = arm.pid(service)
    mark = len(arm.proc.lines)
    cause = time.time()
    os.kill(pid, signal.SIGKILL)
    t, event = arm.event(code, since)
    latency(f"{service.value} SIGKILL", cause, t)
    assert event.alarm.type is AlarmType.FAULT and service.value in event.alarm.description
    check_fault_without(arm, service, code)
    arm.proc.wait_for_line("died with SIGKILL; restarting", timeout=5, start=mark)
    arm.proc.wait_for_line(f"arm0/{service.value}: {service.value} up", timeout=20, start=mark)
    wait_alive(arm.session, "arm0", [service], timeout=10)
    check_alarm(arm, code, AlarmType.FAULT, servo_on=False)  # both interfaces agree again
    check_queue_discarded(arm)
    return cause


def hang_mid_motion(arm: AlarmArm, service: Service, code: AlarmCode) -> float:
    """SIGSTOP ``service`` while the arm moves, SIGCONT once the FAULT is raised and kept; the cause [s]."""
    since = start_long_motion(arm)
    cause = time.time()
    with stopped(arm.pid(service)):
        t, event = arm.event(code, since)
        latency(f"{service.value} SIGSTOP (threshold {SAME_HOST.hung_after * 1e3:.0f} ms)", cause, t)
        assert event.alarm.type is AlarmType.FAULT and "hangs" in event.alarm.description, event
        check_fault_without(arm, service, code)
        via = arm.servo if service is Service.COMMAND else arm.common
        kept = via(OP.clearAlarms)  # its cause is still there
        assert kept.id == ReturnCode.STATUS_ERR and format_code(code) in kept.comment, kept
    check_alarm(arm, code, AlarmType.FAULT, servo_on=False)
    check_queue_discarded(arm)
    return cause


# What each service's loss or hang raises. The servo's kill is the one case without the smooth stop: the
# simulated arm restarts at its ready pose (a real one would be held by its brakes).
FAULTS = [
    pytest.param(Service.SERVO, "kill", AlarmCode.SERVO_LOST, id="servo-SIGKILL-0x400"),
    pytest.param(Service.PLANNER, "kill", AlarmCode.PLANNER_LOST, id="planner-SIGKILL-0x401"),
    pytest.param(Service.COMMAND, "kill", AlarmCode.COMMAND_LOST, id="command-SIGKILL-0x402"),
    pytest.param(Service.SERVO, "hang", AlarmCode.SERVO_HUNG, id="servo-SIGSTOP-0x410"),
    pytest.param(Service.PLANNER, "hang", AlarmCode.PLANNER_HUNG, id="planner-SIGSTOP-0x411"),
    pytest.param(Service.COMMAND, "hang", AlarmCode.COMMAND_HUNG, id="command-SIGSTOP-0x412"),
]


@pytest.mark.parametrize("service, how, code", FAULTS)
def test_a_service_killed_or_hung_mid_motion_is_a_fault(arm: AlarmArm, service: Service, how: str,
                                                        code: AlarmCode):
    """SIGKILL: the FAULT names the lost service and the launcher restarts it; SIGSTOP (token up, heartbeat
    silent): the FAULT says it hangs and stays while it does. Either way the arm stops smoothly (except a
    killed servo's), the queue is discarded, and the arm is back to work once the alarm is cleared."""
    cause = (kill_mid_motion if how == "kill" else hang_mid_motion)(arm, service, code)
    if not (service is Service.SERVO and how == "kill"):
        check_no_jump(arm, since=cause)
    check_back_to_work(arm)


def kill_servo_while_braking(arm: AlarmArm) -> bool:
    """An e-stop mid-motion, and the servo SIGKILLed as soon as its status says its latch's cause is present
    (the arm brakes); back once the launcher's new servo is up. True if no status of the dead servo said the
    cause had gone (the kill came while it braked), False if the kill was late. At 60 % the braking lasts about
    three times as long as at 20 %: a starved test process's kill came late in 3 tries of 3 at 20 % (a quiet
    run of three test workers)."""
    start_long_motion(arm, 60)
    statuses = arm.session.declare_subscriber(arm.keys.servo_status, zenoh.handlers.FifoChannel(1024))
    try:
        arm.session.put(arm.keys.estop, b"")
        started: list[Time] = []  # of the servo that is killed: its first status's
        seen: list[ServoLatch] = []  # the e-stop latch in every status of that servo

        def heard_present() -> bool:
            for sample in iter(statuses.try_recv, None):
                status = decode_sample(SERVO_STATUS, sample)
                started[:] = started or [status.started]
                if status.started == started[0]:
                    seen.extend(x for x in status.latches if x.alarm.code == AlarmCode.EMERGENCY_STOP)
            return any(x.present for x in seen)

        wait_until(heard_present, 5.0, 0.001, "the servo's status with its e-stop latch, its cause present")
        mark = len(arm.proc.lines)
        os.kill(arm.pid(Service.SERVO), signal.SIGKILL)
        arm.proc.wait_for_line("died with SIGKILL; restarting", timeout=5, start=mark)
        arm.proc.wait_for_line("arm0/servo: servo up", timeout=20, start=mark)
        wait_alive(arm.session, "arm0", [Service.SERVO], timeout=10)
        heard_present()
        return seen[-1].present
    finally:
        statuses.undeclare()


def test_a_servo_killed_while_braking_for_an_e_stop_leaves_no_cause_behind(arm: AlarmArm):
    """The servo's status says its e-stop latch's cause is present while the arm brakes. Killed then, it never
    says the cause has gone: the monitor takes a new servo process's status for the whole of the servo's
    latches, so the alarms clear and the arm works again (before, 0x01 stayed "cause still present" until the
    monitor restarted)."""
    for _ in range(3):  # a kill that came after the arm stopped proves nothing: again
        mark = len(arm.proc.lines)
        braking = kill_servo_while_braking(arm)
        check_back_to_work(arm)
        if braking:
            arm.proc.wait_for_line("alarm 0x01: its cause as the servo before this one saw it is void",
                                   timeout=5, start=mark)
            return
    pytest.fail("the servo was never killed while it braked, in 3 tries")


def restart_monitor(arm: AlarmArm) -> float:
    """SIGKILL the alarm monitor and wait until the launcher's new one is up; the time of the kill [s]."""
    mark = len(arm.proc.lines)
    cause = time.time()
    os.kill(arm.pid(Service.ALARM_MONITOR), signal.SIGKILL)
    arm.proc.wait_for_line("died with SIGKILL; restarting", timeout=5, start=mark)
    arm.proc.wait_for_line("arm0/alarm-monitor: alarm monitor up", timeout=20, start=mark)
    wait_alive(arm.session, "arm0", [Service.ALARM_MONITOR], timeout=10)
    return cause


def servo_alarm_latency(arm: AlarmArm, name: str, cause: float) -> None:
    """Poll the servo's state until bit 0x04 shows (no monitor to publish an event); record the latency."""
    wait_until(lambda: arm.servo(OP.getState)["state"] & StateBit.ALARM, SAME_HOST.hung_after + 2.0, 0.001,
               "the servo's bit 0x04")
    latency(name, cause, time.time())


def monitor_lists(arm: AlarmArm) -> set[int]:
    """The codes the alarm monitor itself answers (not a fallback of the servo's own alarms)."""
    listed = arm.client.raw(arm.keys.monitor_common(OP.getActiveAlarm), b"{}", json=True)
    return {a["code"] for a in listed["alarms"]}


def test_a_restarted_monitor_takes_the_active_alarms_over(arm: AlarmArm):
    """Monitor SIGKILL with a FAULT active: the restarted monitor lists it again; nothing moves until cleared."""
    since = arm.mark()
    with stopped(arm.pid(Service.PLANNER)):  # a FAULT only the monitor knows of (no servo latch)
        arm.event(AlarmCode.PLANNER_HUNG, since)
    check_alarm(arm, AlarmCode.PLANNER_HUNG, AlarmType.FAULT, servo_on=False)
    mark = len(arm.proc.lines)
    restart_monitor(arm)
    assert any("took over 1 active alarms" in line for line in list(arm.proc.lines)[mark:]), arm.log_tail()
    # The new monitor lists it, and the servo's report of the monitor's loss as well.
    wait_until(lambda: monitor_lists(arm) == {AlarmCode.PLANNER_HUNG, AlarmCode.MONITOR_LOST}, 2.0,
               what="0x411 and 0x403 listed by the new monitor")
    check_alarm(arm, AlarmCode.PLANNER_HUNG, AlarmType.FAULT, servo_on=False)
    # The arm stays stopped until they are cleared.
    assert arm.common(OP.servoON).id == ReturnCode.STATUS_ERR
    assert arm.middle(OP.goHome).id != ReturnCode.OK
    check_back_to_work(arm)


def test_monitor_killed_in_the_middle_of_a_motion(arm: AlarmArm):
    """Monitor SIGKILL: the servo stops the arm and goes off (0x403); the new monitor lists it; back to work."""
    since = start_long_motion(arm)
    mark = len(arm.proc.lines)
    cause = time.time()
    os.kill(arm.pid(Service.ALARM_MONITOR), signal.SIGKILL)
    servo_alarm_latency(arm, "alarm-monitor SIGKILL (servo's state)", cause)
    # the cause, then the motions it cut short (0x420 WARNING)
    assert [a.code for a in arm.servo(OP.getActiveAlarm)["alarms"]] == [AlarmCode.MONITOR_LOST,
                                                                          AlarmCode.MOTION_NOT_COMPLETED]
    arm.proc.wait_for_line("arm0/alarm-monitor: alarm monitor up", timeout=20, start=mark)
    wait_alive(arm.session, "arm0", [Service.ALARM_MONITOR], timeout=10)
    _, event = arm.event(AlarmCode.MONITOR_LOST, since)  # raised by the new monitor on the servo's report
    assert event.alarm.type is AlarmType.FAULT and "alarm monitor is gone" in event.alarm.description
    check_alarm(arm, AlarmCode.MONITOR_LOST, AlarmType.FAULT, servo_on=False)
    check_queue_discarded(arm)
    check_no_jump(arm, since=cause)
    check_back_to_work(arm)


def test_monitor_hung_by_sigstop(arm: AlarmArm):
    """Monitor SIGSTOP mid-motion: the servo stops the arm (0x413) and keeps it; listed after SIGCONT."""
    since = start_long_motion(arm)
    mark = len(arm.proc.lines)
    cause = time.time()
    with stopped(arm.pid(Service.ALARM_MONITOR)):
        servo_alarm_latency(arm, "alarm-monitor SIGSTOP (servo's state; threshold "
                            f"{SAME_HOST.hung_after * 1e3:.0f} ms)", cause)
        reply = arm.servo(OP.getActiveAlarm)  # the monitor does not answer: the servo's own, said so
        assert [a.code for a in reply["alarms"]] == [AlarmCode.MONITOR_HUNG, AlarmCode.MOTION_NOT_COMPLETED]
        assert "monitor" in reply.comment
        through_command = arm.common(OP.getActiveAlarm)  # the command asks the monitor once, then the servo
        assert [a.code for a in through_command["alarms"]] == [a.code for a in reply["alarms"]], through_command
        assert "monitor" in through_command.comment, through_command
        kept = arm.servo(OP.clearAlarms)
        assert kept.id == ReturnCode.STATUS_ERR and "0x413" in kept.comment, kept
        assert not arm.servo(OP.getState)["state"] & StateBit.SERVO_ON
        time.sleep(0.5)  # the forwarded clearAlarms' deadline passes while it waits in the monitor's queue
    arm.event(AlarmCode.MONITOR_HUNG, since)  # the monitor, back, lists the servo's report
    # ... and does not act on the clearAlarms the servo forwarded while it was stopped.
    arm.proc.wait_for_line("Monitor/Common/clearAlarms unanswered: its requester gave up", timeout=2, start=mark)
    # ... and was not asked getActiveAlarm at all: the servo had latched it hung and answered itself.
    assert not [line for line in arm.proc.lines[mark:] if "Monitor/Common/getActiveAlarm unanswered" in line]
    check_alarm(arm, AlarmCode.MONITOR_HUNG, AlarmType.FAULT, servo_on=False)
    check_queue_discarded(arm)
    check_no_jump(arm, since=cause)
    check_back_to_work(arm)


def test_monitor_list_and_alarm_events_agree(arm: AlarmArm):
    """The monitor's AlarmList, getActiveAlarm and the events tell one story (e-stop, then clear)."""
    lists = arm.session.declare_subscriber(arm.keys.monitor_alarms, zenoh.handlers.FifoChannel(256))
    try:
        since = arm.mark()
        arm.session.put(arm.keys.estop, b"")
        arm.event(AlarmCode.EMERGENCY_STOP, since)
        arm.wait_rest()
        arm.clear()
        arm.event(AlarmCode.EMERGENCY_STOP, since, AlarmEventKind.CLEARED)
        seen = []
        while (s := lists.try_recv()) is not None:
            seen.append(decode_sample(ALARM_LIST, s))
        codes = [tuple(a.code for a in lst.alarms) for lst in seen]
        assert (AlarmCode.EMERGENCY_STOP,) in codes and codes[-1] == (), codes
        assert all(b.tm.to_seconds() > a.tm.to_seconds() for a, b in zip(seen, seen[1:]))
        assert [e.event for _, e in arm.events[since:]] == ["raised", "cleared"]
        # The monitor serves only the alarm operations of the Common table.
        assert arm.client.raw(arm.keys.monitor_common(OP.getState), b"")["id"] == ReturnCode.NOT_IMPLEMENTED
        assert arm.client.raw(arm.keys.monitor_common(OP.getActiveAlarm), b"{}", json=True) == {
            "id": 0, "comment": "OK", "alarms": []}
    finally:
        lists.undeclare()
    arm.ok(arm.common(OP.servoON))
