"""The ROS 2 messages of an arm, built and serialized with ``rosbags`` (Jazzy's message definitions and their
RIHS01 type hashes; no ROS install, no hand-written CDR).

Per arm (``bridge.py`` publishes them, ``record --ros2`` writes them):

* ``joint_states``: ``sensor_msgs/msg/JointState``, the URDF's joint names, the measured positions and
  velocities (the gripper axis as each of its URDF joints);
* ``tf``: ``tf2_msgs/msg/TFMessage``, the URDF's root link to each other link, from the measured joints
  (Pinocchio's forward kinematics of the URDF);
* ``robot_description``: ``std_msgs/msg/String``, the URDF;
* ``jara_arm/state``: ``diagnostic_msgs/msg/DiagnosticStatus``, the standard type for a device's health
  (rqt_robot_monitor and Foxglove read it): ``level`` OK, WARN with a warning alarm, ERROR with a fault;
  ``message`` the state bits in words; ``values`` the state (``0x..``) and the active alarm codes.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Sequence
from typing import Any

import numpy as np

from jara_arm.robots import RobotModel
from jara_arm.schema.alarms import format_code
from jara_arm.schema.codes import StateBit
from jara_arm.schema.codes import AlarmType
from jara_arm.schema.types import Alarm

#: The ROS distribution whose message definitions and type hashes are used.
DISTRO = "jazzy"
JOINT_STATE = "sensor_msgs/msg/JointState"
TF_MESSAGE = "tf2_msgs/msg/TFMessage"
STRING = "std_msgs/msg/String"
DIAGNOSTIC_STATUS = "diagnostic_msgs/msg/DiagnosticStatus"


@functools.cache
def typestore() -> Any:
    """rosbags' Jazzy type store (built once: 0.1 s)."""
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_JAZZY)


def type_hash(ros_type: str) -> str:
    """``RIHS01_<64 hex>`` of ``ros_type`` in :data:`DISTRO`."""
    return str(typestore().hash_rihs01(ros_type))


def cdr(message: Any, ros_type: str) -> bytes:
    """``message`` in CDR, little-endian, with its encapsulation header."""
    return bytes(typestore().serialize_cdr(message, ros_type))


def _stamp(t: float) -> Any:
    types = typestore().types
    sec = int(np.floor(t))
    return types["builtin_interfaces/msg/Time"](sec=sec, nanosec=int(round((t - sec) * 1e9)) % 1_000_000_000)


def _header(t: float, frame: str = "") -> Any:
    return typestore().types["std_msgs/msg/Header"](stamp=_stamp(t), frame_id=frame)


@dataclasses.dataclass(frozen=True)
class ArmDescription:
    """What the messages of one arm need of its robot model: joint names and the URDF's tree."""

    model: RobotModel
    urdf: str  # the URDF text
    joints: tuple[str, ...]  # JointState names: the arm's joints, then each gripper joint
    root: str  # the URDF's root link

    @classmethod
    def of(cls, model: RobotModel) -> ArmDescription:
        import pinocchio as pin

        full = pin.buildModelFromUrdf(str(model.urdf))
        root = next(f.name for f in full.frames if f.type == pin.FrameType.BODY)
        return cls(model, model.urdf.read_text(), (*model.arm_joints, *model.gripper_joints), root)

    def positions(self, q: Sequence[float]) -> np.ndarray:
        """JointState positions (or velocities) from the servo's ``q`` (arm axes, then the gripper axis)."""
        n = self.model.axis_num
        arm = np.asarray(q[:n], dtype=float)
        grip = [float(q[n])] * len(self.model.gripper_joints) if self.model.has_gripper and len(q) > n else []
        return np.concatenate([arm, grip]) if grip else arm


class Kinematics:
    """The URDF's forward kinematics for ``tf`` (Pinocchio; its own data: one thread uses it)."""

    def __init__(self, arm: ArmDescription) -> None:
        import pinocchio as pin

        self._pin = pin
        self.arm = arm
        self.model = pin.buildModelFromUrdf(str(arm.model.urdf))
        self.data = self.model.createData()
        self.links = [f for f in self.model.frames if f.type == pin.FrameType.BODY and f.name != arm.root]
        self._index = [self.model.joints[self.model.getJointId(j)].idx_q for j in arm.joints]

    def transforms(self, positions: np.ndarray) -> list[tuple[str, np.ndarray, np.ndarray]]:
        """Each link's pose in the root link: (name, translation [m], quaternion x, y, z, w)."""
        pin = self._pin
        q = pin.neutral(self.model)
        q[self._index] = positions
        pin.framesForwardKinematics(self.model, self.data, q)
        out = []
        for f in self.links:
            m = self.data.oMf[self.model.getFrameId(f.name)]
            out.append((f.name, np.array(m.translation), pin.Quaternion(m.rotation).coeffs().copy()))
        return out


def joint_state(arm: ArmDescription, t: float, q: Sequence[float], v: Sequence[float]) -> Any:
    """``sensor_msgs/msg/JointState`` at ``t`` [s since the epoch]."""
    return typestore().types[JOINT_STATE](header=_header(t), name=list(arm.joints), position=arm.positions(q),
                                          velocity=arm.positions(v), effort=np.zeros(0))


def tf_message(kin: Kinematics, t: float, q: Sequence[float]) -> Any:
    """``tf2_msgs/msg/TFMessage``: the root link to every other link at ``t``."""
    types = typestore().types
    out = []
    for name, p, quat in kin.transforms(kin.arm.positions(q)):
        out.append(types["geometry_msgs/msg/TransformStamped"](
            header=_header(t, kin.arm.root), child_frame_id=name,
            transform=types["geometry_msgs/msg/Transform"](
                translation=types["geometry_msgs/msg/Vector3"](x=float(p[0]), y=float(p[1]), z=float(p[2])),
                rotation=types["geometry_msgs/msg/Quaternion"](x=float(quat[0]), y=float(quat[1]),
                                                               z=float(quat[2]), w=float(quat[3])))))
    return types[TF_MESSAGE](transforms=out)


def description(arm: ArmDescription) -> Any:
    """``std_msgs/msg/String``: the URDF."""
    return typestore().types[STRING](data=arm.urdf)


def arm_state(arm_id: str, robot: str, state: int, alarms: Sequence[Alarm]) -> Any:
    """``diagnostic_msgs/msg/DiagnosticStatus`` of the state bits and the active alarms."""
    types = typestore().types
    status = types[DIAGNOSTIC_STATUS]
    fault = any(a.type is AlarmType.FAULT for a in alarms)
    level = status.ERROR if fault else (status.WARN if alarms else status.OK)
    words = " ".join((b.name or "").lower() for b in StateBit if state & b) or "servo off"
    kv = types["diagnostic_msgs/msg/KeyValue"]
    values = [kv(key="state", value=f"0x{state:02x}"),
              kv(key="alarms", value=",".join(format_code(a.code) for a in alarms))]
    values += [kv(key=format_code(a.code), value=f"{a.type.value}: {a.description}") for a in alarms]
    return status(level=level, name=f"{arm_id} state", message=words, hardware_id=f"{arm_id} ({robot})",
                  values=values)


__all__ = ["ArmDescription", "DIAGNOSTIC_STATUS", "DISTRO", "JOINT_STATE", "Kinematics", "STRING", "TF_MESSAGE",
           "arm_state", "cdr", "description", "joint_state", "tf_message", "type_hash",
           "typestore"]
