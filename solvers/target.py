"""IK inputs: the target (a point, or a range-sensor reading) and the approach.

``target`` is a point [x, y, z] [m] in the arm's ``base`` frame, or a
:class:`SensorReading` (sensor name, range [m], bearing [rad]) that the arm's sensor frame
turns into a base-frame point first (seed 000 section 4); as a mapping, a reading may give the
sensor's output ``volts`` [V] instead of its range (its model's curve converts it).

``approach`` says what the tool pitch must be: ``"parallel"`` (level, pitch 0),
``"perpendicular"`` (straight down, pitch -pi/2; seed 000 eq. 1), a pitch in radians in
[-pi, pi], or ``"free"``/``None`` (armd picks one: see :mod:`solvers.ik`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from armd.errors import BadRequest
from armd.robots import Robot
from armd.robots.types import FloatArray

_FLOAT64 = np.dtype(np.float64)  # native float64: ``is`` against it is the quick check

PARALLEL = 0.0
PERPENDICULAR = -math.pi / 2
APPROACHES = ("parallel", "perpendicular", "free")


@dataclass(frozen=True)
class SensorReading:
    """A range-sensor reading: the sensor's name, the range [m] and the bearing [rad]."""

    sensor: str
    range: float
    bearing: float = 0.0


def target_point(robot: Robot, target: object, q: FloatArray | None = None) -> FloatArray:
    """The base-frame point [m] a target names; :class:`BadRequest` for anything else.

    ``q`` is needed only for a sensor mounted on the arm (it looks along an arm frame).
    """
    if type(target) is np.ndarray and target.dtype is _FLOAT64 and target.shape == (3,):
        x, y, z = target.tolist()
        if math.isfinite(x) and math.isfinite(y) and math.isfinite(z):
            return target.copy()  # the common case from Python: nothing to convert or check again
        raise BadRequest(f"target must be finite, got {[x, y, z]}", field="target")
    if isinstance(target, (list, tuple)) and len(target) == 3 and all(type(v) in (float, int) for v in target):
        if not all(math.isfinite(v) for v in target):
            raise BadRequest(f"target must be finite, got {list(target)}", field="target")
        return np.array(target, dtype=float)  # the common case from JSON, without NumPy's checks
    if isinstance(target, SensorReading):
        return robot.sensor_point(target.sensor, target.range, target.bearing, q)
    if isinstance(target, Mapping):
        if "sensor" not in target or ("range" in target) == ("volts" in target):
            raise BadRequest("a sensor target needs 'sensor' and one of 'range' [m] or 'volts' [V]", field="target")
        name = str(target["sensor"])
        if "volts" in target:  # the sensor's output: its model's curve says the range
            if name not in robot.sensors:
                robot.sensor_point(name, 0.0)  # (the unknown sensor, named)
            distance = robot.sensors[name].range_of_volts(target["volts"])
        else:
            distance = target["range"]
        return robot.sensor_point(name, distance, target.get("bearing", 0.0), q)
    if isinstance(target, (str, bytes)):
        raise BadRequest(f"target must be [x, y, z] in metres, got {target!r}", field="target")
    try:
        p = np.asarray(target, dtype=float)
    except (TypeError, ValueError):
        raise BadRequest(f"target must be [x, y, z] in metres, got {target!r}", field="target") from None
    if p.shape != (3,):
        raise BadRequest(f"target must be 3 numbers [x, y, z] in metres, got shape {list(p.shape)}", field="target")
    if not np.all(np.isfinite(p)):
        raise BadRequest(f"target must be finite, got {p.tolist()}", field="target")
    return p


def approach_pitch(robot: Robot, approach: object) -> float | None:
    """The tool pitch [rad] an approach asks for, or None when the pitch is free.

    An arm without a wrist (:attr:`Robot.chooses_pitch`) cannot choose its pitch: it accepts
    ``"free"``/None, and an arm whose tool is held level by a linkage also accepts
    ``"parallel"`` (always true for it).
    """
    if approach is None or approach == "free":
        return None
    if approach == "parallel":
        pitch = PARALLEL
    elif approach == "perpendicular":
        pitch = PERPENDICULAR
    elif isinstance(approach, (int, float)) and not isinstance(approach, bool):
        pitch = float(approach)
        if not math.isfinite(pitch) or not -math.pi <= pitch <= math.pi:
            raise BadRequest(f"approach pitch must be a number in [-pi, pi] rad, got {approach!r}", field="approach")
    else:
        raise BadRequest(
            f"approach must be one of {', '.join(APPROACHES)} or a pitch in radians, got {approach!r}",
            field="approach",
        )
    geom = robot.geometry
    if geom is not None and geom.level:
        if abs(pitch) > 1e-12:
            raise BadRequest(
                f"{robot.name} holds its tool level by a linkage: approach can only be 'parallel' or 'free'",
                field="approach",
            )
        return None
    if not robot.chooses_pitch:
        raise BadRequest(
            f"{robot.name} has no wrist: its tool pitch follows from the position; use approach 'free'",
            field="approach",
        )
    return pitch
