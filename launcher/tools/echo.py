"""``jara-arm echo KEY``: any key's samples, decoded (MessagePack or JSON), one JSON line each.

KEY is relative to ``JARA_ARM/<arm>/`` (``state``, ``log/**``,
``Servo/posFeedback``…) and must meet a published key of the schema's key
table (``schema.keys.KEY_TABLE``). Samples arrive in a ring channel (Zenoh's
threads never wait on the printing) that the caller's loop drains.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import threading
import time
from typing import Any, TextIO

import zenoh

from jara_arm.schema import codec
from jara_arm.schema.codec import Encoding
from jara_arm.schema.errors import JaraArmError
from jara_arm.schema.keys import KEY_TABLE, PREFIX, ArmKeys, Service
from jara_arm.services.runtime.arguments import positive_float, positive_int
from jara_arm.services.runtime.stop_signals import StopSignals

from ..command import USAGE_ERROR, Command, setup_logging
from ..session import add_arm, add_client_zenoh_arguments, open_session
from .arm_state import sample_encoding

_ARM_CHUNK = f"{PREFIX}/<arm>/"
_RING = 8192  #: samples held between two drains; the oldest go first when the printer falls behind
_POLL = 0.01  #: [s] sleep of the drain loop when the channel is empty
#: Exit status when ``--timeout`` passes before the samples asked for came.
TIMED_OUT = 1


class EchoKeyError(JaraArmError, ValueError):
    """A KEY that is not a key expression, or that meets no published key of the schema."""


def echo_keys() -> tuple[str, ...]:
    """The keys ``echo`` takes, relative to ``JARA_ARM/<arm>/``, a ``*`` for each parameter chunk:
    every key of the key table that something is published on (queryables and tokens are not)."""
    keys = []
    for row in KEY_TABLE:
        if ("publisher" in row.kind or "subscriber" in row.kind) and row.key.startswith(_ARM_CHUNK):
            chunks = row.key.removeprefix(_ARM_CHUNK).split("/")
            keys.append("/".join("*" if c.startswith("<") else c for c in chunks))
    return tuple(dict.fromkeys(keys))


def echo_key(arm: str, key: str) -> str:
    """The full key expression of ``key`` (relative to the arm) if it meets a key of :func:`echo_keys`."""
    valid = echo_keys()
    try:
        wanted = zenoh.KeyExpr(key)
    except zenoh.ZError:
        raise EchoKeyError(f"{key!r} is not a key expression (chunks separated by single '/', "
                           f"no leading or trailing '/'); keys: {', '.join(valid)}") from None
    if not any(wanted.intersects(zenoh.KeyExpr(k)) for k in valid):
        raise EchoKeyError(f"no published key {key!r} under {PREFIX}/<arm>/; keys: {', '.join(valid)} "
                           "('*' is one chunk, '**' any number)")
    return f"{ArmKeys(arm).root}/{key}"


def echo_words() -> tuple[str, ...]:
    """The keys bash offers for ``echo``: :func:`echo_keys`, a ``<service>`` chunk spelled out for each service
    (a ``*`` in a completion word would meet the shell's file globbing)."""
    words = [k for k in echo_keys() if "*" not in k]
    for row in KEY_TABLE:
        suffix = row.key.removeprefix(f"{PREFIX}/<arm>/")
        if suffix.endswith("/<service>") and "/".join(suffix.split("/")[:-1]) + "/*" in echo_keys():
            words += [f"{suffix.rsplit('/', 1)[0]}/{s.value}" for s in Service]
    return tuple(dict.fromkeys(words))


def decode_payload(payload: bytes, encoding: object | None) -> Any:
    """The value of a sample: JSON if its encoding says so or it starts like a JSON document (a
    MessagePack map or array never does), text for a ``text/`` encoding, else MessagePack; a
    payload that none of them reads but is UTF-8 comes as text. Raises JaraArmError."""
    said = str(encoding or "")
    if sample_encoding(payload, encoding) is Encoding.JSON:
        return codec.loads(payload, Encoding.JSON)
    if said.startswith("text/"):
        return payload.decode("utf-8", errors="replace")
    try:
        return codec.loads(payload, Encoding.MSGPACK)
    except JaraArmError:
        try:
            return payload.decode("utf-8")
        except UnicodeDecodeError:
            raise JaraArmError(f"neither MessagePack nor JSON nor text ({len(payload)} bytes, "
                               f"encoding {said or 'unset'})") from None


def _jsonable(value: Any) -> Any:
    """What ``json.dumps`` cannot write itself: MessagePack binaries, as hex."""
    if isinstance(value, (bytes, bytearray)):
        return bytes(value).hex()
    raise TypeError(f"{type(value).__name__} is not JSON")


def json_line(value: Any, key: str | None = None) -> str:
    """One output line: the value, or ``{"key": ..., "value": ...}`` when the key is asked for."""
    return json.dumps(value if key is None else {"key": key, "value": value}, default=_jsonable)


class Thinner:
    """Lets through at most ``rate`` samples a second [Hz] (all if ``rate`` is None)."""

    def __init__(self, rate: float | None) -> None:
        self.period = 1.0 / rate if rate else 0.0  # [s]
        self._next = -float("inf")

    def keep(self, now: float) -> bool:
        """Whether the sample received at ``now`` [s, monotonic] is printed."""
        if now < self._next:
            return False
        # From the due time, not from now, while that keeps up: the mean rate stays at ``rate``.
        self._next = now + self.period if now - self._next > self.period else self._next + self.period
        return True


@dataclasses.dataclass(frozen=True)
class EchoSettings:
    key: str  # the full key expression
    rate: float | None = None  # [Hz] at most, None for every sample
    count: int | None = None  # samples to print before exiting, None for no end
    timeout: float | None = None  # [s] to wait for them, None for no end
    show_key: bool = False
    began: float | None = None  # [s, monotonic] where the timeout counts from (default: the echo's start)


def run_echo(session: zenoh.Session, settings: EchoSettings, stop: threading.Event, out: TextIO,
             err: TextIO) -> int:
    """Print the samples until ``stop``, ``count`` of them, or ``timeout`` (then TIMED_OUT)."""
    sub = session.declare_subscriber(settings.key, zenoh.handlers.RingChannel(_RING))
    thinner = Thinner(settings.rate)
    printed = 0
    began = time.monotonic() if settings.began is None else settings.began
    deadline = began + settings.timeout if settings.timeout is not None else None
    try:
        while not stop.is_set():
            sample = sub.try_recv()
            if sample is None:
                if deadline is not None and time.monotonic() > deadline:
                    print(f"jara-arm echo: {printed} sample(s) on {settings.key} within {settings.timeout:g} s",
                          file=err, flush=True)
                    return TIMED_OUT
                stop.wait(_POLL)
                continue
            if not thinner.keep(time.monotonic()):
                continue
            key = str(sample.key_expr)
            try:
                value = decode_payload(sample.payload.to_bytes(), sample.encoding)
            except JaraArmError as exc:  # anyone may publish here: say it and go on
                print(f"jara-arm echo: undecodable sample on {key}: {exc}", file=err, flush=True)
                continue
            try:
                print(json_line(value, key if settings.show_key else None), file=out, flush=True)
            except BrokenPipeError:  # `| head`: the reader has had enough
                return 0
            printed += 1
            if settings.count is not None and printed >= settings.count:
                return 0
        return 0
    finally:
        sub.undeclare()


def _arguments(parser: argparse.ArgumentParser) -> None:
    add_arm(parser)
    parser.add_argument("key", metavar="KEY", help="relative to JARA_ARM/<arm>/, e.g. state, log/**")
    parser.add_argument("--rate", type=positive_float, metavar="HZ",
                        help="print at most this many samples a second (thins the 1 kHz streams)")
    ends = parser.add_mutually_exclusive_group()
    ends.add_argument("--once", action="store_true", help="exit after the first sample")
    ends.add_argument("--count", type=positive_int, metavar="N", help="exit after N samples")
    parser.add_argument("--timeout", type=positive_float, metavar="S",
                        help="exit 1 if the samples asked for did not come within S seconds (joining the network "
                        "included)")
    parser.add_argument("--show-key", action="store_true",
                        help='print {"key": ..., "value": ...} (for keys with wildcards)')
    add_client_zenoh_arguments(parser)


def _run(args: argparse.Namespace, parser: argparse.ArgumentParser) -> int:
    """The key checked first (exit 2, nothing joined), then one session for its samples."""
    setup_logging("WARNING")
    try:
        key = echo_key(args.arm, args.key)
    except EchoKeyError as exc:
        print(f"{parser.prog}: {exc}", file=sys.stderr)
        return USAGE_ERROR
    began = time.monotonic()
    session = open_session(args, parser, join_within=args.timeout)
    signals = StopSignals()
    with session:
        count = 1 if args.once else args.count
        return run_echo(session, EchoSettings(key, args.rate, count, args.timeout, args.show_key, began),
                        signals.stop, sys.stdout, sys.stderr)


COMMAND = Command(
    "echo", arguments=_arguments, run=_run, words=echo_words(),
    help="print the samples of any key as JSON lines",
    description="Subscribe to JARA_ARM/<arm>/KEY and print every sample decoded (MessagePack "
    "or JSON) as one JSON line. Keys: " + ", ".join(echo_keys()) + " ('*' is one chunk, "
    "'**' any number of them).")
