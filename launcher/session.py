"""How a client command joins the network: its ``--arm`` and Zenoh options, its session, its silences.

Every command that joins as a client (call, echo, state, wait, logs, alarms,
demo, record, replay, plot, view) takes the same Zenoh options, by default a
client of the launcher's endpoint; a session it cannot have is a usage error
(exit 2, with the reason).
"""

from __future__ import annotations

import argparse
import contextlib
import sys
import threading
from collections.abc import Iterator

import zenoh

from jara_arm.client import ArmError
from jara_arm.schema.keys import DEFAULT_ARM, ArmIdError, check_arm
from jara_arm.services.runtime.cell import CellError
from jara_arm.services.runtime.stop_signals import StopSignals
from jara_arm.services.runtime.zenoh_args import add_zenoh_arguments, default_endpoint, zenoh_config

from .up.router import DEFAULT_LISTEN, zerror_text


def arm_id(text: str) -> str:
    """An ``--arm`` value: a valid arm id."""
    try:
        return check_arm(text)
    except ArmIdError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def add_arm(parser: argparse.ArgumentParser) -> None:
    """``--arm ID``: the one arm the command is about."""
    parser.add_argument("--arm", type=arm_id, default=DEFAULT_ARM, metavar="ID",
                        help=f"the arm (default: {DEFAULT_ARM})")


def add_arm_filter(parser: argparse.ArgumentParser) -> None:
    """``--arm ID``: one arm of all those the command hears."""
    parser.add_argument("--arm", type=arm_id, metavar="ID", help="only this arm (default: every arm)")


def add_client_zenoh_arguments(parser: argparse.ArgumentParser) -> None:
    """The shared Zenoh options; a client of the launcher's default endpoint unless told otherwise."""
    add_zenoh_arguments(parser, default_mode="client",
                        default_connect=f"{DEFAULT_LISTEN}, {default_endpoint('secure')} with --secure")


def open_session(args: argparse.Namespace, parser: argparse.ArgumentParser,
                 join_within: float | None = None, timestamping: bool = False) -> zenoh.Session:
    """A session on the network of the client options (exit 2 with the reason if it cannot be had), trying
    for up to ``join_within`` [s] (a command with a timeout, started before the router listens);
    ``timestamping``: its samples carry a timestamp (what a Zenoh advanced publisher needs)."""
    connect = args.connect or ([] if args.config else [default_endpoint(args.secure)])
    try:
        conf = zenoh_config(args.mode, args.listen, connect, args.config, args.multicast, args.secure,
                            args.identity, join_within)
        if timestamping:
            conf.insert_json5("timestamping/enabled", "true")
        return zenoh.open(conf)
    except CellError as exc:
        parser.error(str(exc))
    except zenoh.ZError as exc:
        parser.error(f"cannot join the Zenoh network ({', '.join(connect) or args.config}): "
                     f"{zerror_text(exc)}")


@contextlib.contextmanager
def listening(args: argparse.Namespace, parser: argparse.ArgumentParser, join_within: float | None = None,
              timestamping: bool = False) -> Iterator[tuple[zenoh.Session, threading.Event]]:
    """A command that runs until SIGINT / SIGTERM: its session (:func:`open_session`), closed at the end,
    and the event those signals set."""
    session = open_session(args, parser, join_within, timestamping)
    signals = StopSignals()
    with session:
        yield session, signals.stop


def no_answer(args: argparse.Namespace, parser: argparse.ArgumentParser, exc: ArmError) -> int:
    """A query of the command that got no answer: why on stderr, exit 1."""
    # A router drops what a role may not do without a word to the client: silence.
    hint = (f" (in a secure cell this is also what identity {args.identity!r} gets for what its role "
            "may not do: the router's log says which)") if args.secure else ""
    print(f"{parser.prog}: {exc}{hint}", file=sys.stderr)
    return 1
