"""A command of ``jara-arm``: its registration, and what every command shares.

A module that implements a command says so with a :class:`Command` (its name,
help texts, the function that adds its arguments, the function that runs it);
``cli.COMMANDS`` says where each lives. A run gets the command's own parser, so that its
messages start with ``parser.prog`` (``jara-arm NAME``) as argparse's do.
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
import sys
from collections.abc import Callable, Mapping

#: The exit status of a user mistake (unknown robot, bad arm id, a port already in use…), as argparse's.
USAGE_ERROR = 2

#: Runs a parsed command line with the command's own parser (for its usage errors); returns the exit status.
Run = Callable[[argparse.Namespace, argparse.ArgumentParser], int]

#: The parser of another program that reads the words after the command's name, and the words it gets; None
#: if they do not name one (``service NAME ...``: the service's own).
Inner = Callable[[list[str]], tuple[argparse.ArgumentParser, list[str]] | None]


@dataclasses.dataclass(frozen=True)
class Command:
    """``jara-arm NAME``: how its parser is made and what runs it."""

    name: str
    help: str  #: its line in ``jara-arm --help``
    description: str
    arguments: Callable[[argparse.ArgumentParser], None]  #: adds its options and positional arguments
    run: Run
    epilog: str | None = None
    #: what bash offers for the first positional argument when its parser has no choices to offer
    words: tuple[str, ...] = ()
    #: what bash offers instead when an option is on the line (``call --servo``: the servo's operations)
    option_words: Mapping[str, tuple[str, ...]] = dataclasses.field(default_factory=dict)
    #: a command that hands the words after its name to another program's parser (``service``), for
    #: ``cli.command_parser``
    inner: Inner | None = None

    def add_to(self, commands: argparse._SubParsersAction[argparse.ArgumentParser]) -> argparse.ArgumentParser:
        """The command's parser, made among ``commands`` (the subparsers of ``jara-arm``)."""
        parser = commands.add_parser(self.name, help=self.help, description=self.description, epilog=self.epilog)
        self.arguments(parser)
        return parser


def setup_logging(level: str) -> None:
    """The launcher's own messages: stderr, in the format of the services' log lines."""
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(logging.Formatter(
        "%(asctime)s.%(msecs)03d %(levelname)-7s jara-arm: %(message)s", datefmt="%H:%M:%S"))
    root = logging.getLogger()
    root.addHandler(handler)
    root.setLevel(level)
