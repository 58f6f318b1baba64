"""``plan`` and ``plan_stop``: the planning layer's entry points."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np

from armd.errors import BadRequest, CollisionError, LimitError, TrajectoryTooLong
from armd.robots import Robot
from armd.robots.collision import GROUND
from armd.robots.types import FloatArray

from . import sampling
from .clearance import check_clear
from .goal import goal_configuration, goal_point
from .line import line_samples
from .ruckig_path import RuckigPath, joint_path, stop_path, straight_path, whole_cycles
from .state import JointState, clamped, joint_state
from .trajectory import Trajectory, build

DEFAULT_RATE_HZ = 50.0
PATHS = ("joint", "line")
# The slowest speed planned: below it the scaled limits (jerk by speed^3) vanish in Ruckig's
# arithmetic (at 1e-30 it refuses "zero limits"), and even at it 1e-9 rad takes 15 minutes.
MIN_SPEED = 1e-6


def _rate(robot: Robot, rate_hz: object) -> float:
    rate = robot.controller.get("rate_hz", DEFAULT_RATE_HZ) if rate_hz is None else rate_hz
    if isinstance(rate, bool) or not isinstance(rate, (int, float)) or not math.isfinite(rate) or not 1 <= rate <= 1000:
        raise BadRequest(f"rate_hz must be a number in [1, 1000] Hz, got {rate!r}", field="rate_hz")
    return float(rate)


def _speed(speed: object) -> float:
    if (
        isinstance(speed, bool)
        or not isinstance(speed, (int, float))
        or not math.isfinite(speed)
        or not MIN_SPEED <= speed <= 1
    ):
        raise BadRequest(f"speed must be a number in [{MIN_SPEED:g}, 1], got {speed!r}", field="speed")
    return float(speed)


def plan(
    robot: Robot,
    start: object,
    goal: object,
    *,
    path: str = "joint",
    speed: float = 1.0,
    rate_hz: float | None = None,
    via: Sequence[object] = (),
    max_samples: int | None = None,
    check: Callable[[], None] | None = None,
) -> Trajectory:
    """A jerk-limited trajectory from ``start`` to ``goal``, checked against every limit.

    Args:
        robot: an arm from :func:`robots.load`.
        start: the current state: a joint vector [rad], or a :class:`JointState` / mapping
            with ``position`` and optional ``velocity``, ``acceleration`` (the arm may move).
        goal: a joint vector [rad], or a Cartesian goal: ``{"target": [x, y, z], "approach": ...}``
            or :class:`~planning.goal.CartesianGoal` (solved by IK, seeded with the start).
        path: ``"joint"`` (time-synchronised in joint space) or ``"line"`` (the tool on the
            straight segment to the goal).
        speed: fraction [MIN_SPEED, 1] of the velocity limits (acceleration and jerk scaled to match).
        rate_hz: samples per second (the adapter's control rate); default from the arm's
            ``[controller] rate_hz``, else 50.
        via: waypoints (same forms as ``goal``) passed through in order, without stopping
            where possible (joint paths only).
        max_samples: the most samples the trajectory may have (None: no bound); checked
            once its duration is known, before it is sampled.
        check: called between the planning stages (each IK, each timing pass); whatever it
            raises abandons the plan. The service's per-request deadline uses it.

    Every sample and the straight joint moves between them are checked against the arm's world
    (:mod:`planning.clearance`: its own links, its floor, its obstacles).

    Raises:
        BadRequest: malformed input. PlanRejected: a goal out of reach, a line that leaves the
        reachable space or needs a branch flip. LimitError: a sample would break a limit.
        CollisionError: the goal, or the motion at some time, puts two things in contact.
        TrajectoryTooLong: more than ``max_samples`` samples.
    """
    rate = _rate(robot, rate_hz)
    spd = _speed(speed)
    if path not in PATHS:
        raise BadRequest(f"path must be one of {', '.join(PATHS)}, got {path!r}", field="path")
    s = joint_state(robot, start)
    if path == "line":
        if via:
            raise BadRequest("a line goes straight to its goal: via points are for joint paths", field="via")
        point, pitch, roll = goal_point(robot, goal, s.position)
        world = robot.collision
        if world is not None and world.ground is not None and float(point[2]) < world.ground:
            raise CollisionError(
                f"goal: the target is {world.ground - float(point[2]):.4g} m below the floor",
                pair=(robot.tool_frame, GROUND),
                field="goal",
            )
        duration, times, P, V, A, evaluate = line_samples(
            robot, s, point, pitch, spd, rate, max_samples=max_samples, check=check, goal_roll=roll
        )
        traj = build(robot, "line", rate, duration, times, P, V, A, evaluate)
        check_clear(robot, traj.times, traj.position, "the line")
        return traj
    if isinstance(via, (str, bytes)) or not isinstance(via, Sequence):
        raise BadRequest("via must be a list of goals", field="via")
    goals = []
    seed = s.position
    for k, g in enumerate([*via, goal]):
        q = goal_configuration(robot, g, seed, field="goal" if k == len(via) else f"via[{k}]")
        goals.append(q)
        seed = q
        if check is not None:
            check()
    rpath = joint_path(robot, s, goals, spd, 1.0 / rate)
    if check is not None:
        check()
    traj = _sampled(robot, "joint", rate, rpath, max_samples)
    try:
        check_clear(robot, traj.times, traj.position)
    except CollisionError as e:
        if s.moving or e.time is None:  # (from a moving state the arm is not on a straight move: no way round)
            raise
        traj = _around(robot, s, goals, spd, rate, max_samples, check, e)
    return traj


def _around(
    robot: Robot,
    s: JointState,
    goals: list[FloatArray],
    spd: float,
    rate: float,
    max_samples: int | None,
    check: Callable[[], None] | None,
    hit: CollisionError,
) -> Trajectory:
    """The joint path through ``goals`` from ``s`` (at rest) around what ``hit`` ran into: each
    leg by the sampling planner, timed through its configurations without stopping where the
    result stays clear, else at rest on each (straight joint moves: clear by construction)."""
    vias: list[FloatArray] = []
    prev = s.position
    for goal in goals:
        leg = sampling.path_around(robot, prev, goal)
        if check is not None:
            check()
        if leg is None:
            raise CollisionError(
                f"{hit.message}, and the sampling planner (RRT-Connect) found no way around in {sampling.TIME:g} s",
                pair=(hit.pair[0], hit.pair[1]),
                time=hit.time,
            )
        vias += leg[1:]
        prev = goal
    try:  # through the path's configurations without stopping: clear and within the limits?
        traj = _sampled(robot, "joint", rate, joint_path(robot, s, vias, spd, 1.0 / rate), max_samples)
        check_clear(robot, traj.times, traj.position)
        return traj
    except (CollisionError, LimitError):
        pass
    # at rest on each: every segment the straight joint move the sampling planner checked
    traj = _sampled(robot, "joint", rate, straight_path(robot, s.position, vias, spd, 1.0 / rate), max_samples)
    check_clear(robot, traj.times, traj.position)
    return traj


def plan_stop(robot: Robot, state: object, *, rate_hz: float | None = None, clamp: bool = False) -> Trajectory:
    """From ``state`` (possibly moving) to rest, jerk-limited, as fast as the limits allow.

    ``clamp``: a ``state`` (a :class:`JointState`) outside a limit is brought inside it first
    (:func:`~planning.state.clamped`) instead of being refused: for stops from a measured state."""
    rate = _rate(robot, rate_hz)
    if clamp and isinstance(state, JointState):
        state = clamped(robot, state)
    s = joint_state(robot, state, "state")
    return _sampled(robot, "stop", rate, stop_path(robot, s, 1.0 / rate))


def _sampled(robot: Robot, kind: str, rate: float, rpath: RuckigPath, max_samples: int | None = None) -> Trajectory:
    dt = 1.0 / rate
    k = whole_cycles(rpath.duration, dt)
    if max_samples is not None and k + 1 > max_samples:
        raise TrajectoryTooLong(k + 1, max_samples, k * dt, rate)
    times = np.arange(k + 1, dtype=float) * dt
    P, V, A, J = rpath.sample(times, dt)
    return build(robot, kind, rate, float(times[-1]), times, P, V, A, rpath.at, jerk=J)


__all__ = ["JointState", "plan", "plan_stop"]
