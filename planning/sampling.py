"""A way around: OMPL's RRT-Connect in joint space, with coal's distances as its checker.

When the straight joint move to a goal collides (:mod:`planning.clearance`), the sampling
planner looks for a collision-free joint path from the start to the goal, then shortens it
(OMPL's path simplifier: shortcuts, vertex reduction). A configuration is valid when it is
within every joint limit (box and coupled) and every checked pair is more than :data:`MARGIN`
apart (room for the timed motion's rounding of the corners); a motion between two
configurations is valid when the clearance walk (:func:`planning.clearance.check_clear`)
finds the straight joint move between them clear: the same certificate as every plan's, so
the path found is clear along its whole length, not only at the configurations OMPL checked.
The path is returned as its configurations (the start first, the goal last); the planner
times it through them (:func:`planning.plan`). OMPL's own messages go to armd's log at debug
(:class:`_Chatter`), never to the terminal.
"""

from __future__ import annotations

import logging
import math
import os
import tempfile
import threading

import numpy as np
from ompl import base as ob
from ompl import geometric as og
from ompl import util as ou

from armd.robots import Robot
from armd.robots.types import FloatArray
from armd.solvers.world import compiled

from .clearance import clear_move

MARGIN = 0.002  # [m]: the clearance a valid configuration keeps
TIME = 1.0  # [s]: the longest the planner searches
SHORTENING = 0.01  # [s]: the time the path simplifier is given

log = logging.getLogger(__name__)


class _Chatter:
    """OMPL's messages (its warnings and errors: "RRTConnect: ... no solution", written on the
    process's stderr by default, on a user's terminal) into armd's log at debug instead. OMPL's
    Python binding cannot take a handler written in Python, so its file handler writes to a file
    of our own (unlinked at once: nothing is left behind), read after each search, under the
    search's lock, and emptied."""

    def __init__(self) -> None:
        fd, path = tempfile.mkstemp(prefix="armd-ompl-")
        self.handler = ou.OutputHandlerFile(path)  # (it opens the file to append: kept open)
        os.unlink(path)
        self.file = os.fdopen(fd, "r+b", buffering=0)
        ou.useOutputHandler(self.handler)
        ou.setLogLevel(ou.LogLevel.LOG_WARN)  # (at INFO, OMPL says every solve)

    def flush(self) -> None:
        """What OMPL wrote since the last call, logged (the search's lock held)."""
        self.file.seek(0)
        said = self.file.read()
        if said:
            for line in said.decode(errors="replace").splitlines():
                if line.strip():
                    log.debug("OMPL: %s", line.strip())
            self.file.truncate(0)


_chatter = _Chatter()
_lock = threading.Lock()  # OMPL's random generators are not shared safely between threads: one search at a time


class _Motions(ob.MotionValidator):
    """A straight joint move is valid when it ends within the limits and the clearance walk
    finds it clear (the start: valid already, OMPL checked it)."""

    def __init__(self, info: object, robot: Robot) -> None:
        super().__init__(info)
        self.robot = robot

    def checkMotion(self, s1: object, s2: object, *_: object) -> bool:  # noqa: N802 (OMPL's name)
        n = self.robot.nq
        qb = _q(s2, n)
        return bool(self.robot.limits.contains(qb, tol=0.0)) and clear_move(self.robot, _q(s1, n), qb)


def _q(state: object, n: int) -> FloatArray:
    """An OMPL state's joint vector."""
    return np.array([state[i] for i in range(n)])  # type: ignore[index]


def path_around(
    robot: Robot, start: FloatArray, goal: FloatArray, *, time_limit: float | None = None
) -> list[FloatArray] | None:
    """A collision-free joint path from ``start`` to ``goal`` (both clear: see module notes),
    shortened: its configurations, or None when none was found in ``time_limit`` [s] (None:
    :data:`TIME`). A start or goal nearer than MARGIN to something lowers the margin to half
    their clearance (an arm at rest 1 mm from a box may still leave it)."""
    if robot.collision is None:
        return [np.array(start, dtype=float), np.array(goal, dtype=float)]
    world = compiled(robot.collision)
    lim = robot.limits
    n = robot.nq
    space = ob.RealVectorStateSpace(n)
    bounds = ob.RealVectorBounds(n)
    for i in range(n):
        bounds.setLow(i, float(lim.lower[i]))
        bounds.setHigh(i, float(lim.upper[i]))
    space.setBounds(bounds)
    setup = og.SimpleSetup(space)

    margin = min(MARGIN, 0.5 * world.clearance(start)[0], 0.5 * world.clearance(goal)[0])

    def valid(state: object) -> bool:
        q = _q(state, n)
        return bool(lim.contains(q, tol=0.0)) and world.clearance(q)[0] > margin

    setup.setStateValidityChecker(valid)
    info = setup.getSpaceInformation()
    motions = _Motions(info, robot)  # (kept alive here while OMPL holds it)
    info.setMotionValidator(motions)
    a, b = space.allocState(), space.allocState()
    for i in range(n):
        a[i] = float(start[i])
        b[i] = float(goal[i])
    setup.setStartAndGoalStates(a, b)
    setup.setPlanner(og.RRTConnect(setup.getSpaceInformation()))
    with _lock:
        try:
            status = setup.solve(TIME if time_limit is None else time_limit)
            if status.getStatus() != ob.PlannerStatus.EXACT_SOLUTION:
                return None
            setup.simplifySolution(SHORTENING)
            path = setup.getSolutionPath()
            out = [_q(path.getState(k), n) for k in range(path.getStateCount())]
        finally:
            _chatter.flush()
    out[0], out[-1] = np.array(start, dtype=float), np.array(goal, dtype=float)  # (exactly: not via floats of OMPL's)
    return [q for k, q in enumerate(out) if k == 0 or not math.isclose(float(np.max(np.abs(q - out[k - 1]))), 0.0)]


__all__ = ["MARGIN", "SHORTENING", "TIME", "path_around"]
