"""Joint states: where a plan starts (the arm may be moving) and what a trajectory gives at a time."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from armd.errors import BadRequest
from armd.robots import Robot
from armd.robots.types import FloatArray


@dataclass(frozen=True)
class JointState:
    """Joint positions [rad], velocities [rad/s] and accelerations [rad/s^2]."""

    position: FloatArray
    velocity: FloatArray
    acceleration: FloatArray

    @classmethod
    def at_rest(cls, position: FloatArray) -> JointState:
        z = np.zeros_like(position)
        return cls(np.asarray(position, dtype=float), z, z.copy())

    @property
    def moving(self) -> bool:
        return max(map(abs, self.velocity.tolist() + self.acceleration.tolist()), default=0.0) > 1e-9

    def to_dict(self) -> dict[str, Any]:
        return {
            "position": self.position.tolist(),
            "velocity": self.velocity.tolist(),
            "acceleration": self.acceleration.tolist(),
        }


def joint_state(robot: Robot, start: object, field: str = "start") -> JointState:
    """A :class:`JointState` from a JointState, a position vector, or a mapping with
    ``position`` and optional ``velocity``/``acceleration``. The position must be within every
    joint limit (a plan never starts from outside them); :class:`BadRequest` otherwise."""
    pos: object
    vel: object
    acc: object
    if isinstance(start, JointState):
        pos, vel, acc = start.position, start.velocity, start.acceleration
    elif isinstance(start, Mapping):
        if "position" not in start:
            raise BadRequest(f"{field} needs a 'position'", field=field)
        pos = start["position"]
        vel = start.get("velocity")
        acc = start.get("acceleration")
    else:
        pos, vel, acc = start, None, None
    p = robot.joint_vector(pos, f"{field}.position")
    v = np.zeros(robot.nq) if vel is None else robot.joint_vector(vel, f"{field}.velocity")
    a = np.zeros(robot.nq) if acc is None else robot.joint_vector(acc, f"{field}.acceleration")
    lim = robot.limits
    if not lim.contains(p, tol=1e-9):
        bad = lim.violations(p, tol=1e-9)
        raise BadRequest(f"{field} is outside the joint limits: {bad[0].message}", field=f"{field}.position")
    for given, values, limit, what, unit in (
        (vel, v, lim.velocity, "velocity", "rad/s"),
        (acc, a, lim.acceleration, "acceleration", "rad/s^2"),
    ):
        if given is None:  # zeros: within any limit
            continue
        over = np.abs(values) > limit * (1 + 1e-9)
        if over.any():
            i = int(np.argmax(over))
            raise BadRequest(
                f"{field}: joint {robot.joint_names[i]!r} {what} {values[i]:.4g} {unit} is over its "
                f"limit {limit[i]:.4g}",
                field=f"{field}.{what}",
            )
    return JointState(lim.clip(p), v, a)


def clamped(robot: Robot, state: JointState) -> JointState:
    """``state`` brought inside every limit: each position onto its box, each velocity and
    acceleration onto its limit. For a stop from a measured state a hair outside (a servo's
    quantisation, a stepper's whole steps, noise): a stop is never refused, and it brakes from
    the nearest state the limits allow. Coupled limits are not moved onto (the planner's gate
    reports a state outside them)."""
    lim = robot.limits
    p = lim.clip(np.nan_to_num(state.position))
    v = np.clip(np.nan_to_num(state.velocity), -lim.velocity, lim.velocity)
    a = np.clip(np.nan_to_num(state.acceleration), -lim.acceleration, lim.acceleration)
    # on a limit, a joint is not moving on past it (the reading is; the joint cannot)
    out = ((p >= lim.upper) & (v > 0)) | ((p <= lim.lower) & (v < 0))
    v[out] = 0.0
    a[out | ((p >= lim.upper) & (a > 0)) | ((p <= lim.lower) & (a < 0))] = 0.0
    return JointState(p, v, a)
