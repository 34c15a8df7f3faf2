"""``jara-arm record --ros2``: a ROS 2 bag (rosbag2, MCAP storage) beside the recording, of the topics
``jara-arm ros2`` publishes (``bridge.py``), made from the same samples.

rosbags writes it: a directory with ``metadata.yaml`` and one MCAP file whose channels have ``ros2msg``
schemas and CDR messages, so ``ros2 bag info`` / ``ros2 bag play`` and Foxglove open it as a ROS 2 bag.
Per arm, under ``/<arm>``: ``joint_states`` and ``tf`` at each ``Servo/status`` (100 Hz moving, 10 Hz at
rest: what the servo published, not resampled), ``robot_description`` once the arm's robot is known (its
``Servo/world``, asked once), ``jara_arm/state`` on every change of the state or the alarms. Each message
is logged at its own stamp (the servo's clock) or, without one, at its arrival.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import zenoh

from jara_arm.robots import RobotModelError
from jara_arm.robots import robot as robot_model
from jara_arm.schema import codec
from jara_arm.schema.alarms import ALARM_LIST
from jara_arm.schema.codec import Encoding
from jara_arm.schema.errors import JaraArmError
from jara_arm.schema.keys import ArmKeys, arm_of
from jara_arm.schema.messages import SERVO_STATUS, SERVO_WORLD

from ..tools.arm_state import read_state
from . import messages as msgs

log = logging.getLogger(__name__)

#: How long the servo's world is waited for once asked [s].
ASK_TIMEOUT = 2.0


class BagError(JaraArmError):
    """The bag cannot be written where asked."""


def bag_path(recording: Path) -> Path:
    """Where ``record -o RUN.mcap --ros2`` puts its bag: the directory ``RUN_ros2``."""
    return recording.with_name(recording.stem + "_ros2")


class _Arm:
    def __init__(self, session: zenoh.Session, arm: str) -> None:
        self.keys = ArmKeys(arm)
        self.asked: Any = session.get(self.keys.servo_world, zenoh.handlers.FifoChannel(4), payload=b"{}",
                                      timeout=ASK_TIMEOUT)
        self.desc: msgs.ArmDescription | None = None
        self.kin: msgs.Kinematics | None = None
        self.robot = ""
        self.state = 0
        self.alarms: tuple[Any, ...] = ()
        self.said: tuple[int, tuple[int, ...]] | None = None


class Ros2Bag:
    """The bag being written: :meth:`take` each recorded sample, :meth:`close` at the end."""

    def __init__(self, path: Path, session: zenoh.Session) -> None:
        from rosbags.rosbag2 import StoragePlugin, Writer

        if path.exists():
            raise BagError(f"{path} exists: a ROS 2 bag is a new directory (remove it or record to another name)")
        self.path = path
        self._session = session
        self._writer = Writer(path, version=9, storage_plugin=StoragePlugin.MCAP)
        try:
            self._writer.open()
        except Exception as exc:  # rosbags' WriterError or an OSError: the directory cannot be made
            raise BagError(f"cannot write a ROS 2 bag at {path}: {exc}") from None
        self._connections: dict[str, Any] = {}
        self._arms: dict[str, _Arm] = {}
        self.count = 0

    def _put(self, topic: str, ros_type: str, t_ns: int, message: Any) -> None:
        conn = self._connections.get(topic)
        if conn is None:
            conn = self._connections[topic] = self._writer.add_connection(topic, ros_type,
                                                                         typestore=msgs.typestore())
        self._writer.write(conn, t_ns, msgs.cdr(message, ros_type))
        self.count += 1

    def take(self, key: str, received_ns: int, payload: bytes, encoding: object) -> None:
        """One recorded sample: written as the ROS 2 messages it makes, if any."""
        try:
            arm_id = arm_of(key)
        except JaraArmError:
            return
        arm = self._arms.get(arm_id)
        if arm is None:
            arm = self._arms[arm_id] = _Arm(self._session, arm_id)
        self._world(arm_id, arm, received_ns)
        enc = Encoding.JSON if payload.lstrip()[:1] == b"{" else Encoding.of(encoding)
        try:
            if key == arm.keys.servo_status and arm.desc is not None and arm.kin is not None:
                st = codec.decode_message(SERVO_STATUS, payload, enc)
                if st.pos:
                    t = st.tm.to_seconds()
                    ns = f"/{arm_id}"
                    self._put(f"{ns}/joint_states", msgs.JOINT_STATE, int(t * 1e9),
                              msgs.joint_state(arm.desc, t, st.pos, st.vel))
                    self._put(f"{ns}/tf", msgs.TF_MESSAGE, int(t * 1e9), msgs.tf_message(arm.kin, t, st.pos))
            elif key == arm.keys.state:
                arm.state = read_state(payload, encoding).state
                self._said(arm_id, arm, received_ns)
            elif key == arm.keys.monitor_alarms:
                arm.alarms = tuple(codec.decode_message(ALARM_LIST, payload, enc).alarms)
                self._said(arm_id, arm, received_ns)
            elif key == arm.keys.servo_world:
                arm.asked = None
                self._describe(arm_id, arm, codec.decode_message(SERVO_WORLD, payload, enc).robot, received_ns)
        except JaraArmError as exc:
            log.warning("ROS 2 bag: ignored a malformed sample on %s: %s", key, exc)

    def _world(self, arm_id: str, arm: _Arm, received_ns: int) -> None:
        if arm.asked is None:
            return
        try:
            reply = arm.asked.try_recv()
        except zenoh.ZError:  # the get ended without an answer
            arm.asked = None
            log.warning("ROS 2 bag: arm %s did not say its robot: no robot_description, joint_states or tf "
                        "until its world is published", arm_id)
            return
        if reply is None:
            return
        arm.asked = None
        if reply.ok is None:
            log.warning("ROS 2 bag: arm %s did not say its robot: no robot_description, joint_states or tf",
                        arm_id)
            return
        try:
            world = codec.decode_message(SERVO_WORLD, reply.ok.payload.to_bytes(), Encoding.of(reply.ok.encoding))
        except JaraArmError as exc:
            log.warning("ROS 2 bag: arm %s: malformed world: %s", arm_id, exc)
            return
        self._describe(arm_id, arm, world.robot, received_ns)

    def _describe(self, arm_id: str, arm: _Arm, robot: str, t_ns: int) -> None:
        if robot == arm.robot:
            return
        try:
            model = robot_model(robot)
        except RobotModelError as exc:
            log.warning("ROS 2 bag: arm %s: robot %r unknown here: %s", arm_id, robot, exc)
            return
        arm.robot, arm.desc = robot, msgs.ArmDescription.of(model)
        arm.kin = msgs.Kinematics(arm.desc)
        self._put(f"/{arm_id}/robot_description", msgs.STRING, t_ns, msgs.description(arm.desc))

    def _said(self, arm_id: str, arm: _Arm, t_ns: int) -> None:
        said = (arm.state, tuple(a.code for a in arm.alarms))
        if said != arm.said and arm.robot:
            self._put(f"/{arm_id}/jara_arm/state", msgs.DIAGNOSTIC_STATUS, t_ns,
                      msgs.arm_state(arm_id, arm.robot, arm.state, arm.alarms))
            arm.said = said

    def close(self) -> None:
        self._writer.close()


__all__ = ["BagError", "Ros2Bag", "bag_path"]
