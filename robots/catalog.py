"""The robot models selectable with ``--robot NAME``."""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path
from types import MappingProxyType

import pybullet_data

from .model import Family, RobotModel, RobotModelError

_PB = Path(pybullet_data.getDataPath())
_DEG = math.pi / 180.0

#: KUKA LBR iiwa 14 R820 (the pybullet_data model), rated speeds from KUKA's data sheet.
IIWA = RobotModel(
    name="iiwa",
    manufacturer="KUKA",
    type="LBR iiwa 14 R820",
    family=Family.ARTICULATED,
    urdf=_PB / "kuka_iiwa" / "model.urdf",
    arm_joints=tuple(f"lbr_iiwa_joint_{i}" for i in range(1, 8)),
    flange_frame="lbr_iiwa_link_7",
    rated_speed=tuple(d * _DEG for d in (85, 85, 100, 75, 130, 135, 135)),
    rated_effort=(320.0, 320.0, 176.0, 176.0, 110.0, 40.0, 40.0),
    min_accel_time=0.2,
    min_accel_time_cartesian=0.2,
    ready_pose=(0.0, 0.5, 0.0, -1.2, 0.0, 0.8, 0.0),
)

#: Franka Emika Panda; both fingers are one gripper axis [m per finger], 0 closed .. 0.04 open.
PANDA = RobotModel(
    name="panda",
    manufacturer="Franka Emika",
    type="Panda",
    family=Family.ARTICULATED,
    urdf=_PB / "franka_panda" / "panda.urdf",
    arm_joints=tuple(f"panda_joint{i}" for i in range(1, 8)),
    flange_frame="panda_link8",
    rated_speed=(2.175, 2.175, 2.175, 2.175, 2.61, 2.61, 2.61),
    rated_effort=(87.0, 87.0, 87.0, 87.0, 12.0, 12.0, 12.0),
    min_accel_time=0.2,
    min_accel_time_cartesian=0.2,
    ready_pose=(0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785),
    gripper_joints=("panda_finger_joint1", "panda_finger_joint2"),
    gripper_speed=0.1,
    gripper_effort=70.0,
)

ROBOTS: Mapping[str, RobotModel] = MappingProxyType({r.name: r for r in (IIWA, PANDA)})
DEFAULT_ROBOT = IIWA.name


def robot(name: str) -> RobotModel:
    """The model called ``name``; RobotModelError listing the valid names otherwise."""
    try:
        return ROBOTS[name]
    except KeyError:
        raise RobotModelError(f"unknown robot {name!r}; valid robots: {', '.join(ROBOTS)}") from None
