"""The servo loop in-process, driven cycle by cycle: what a caller of ``ServoLoop.call`` reads once it has its
result. A real PyBullet world and a Zenoh session that listens nowhere (multicast off): nothing leaves the
process."""

from __future__ import annotations

import concurrent.futures
import time
from collections.abc import Callable, Iterator
from typing import Any

import pytest
import zenoh

from jara_arm.robots import robot
from jara_arm.schema.codes import AlarmCode, AlarmType, StateBit
from jara_arm.schema.keys import ArmKeys
from jara_arm.services.runtime.zenoh_args import zenoh_config
from jara_arm.services.servo.loop import ServoLoop


@pytest.fixture
def loop() -> Iterator[ServoLoop]:
    with zenoh.open(zenoh_config("peer")) as session:
        servo = ServoLoop(robot("iiwa"), session, ArmKeys("inprocess"))
        now = time.time_ns()
        servo.begin(now)
        servo.tick(now, time.monotonic_ns(), False)
        try:
            yield servo
        finally:
            servo.close()


def bits_when_answered(loop: ServoLoop, fn: Callable[[], Any]) -> int:
    """The state bits a caller of ``loop.call(fn)`` reads at the moment its result is handed over: the
    getState of a client that asks again as soon as it has its reply (a done callback runs then, on the
    loop's thread, so the test does not depend on which thread the OS runs first)."""
    seen: list[int] = []
    fut: concurrent.futures.Future[Any] = concurrent.futures.Future()
    fut.add_done_callback(lambda _f: seen.append(loop.state_bits))
    loop._calls.append((fn, fut))  # what call() does, without blocking this thread on the next cycle
    loop.tick(time.time_ns(), time.monotonic_ns(), False)
    assert fut.done() and fut.exception() is None, fut.exception()
    return seen[0]


def test_a_servo_on_reads_servo_on_as_soon_as_it_is_answered(loop: ServoLoop) -> None:
    assert loop.state_bits == 0
    assert bits_when_answered(loop, loop.servo_on_now) == StateBit.SERVO_ON


def test_a_clear_reads_no_alarm_as_soon_as_it_is_answered(loop: ServoLoop) -> None:
    """CI run 54: ``clearAlarms`` answered OK, and a getState right after it still said ALARM (0x05), the bits
    of the cycle before the clear."""
    bits_when_answered(loop, loop.servo_on_now)
    loop.alarm_state.latch(AlarmCode.SOFT_LIMIT_JOINT, AlarmType.WARNING, "J1 outside its soft limit")
    loop.tick(time.time_ns(), time.monotonic_ns(), False)
    assert loop.state_bits == StateBit.SERVO_ON | StateBit.ALARM
    assert bits_when_answered(loop, loop.clear_alarms_now) == StateBit.SERVO_ON
