"""armd's robot catalogue: arm models, limits, actuator maps and forward kinematics.

>>> from armd import robots
>>> robots.names()
['desk4', 'gupta3', 'insomniac', 'sg5ut', 'so101']
>>> arm = robots.load("gupta3")
>>> arm.fk([0.0, 0.0, 0.0]).round(3).tolist()
[0.28, 0.0, 0.0]
"""

from typing import TYPE_CHECKING, Any

# Its names are imported when first asked for (the catalogue loads Pinocchio: 0.3 s that a
# client does not need). Its errors are armd.errors'.

if TYPE_CHECKING:
    from .actuators import ActuatorMap, BusServo, Gripper, Servo, Stepper
    from .catalogue import CATALOGUE_DIR, load, load_dir, load_folder, names
    from .geometry import Geometry
    from .limits import CoupledLimit, JointLimits
    from .robot import Robot, ToolPose
    from .sensors import RangeSensor

_LAZY = {
    **dict.fromkeys(("ActuatorMap", "BusServo", "Gripper", "Servo", "Stepper"), ".actuators"),
    **dict.fromkeys(("CATALOGUE_DIR", "load", "load_dir", "load_folder", "names"), ".catalogue"),
    "Geometry": ".geometry",
    **dict.fromkeys(("CoupledLimit", "JointLimits"), ".limits"),
    **dict.fromkeys(("Robot", "ToolPose"), ".robot"),
    "RangeSensor": ".sensors",
}


def __getattr__(name: str) -> Any:
    """The package's names, imported when first used (PEP 562)."""
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    import importlib

    value = getattr(importlib.import_module(module, __name__), name)
    globals()[name] = value
    return value


__all__ = [
    "CATALOGUE_DIR",
    "ActuatorMap",
    "BusServo",
    "CoupledLimit",
    "Geometry",
    "Gripper",
    "JointLimits",
    "RangeSensor",
    "Robot",
    "Servo",
    "Stepper",
    "ToolPose",
    "load",
    "load_dir",
    "load_folder",
    "names",
]
