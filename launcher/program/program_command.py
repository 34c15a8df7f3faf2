"""``jara-arm program check FILE`` and ``jara-arm program run FILE [--step] [--cycles N]``."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from jara_arm.client import Arm, ArmError
from jara_arm.schema.keys import DEFAULT_ARM
from jara_arm.schema.program import ProgramError, load
from jara_arm.services.runtime.arguments import positive_int

from ..command import Command, setup_logging
from ..session import add_client_zenoh_arguments, arm_id, open_session
from .check import check
from .run import Runner


def _arguments(parser: argparse.ArgumentParser) -> None:
    actions = parser.add_subparsers(dest="program_command", required=True, metavar="ACTION")
    for name, help_text in (("check", "check a program against the live arm, moving nothing"),
                            ("run", "run a program on the live arm, step by step")):
        p = actions.add_parser(name, help=help_text, description=help_text[0].upper() + help_text[1:] + ".")
        p.add_argument("file", type=Path, metavar="FILE", help="the program (YAML; docs/programs.md)")
        p.add_argument("--arm", type=arm_id, default=DEFAULT_ARM, metavar="ID",
                       help=f"the arm (default: {DEFAULT_ARM})")
        p.add_argument("--cycles", type=positive_int, default=1, metavar="N",
                       help="run the whole program N times (default: 1)")
        if name == "run":
            p.add_argument("--step", action="store_true", help="wait for Enter before each step")
        add_client_zenoh_arguments(p)


def _run(args: argparse.Namespace, parser: argparse.ArgumentParser) -> int:
    """0: checked clean / ran and arrived; 1: a mistake or a step that failed (said on stdout)."""
    setup_logging("WARNING")
    try:
        program = load(args.file)
    except ProgramError as exc:
        print(exc, file=sys.stdout)
        print(f"{len(exc.mistakes)} mistake(s)" + (": nothing moved" if args.program_command == "run" else ""))
        return 1
    session = open_session(args, parser)
    with session:
        try:
            with Arm(session, args.arm) as arm:
                if args.program_command == "check":
                    mistakes = check(program, arm, args.cycles)
                    for m in mistakes:
                        print(f"{program.path}:{m}")
                    print(f"{len(mistakes)} mistake(s)" if mistakes else
                          f"{program.path}: ok, {len(program.flat(args.cycles))} steps")
                    return 1 if mistakes else 0
                return Runner(arm, sys.stdout, input if args.step else None).run(program, args.cycles)
        except ArmError as exc:
            print(f"{parser.prog}: {exc}", file=sys.stderr)
            return 1


COMMAND = Command(
    "program", arguments=_arguments, run=_run,
    help="check or run a program of taught points (docs/programs.md)",
    description="A program (YAML: named points, as Ext/teach stores them, and steps: ptp, lin, circ, wait, "
    "loop) checked against the live arm (every motion planned, nothing moved), or run on it step by step, "
    "every arrival measured. A program with a mistake moves nothing.")
