"""The simulated arm: a PyBullet DIRECT world stepping one servo cycle at a time.

PyBullet is not thread-safe: only the servo loop thread touches a ``World``.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pybullet
import pybullet_data

from jara_arm.robots import Obstacle, RobotModel

#: Position-servo gains of PyBullet's motor constraint: the joint closes most of
#: its position error within one step, with the commanded velocity fed forward.
POSITION_GAIN = 0.8  # [-]
VELOCITY_GAIN = 1.0  # [-]
#: Peak effort of the simulated drives as a multiple of their rating [-]: servo
#: drives deliver 2-3x their rated torque for short times, so an arm pushed
#: against an obstacle shows an effort above its rating (the overload alarm).
PEAK_EFFORT = 2.0


class World:
    """One robot, fixed base, gravity on, time step = the servo period, fixed obstacle boxes."""

    def __init__(self, model: RobotModel, obstacles: Sequence[Obstacle] = ()) -> None:
        self.model = model
        self._pb = pybullet.connect(pybullet.DIRECT)
        pybullet.setAdditionalSearchPath(pybullet_data.getDataPath(), physicsClientId=self._pb)
        pybullet.setGravity(0, 0, -9.81, physicsClientId=self._pb)
        pybullet.setTimeStep(model.cmd_cycle, physicsClientId=self._pb)
        self.robot = pybullet.loadURDF(str(model.urdf), basePosition=model.base_position,
                                       useFixedBase=True, physicsClientId=self._pb)
        index = {}
        for j in range(pybullet.getNumJoints(self.robot, physicsClientId=self._pb)):
            info = pybullet.getJointInfo(self.robot, j, physicsClientId=self._pb)
            index[info[1].decode()] = j
        self._arm = [index[n] for n in model.arm_joints]
        self._grip = [index[n] for n in model.gripper_joints]
        # Wire axis k drives these PyBullet joints (the gripper axis drives all fingers).
        self._joints = self._arm + self._grip
        self._axis_of_joint = np.array(list(range(model.axis_num)) + [model.axis_num] * len(self._grip))
        self._one_joint_per_axis = len(self._grip) <= 1  # then command() needs no indexing
        self._position_gains = [POSITION_GAIN] * len(self._joints)
        self._velocity_gains = [VELOCITY_GAIN] * len(self._joints)
        self._measured = self._arm + self._grip[:1]  # one joint per wire axis
        self._forces = [PEAK_EFFORT * f for f in
                        list(model.rated_effort) + [model.gripper_effort] * len(self._grip)]
        self.obstacles = tuple(model.obstacles) + tuple(obstacles)
        for box in self.obstacles:
            self._add_box(box)
        for j in self._joints:  # PyBullet's default joint motors would fight ours
            pybullet.changeDynamics(self.robot, j, linearDamping=0, angularDamping=0,
                                    jointDamping=0.0, physicsClientId=self._pb)
        home = list(model.ready_pose) + ([model.gripper_limits.upper] if model.has_gripper else [])
        self.reset(np.array(home))

    def _add_box(self, box: Obstacle) -> None:
        """A static (massless) box that collides with every link of the robot."""
        shape = pybullet.createCollisionShape(pybullet.GEOM_BOX, halfExtents=list(box.half_extents),
                                              physicsClientId=self._pb)
        pybullet.createMultiBody(baseMass=0.0, baseCollisionShapeIndex=shape,
                                 basePosition=list(box.position), physicsClientId=self._pb)

    def reset(self, q: np.ndarray) -> None:
        """Place the arm at ``q`` [rad or m] at rest (start-up only)."""
        for j, k in zip(self._joints, self._axis_of_joint):
            pybullet.resetJointState(self.robot, j, float(q[k]), 0.0, physicsClientId=self._pb)
        self.command(q, np.zeros_like(q))

    def command(self, q: np.ndarray, qd: np.ndarray) -> None:
        """Position target [rad or m] and its velocity [rad/s or m/s], one per wire axis."""
        if self._one_joint_per_axis:
            positions, velocities = q.tolist(), qd.tolist()
        else:
            k = self._axis_of_joint
            positions, velocities = q[k].tolist(), qd[k].tolist()
        pybullet.setJointMotorControlArray(
            self.robot, self._joints, pybullet.POSITION_CONTROL,
            targetPositions=positions, targetVelocities=velocities,
            forces=self._forces, positionGains=self._position_gains,
            velocityGains=self._velocity_gains, physicsClientId=self._pb)

    def step(self) -> None:
        pybullet.stepSimulation(physicsClientId=self._pb)

    def read(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Measured (position, velocity, effort) per wire axis; the gripper axis is finger 1."""
        states = pybullet.getJointStates(self.robot, self._measured, physicsClientId=self._pb)
        return (np.array([s[0] for s in states]), np.array([s[1] for s in states]),
                np.array([s[3] for s in states]))

    def close(self) -> None:
        try:
            pybullet.disconnect(physicsClientId=self._pb)
        except pybullet.error:
            pass
