"""A trajectory's clearance: every sample, and the motion between them, clear of the arm's world.

What the controller does between two samples is a straight move of the joints (a servo
controller ramps each pulse linearly over the cycle; a stepper planner runs the segment): the
motion checked is the polyline through the samples in joint space. Along it, a straight move
``dq`` moves no point of the arm farther than ``abs(dq) @ travel``
(:attr:`robots.collision.CollisionModel.travel`), so a configuration whose shapes are ``d``
apart from everything they are checked against clears every configuration within a travel
``d`` of it (conservative advancement). The walk checks a configuration and steps on by its
clearance ``d``, or by ``2 * CONTACT`` where ``d`` is smaller: every point of the motion is
then within the clearance of a checked configuration, or within ``CONTACT`` of travel of one
at least ``CONTACT`` clear: the whole motion is certified clear, not sampled (and no point of
any link moves farther between two checks than the clearance at the first, or 20 um). Each
check is the compiled collision stage's (:func:`armd.solvers.world.compiled`); where every
pair is a primitive one, the whole walk is one compiled call
(:func:`planning.compiled.clear_walk`), else it is walked here, the mesh pairs through coal.
A configuration nearer than :data:`CONTACT` (10 um: coal's distances are good to about a
micrometre) to something counts as in contact.

A contact raises :class:`~armd.errors.CollisionError` naming the pair and the time [s]
(narrowed down by bisection to 1/256 of the last step). Stops are never checked (a stop is
never refused).
"""

from __future__ import annotations

from typing import NoReturn

import numpy as np

from armd.errors import CollisionError
from armd.robots import Robot
from armd.robots.collision import Contact
from armd.robots.types import FloatArray
from armd.solvers.world import compiled

from .compiled import clear_walk

CONTACT = 1e-5  # [m]: nearer than this counts as in contact (and the walk's step is at least twice it)
BISECTIONS = 8  # a contact found is narrowed down to 1/256 of the step that found it


def check_clear(robot: Robot, times: FloatArray, position: FloatArray, what: str = "the motion") -> int:
    """Raise :class:`CollisionError` at the first contact along the samples ``position`` (rows,
    at ``times`` [s]) and the straight moves between them; the number of checks made."""
    model = robot.collision
    if model is None or not model.pairs:
        return 0
    world = compiled(model)
    P = np.ascontiguousarray(position, dtype=float)
    T = np.ascontiguousarray(times, dtype=float)
    if not world.coal_pairs:  # every pair a primitive one: the whole walk in one compiled call
        out = np.empty(P.shape[1] + 3)
        p = int(clear_walk(world.packed_shapes, T, P, model.travel, CONTACT, BISECTIONS, out))
        if p >= 0:
            _contact(what, world.pairs[int(world.compiled_pairs[p])], out[3:], float(out[0]), out[2] == 1.0)
        return int(out[1])
    s = np.zeros(len(P))  # the travel bound [m] from the first sample to each
    if len(P) > 1:
        np.cumsum(np.abs(np.diff(P, axis=0)) @ model.travel, out=s[1:])
    end = float(s[-1])

    def point(at: float) -> tuple[FloatArray, float]:
        """The configuration and the time a travel ``at`` [m] along the polyline."""
        k = min(max(int(np.searchsorted(s, at, side="right")) - 1, 0), max(len(s) - 2, 0))
        if len(P) == 1 or s[k + 1] <= s[k]:
            return P[k], float(T[k])
        f = min(max((at - s[k]) / (s[k + 1] - s[k]), 0.0), 1.0)
        return P[k] + f * (P[k + 1] - P[k]), float(T[k] + f * (T[k + 1] - T[k]))

    at, last_clear, checks = 0.0, -1.0, 0
    while True:
        q, t = point(at)
        d, pair = world.clearance(q)
        checks += 1
        if d < CONTACT and pair is not None:
            if last_clear >= 0.0:  # somewhere after the last clear check: narrow it down
                lo, hi = last_clear, at
                for _ in range(BISECTIONS):
                    mid = 0.5 * (lo + hi)
                    dm, pm = world.clearance(point(mid)[0])
                    checks += 1
                    if dm < CONTACT and pm is not None:
                        hi, pair = mid, pm
                    else:
                        lo = mid
                q, t = point(hi)
            _contact(what, pair, q, t, at == 0.0)
        if at + d >= end:
            return checks
        last_clear = at
        at = min(at + max(d, 2.0 * CONTACT), end)


def _contact(what: str, pair: Contact, q: FloatArray, t: float, start: bool) -> NoReturn:
    where = "at its start" if start else f"at t = {t:.4f} s"
    raise CollisionError(
        f"{what} puts {pair.first} and {pair.second} in contact {where} (q = [{', '.join(f'{x:.4f}' for x in q)}] rad)",
        pair=(pair.first, pair.second),
        time=t,
    )


def clear_move(robot: Robot, a: FloatArray, b: FloatArray) -> bool:
    """Whether the straight joint move from ``a`` to ``b`` is clear of the arm's world."""
    try:
        check_clear(robot, _ENDS, np.array([a, b]))
    except CollisionError:
        return False
    return True


_ENDS = np.array([0.0, 1.0])


__all__ = ["CONTACT", "check_clear", "clear_move"]
