"""A trajectory's clearance: every sample, and the motion between them, clear of the arm's world.

What the controller does between two samples is a straight move of the joints (a servo
controller ramps each pulse linearly over the cycle; a stepper planner runs the segment): the
motion checked is the polyline through the samples in joint space. Along it, a straight move
``dq`` moves no point of the arm farther than ``abs(dq) @ travel``
(:attr:`robots.collision.CollisionModel.travel`), so a configuration whose shapes are ``d``
apart from everything they are checked against clears every configuration within a travel
``d`` of it (conservative advancement). The walk checks a configuration, skips what that
clears, and never steps farther than :data:`RESOLUTION` where the clearance is smaller: no
point of any link moves more than 5 mm between checks that are not already known clear, and
every sample is either checked or within the clearance of one that was.

A contact raises :class:`~armd.errors.CollisionError` naming the pair and the time [s] (found
within 5 mm of travel, then narrowed down by bisection to 20 um of travel: the first contact
on the way, unless two come and go within 5 mm).
Stops are never checked (a stop is never refused).
"""

from __future__ import annotations

import numpy as np

from armd.errors import CollisionError
from armd.robots import Robot
from armd.robots.types import FloatArray

RESOLUTION = 0.005  # [m]: the farthest any point of the arm moves between two checks not known clear
BISECTIONS = 8  # a contact found is narrowed down to RESOLUTION / 2**8 (20 um) of travel


def check_clear(robot: Robot, times: FloatArray, position: FloatArray, what: str = "the motion") -> int:
    """Raise :class:`CollisionError` at the first contact along the samples ``position`` (rows,
    at ``times`` [s]) and the straight moves between them; the number of checks made."""
    world = robot.collision
    if world is None or not world.pairs:
        return 0
    P = np.asarray(position, dtype=float)
    T = np.asarray(times, dtype=float)
    s = np.zeros(len(P))  # the travel bound [m] from the first sample to each
    if len(P) > 1:
        np.cumsum(np.abs(np.diff(P, axis=0)) @ world.travel, out=s[1:])
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
        if d <= 0.0 and pair is not None:
            if last_clear >= 0.0:  # somewhere after the last clear check: narrow it down
                lo, hi = last_clear, at
                for _ in range(BISECTIONS):
                    mid = 0.5 * (lo + hi)
                    dm, pm = world.clearance(point(mid)[0])
                    checks += 1
                    if dm <= 0.0 and pm is not None:
                        hi, pair = mid, pm
                    else:
                        lo = mid
                q, t = point(hi)
            where = "at its start" if at == 0.0 else f"at t = {t:.4f} s"
            raise CollisionError(
                f"{what} puts {pair.first} and {pair.second} in contact {where} "
                f"(q = [{', '.join(f'{x:.4f}' for x in q)}] rad)",
                pair=(pair.first, pair.second),
                time=t,
            )
        if at + d >= end:
            return checks
        last_clear = at
        step = at + max(d, RESOLUTION)
        first_open = int(np.searchsorted(s, at + d, side="right"))  # the first sample not cleared
        at = min(step, float(s[first_open])) if first_open < len(s) else min(step, end)


__all__ = ["RESOLUTION", "check_clear"]
