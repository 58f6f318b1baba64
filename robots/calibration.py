"""An arm's calibration: each bus servo's zero, direction and range as measured on the arm
itself (``armd calibrate``), which override robot.toml's factory values.

The file, ``calibration.toml``, has one table per actuator, by name::

    [shoulder_pan]
    zero = 2051          # the count at actuator angle 0 (the reference pose)
    direction = -1       # the count's sign against the joint's angle
    range = [812, 3290]  # the counts the joint was seen to reach

It is checked against the arm at load: every actuator named must be a bus servo of the arm,
and the joint limits must map inside the range measured (a calibration that says the arm
cannot reach what its URDF allows is refused: narrow the limits, or calibrate again).
"""

from __future__ import annotations

import copy
import dataclasses
from pathlib import Path
from typing import Any

import numpy as np
import tomllib

from armd.errors import RobotFileError

from .actuators import ActuatorMap, BusServo
from .robot import Robot

FILE = "calibration.toml"


def read(path: Path) -> dict[str, dict[str, Any]]:
    """The file's tables, as they are (:func:`apply` checks them)."""
    try:
        with path.open("rb") as f:
            data = tomllib.load(f)
    except (OSError, tomllib.TOMLDecodeError) as e:
        raise RobotFileError(str(path), None, f"cannot be read: {e}") from None
    return data


def apply(robot: Robot, path: Path) -> Robot:
    """A copy of ``robot`` whose bus servos take the calibration in ``path``; else
    :class:`RobotFileError` naming the file, the actuator and the problem."""
    data = read(path)
    servos = {a.name: (k, a) for k, a in enumerate(robot.actuators.actuators)}
    acts = list(robot.actuators.actuators)
    for name, table in data.items():
        if name not in servos or not isinstance(servos[name][1], BusServo):
            bus = [n for n, (_, a) in servos.items() if isinstance(a, BusServo)]
            raise RobotFileError(str(path), name, f"is not a bus servo of {robot.name} ({', '.join(bus) or 'none'})")
        if not isinstance(table, dict) or set(table) - {"zero", "direction", "range"}:
            raise RobotFileError(str(path), name, "takes zero, direction and range only")
        k, servo = servos[name]
        assert isinstance(servo, BusServo)
        try:
            zero = float(table.get("zero", servo.zero))
            direction = int(table.get("direction", servo.direction))
            lo, hi = (float(x) for x in table.get("range", servo.count_range))
        except (TypeError, ValueError) as e:
            raise RobotFileError(str(path), name, f"zero, direction and range must be numbers: {e}") from None
        if direction not in (1, -1) or not lo < hi:
            raise RobotFileError(str(path), name, "direction must be 1 or -1, and range [lower, upper] counts")
        new = dataclasses.replace(servo, zero=zero, direction=direction, count_range=(lo, hi))
        ends = sorted(float(new.to_command(np.array(x))) for x in servo.angle_range)
        if ends[0] < lo - 1e-6 or ends[1] > hi + 1e-6:
            a, b = (float(new.to_angle(np.array(c))) for c in (lo, hi))
            raise RobotFileError(
                str(path),
                name,
                f"contradicts the joint limits: the arm was seen to reach [{min(a, b):.4f}, {max(a, b):.4f}] rad, "
                f"its limits allow [{servo.angle_range[0]:.4f}, {servo.angle_range[1]:.4f}] rad (counts "
                f"[{ends[0]:.0f}, {ends[1]:.0f}] against [{lo:.0f}, {hi:.0f}]): calibrate again, or narrow the limits",
            )
        acts[k] = new
    out = copy.copy(robot)
    out.actuators = ActuatorMap(tuple(acts), robot.actuators.M, robot.actuators.b)
    return out


def write(path: Path, values: dict[str, tuple[float, int, tuple[float, float]]]) -> None:
    """Write ``{actuator: (zero, direction, (low, high))}`` to ``path``."""
    lines = ["# armd calibrate: each bus servo as measured on the arm (robots/calibration.py)", ""]
    for name, (zero, direction, (lo, hi)) in values.items():
        lines += [f"[{name}]", f"zero = {zero:g}", f"direction = {direction}", f"range = [{lo:g}, {hi:g}]", ""]
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines))
