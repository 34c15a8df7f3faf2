"""The secure cell over three hosts (``tests/cell_hosts.py``): a whole session from the operator's host, and
the links cut under a moving arm.

Skipped, with the reason, where network namespaces cannot be made (not root,
no ``ip``). The tests run in order on one topology: each leaves the arm
servo-on, at rest and without alarms.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from jara_arm import robots
from jara_arm.schema.codes import AlarmCode, StateBit

from .cell_hosts import CellHosts, feedback
from .hosts import Hosts
from .support import Proc, wait_until

pytestmark = pytest.mark.timeout(240)

MODEL = robots.robot("iiwa")
READY = np.array(MODEL.ready_pose, dtype=float)


@pytest.fixture(scope="module")
def cell(tmp_path_factory: pytest.TempPathFactory) -> Iterator[CellHosts]:
    reason = Hosts.available()
    if reason:
        pytest.skip(reason)
    with Hosts() as hosts:
        topology = CellHosts(hosts, tmp_path_factory.mktemp("cell"))
        try:
            wait_until(lambda: topology.call(topology.op_host, "getState", timeout=3).get("id") == 0,
                       timeout=60, interval=0.5, what="the command service, from the operator's host")
            yield topology
        finally:
            topology.close()


def ok(reply: dict) -> dict:
    assert reply.get("id") == 0, reply
    return reply


def state(cell: CellHosts) -> int:
    return int(ok(cell.call(cell.op_host, "getState"))["state"])


def at_rest(samples: list[tuple[float, list[float]]], seconds: float = 0.5, tol: float = 1e-6) -> bool:
    """The last ``seconds`` of feedback did not move."""
    if not samples or samples[-1][0] - samples[0][0] < seconds:
        return False
    recent = np.array([q for t, q in samples if t >= samples[-1][0] - seconds])
    return bool(np.ptp(recent, axis=0).max() < tol)


def largest_step(samples: list[tuple[float, list[float]]]) -> float:
    """The largest joint change between two feedback samples, per second between them [rad/s]."""
    t = np.array([s[0] for s in samples])
    q = np.array([s[1] for s in samples])
    dt = np.maximum(np.diff(t), 1e-3)
    return float((np.abs(np.diff(q, axis=0)).max(axis=1) / dt).max())


def servo_alarms(cell: CellHosts) -> list[int]:
    """The alarms the servo holds, asked on the cell host (the side that still sees the servo)."""
    return [a["code"] for a in ok(cell.call(cell.cell_host, "getActiveAlarm", servo=True))["alarms"]]


def test_a_middle_level_session_from_the_operator_host(cell: CellHosts) -> None:
    demo = Proc(cell.client_argv(cell.op_host, "demo", "--arm", "arm0"))
    cell.procs.append(demo)
    demo.wait_for_line("demo done", timeout=120)
    assert demo.popen.wait(10) == 0, demo.output
    assert "FAILED" not in demo.output, demo.output


def test_cutting_the_operator_link_leaves_a_motion_alone(cell: CellHosts) -> None:
    ok(cell.call(cell.op_host, "servoON"))
    ok(cell.call(cell.op_host, "setSpeedJoint", {"spdRatio": 20}))
    target = READY.copy()
    target[0] += 0.6
    watch = cell.watch_feedback()
    ok(cell.call(cell.op_host, "movePTPJointAbs", {"jointPoints": target.tolist()}))
    cell.poor.cut()
    try:
        wait_until(lambda: np.allclose(feedback(watch.lines)[-1][1][:7], target, atol=1e-3)
                   if feedback(watch.lines) else False, timeout=30, what="the arm at the target, link cut")
    finally:
        cell.poor.restore()
    assert servo_alarms(cell) == []
    wait_until(lambda: cell.call(cell.op_host, "getState", timeout=3).get("id") == 0, timeout=30,
               interval=0.5, what="the operator's client again")
    assert not state(cell) & StateBit.ALARM
    watch.stop()


def test_cutting_the_cell_from_its_controller_stops_the_arm(cell: CellHosts) -> None:
    """Mid-motion, with a second motion queued: the arm comes to rest without a jump, the servo holds the
    alarm, nothing moves when the link is back, and clearAlarms + servoON recover."""
    ok(cell.call(cell.op_host, "servoON"))
    ok(cell.call(cell.op_host, "setSpeedJoint", {"spdRatio": 5}))
    far, back = READY.copy(), READY.copy()
    far[0] -= 1.2
    watch = cell.watch_feedback()
    ok(cell.call(cell.op_host, "movePTPJointAbs", {"jointPoints": far.tolist()}))
    ok(cell.call(cell.op_host, "movePTPJointAbs", {"jointPoints": back.tolist()}))  # queued
    wait_until(lambda: len(feedback(watch.lines)) > 10 and not at_rest(feedback(watch.lines), 0.1),
               what="the arm moving")
    cell.lan.cut()
    try:
        wait_until(lambda: at_rest(feedback(watch.lines), 1.0), timeout=30, what="the arm at rest, link cut")
        samples = feedback(watch.lines)
        assert largest_step(samples) < 1.5 * max(MODEL.rated_speed), "a jump in the feedback"
        assert AlarmCode.MONITOR_HUNG in servo_alarms(cell)
        assert not np.allclose(samples[-1][1][:7], far, atol=1e-2), "the motion ran to its end"
        # Out long enough for Zenoh's lease (10 s) to end the sessions across the link: the routers must
        # reconnect, not merely retransmit.
        wait_until(lambda: AlarmCode.MONITOR_LOST in servo_alarms(cell), timeout=20, interval=0.5,
                   what="0x403: the monitor's token gone from the cell's side")
    finally:
        cell.lan.restore()
    rest = feedback(watch.lines)[-1][1]
    # The link back: the services see each other again; nothing moves on its own.
    wait_until(lambda: cell.call(cell.op_host, "getState", timeout=3).get("id") == 0, timeout=60,
               interval=0.5, what="the command service answering again")
    # clearAlarms keeps an alarm whose cause is still there (the monitor's heartbeat not yet heard again).
    wait_until(lambda: cell.call(cell.op_host, "clearAlarms").get("id") == 0 and not state(cell) & StateBit.ALARM,
               timeout=60, interval=1.0, what="clearAlarms taking every alarm away")
    # The routers may still be settling their routes: a user tries again, as this does.
    replies: list[dict] = []
    wait_until(lambda: replies.append(cell.call(cell.op_host, "servoON")) or replies[-1].get("id") == 0,
               timeout=30, interval=1.0, what="servoON answered OK",
               explain=lambda: f"last reply {replies[-1]}\n{cell.logs()}")
    mark = len(watch.lines)
    wait_until(lambda: at_rest(feedback(watch.lines[mark:]), 1.0), timeout=10, what="a second at rest")
    assert np.allclose(feedback(watch.lines)[-1][1], rest, atol=1e-6), "a queued motion moved after recovery"
    # And it moves again when told.
    ok(cell.call(cell.op_host, "setSpeedJoint", {"spdRatio": 50}))
    ok(cell.call(cell.op_host, "movePTPJointAbs", {"jointPoints": READY.tolist()}))
    wait_until(lambda: np.allclose(feedback(watch.lines)[-1][1][:7], READY, atol=1e-3), timeout=30,
               what="the arm back at the ready pose")
    watch.stop()
