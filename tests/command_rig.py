"""The command service's rigs (``test_command_operations.py``, ``test_command_peers.py``): an in-process
Zenoh router of the test's own, as the launcher runs one, with service processes as its clients; and
what each test starts from.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

import numpy as np
import pinocchio as pin
import zenoh

from jara_arm.robots import robot
from jara_arm.schema.operations import OP, Interface
from jara_arm.schema.types import CartesianSpeed, hg_matrix
from jara_arm.services.runtime.zenoh_args import zenoh_config

from .harness import LiveArm
from .support import endpoint, free_port

IIWA = robot("iiwa")


@contextlib.contextmanager
def router() -> Iterator[tuple[zenoh.Session, int]]:
    """A router session listening on a loopback port of its own, and that port."""
    port = free_port()
    with zenoh.open(zenoh_config("router", listen=[endpoint(port)])) as session:
        yield session, port


DEFAULT_SETTINGS: tuple[tuple[Interface, str, dict], ...] = (
    (Interface.MIDDLE, OP.setSpeedJoint, {"spdRatio": 0}),
    (Interface.MIDDLE, OP.setSpeedCartesian, {"spdRatio": 0}),
    (Interface.MIDDLE, OP.setMaxSpeedJoint, {"speed": IIWA.rated_speed}),
    (Interface.MIDDLE, OP.setMaxSpeedCartesian, {"speed": CartesianSpeed(0.25, 1.0)}),
    (Interface.MIDDLE, OP.setMinAccelTimeJoint, {"aclTime": IIWA.min_accel_time}),
    (Interface.MIDDLE, OP.setAccelTimeJoint, {"aclTime": IIWA.min_accel_time}),
    (Interface.MIDDLE, OP.setMinAccelTimeCartesian, {"aclTime": IIWA.min_accel_time_cartesian}),
    (Interface.MIDDLE, OP.setAccelTimeCartesian, {"aclTime": IIWA.min_accel_time_cartesian}),
    (Interface.MIDDLE, OP.setBaseOffset, {"offset": hg_matrix()}),
    (Interface.MIDDLE, OP.setControlPointOffset, {"offset": hg_matrix()}),
    (Interface.MIDDLE, OP.setHome, {"jointPoint": IIWA.ready_pose}),
    (Interface.EXT, OP.setBlendDistance, {"distance": 0.0}),
    (Interface.EXT, OP.setSpeedOverride, {"ratio": 100.0}),  # the servo keeps it across servoOFF
)


def reset(rig: LiveArm) -> None:
    """Servo off (queue discarded), at rest, alarms cleared, default settings, servo on."""
    rig.call_ok(Interface.COMMON, OP.servoOFF)
    rig.wait_rest()
    rig.call_ok(Interface.COMMON, OP.clearAlarms)
    rig.call_ok(Interface.COMMON, OP.setSoftLimitJoint, {"softLimit": IIWA.hard_limits})
    for interface, name, args in DEFAULT_SETTINGS:
        rig.call_ok(interface, name, args)
    rig.call_ok(Interface.COMMON, OP.servoON)


def rot(axis: str, angle: float) -> np.ndarray:
    return pin.utils.rpyToMatrix(*(angle if a == axis else 0.0 for a in "xyz"))
