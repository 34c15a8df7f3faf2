"""Alarms of what the arm does or is told, for real: the whole system under ``jara-arm up``
(``alarm_system.py``: servo, planner, command, alarm monitor, an obstacle box in the simulated
world), once for the module.

The e-stop during a LIN, the arm driven into the box (overload), and a low-level stream that
jumps, leaves the joint soft limits or lifts the tool out of the Cartesian box. For each the
test checks the alarm on both Common interfaces, the ``raised`` event on
``JARA_ARM/<arm>/alarm``, the state bits, the stop without a jump, the queue discarded, and the
way back to work (``alarm_system.py``'s checks).

Detection latency (cause -> alarm event received here) is measured for each and printed at
the end of the module (``pytest -s`` shows it); the cause is: the e-stop put, the publication
of the first position command that jumps or leaves the joint soft limits, the servo's timestamp
(``tm``) of the first feedback sample beyond the Cartesian limit or of the first status sample
whose effort is above the rating.
"""

from __future__ import annotations

import dataclasses
import os
import re
import signal
import sys
import time

import numpy as np
import pytest

from jara_arm.schema import messages
from jara_arm.schema.codes import AlarmCode, AlarmType, ReturnCode, StateBit
from jara_arm.schema.keys import Service
from jara_arm.schema.operations import OP
from jara_arm.schema.types import CarPosWithElbow, LimitValue, hg_matrix
from jara_arm.services.runtime.wire import Publication
from jara_arm.services.servo.control import LIMIT_STOP_ACCEL, OVERSPEED_MARGIN

from .alarm_system import (
    AMAX,
    DT,
    IIWA,
    N,
    READY,
    AlarmArm,
    check_alarm,
    check_back_to_work,
    check_no_jump,
    check_queue_discarded,
    latency,
)
from .support import Proc, wait_until

pytestmark = pytest.mark.timeout(60)

VMAX = np.array(IIWA.rated_speed)
#: [s] of the servo's own time in which an arm held against an obstacle lets its push fade
#: (README, "Reactions": 0.2 s).
PUSH_FADE = 0.2


@pytest.fixture
def arm(alarm_system: AlarmArm) -> AlarmArm:
    """conftest's ``alarm_system``, back at its starting point."""
    alarm_system.reset()
    return alarm_system


def min_jerk(q0: np.ndarray, q1: np.ndarray, duration: float) -> np.ndarray:
    u = np.linspace(0.0, 1.0, int(round(duration / DT)) + 1)[:, None]
    return q0 + (10 * u**3 - 15 * u**4 + 6 * u**5) * (q1 - q0)


def wait_listening(arm: AlarmArm, cli: Proc, service: Service, timeout: float = 30.0) -> None:
    """Until ``jara-arm logs`` (``cli``, showing ``service`` at ERROR) prints a record published
    now: its subscriber is up and the router routes ``service``'s records to it.

    The probe is an ERROR record on ``service``'s log key that says it is the test's own;
    it is published again at each poll, the first ones may come before the subscriber.
    """
    probe = f"test probe from tests/test_alarms_motion.py (pid {os.getpid()}): is `jara-arm logs` listening?"
    pub = Publication(arm.session, arm.keys.log(service))  # as the services publish: JSON, labelled
    record = messages.LogRecord(0.0, "ERROR", service.value, probe, "tests")
    try:
        def printed() -> bool:
            pub.put_message(messages.LOG_RECORD, dataclasses.replace(record, t=time.time()))
            return any(probe in line for line in list(cli.lines))

        wait_until(printed, timeout, 0.2, "`jara-arm logs` to print a probe record",
                   explain=lambda: cli.output[-2000:])
    finally:
        pub.close()


# ---------------------------------------------------------------------------- scenarios


def test_estop_during_a_lin(arm: AlarmArm):
    """E-stop: FAULT 0x01, servo off, controlled stop along the way, queue gone; the CLI prints it."""
    alarms_cli = Proc([sys.executable, "-m", "jara_arm.launcher", "alarms", "--connect", arm.endpoint])
    logs_cli = Proc([sys.executable, "-m", "jara_arm.launcher", "logs", "--connect", arm.endpoint,
                     "--service", "alarm-monitor", "--level", "ERROR"])
    try:
        alarms_cli.wait_for_line("arm0 ACTIVE  none", timeout=20)
        wait_listening(arm, logs_cli, Service.ALARM_MONITOR)
        arm.ok(arm.middle(OP.setSpeedCartesian, {"spdRatio": 60}))
        down = CarPosWithElbow(hg_matrix(translation=(0.0, -0.2, -0.1)), 0.0, 0)
        base = arm.consumed()
        arm.ok(arm.middle(OP.moveLinearCartesianRel, {"carPoint": down}))
        arm.ok(arm.middle(OP.moveLinearCartesianRel, {"carPoint": down}))
        since = arm.mark()
        arm.under_way(base, 600)  # in the middle of the first LIN
        assert arm.state() & StateBit.MOVING, arm.log_tail()
        cause = time.time()
        arm.session.put(arm.keys.estop, b"")
        t, event = arm.event(AlarmCode.EMERGENCY_STOP, since)
        latency("e-stop put", cause, t)
        assert event.alarm.type is AlarmType.FAULT
        check_alarm(arm, AlarmCode.EMERGENCY_STOP, AlarmType.FAULT, servo_on=False)
        check_queue_discarded(arm)
        check_no_jump(arm, since=cause)
        refused = arm.middle(OP.moveLinearCartesianRel, {"carPoint": down})
        assert refused.id in (ReturnCode.STATUS_ERR, ReturnCode.NOT_SV_ON_ERR), refused
        assert "0x01 FAULT emergency stop" in alarms_cli.wait_for_line("RAISED", timeout=5)
        assert " ERROR " in logs_cli.wait_for_line("0x01 FAULT raised", timeout=5)
        check_back_to_work(arm)
        assert "0x01" in alarms_cli.wait_for_line("CLEARED", timeout=5)
    finally:
        for cli in (alarms_cli, logs_cli):
            assert cli.stop(signal.SIGINT) == 0, cli.output
            assert "Traceback" not in cli.output, cli.output
    assert not any(" INFO " in line for line in logs_cli.lines), "--level ERROR let INFO through"


def test_driven_into_an_obstacle(arm: AlarmArm):
    """Overload: WARNING 0x02, servo stays on, the arm stops and stops pushing, queue gone."""
    for attempt in range(3):  # again if the planner gave up on the move before the box
        arm.ok(arm.middle(OP.setSpeedJoint, {"spdRatio": 15}))
        since = arm.mark()
        arm.ok(arm.middle(OP.movePTPJointRel, {"jointPoints": (0.8,) + (0.0,) * (N - 1)}))
        arm.ok(arm.middle(OP.movePTPJointRel, {"jointPoints": (0.1,) + (0.0,) * (N - 1)}))
        start = time.monotonic()
        wait_until(lambda: arm.events[since:] or (time.monotonic() - start > 0.5
                                                  and not arm.state() & StateBit.MOVING),
                   10, 0.01, "an alarm or the end of the moves")
        if arm.events[since:] or attempt == 2:
            break
        arm.goto(READY)
    t, event = arm.event(AlarmCode.OVERLOAD, since, timeout=1)
    rating = np.array(IIWA.rated_effort)
    above = [s for s in arm.statuses.drain() if np.any(np.abs(s.effort[:N]) > rating)]
    assert above, "no status sample above the rating"
    latency("overload (first effort above rating)", above[0].tm.to_seconds(), t)
    assert event.alarm.type is AlarmType.WARNING and "J1" in event.alarm.description
    check_alarm(arm, AlarmCode.OVERLOAD, AlarmType.WARNING, servo_on=True)
    check_queue_discarded(arm)
    # From the alarm on (the impact itself is the box's doing). The arm presses on the box
    # while it stops and while the push fades: PyBullet's contact makes the measured joints
    # chatter (2-3 x the limits seen), so the bound is looser than for a stop in free space;
    # a step would be hundreds of rad/s^2.
    q = check_no_jump(arm, since=t, allowed=AMAX * 4.0)
    assert 0.15 < q[0] < 0.6, q  # stopped by the box, long before the target (0.8)
    # Held where it stopped, not pushing: the effort falls back below the rating.
    arm.mark()
    faded = time.time() + PUSH_FADE
    newest = arm.statuses.until(lambda s: s.tm.to_seconds() >= faded, f"a servo status {PUSH_FADE} s on")[-1]
    assert np.all(np.abs(np.array(newest.effort[:N])) < rating)
    refused = arm.middle(OP.movePTPJointRel, {"jointPoints": (-0.1,) + (0.0,) * (N - 1)})
    assert refused.id == ReturnCode.STATUS_ERR and "alarm" in refused.comment, refused
    check_back_to_work(arm, servo_on_needed=False)


def test_position_stream_that_jumps(arm: AlarmArm):
    """A jump in a low-level stream: FAULT 0x03, not applied, servo off, stop without a jump."""
    jump = 300

    def jumping(q0: np.ndarray) -> np.ndarray:
        path = min_jerk(q0, q0 + np.array([0.3, 0, 0, 0, 0, 0, 0]), 0.6)
        path[jump:, 2] += VMAX[2] * DT * OVERSPEED_MARGIN * 3  # J3 jumps, then goes on from there
        return path[: jump + 50]

    run = arm.stream_to(AlarmCode.OVERSPEED, jumping)
    q0, base, sent, t, event = run.path[0], run.base, run.sent, run.t, run.event
    taken = arm.statuses.until(lambda s: s.consumed >= base + jump + 1, "a status with the jump taken")
    latency("jump in the stream (servo takes it)", arm.consumed_at(taken, base + jump + 1), t)
    assert event.alarm.type is AlarmType.FAULT and "J3" in event.alarm.description
    check_alarm(arm, AlarmCode.OVERSPEED, AlarmType.FAULT, servo_on=False)
    q = check_no_jump(arm, since=sent[0])
    assert abs(q[2] - q0[2]) < 1e-3, "the jump was applied"
    check_back_to_work(arm)


def test_position_stream_that_leaves_the_joint_soft_limits(arm: AlarmArm):
    """A stream through a joint soft limit: WARNING 0x04; the servo stops in front of it, servo on."""
    q0 = arm.target()
    limits = list(IIWA.hard_limits)
    limits[0] = LimitValue(upper=q0[0] + 0.5, lower=q0[0] - 0.1)
    arm.ok(arm.common(OP.setSoftLimitJoint, {"softLimit": limits}))
    run = arm.stream_to(AlarmCode.SOFT_LIMIT_JOINT,  # through the lower limit
                        lambda start: min_jerk(start, start - np.array([0.3, 0, 0, 0, 0, 0, 0]), 0.6))
    path, base, sent, t, event = run.path, run.base, run.sent, run.t, run.event
    # The servo refuses the first command from which it could not stop before the limit
    # (its description names it): the cycle it takes that command is the cause.
    refused = float(re.search(r"J1=(\S+) ", event.alarm.description)[1])
    first = int(np.argmin(np.abs(path[:, 0] - refused)))
    assert abs(path[first, 0] - refused) < 1e-5 and path[first, 0] > limits[0].lower
    taken = arm.statuses.until(lambda s: s.consumed >= base + first + 1, "a status with the refused command taken")
    latency("joint soft limit (servo takes it)", arm.consumed_at(taken, base + first + 1), t)
    assert event.alarm.type is AlarmType.WARNING
    check_alarm(arm, AlarmCode.SOFT_LIMIT_JOINT, AlarmType.WARNING, servo_on=True)
    # A stop in front of a limit may use the planner's peak deceleration (servo LIMIT_STOP_ACCEL).
    q = check_no_jump(arm, since=sent[0], allowed=AMAX * LIMIT_STOP_ACCEL * 1.2)
    assert limits[0].lower - 1e-3 <= q[0] < limits[0].lower + 5e-3, (q[0], limits[0])
    check_back_to_work(arm, servo_on_needed=False)


def test_control_point_crosses_the_cartesian_soft_limits(arm: AlarmArm):
    """A stream that lifts the tool above the Cartesian box: WARNING 0x05, kept while outside."""
    q0 = arm.target()
    z0 = arm.kin.fk(q0).translation[2]
    c = arm.cart_limits
    box = {"xLimit": c["xLimit"], "yLimit": c["yLimit"], "zLimit": LimitValue(upper=z0 + 0.03, lower=c["zLimit"].lower)}
    arm.ok(arm.middle(OP.setSoftLimitCartesian, box))
    arm.wait_cartesian_box(box)  # the monitor has the new settings
    q1 = q0 + np.array([0.0, -0.4, 0.0, 0.3, 0.0, 0.0, 0.0])
    assert arm.kin.fk(q1).translation[2] > z0 + 0.06, "the test motion must lift the flange"
    run = arm.stream_to(AlarmCode.SOFT_LIMIT_CARTESIAN, lambda start: min_jerk(start, q1, 0.8))
    t, event = run.t, run.event
    tm, q = arm.recorded_timed()
    z = np.array([arm.kin.fk(x[:N]).translation[2] for x in q])
    crossed = tm[int(np.argmax(z > box["zLimit"].upper + 1e-3))]
    latency("Cartesian soft limit (feedback tm)", crossed, t)
    assert event.alarm.type is AlarmType.WARNING and "z" in event.alarm.description
    check_alarm(arm, AlarmCode.SOFT_LIMIT_CARTESIAN, AlarmType.WARNING, servo_on=True)
    arm.wait_rest()
    kept = arm.common(OP.clearAlarms)  # the tool is still above the box: the cause is present
    assert kept.id == ReturnCode.STATUS_ERR and "0x05" in kept.comment and "still present" in kept.comment, kept
    arm.ok(arm.middle(OP.setSoftLimitCartesian, {k: c[k] for k in ("xLimit", "yLimit", "zLimit")}))
    arm.wait_cartesian_box(c)  # the monitor has the box back: the cause has gone
    check_back_to_work(arm, servo_on_needed=False)
