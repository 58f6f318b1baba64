"""The :class:`Trajectory`: what the planner hands to the service and the adapters.

Samples at the adapter's control rate (the duration is a whole number of cycles), each
with position, velocity, acceleration and jerk per joint and the actuator commands (servo
pulses [us], stepper micro-steps), all checked against every limit before the trajectory
exists (:mod:`planning.checks`), and a way to evaluate any time in between.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from armd.robots import Robot
from armd.robots.types import FloatArray

from .checks import POSITION_TOL, RATE_TOL, actuator_commands, check_samples
from .compiled import all_clear
from .state import JointState

IntArray = NDArray[np.int64]
Evaluator = Callable[[float], tuple[FloatArray, FloatArray, FloatArray]]


@dataclass(frozen=True)
class Trajectory:
    """A checked, sampled joint trajectory.

    Attributes:
        robot: the arm's name.
        path: ``"joint"``, ``"line"`` or ``"stop"``.
        joint_names: joint order of the columns.
        actuator_names, actuator_units: the columns of ``commands`` and their units.
        rate_hz: sample rate [Hz]; ``times`` are ``k / rate_hz``.
        duration: [s], a whole number of cycles.
        times: (k,) [s]. position (k, n) [rad], velocity [rad/s], acceleration [rad/s^2],
            jerk [rad/s^3] (forward differences of the acceleration over one cycle).
        commands: (k, m) integer actuator commands for each sample.
    """

    robot: str
    path: str
    joint_names: tuple[str, ...]
    actuator_names: tuple[str, ...]
    actuator_units: tuple[str, ...]
    rate_hz: float
    duration: float
    times: FloatArray
    position: FloatArray
    velocity: FloatArray
    acceleration: FloatArray
    jerk: FloatArray
    commands: IntArray
    evaluator: Evaluator = field(repr=False, compare=False)

    def at(self, t: float) -> JointState:
        """The state at time ``t`` [s] (clamped to [0, duration])."""
        p, v, a = self.evaluator(min(max(float(t), 0.0), self.duration))
        return JointState(p, v, a)

    @property
    def start(self) -> JointState:
        return JointState(self.position[0], self.velocity[0], self.acceleration[0])

    @property
    def end(self) -> JointState:
        return JointState(self.position[-1], self.velocity[-1], self.acceleration[-1])

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready: what ``armd/<robot>/trajectory`` carries."""
        return {
            "robot": self.robot,
            "path": self.path,
            "joint_names": list(self.joint_names),
            "actuator_names": list(self.actuator_names),
            "actuator_units": list(self.actuator_units),
            "rate_hz": self.rate_hz,
            "duration": self.duration,
            "times": self.times.tolist(),
            "position": self.position.tolist(),
            "velocity": self.velocity.tolist(),
            "acceleration": self.acceleration.tolist(),
            "commands": self.commands.tolist(),
        }


def forward_jerk(acceleration: FloatArray, dt: float) -> FloatArray:
    """(a[k+1] - a[k]) / dt per sample, 0 on the last [rad/s^3]."""
    j = np.zeros_like(acceleration)
    if len(acceleration) > 1:
        j[:-1] = np.diff(acceleration, axis=0) / dt
    return j


@dataclass(frozen=True)
class _Gate:
    """One arm's limits as the compiled gate takes them (packed: see :func:`all_clear`)."""

    C: FloatArray  # coupled limits' coefficients (k, n)
    joints: FloatArray
    couplings: FloatArray
    actuators: FloatArray
    tolerances: FloatArray
    names: tuple[str, ...]
    units: tuple[str, ...]

    @classmethod
    def of(cls, robot: Robot) -> _Gate:
        held = _gates.get(id(robot))
        if held is not None and held[0] is robot:
            return held[1]
        lim = robot.limits
        co = lim.coupled
        amap = robot.actuators
        lo, hi, gain, bias, cmd_lo, cmd_hi, angle_tol = amap.ranges
        gate = cls(
            np.array([c.coefficients for c in co]).reshape(len(co), robot.nq),
            np.array([lim.lower, lim.upper, lim.velocity, lim.acceleration, lim.jerk]),
            np.array([[c.lower for c in co], [c.upper for c in co]], dtype=float).reshape(2, len(co)),
            np.array([lo, hi, gain, bias, cmd_lo, cmd_hi]),
            np.array([POSITION_TOL, RATE_TOL, angle_tol]),
            tuple(a.name for a in amap.actuators),
            tuple(a.unit for a in amap.actuators),
        )
        _gates[id(robot)] = (robot, gate)  # a dict write is atomic: threads at worst build it twice
        return gate


_gates: dict[int, tuple[Robot, _Gate]] = {}


def build(
    robot: Robot,
    path: str,
    rate_hz: float,
    duration: float,
    times: FloatArray,
    position: FloatArray,
    velocity: FloatArray,
    acceleration: FloatArray,
    evaluator: Evaluator,
    jerk: FloatArray | None = None,
) -> Trajectory:
    """Check every sample against every limit, map to actuator commands, and wrap it up.

    ``jerk``: the forward differences of ``acceleration`` when the caller has them already.
    The compiled :func:`~planning.compiled.all_clear` passes a trajectory that is clearly
    inside every limit; anything else takes the exact checks, which raise the first
    violation (or pass a sample that is inside by less than the compiled margin).
    """
    if jerk is None:
        jerk = forward_jerk(acceleration, 1.0 / rate_hz)
    lim = robot.limits
    gate = _Gate.of(robot)
    # noise within POSITION_TOL of a box limit is put exactly on it (anything more raises)
    clipped = lim.clip(position)
    commands = np.empty((len(times), len(gate.names)), dtype=np.int64)
    if not all_clear(
        position,
        velocity,
        acceleration,
        jerk,
        position @ gate.C.T,
        robot.actuators.angles(clipped),  # (a linkage's: its own function; NaN where it cannot reach)
        gate.joints,
        gate.couplings,
        gate.actuators,
        gate.tolerances,
        commands,
    ):
        check_samples(robot, times, position, velocity, acceleration, jerk)
        commands = actuator_commands(robot, times, clipped)
    return Trajectory(
        robot=robot.name,
        path=path,
        joint_names=robot.joint_names,
        actuator_names=gate.names,
        actuator_units=gate.units,
        rate_hz=rate_hz,
        duration=duration,
        times=times,
        position=clipped,
        velocity=velocity,
        acceleration=acceleration,
        jerk=jerk,
        commands=commands,
        evaluator=evaluator,
    )
