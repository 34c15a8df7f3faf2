"""Robot models: URDF, joints, ratings and defaults of every supported arm."""

from .catalog import DEFAULT_ROBOT, ROBOTS, robot
from .model import Family, Obstacle, RobotModel, RobotModelError

__all__ = ["DEFAULT_ROBOT", "Family", "ROBOTS", "RobotModel", "RobotModelError", "robot"]
