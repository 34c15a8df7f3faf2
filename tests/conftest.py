"""Fixtures shared by several test modules; the live harness they use is ``harness.py``, plain helpers
live in ``support.py``.

``live`` and ``arm``: the whole system (``jara-arm up``) of one robot, driven as a
black box (``test_middle.py``, ``test_families.py``, ...). A module that uses them
provides a module-scoped ``robot_name`` fixture whose params are the robots to run,
one system each (pytest groups the module's tests by robot, so one system is up at
a time). Its client of the system is the module's ``Arm`` class if it has one (a
``harness.LiveArm``, often a ``RecordingArm``, with what only that module needs),
else a ``LiveArm``.

The rigs of ``test_servo.py`` (a servo alone), ``test_planner.py`` (a servo and a
planner, the test a peer of both) and ``test_command.py`` (a router of the test's
own, a servo, a planner and two command services, one of them with fake peers)
start different services and stay with their modules; ``test_alarms.py``'s
system stays there too (``bench/alarm_latency.py`` imports it).
"""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from jara_arm.schema.keys import Service

from .harness import LiveArm, launched
from .support import client_session


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
