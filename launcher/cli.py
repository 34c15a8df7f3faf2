"""``jara-arm``: run the arm services on this host, one of them, or a bare Zenoh router.

    jara-arm up [--arm ID[:ROBOT]]... [--robot NAME] [--demo] [--obstacle X,Y,Z,HX,HY,HZ]... [--hidden-obstacle ...]...
                [--listen ENDPOINT]... [--connect ENDPOINT]... [--config ZENOH_CONFIG_FILE] [--multicast]
                [--bus-listen ENDPOINT]... [--log-level LEVEL]
    jara-arm service NAME [the service's own arguments; see jara-arm service NAME --help]
    jara-arm router [--gateway | --bus] [--gateway-id HEX]... [--listen ENDPOINT]... [--connect ENDPOINT]...
                    [--config FILE] [--multicast]
    jara-arm logs [--arm ID] [--service NAME] [--level LEVEL] [Zenoh options]
    jara-arm alarms [--arm ID] [Zenoh options]
    jara-arm call [--arm ID] [--servo] [--timeout S] OP [JSON] [Zenoh options]
    jara-arm echo [--arm ID] [--rate HZ] [--once | --count N] [--timeout S] [--show-key] KEY [Zenoh options]
    jara-arm state [--arm ID] [--once] [--period S] [Zenoh options]
    jara-arm wait [--arm ID] [--timeout S] [--poll S] CONDITION [Zenoh options]
    jara-arm record [--arm ID]... -o FILE.mcap [--duration S] [--ros2] [Zenoh options]
    jara-arm replay FILE.mcap [--speed X] [--arm ID]... [Zenoh options]
    jara-arm plot [--arm ID] (--seconds S | --from FILE.mcap) [--start S] [--end S] [--robot NAME] -o FILE.png
                  [--path FILE.png] [--size WxH] [--no-show] [Zenoh options]
    jara-arm view [--arm ID]... [--host ADDRESS] [--port P] [--rate HZ] [Zenoh options]
    jara-arm pendant [--arm ID] [--host ADDRESS] [--port P] [--program FILE] [--no-3d] [Zenoh options]
    jara-arm program (check | run [--step]) FILE [--arm ID] [--cycles N] [Zenoh options]
    jara-arm ros2 [--arm ID]... [--ros-domain N] [--ros-namespace NS] [--ros-rate HZ] [Zenoh options]
    jara-arm certs init DIR [--days N] [--host H]...
    jara-arm certs issue DIR NAME --role ROLE [--host H]... [--days N] [--force]
    jara-arm certs list DIR
    jara-arm completion bash

``logs`` and ``alarms`` join any Zenoh network (by default as a client of
tcp/127.0.0.1:7447) and print what arrives until SIGINT/SIGTERM
(``launcher/tools/watch.py``); ``call``, ``echo``, ``state`` and ``wait`` join it
the same way (``launcher/tools/call.py``, ``echo.py``, ``state_view.py``,
``wait.py``), and ``plot`` too unless it reads a recording
(``launcher/record/plot_command.py``, ``plot.py``); ``view`` serves a web page with
a live 3D view of the arms (``launcher/view/view.py``); ``ros2`` publishes them
as ROS 2 topics for nodes on rmw_zenoh (``launcher/ros2/bridge.py``). ``certs`` makes a secure
cell's directory, its certificate authority and the certificates of its
identities, and lists them (``launcher/secure/certs.py``). ``up``, ``service`` and
``router`` are in ``launcher/up/``.

Each command registers itself next to its code (a ``command.Command``: name,
help, arguments, run); this module is their table, in the order of
``jara-arm --help``, and imports only the command a line names.

A user mistake (unknown robot, bad arm id, a port already in use…) prints one
readable message and exits with status 2.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Sequence

from .command import Command

#: Where each command lives (``module:attribute`` under ``jara_arm.launcher``), in the order of
#: ``jara-arm --help``. A command line imports only its own command's module: every module pulls in what its
#: command needs (the client, cryptography, a web server...), and the router, the gateway and ``jara-arm call``
#: start 0.3-0.6 s sooner without the rest (``python -X importtime``, 2026-11-28).
COMMANDS: dict[str, str] = {
    "up": "up.up:COMMAND", "service": "up.services:COMMAND", "router": "up.router:COMMAND",
    "logs": "tools.watch:LOGS", "alarms": "tools.watch:ALARMS", "demo": "tools.demo:COMMAND",
    "call": "tools.call:COMMAND", "echo": "tools.echo:COMMAND", "state": "tools.state_view:COMMAND",
    "wait": "tools.wait:COMMAND", "record": "record.record:COMMAND", "replay": "record.replay:COMMAND",
    "plot": "record.plot_command:COMMAND", "view": "view.view:COMMAND", "pendant": "pendant.pendant:COMMAND",
    "program": "program.program_command:COMMAND", "ros2": "ros2.bridge:COMMAND", "certs": "secure.certs:COMMAND",
    "completion": "completion:COMMAND",
}


def command(name: str) -> Command:
    """The command ``name`` (a key of :data:`COMMANDS`), its module imported."""
    module, attribute = COMMANDS[name].split(":")
    found: Command = getattr(importlib.import_module(f"{__package__}.{module}"), attribute)
    return found


def _parsers(only: str | None = None
             ) -> tuple[argparse.ArgumentParser, dict[str, tuple[Command, argparse.ArgumentParser]]]:
    """``jara-arm``'s parser with every command's, or with ``only``'s."""
    top = argparse.ArgumentParser(prog="jara-arm", description="JARA_ARM robot-arm services over Zenoh.")
    sub = top.add_subparsers(dest="command", required=True, metavar="COMMAND")
    names = [only] if only is not None else list(COMMANDS)
    return top, {name: (found, found.add_to(sub)) for name in names for found in [command(name)]}


def parser() -> argparse.ArgumentParser:
    """The parser of ``jara-arm``'s command line."""
    return _parsers()[0]


def command_parsers() -> dict[str, tuple[Command, argparse.ArgumentParser]]:
    """Every command with its parser, by name, in the order of ``jara-arm --help``."""
    return _parsers()[1]


def command_parser(argv: Sequence[str]) -> tuple[argparse.ArgumentParser, list[str]]:
    """The parser that reads ``jara-arm <argv>``, and the arguments it gets.

    ``["service", "servo", "--arm", "a1"]`` gives the servo's own parser and
    ``["--arm", "a1"]``. ValueError for an unknown command or service.
    """
    argv = list(argv)
    found = command_parsers().get(argv[0]) if argv else None
    if found is not None:
        command, own_parser = found
        read = command.inner(argv[1:]) if command.inner is not None else (own_parser, argv[1:])
        if read is not None:
            return read
    raise ValueError(f"not a jara-arm command: {' '.join(argv)!r}")


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``jara-arm`` console script; returns the exit status."""
    try:
        words = list(sys.argv[1:] if argv is None else argv)
        top, commands = _parsers(words[0] if words and words[0] in COMMANDS else None)
        args = top.parse_args(words)
        command, own_parser = commands[args.command]
        return command.run(args, own_parser)
    except SystemExit as exc:  # argparse's exits (usage errors: 2, --help: 0)
        if exc.code is None or isinstance(exc.code, int):
            return exc.code or 0
        print(exc.code, file=sys.stderr)
        return 1


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
