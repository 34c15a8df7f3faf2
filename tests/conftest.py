"""Fixtures shared by several test modules; the live harness they use is ``harness.py``, plain helpers
live in ``support.py``.

``live`` and ``arm``: the whole system (``jara-arm up``) of one robot, driven as a
black box (``test_middle.py``, ``test_families.py``, ...). A module that uses them
provides a module-scoped ``robot_name`` fixture whose params are the robots to run,
one system each (pytest groups the module's tests by robot, so one system is up at
a time). Its client of the system is the module's ``Arm`` class if it has one (a
``harness.LiveArm``, often a ``RecordingArm``, with what only that module needs),
else a ``LiveArm``.

``alarm_system``: the system of the alarm tests (``alarm_system.py``: an obstacle in
the simulated world, every service alive), once per module that uses it. A system
shared by the modules for the whole session would run beside every later module.

The rigs of ``test_servo.py`` (a servo alone), ``planner_rig.py`` (a servo and a
planner, the test a peer of both) and ``command_rig.py`` (a router of the test's
own, with service processes as its clients) start some of the services only; they
stay with the modules that use them.
"""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from jara_arm.schema.keys import Service

from .alarm_system import AlarmArm, report_latencies, started_system
from .harness import LiveArm, launched
from .support import client_session

#: The files that take longest, longest first (one process, quiet, 2026-11-28: from 144 s down to 20 s): they
#: run first, so that on the workers of ``make test`` (three, each file whole on one worker) the long
#: ones start at once and the short ones fill in around them, instead of a long file starting last.
LONGEST_FIRST = ("test_families.py", "test_isolation.py", "test_view.py", "test_launcher.py", "test_jog.py",
                 "test_cell_hosts.py", "test_program.py", "test_middle.py", "test_alarms_services.py",
                 "test_planner_service.py", "test_plot.py", "test_cli_tools.py", "test_blend.py", "test_ros2.py",
                 "test_secure.py", "test_record.py", "test_elbow.py", "test_pendant.py")


@pytest.hookimpl(trylast=True)  # after pytest's own grouping by fixtures: only whole files move
def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    rank = {name: i for i, name in enumerate(LONGEST_FIRST)}
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))


@pytest.fixture(scope="module")
def live(request: pytest.FixtureRequest, robot_name: str) -> Iterator[LiveArm]:
    """``jara-arm up --robot <robot_name>`` for the module and the module's ``Arm`` client of it (a ``LiveArm``
    if it has none), once the servo, the planner and the command service are alive; ``arm.proc`` is the
    launcher."""
    arm_type = getattr(request.module, "Arm", LiveArm)
    with launched("--robot", robot_name) as (proc, port), client_session(port) as session:
        arm = arm_type(session, robot_name, proc=proc)
        arm.client.wait_alive((Service.SERVO, Service.PLANNER, Service.COMMAND))
        yield arm


@pytest.fixture
def arm(live: LiveArm) -> LiveArm:
    """``live``, back at the module's starting point (``reset()``)."""
    live.reset()
    return live


@pytest.fixture(scope="module")
def alarm_system() -> Iterator[AlarmArm]:
    """The alarm tests' system and client of it; the detection latencies measured, printed at the end."""
    with started_system() as arm:
        yield arm
    report_latencies()
