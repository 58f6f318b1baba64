"""armd's robot catalogue: arm models, limits, actuator maps and forward kinematics.

>>> import robots
>>> robots.names()
['desk4', 'gupta3', 'insomniac', 'sg5ut']
>>> arm = robots.load("gupta3")
>>> arm.fk([0.0, 0.0, 0.0]).round(3).tolist()
[0.28, 0.0, 0.0]
"""

from .actuators import ActuatorMap, Gripper, Servo, Stepper
from .catalogue import CATALOGUE_DIR, load, load_dir, load_folder, names
from .errors import (
    ActuatorMapError,
    ActuatorRangeError,
    ArmdError,
    BadRequest,
    CoupledLimitError,
    JointLimitError,
    LimitError,
    PositionUnknown,
    RobotFileError,
    UnknownRobot,
)
from .geometry import Geometry
from .limits import CoupledLimit, JointLimits
from .robot import Robot, ToolPose
from .sensors import RangeSensor

__all__ = [
    "CATALOGUE_DIR",
    "ActuatorMap",
    "ActuatorMapError",
    "ActuatorRangeError",
    "ArmdError",
    "BadRequest",
    "CoupledLimit",
    "CoupledLimitError",
    "Geometry",
    "Gripper",
    "JointLimitError",
    "JointLimits",
    "LimitError",
    "PositionUnknown",
    "RangeSensor",
    "Robot",
    "RobotFileError",
    "Servo",
    "Stepper",
    "ToolPose",
    "UnknownRobot",
    "load",
    "load_dir",
    "load_folder",
    "names",
]
