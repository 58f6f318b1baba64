"""Plan goals: a joint configuration, or a Cartesian target with an approach (solved by IK)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

from armd.errors import BadRequest, CollisionError, PlanRejected
from armd.robots import Robot
from armd.robots.types import FloatArray
from armd.solvers import SensorReading, approach_pitch, solve_ik, target_point
from armd.solvers.world import compiled


@dataclass(frozen=True)
class CartesianGoal:
    """A tool point [x, y, z] [m] in ``base`` (or a sensor reading), an approach and a tool roll
    [rad] (None: the seed's)."""

    target: object
    approach: object = None
    roll: float | None = None


def cartesian(goal: object) -> CartesianGoal | None:
    """The goal as a :class:`CartesianGoal`, or None when it is a joint configuration."""
    if isinstance(goal, CartesianGoal):
        return goal
    if isinstance(goal, SensorReading):
        return CartesianGoal(goal)
    if isinstance(goal, Mapping):
        if "target" in goal:
            return CartesianGoal(goal["target"], goal.get("approach"), goal.get("roll"))
        if "q" in goal:
            return None
        raise BadRequest("a goal mapping needs 'target' (Cartesian) or 'q' (joints)", field="goal")
    return None


def goal_configuration(robot: Robot, goal: object, seed: FloatArray, field: str = "goal") -> FloatArray:
    """The joint configuration [rad] a goal names: IK (seeded with ``seed``) for a Cartesian goal.

    An unreachable target is :class:`PlanRejected`; a pitch that is not reachable there
    (IK ``approximate``) is too: a plan never silently changes the approach it was given. A goal
    that collides (a joint goal in contact, a target IK answers ``collision``) is
    :class:`CollisionError`, naming the pair.
    """
    cg = cartesian(goal)
    if cg is None:
        q = goal["q"] if isinstance(goal, Mapping) else goal
        qv = robot.joint_vector(q, field)
        bad = robot.limits.violations(qv, tol=1e-9)
        if bad:
            raise BadRequest(f"{field} is outside the joint limits: {bad[0].message}", field=field)
        qv = robot.limits.clip(qv)
        hit = compiled(robot.collision).first_contact(qv) if robot.collision is not None else None
        if hit is not None:
            raise CollisionError(
                f"{field}: the joint configuration puts {hit} in contact", pair=(hit.first, hit.second), field=field
            )
        return qv
    r = solve_ik(robot, cg.target, approach=cg.approach, seed=seed, roll=cg.roll)
    if r.status == "collision" and r.contact is not None:
        raise CollisionError(f"{field}: {r.reason}", pair=r.contact, field=field, position_error=r.position_error)
    if r.status != "ok":
        raise PlanRejected(f"{field}: {r.reason}", field=field, position_error=r.position_error)
    return r.q


def goal_point(robot: Robot, goal: object, seed: FloatArray) -> tuple[FloatArray, float | None, float | None]:
    """Tool point [m], asked pitch [rad] (None: free) and asked tool roll [rad] (None: the
    start's kept) of a goal, for a Cartesian line."""
    cg = cartesian(goal)
    if cg is None:
        q = goal_configuration(robot, goal, seed)
        return robot.fk(q), (robot.tool_pitch(q) if robot.chooses_pitch else None), None
    return target_point(robot, cg.target, seed), approach_pitch(robot, cg.approach), cg.roll
