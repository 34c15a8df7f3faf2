"""``jara-arm wait CONDITION``: block until the arm is idle, servo on, alarmed… or time out, for scripts.

Exit 0 when the condition holds, ``TIMED_OUT`` with what was seen last when it
did not within the timeout. The state comes from ``getState`` polled every
``poll`` seconds (its publication only speaks on changes); ``alive`` asks for
the services' liveliness tokens.
"""

from __future__ import annotations

import argparse
import dataclasses
import enum
import sys
import threading
import time
from typing import TextIO

from jara_arm.client import Arm, ArmError
from jara_arm.client.arm import alive_services
from jara_arm.schema.codes import StateBit
from jara_arm.schema.keys import Service
from jara_arm.services.runtime.arguments import positive_float

from ..command import Command, setup_logging
from ..session import add_arm, add_client_zenoh_arguments, listening, no_answer
from .arm_state import format_state

TIMED_OUT = 1
INTERRUPTED = 130  #: the shell's status for SIGINT


class Condition(enum.StrEnum):
    """What ``wait`` waits for."""

    IDLE = "idle"  # servo on, not moving, nothing queued (the command's moving bit counts queued motions)
    SERVO_ON = "servo-on"
    SERVO_OFF = "servo-off"
    ALARM = "alarm"
    NO_ALARM = "no-alarm"
    ALIVE = "alive"  # every service of the arm has its liveliness token up


CONDITION_HELP = {
    Condition.IDLE: "servo on, not moving, no motion queued",
    Condition.SERVO_ON: "servo on",
    Condition.SERVO_OFF: "servo off",
    Condition.ALARM: "an alarm is active",
    Condition.NO_ALARM: "no alarm is active",
    Condition.ALIVE: f"every service is up ({', '.join(s.value for s in Service)})",
}


def state_meets(condition: Condition, bits: int) -> bool:
    """Whether the state bits ``bits`` meet ``condition`` (not ``alive``, which has no bits)."""
    if condition is Condition.IDLE:
        return bool(bits & StateBit.SERVO_ON) and not bits & StateBit.MOVING
    if condition is Condition.SERVO_ON:
        return bool(bits & StateBit.SERVO_ON)
    if condition is Condition.SERVO_OFF:
        return not bits & StateBit.SERVO_ON
    if condition is Condition.ALARM:
        return bool(bits & StateBit.ALARM)
    if condition is Condition.NO_ALARM:
        return not bits & StateBit.ALARM
    raise ValueError(f"{condition} is not a condition on the state bits")


@dataclasses.dataclass(frozen=True)
class Check:
    """One look: whether the condition holds, and what was seen (for the timeout message)."""

    met: bool
    seen: str


def check(client: Arm, condition: Condition) -> Check:
    if condition is Condition.ALIVE:
        up = alive_services(client.session, client.keys)
        missing = [s.value for s in Service if s.value not in up]
        return Check(not missing, f"not up: {', '.join(missing)}" if missing else "every service up")
    try:
        bits = client.state
    except ArmError as exc:
        return Check(False, str(exc))
    return Check(state_meets(condition, bits), f"state {format_state(bits)}")


def run_wait(client: Arm, condition: Condition, timeout: float, poll: float, stop: threading.Event,
             err: TextIO, began: float | None = None) -> int:
    """Until ``condition`` holds (0), ``timeout`` [s] passes (TIMED_OUT) or ``stop`` (INTERRUPTED); the timeout
    counts from ``began`` [s, monotonic] if given (the command's start: joining the network included)."""
    deadline = (time.monotonic() if began is None else began) + timeout
    while True:
        seen = check(client, condition)
        if seen.met:
            return 0
        if time.monotonic() >= deadline:
            print(f"jara-arm wait: {client.keys.arm} not {condition} ({CONDITION_HELP[condition]}) within "
                  f"{timeout:g} s; last seen: {seen.seen}", file=err, flush=True)
            return TIMED_OUT
        if stop.wait(min(poll, max(0.0, deadline - time.monotonic()))):
            print(f"jara-arm wait: interrupted; last seen: {seen.seen}", file=err, flush=True)
            return INTERRUPTED


def _arguments(parser: argparse.ArgumentParser) -> None:
    add_arm(parser)
    parser.add_argument("condition", choices=[c.value for c in Condition], metavar="CONDITION",
                        help=", ".join(c.value for c in Condition))
    parser.add_argument("--timeout", type=positive_float, default=60.0, metavar="S",
                        help="give up after S seconds, joining the network included (default: 60)")
    parser.add_argument("--poll", type=positive_float, default=0.05, metavar="S",
                        help="look this often [s] (default: 0.05)")
    add_client_zenoh_arguments(parser)


def _run(args: argparse.Namespace, parser: argparse.ArgumentParser) -> int:
    setup_logging("WARNING")
    began = time.monotonic()
    with listening(args, parser, join_within=args.timeout) as (session, stop):
        client = Arm(session, args.arm, timeout=2.0)
        try:
            return run_wait(client, Condition(args.condition), args.timeout, args.poll, stop, sys.stderr,
                            began)
        except ArmError as exc:
            return no_answer(args, parser, exc)
        finally:
            client.close()


COMMAND = Command(
    "wait", arguments=_arguments, run=_run,
    help="wait until the arm meets a condition (for scripts)",
    description="Exit 0 as soon as the condition holds, 1 with what was seen last if it did not "
    "within the timeout. Conditions: " + "; ".join(f"{c.value}: {h}" for c, h in CONDITION_HELP.items()))
