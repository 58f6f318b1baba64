"""Collision-free IK answers: the answer of :func:`solvers.solve_ik` checked against the arm
itself, the ground and the obstacles of its world (:attr:`Robot.collision`).

- The chosen configuration is clear: the other branches listed are the clear ones.
- It collides: the nearest clear branch is chosen instead (the branches are nearest the seed
  first); with a free pitch, the pitches nearest the one chosen, then (outside the closed-form
  family) the numerical IK from clear atlas configurations, are tried in turn. None is clear:
  status ``collision``, ``contact`` naming the nearest branch's colliding pair.
- A target below the ground: every configuration that reaches it has the tool under the floor:
  status ``collision``, the tool and the ground.
- An unreachable target whose closest configuration collides: the closest clear configuration
  found (from the clear atlas configurations whose tool points are nearest the target, each
  moved toward the colliding one as far as it stays clear, by bisection); none: ``collision``.
"""

from __future__ import annotations

import math
import threading
import weakref
from collections.abc import Callable, Iterable

import numpy as np

from armd.robots.angles import wrap
from armd.robots.collision import GROUND, Contact
from armd.robots.types import FloatArray

from .arm import ArmState
from .result import COLLISION, UNREACHABLE, Branch, IKResult
from .world import World

BISECTIONS = 12  # halvings of the segment from a clear configuration toward a colliding one
FREE_STARTS = 8  # clear atlas configurations tried for an unreachable target's answer
PITCH_STEPS = 24  # with a free pitch: the pitches tried, every 2 pi / PITCH_STEPS

_masks: weakref.WeakKeyDictionary[World, tuple[np.ndarray, FloatArray, object]] = weakref.WeakKeyDictionary()
_lock = threading.Lock()


Stage = list[Branch]  # configurations on a target, preferred first: checked in one call


def clear(arm: ArmState, world: World, result: IKResult, alternatives: Callable[[], Iterable[Stage]]) -> IKResult:
    """``result`` made collision-free in ``world`` (the module's doc; the robot's own, which
    is not always ``arm.robot``'s: a copy of a robot shares its solver state). ``alternatives()``:
    other configurations on the target in stages, preferred first (the closed form's at other
    pitches, with the wrist rolled, the numerical IK's from clear starts), each stage checked in
    one call (:meth:`World.colliding`) when every branch of ``result`` collides."""
    if world.ground is not None and float(result.target[2]) < world.ground:
        depth = world.ground - float(result.target[2])
        return result._replace(
            status=COLLISION,
            contact=(arm.robot.tool_frame, GROUND),
            reason=f"the target is {depth:.4g} m below the ground (z = {world.ground:.4g} m): "
            "nothing there is reachable",
        )
    # the answer and its other branches in one call; the pair named only where one collides
    hits = world.colliding(np.array([result.q, *(b.q for b in result.branches)])).tolist()
    free = [b for b, h in zip(result.branches, hits[1:], strict=True) if not h]
    hit = world.first_contact(result.q) if hits[0] else None
    if hit is None:
        return result if len(free) == len(result.branches) else result._replace(branches=tuple(free))
    if result.status == UNREACHABLE:
        return _unreachable(arm, world, result, hit)
    if free:
        return _chosen(arm, result, free[0], free[1:])
    for stage in alternatives():
        free = _clear_of(world, stage)
        if free:
            return _chosen(arm, result, free[0], [])
    return result._replace(
        status=COLLISION,
        contact=(hit.first, hit.second),
        reason=f"every configuration found on the target collides: at the nearest ({result.branch}), {hit}",
    )


def _clear_of(world: World, branches: list[Branch]) -> list[Branch]:
    """The branches clear in ``world``, in order (one call for all)."""
    if not branches:
        return []
    hit = world.colliding(np.array([b.q for b in branches]))
    return [b for b, h in zip(branches, hit.tolist(), strict=True) if not h]


def pitches(chosen: float) -> list[float]:
    """The tool pitches [rad] other than ``chosen``, nearest it first."""
    step = 2 * math.pi / PITCH_STEPS
    grid = [wrap(chosen + k * step) for k in range(1, PITCH_STEPS)]
    return sorted(grid, key=lambda p: abs(wrap(p - chosen)))


def _chosen(arm: ArmState, result: IKResult, chosen: Branch, others: list[Branch]) -> IKResult:
    """``result`` answered by the clear branch ``chosen`` instead (its pose by FK)."""
    reached, pitch = arm.tool_pose(chosen.q)
    asked = None if result.pitch_error is None else wrap(result.pitch - result.pitch_error)
    return result._replace(
        q=chosen.q,
        position_error=math.dist(reached.tolist(), result.target.tolist()),
        reached=reached,
        pitch=pitch,
        pitch_error=None if asked is None else wrap(pitch - asked),
        branch=chosen.name,
        branches=tuple(others),
    )


def _touch(arm: ArmState, world: World, q: FloatArray) -> Contact | None:
    """The colliding pair at ``q``, counting the tool point under the ground as one."""
    hit = world.first_contact(q)
    if hit is None and world.ground is not None and float(arm.robot.fk(q)[2]) < world.ground:
        return Contact(arm.robot.tool_frame, GROUND)
    return hit


def _clear_atlas(arm: ArmState, world: World) -> tuple[np.ndarray, FloatArray]:
    """The rows of the arm's atlas clear in ``world`` and their tool points (made once per
    world)."""
    with _lock:
        held = _masks.get(world)
    if held is None or held[2] is not arm.atlas:
        mask = ~world.colliding(arm.atlas.q)  # (the tool point under the ground too, as _touch)
        if world.ground is not None:
            mask &= arm.atlas.p[:, 2] >= world.ground
        rows = np.flatnonzero(mask)
        held = (rows, np.ascontiguousarray(arm.atlas.p[rows]), arm.atlas)
        with _lock:
            _masks[world] = held
    return held[0], held[1]


def clear_starts(arm: ArmState, world: World, point: FloatArray, count: int) -> list[FloatArray]:
    """The ``count`` clear atlas configurations whose tool points are nearest ``point``."""
    rows, p = _clear_atlas(arm, world)
    away = p - point
    d = np.einsum("ij,ij->i", away, away)
    if len(d) > count:  # the nearest ``count``, in order (a partition first: the atlas is large)
        near = np.argpartition(d, count)[:count]
        rows, d = rows[near], d[near]
    return [arm.atlas.q[r] for r in rows[np.argsort(d, kind="stable")]]


def closest_clear(arm: ArmState, world: World, point: FloatArray, toward: FloatArray) -> FloatArray | None:
    """A clear configuration within limits with its tool point near ``point``: from each of the
    clear atlas configurations nearest it, the farthest clear point found toward ``toward`` (a
    configuration that collides) by bisection; the best of them. None: no clear configuration."""
    limits = arm.robot.limits
    best, best_d = None, math.inf
    for a in clear_starts(arm, world, point, FREE_STARTS):
        lo, hi = 0.0, 1.0
        for _ in range(BISECTIONS):
            mid = 0.5 * (lo + hi)
            q = a + mid * (toward - a)
            if limits.contains(q, tol=0.0) and _touch(arm, world, q) is None:
                lo = mid
            else:
                hi = mid
        q = a + lo * (toward - a)
        d = math.dist(arm.robot.fk(q).tolist(), point.tolist())
        if d < best_d:
            best, best_d = q, d
    return best


def _unreachable(arm: ArmState, world: World, result: IKResult, hit: Contact) -> IKResult:
    q = closest_clear(arm, world, result.target, result.q)
    if q is None:
        return result._replace(
            status=COLLISION,
            contact=(hit.first, hit.second),
            reason=f"the target is out of reach, and no collision-free configuration was found near it "
            f"(the closest within limits has {hit} in contact)",
        )
    chosen = _chosen(arm, result, Branch("numerical", q, 0.0), [])
    return chosen._replace(
        status=UNREACHABLE,
        reason=f"the target is out of reach within the joint limits and clear of collisions: the closest "
        f"collision-free configuration found puts the tool {chosen.position_error:.6g} m away (the closest "
        f"within limits, {result.position_error:.6g} m away, has {hit} in contact)",
    )
