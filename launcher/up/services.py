"""The table of services the launcher runs for every arm, in start order, and ``jara-arm service NAME``.

A service is a module ``jara_arm.services.<x>`` whose ``main`` module names its
``PROGRAM`` (an ``runtime.service.ArmService``) and its ``run(argv) -> int`` entry,
with a ``__main__`` so that
``python -m jara_arm.services.<x>`` runs it. List a service here only once its
module exists; ``jara-arm up`` starts them in this order and stops them in the
reverse order (the command service before the servo it drives). ``jara-arm service NAME``
runs one of them in this process (as compose does).
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib
from collections.abc import Sequence
from types import ModuleType
from typing import TYPE_CHECKING

from jara_arm.schema.keys import Service

from ..command import Command

if TYPE_CHECKING:
    from jara_arm.services.runtime.service import ArmService


@dataclasses.dataclass(frozen=True)
class ServiceSpec:
    """One row of the table: which service, which module, what it does."""

    service: Service
    module: str
    description: str

    @property
    def name(self) -> str:
        """The ``<service>`` key chunk, also the ``jara-arm service NAME`` name."""
        return self.service.value

    def entry(self) -> ModuleType:
        """The service's ``main`` module (imported on demand: PyBullet is heavy)."""
        return importlib.import_module(f"{self.module}.main")

    def run(self, argv: Sequence[str]) -> int:
        """Run the service in this process, as ``python -m <module> <argv>`` would."""
        return int(self.entry().run(list(argv)))

    def parser(self) -> argparse.ArgumentParser:
        """The service's own argument parser: the shared options plus its extra ones."""
        program: type[ArmService] = self.entry().PROGRAM
        return program.parser()


# One line per service, lower layers first.
SERVICES: tuple[ServiceSpec, ...] = (
    ServiceSpec(Service.SERVO, "jara_arm.services.servo", "low level: simulated arm, servo loop, interpolator, SyncFIFO, Servo/Common"),
    ServiceSpec(Service.PLANNER, "jara_arm.services.planner", "middle level: plans motions and hands them to the servo whole"),
    ServiceSpec(Service.COMMAND, "jara_arm.services.command", "middle level: Common and Middle, state, settings, motion queue"),
    ServiceSpec(Service.ALARM_MONITOR, "jara_arm.services.alarm_monitor", "active alarms: detection, reactions, alarm events"),
)

NAMES: tuple[str, ...] = tuple(s.name for s in SERVICES)


def spec(name: str) -> ServiceSpec:
    """The table row of service ``name``; KeyError naming the valid ones otherwise."""
    for s in SERVICES:
        if s.name == name:
            return s
    raise KeyError(f"no service {name!r}; services: {', '.join(NAMES)}")


def _arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("name", choices=NAMES, metavar="NAME",
                        help="; ".join(f"{s.name}: {s.description}" for s in SERVICES))
    parser.add_argument("args", nargs=argparse.REMAINDER,
                        help="the service's arguments (jara-arm service NAME --help)")


def _run(args: argparse.Namespace, parser: argparse.ArgumentParser) -> int:
    return spec(args.name).run(args.args)


def _inner(words: list[str]) -> tuple[argparse.ArgumentParser, list[str]] | None:
    """``NAME ARGS...``: the service's own parser, and ARGS."""
    if words and words[0] in NAMES:
        return spec(words[0]).parser(), words[1:]
    return None


COMMAND = Command(
    "service", arguments=_arguments, run=_run, inner=_inner,
    help="run one service in this process",
    description="Run one service of one arm in this process (as compose does).")
