"""An arm's calibration: each bus servo's zero, direction and range as measured on the arm
itself (``armd calibrate``), which override robot.toml's factory values.

The file, ``calibration.toml``, has one table per actuator, by name::

    [shoulder_pan]
    zero = 2051          # the count at actuator angle 0 (the reference pose)
    direction = -1       # the count's sign against the joint's angle
    range = [812, 3290]  # the counts the joint was seen to reach

and, for a gripper on the bus, its counts closed and open::

    [gripper]
    closed = 2010
    open = 3050

It is checked against the arm at load: every actuator named must be a bus servo of the arm,
and the joint limits must map inside the range measured (a calibration that says the arm
cannot reach what its URDF allows is refused: narrow the limits, or calibrate again).
"""

from __future__ import annotations

import copy
import dataclasses
import math
from pathlib import Path
from typing import Any

import numpy as np
import tomllib

from armd.errors import RobotFileError

from .actuators import BusServo, Gripper, Servo
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
    return apply_tables(robot, read(path), str(path))


def apply_tables(robot: Robot, data: dict[str, Any], source: str) -> Robot:
    """:func:`apply`, of the tables ``data`` (a file's, or just measured: ``source`` names it)."""
    out = copy.copy(robot)
    data = dict(data)
    if "gripper" in data:
        out.gripper = _gripper(robot, data.pop("gripper"), source)
    servos = {a.name: (k, a) for k, a in enumerate(robot.actuators.actuators)}
    acts = list(robot.actuators.actuators)
    for name, table in data.items():
        if name not in servos or not isinstance(servos[name][1], (BusServo, Servo)):
            ours = [n for n, (_, a) in servos.items() if isinstance(a, (BusServo, Servo))]
            raise RobotFileError(source, name, f"is not a servo of {robot.name} ({', '.join(ours) or 'none'})")
        k, servo = servos[name]
        acts[k] = _servo(servo, table, source) if isinstance(servo, Servo) else _bus_servo(servo, table, source)  # type: ignore[arg-type]
    out.actuators = robot.actuators.with_actuators(tuple(acts))
    return out


def _number(value: object, source: str, name: str, key: str) -> float:
    """``value`` as a finite number, else :class:`RobotFileError` naming ``key`` (a bool is not one)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise RobotFileError(source, name, f"{key} must be a finite number, got {value!r}")
    return float(value)


def _direction(value: object, source: str, name: str) -> int:
    if isinstance(value, bool) or value not in (1, -1):
        raise RobotFileError(source, name, f"direction must be 1 or -1, got {value!r}")
    return int(value)


def _keys(table: object, keys: set[str], source: str, name: str, what: str) -> dict[str, Any]:
    if not isinstance(table, dict) or set(table) - keys:
        raise RobotFileError(source, name, f"takes {what} only")
    return table


def _bus_servo(servo: BusServo, table: object, source: str) -> BusServo:
    """``servo`` with its measured zero, direction and range."""
    name = servo.name
    t = _keys(table, {"zero", "direction", "range"}, source, name, "zero, direction and range")
    zero = _number(t.get("zero", servo.zero), source, name, "zero")
    direction = _direction(t.get("direction", servo.direction), source, name)
    rng = t.get("range", servo.count_range)
    if not isinstance(rng, (list, tuple)) or len(rng) != 2:
        raise RobotFileError(source, name, f"range must be [lower, upper] counts, got {rng!r}")
    lo, hi = (_number(x, source, name, "range") for x in rng)
    if not lo < hi:
        raise RobotFileError(source, name, f"range must be [lower, upper] counts, lower first, got {rng!r}")
    new = dataclasses.replace(servo, zero=zero, direction=direction, count_range=(lo, hi))
    ends = sorted(float(new.to_command(np.array(x))) for x in servo.angle_range)
    if ends[0] < lo - 1e-6 or ends[1] > hi + 1e-6:
        a, b = (float(new.to_angle(np.array(c))) for c in (lo, hi))
        raise RobotFileError(
            source,
            name,
            f"contradicts the joint limits: the arm was seen to reach [{min(a, b):.4f}, {max(a, b):.4f}] rad, "
            f"its limits allow [{servo.angle_range[0]:.4f}, {servo.angle_range[1]:.4f}] rad (counts "
            f"[{ends[0]:.0f}, {ends[1]:.0f}] against [{lo:.0f}, {hi:.0f}]): calibrate again, or narrow the limits",
        )
    return new


def _servo(servo: Servo, table: object, source: str) -> Servo:
    """``servo`` (an SSC-32 channel) with its measured centre pulse and direction."""
    name = servo.name
    t = _keys(table, {"centre_pulse", "direction"}, source, name, "centre_pulse and direction")
    centre = _number(t.get("centre_pulse", servo.centre_pulse), source, name, "centre_pulse")
    direction = _direction(t.get("direction", servo.direction), source, name)
    new = dataclasses.replace(servo, centre_pulse=centre, direction=direction)
    problem = servo_misfit(new)
    if problem:
        raise RobotFileError(
            source, name, f"contradicts the joint limits: {problem}: calibrate again, or narrow the limits"
        )
    return new


def servo_misfit(servo: Servo) -> str | None:
    """Why ``servo``'s joint limits need a pulse beyond its range, or None if they do not."""
    lo, hi = servo.pulse_range
    ends = sorted(float(servo.to_command(np.array(x))) for x in servo.angle_range)
    if ends[0] < lo - 1e-6 or ends[1] > hi + 1e-6:
        return (
            f"centred at {servo.centre_pulse:g} us, its limits [{servo.angle_range[0]:.4f}, "
            f"{servo.angle_range[1]:.4f}] rad need pulses [{ends[0]:.0f}, {ends[1]:.0f}] us, beyond the servo's "
            f"[{lo:g}, {hi:g}]"
        )
    return None


def _gripper(robot: Robot, table: object, source: str) -> Gripper:
    """The arm's gripper with the counts measured closed and open."""
    if robot.gripper is None or not robot.actuators.actuators or not isinstance(robot.actuators.actuators[0], BusServo):
        raise RobotFileError(source, "gripper", f"{robot.name} has no gripper on a bus")
    if not isinstance(table, dict) or set(table) != {"closed", "open"}:
        raise RobotFileError(source, "gripper", "takes closed and open [counts], both")
    closed = _number(table["closed"], source, "gripper", "closed")
    opened = _number(table["open"], source, "gripper", "open")
    if closed == opened:
        raise RobotFileError(source, "gripper", f"closed and open must be two different counts, got {closed:g} twice")
    return dataclasses.replace(robot.gripper, closed=closed, open=opened)


def write_servos(path: Path, values: dict[str, tuple[float, int]]) -> None:
    """Write ``{actuator: (centre_pulse, direction)}`` (an SSC-32 arm's jog) to ``path``."""
    lines = ["# armd calibrate: each servo's centre pulse and direction, as jogged on the arm", ""]
    for name, (centre, direction) in values.items():
        lines += [f"[{name}]", f"centre_pulse = {centre:g}", f"direction = {direction}", ""]
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines))


def write(
    path: Path,
    values: dict[str, tuple[float, int, tuple[float, float]]],
    gripper: tuple[float, float] | None = None,
) -> None:
    """Write ``{actuator: (zero, direction, (low, high))}`` (and the gripper's ``(closed, open)``
    counts) to ``path``."""
    lines = ["# armd calibrate: each bus servo as measured on the arm (robots/calibration.py)", ""]
    for name, (zero, direction, (lo, hi)) in values.items():
        lines += [f"[{name}]", f"zero = {zero:g}", f"direction = {direction}", f"range = [{lo:g}, {hi:g}]", ""]
    if gripper is not None:
        lines += ["[gripper]", f"closed = {gripper[0]:g}", f"open = {gripper[1]:g}", ""]
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines))
