"""Printing what the services publish: log records and alarm events, one line each.

Shared by ``jara-arm up`` (which prints every service's log), ``jara-arm logs``
and ``jara-arm alarms``. Subscribers only fill Zenoh channels; the printers
are drained from the caller's own loop, never from a Zenoh callback.
"""

from __future__ import annotations

import abc
import argparse
import logging
import threading
import time

import zenoh

from jara_arm.schema import codec, messages
from jara_arm.schema.alarms import format_code
from jara_arm.schema.encoding import Encoding
from jara_arm.services.runtime.ask import Asker
from jara_arm.schema.errors import JaraArmError
from jara_arm.schema.keys import (ArmKeys, Service, any_arm_alarm, any_arm_log, any_arm_monitor_common,
                                  arm_of, parse_log)
from jara_arm.schema.operations import COMMON, OP
from jara_arm.schema.types import Alarm

from ..command import Command, setup_logging
from ..session import add_arm_filter, add_client_zenoh_arguments, listening
from ..up.router import say

log = logging.getLogger("jara_arm.launcher")

LOG_LEVELS = ("DEBUG", "INFO", "WARNING", "ERROR", "CRITICAL")
_QUEUE = 4096  #: records buffered between two drains; more are dropped by Zenoh
_PER_DRAIN = 2000  #: bound on the lines printed per drain, so that the caller keeps its pace
DRAIN_PERIOD = 0.05  #: [s] between two drains of ``jara-arm logs`` and ``jara-arm alarms``


def _stamp(t: float) -> str:
    """``HH:MM:SS.mmm`` local time of Unix time ``t`` [s]."""
    return f"{time.strftime('%H:%M:%S', time.localtime(t))}.{int(t * 1000.0) % 1000:03d}"


def level_number(name: str) -> int:
    """The ``logging`` number of a level name; unknown names count as INFO."""
    number = logging.getLevelName(name.upper())
    return number if isinstance(number, int) else logging.INFO


def format_log(key: str, payload: bytes, encoding: Encoding) -> tuple[str, int]:
    """``(HH:MM:SS.mmm LEVEL arm/service: msg, level number)`` for one ``LogRecord``."""
    arm, service = parse_log(key)
    try:
        rec = codec.decode_message(messages.LOG_RECORD, payload, encoding)
    except JaraArmError as exc:
        return (f"{time.strftime('%H:%M:%S')} ?       {arm}/{service}: (undecodable log record: {exc})",
                logging.WARNING)
    return f"{_stamp(rec.t)} {rec.level:<7} {arm}/{service}: {rec.msg}", level_number(rec.level)


def format_alarm(alarm: Alarm) -> str:
    """``0x001 FAULT emergency stop: ...``"""
    return f"{format_code(alarm.code)} {alarm.type.value} {alarm.description}"


def format_alarm_event(key: str, payload: bytes, encoding: Encoding) -> str:
    """``HH:MM:SS.mmm arm0 RAISED 0x001 FAULT ...`` for one ``AlarmEvent`` (receipt time)."""
    arm = arm_of(key)
    try:
        event = codec.decode_message(messages.ALARM_EVENT, payload, encoding)
    except JaraArmError as exc:
        return f"{_stamp(time.time())} {arm} ? (undecodable alarm event: {exc})"
    return f"{_stamp(time.time())} {arm} {event.event.upper():<7} {format_alarm(event.alarm)}"


class _Printer(abc.ABC):
    """Prints the lines made of what arrives on ``key``; polled by :meth:`drain`."""

    def __init__(self, session: zenoh.Session, key: str) -> None:
        # A ring, not a FIFO: a full FIFO would hold up the session's thread that delivers into it, and
        # in the launcher that is the cell bus's own router: a printer behind loses its oldest lines.
        self._sub = session.declare_subscriber(key, zenoh.handlers.RingChannel(_QUEUE))

    @abc.abstractmethod
    def line(self, key: str, payload: bytes, encoding: Encoding) -> str | None:
        """The line to print for one sample (``payload`` in ``encoding``, its label's), or None to skip it."""

    def drain(self) -> None:
        for _ in range(_PER_DRAIN):
            sample = self._sub.try_recv()
            if sample is None:
                return
            try:
                line = self.line(str(sample.key_expr), sample.payload.to_bytes(), Encoding.of(sample.encoding))
            except Exception as exc:  # anyone may publish here: never let it stop the caller
                log.debug("unprintable sample on %s: %s", sample.key_expr, exc)
                continue
            if line is not None:
                say(line)

    def close(self) -> None:
        self._sub.undeclare()


class LogPrinter(_Printer):
    """Log records on ``key`` (e.g. ``JARA_ARM/*/log/*``) at ``level`` or above."""

    def __init__(self, session: zenoh.Session, key: str, level: str = "DEBUG") -> None:
        super().__init__(session, key)
        self._min = level_number(level)

    def line(self, key: str, payload: bytes, encoding: Encoding) -> str | None:
        text, level = format_log(key, payload, encoding)
        return text if level >= self._min else None


class AlarmPrinter(_Printer):
    """Alarm events on ``key`` (e.g. ``JARA_ARM/*/alarm``)."""

    def line(self, key: str, payload: bytes, encoding: Encoding) -> str | None:
        return format_alarm_event(key, payload, encoding)


def print_active_alarms(session: zenoh.Session, arm: str | None, timeout: float = 2.0) -> int:
    """Ask the alarm monitor of ``arm`` (every arm if None) for its list and print it; monitors that answered."""
    op = COMMON[OP.getActiveAlarm]
    key = ArmKeys(arm).monitor_common(op.name) if arm else any_arm_monitor_common(op.name)
    answered = 0
    asker = Asker(session, key, timeout, target=zenoh.QueryTarget.ALL)
    try:
        answers = asker.ask_all(codec.encode_request(op))
    finally:
        asker.close()
    for answer in answers:
        try:
            who = arm_of(answer.key)
            got = codec.decode_reply(op, answer.payload, answer.encoding)
        except JaraArmError as exc:
            say(f"{_stamp(time.time())} ? undecodable answer on {answer.key}: {exc}")
            continue
        answered += 1
        if not got.ok:
            say(f"{_stamp(time.time())} {who} {got.comment}")
        elif not got["alarms"]:
            say(f"{_stamp(time.time())} {who} ACTIVE  none")
        for alarm in got["alarms"] if got.ok else ():
            say(f"{_stamp(time.time())} {who} ACTIVE  {format_alarm(alarm)}")
    if not answered:
        say(f"{_stamp(time.time())} {arm or '*'} no alarm monitor answered on {key}")
    return answered


def run_logs(session: zenoh.Session, stop: threading.Event, arm: str | None, service: str | None,
             level: str) -> int:
    """``jara-arm logs``: print the records of the chosen arms and services until ``stop``."""
    svc = Service(service) if service else None
    key = ArmKeys(arm).log(svc) if arm else any_arm_log(svc)
    printer = LogPrinter(session, key, level)
    try:
        while not stop.wait(DRAIN_PERIOD):
            printer.drain()
        printer.drain()
    finally:
        printer.close()
    return 0


def run_alarms(session: zenoh.Session, stop: threading.Event, arm: str | None) -> int:
    """``jara-arm alarms``: the active list, then every alarm event as it comes, until ``stop``."""
    printer = AlarmPrinter(session, ArmKeys(arm).alarm if arm else any_arm_alarm())  # before the list
    try:
        print_active_alarms(session, arm)
        while not stop.wait(DRAIN_PERIOD):
            printer.drain()
        printer.drain()
    finally:
        printer.close()
    return 0


def _logs_arguments(parser: argparse.ArgumentParser) -> None:
    add_arm_filter(parser)
    parser.add_argument("--service", choices=[s.value for s in Service], metavar="NAME",
                        help=f"only this service ({', '.join(s.value for s in Service)}; default: every one)")
    parser.add_argument("--level", type=str.upper, default="DEBUG", choices=LOG_LEVELS,
                        help="only records at this level or above (default: DEBUG, all)")
    add_client_zenoh_arguments(parser)


def _logs(args: argparse.Namespace, parser: argparse.ArgumentParser) -> int:
    setup_logging("WARNING")
    with listening(args, parser) as (session, stop):
        return run_logs(session, stop, args.arm, args.service, args.level)


def _alarms_arguments(parser: argparse.ArgumentParser) -> None:
    add_arm_filter(parser)
    add_client_zenoh_arguments(parser)


def _alarms(args: argparse.Namespace, parser: argparse.ArgumentParser) -> int:
    setup_logging("WARNING")
    with listening(args, parser) as (session, stop):
        return run_alarms(session, stop, args.arm)


LOGS = Command(
    "logs", arguments=_logs_arguments, run=_logs,
    help="print the services' log records as they come",
    description="Subscribe to JARA_ARM/<arm>/log/<service> from anywhere on the Zenoh "
    "network and print each record as it arrives.")

ALARMS = Command(
    "alarms", arguments=_alarms_arguments, run=_alarms,
    help="print the active alarms, then every alarm event as it comes",
    description="Ask the alarm monitor for the active alarms and print them, then print "
    "every event on JARA_ARM/<arm>/alarm (raised, cleared) as it arrives.")
