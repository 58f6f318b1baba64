"""The safety gate: every sample of a trajectory against every limit, before it leaves the planner.

Position (box and coupled), velocity, acceleration and jerk limits of ``robot.toml`` and the
URDF, and every actuator's range. Ruckig Community does not enforce position limits, and a
Cartesian line's joint motion comes from IK, so this check is what guarantees them. A
violation raises the :class:`~robots.errors.LimitError` that names the joint (or coupled
limit, or actuator), the time [s] and the value; nothing is clipped.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from armd.errors import ActuatorRangeError, LimitError
from armd.robots import Robot
from armd.robots.types import FloatArray

IntArray = NDArray[np.int64]

POSITION_TOL = 1e-7  # [rad]: numerical noise (Ruckig lands on a target to ~1e-8); far below any actuator step
RATE_TOL = 1e-6  # relative slack on velocity, acceleration and jerk limits (rounding)


def _first(bad: NDArray[np.bool_]) -> tuple[int, int]:
    k, j = np.argwhere(bad)[0]
    return int(k), int(j)


def check_samples(
    robot: Robot,
    times: FloatArray,
    position: FloatArray,
    velocity: FloatArray,
    acceleration: FloatArray,
    jerk: FloatArray,
) -> None:
    """Raise the first limit any sample breaks (rows are samples at ``times`` [s])."""
    lim = robot.limits
    names = robot.joint_names
    for values, kind in (
        (position, "position"),
        (velocity, "velocity"),
        (acceleration, "acceleration"),
        (jerk, "jerk"),
    ):
        finite = np.isfinite(values)
        if not finite.all():  # NaN compares false with every limit: catch it before anything else
            k, j = _first(~finite)
            raise LimitError(
                f"joint {names[j]!r} {kind} is not a number at t = {times[k]:.4f} s",
                name=names[j],
                value=float(values[k, j]),
                bounds=(-np.inf, np.inf),
                kind=kind,
                time=float(times[k]),
            )
    outside = lim.first_outside(position, tol=POSITION_TOL)
    if outside is not None:
        raise _at(outside[1], times[outside[0]])
    for values, limit, kind, unit in (
        (velocity, lim.velocity, "velocity", "rad/s"),
        (acceleration, lim.acceleration, "acceleration", "rad/s^2"),
        (jerk, lim.jerk, "jerk", "rad/s^3"),
    ):
        over = np.abs(values) > limit * (1 + RATE_TOL) + 1e-12
        if over.any():
            k, j = _first(over)
            raise LimitError(
                f"joint {names[j]!r} {kind} {values[k, j]:.6g} {unit} at t = {times[k]:.4f} s exceeds its "
                f"limit {limit[j]:.6g} {unit}",
                name=names[j],
                value=float(values[k, j]),
                bounds=(-float(limit[j]), float(limit[j])),
                kind=kind,
                time=float(times[k]),
            )


def actuator_commands(robot: Robot, times: FloatArray, position: FloatArray) -> IntArray:
    """Every sample's actuator commands (pulses [us] or micro-steps); an actuator leaving its
    range raises :class:`ActuatorRangeError` with the time."""
    try:
        return robot.actuators.commands(position)
    except ActuatorRangeError as e:
        amap = robot.actuators
        a = amap.angles(position)
        k = 0
        for j, act in enumerate(amap.actuators):
            if act.name == e.name:
                lo, hi = act.angle_range
                out = ~((a[:, j] >= lo - 1e-9) & (a[:, j] <= hi + 1e-9))  # (NaN: a linkage that cannot reach)
                k = int(np.argmax(out)) if out.any() else 0
        raise _at(e, times[k]) from None


def _at(err: LimitError, t: float) -> LimitError:
    err.time = float(t)
    err.fields["time"] = float(t)
    err.message = f"{err.message} at t = {t:.4f} s"
    err.args = (err.message,)
    return err
