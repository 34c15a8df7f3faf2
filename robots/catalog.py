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
    ready_pose=(0.0, 0.4, 0.0, -1.74, 0.0, 1.0, 0.0),  # flange at (0.5, 0, 0.45) m, tool down
    # structFlag = 0x100 | bits at a given arm angle (KUKA LBR's Status): 0x1 J2 < 0, 0x2 J4 < 0
    # (stretched at 0), 0x4 J6 < 0. Each bit is one of the 8 solutions of a pose and arm angle,
    # e.g. J1 + pi, -J2, J3 + pi for 0x1; the ready pose is 0x102.
    posture_joints=(1, 3, 5),
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
    # structFlag = 0x100 | bits at a given arm angle, as the iiwa's: 0x1 J2 < 0; 0x2 J4 below its
    # stretched value -0.467 rad (the link offsets bend the straight arm), so only J4 in (-0.467, 0]
    # clears it; 0x4 sin(J6) < 0, i.e. J6 < 0 or J6 > pi (J6 spans -0.087 .. 3.82 rad). The ready
    # pose is 0x103 (J2 < 0); 0x104 .. 0x107 exist only near J6's ends.
    posture_joints=(1, 3, 5),
    gripper_joints=("panda_finger_joint1", "panda_finger_joint2"),
    gripper_speed=0.1,
    gripper_effort=70.0,
)

_URDF = Path(__file__).with_name("urdf")
_SIM = "JARA sim"  # invented models of this project; not a vendor's product

#: 1-axis linear axis; X stroke 1 m; flange on the carriage, frame parallel to the base.
CARTESIAN1 = RobotModel(
    name="cartesian1",
    manufacturer=_SIM,
    type="SIM-C1 1-axis linear gantry",
    family=Family.CARTESIAN,
    urdf=_URDF / "cartesian1.urdf",
    arm_joints=("x_axis",),
    flange_frame="flange",
    rated_speed=(1.5,),
    rated_effort=(500.0,),
    min_accel_time=0.15,
    min_accel_time_cartesian=0.15,
    ready_pose=(0.5,),
)

#: 2-axis XY gantry: J1 = X (1 m), J2 = Y (0.6 m).
CARTESIAN2 = RobotModel(
    name="cartesian2",
    manufacturer=_SIM,
    type="SIM-C2 2-axis XY gantry",
    family=Family.CARTESIAN,
    urdf=_URDF / "cartesian2.urdf",
    arm_joints=("x_axis", "y_axis"),
    flange_frame="flange",
    rated_speed=(1.5, 1.5),
    rated_effort=(500.0, 300.0),
    min_accel_time=0.15,
    min_accel_time_cartesian=0.15,
    ready_pose=(0.5, 0.3),
)

#: 3-axis XYZ portal gantry (1 x 0.6 x 0.3 m, J3 = 0 lowest) with a parallel gripper:
#: both fingers are one gripper axis [m per finger], 0 closed .. 0.04 open.
CARTESIAN3 = RobotModel(
    name="cartesian3",
    manufacturer=_SIM,
    type="SIM-C3 3-axis XYZ gantry",
    family=Family.CARTESIAN,
    urdf=_URDF / "cartesian3.urdf",
    arm_joints=("x_axis", "y_axis", "z_axis"),
    flange_frame="flange",
    rated_speed=(1.5, 1.5, 1.0),
    rated_effort=(600.0, 300.0, 250.0),
    min_accel_time=0.15,
    min_accel_time_cartesian=0.15,
    ready_pose=(0.5, 0.3, 0.15),
    gripper_joints=("finger_joint1", "finger_joint2"),
    gripper_speed=0.1,
    gripper_effort=40.0,
)

#: 4-axis SCARA, 325 + 275 mm arms (0.6 m reach), quill J3 -0.2 (down) .. 0 m; flange frame
#: parallel to the base, so the tool orientation is J1 + J2 + J4 about Z.
SCARA4 = RobotModel(
    name="scara4",
    manufacturer=_SIM,
    type="SIM-S4 600 mm SCARA",
    family=Family.SCARA,
    urdf=_URDF / "scara4.urdf",
    arm_joints=("joint1", "joint2", "joint3", "joint4"),
    flange_frame="flange",
    rated_speed=(7.0, 7.0, 1.1, 12.0),
    rated_effort=(150.0, 60.0, 150.0, 6.0),
    min_accel_time=0.15,
    min_accel_time_cartesian=0.15,
    ready_pose=(0.0, 1.5, -0.1, 0.0),
)

#: 5-axis arm (yaw, pitch, pitch, pitch, roll), 0.28 + 0.25 + 0.08 m; zero pose upright.
ARM5 = RobotModel(
    name="arm5",
    manufacturer=_SIM,
    type="SIM-A5 5-axis articulated arm",
    family=Family.ARTICULATED,
    urdf=_URDF / "arm5.urdf",
    arm_joints=tuple(f"joint{i}" for i in range(1, 6)),
    flange_frame="flange",
    rated_speed=(2.0, 2.0, 2.5, 3.0, 3.0),
    rated_effort=(40.0, 60.0, 30.0, 10.0, 5.0),
    min_accel_time=0.3,
    min_accel_time_cartesian=0.3,
    ready_pose=(0.0, 0.3, 1.3, 1.4, 0.0),
)

#: 6-axis arm, spherical wrist, ~0.8 m reach (IRB-style: zero pose upper arm up, forearm
#: along +X); ready pose has the tool pointing down, elbow and wrist bent.
ARM6 = RobotModel(
    name="arm6",
    manufacturer=_SIM,
    type="SIM-A6 6-axis articulated arm",
    family=Family.ARTICULATED,
    urdf=_URDF / "arm6.urdf",
    arm_joints=tuple(f"joint{i}" for i in range(1, 7)),
    flange_frame="flange",
    rated_speed=(2.5, 2.5, 2.5, 3.0, 3.0, 3.0),
    rated_effort=(120.0, 200.0, 100.0, 30.0, 30.0, 10.0),
    min_accel_time=0.25,
    min_accel_time_cartesian=0.25,
    ready_pose=(0.0, 0.2, 0.2, 0.0, 1.17, 0.0),
    # structFlag = 0x100 | bits (KUKA's 6-axis Status): 0x1 the wrist centre (J5) behind J1's axis
    # (overhead: negative along J1's x axis, which turns with J1); 0x2 elbow down: J3 below its
    # stretched value -1.457 rad; 0x4 wrist flipped: J5 < 0. The ready pose is 0x100.
    posture_joints=(1, 2, 4),
)

ROBOTS: Mapping[str, RobotModel] = MappingProxyType(
    {r.name: r for r in (IIWA, PANDA, CARTESIAN1, CARTESIAN2, CARTESIAN3, SCARA4, ARM5, ARM6)}
)
DEFAULT_ROBOT = IIWA.name


def robot(name: str) -> RobotModel:
    """The model called ``name``; RobotModelError listing the valid names otherwise."""
    try:
        return ROBOTS[name]
    except KeyError:
        raise RobotModelError(f"unknown robot {name!r}; valid robots: {', '.join(ROBOTS)}") from None
