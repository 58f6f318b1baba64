"""``pick`` and ``place``: seed 000's grasp as a sequence of checked steps through the adapters.

A pick of the point ``target`` (an object's centre at the height to grasp it; a sensor reading
too), approached ``perpendicular`` (from above, the tool straight down: seed 000's eq. 1) or
``parallel`` (level, along the line from the base's axis to the target):

1. ``open``: the gripper opened (and given ``GRIPPER_WAIT`` to get there);
2. ``above``: a joint move to the pre-grasp pose, ``above`` [m] from the target, back along
   the approach (straight up over it, or toward the base);
3. ``descend``: the tool on the straight line to the target;
4. ``close``: the gripper closed;
5. ``lift``: the tool straight up by ``lift`` [m].

A ``place`` is the reverse: ``above``, ``descend``, ``open``, ``rise`` (straight back up).

Every motion step is planned first, each from the pose the one before ends at, before anything
moves: a target out of reach, a step that would touch the arm's world or break a limit is
refused naming the step, and nothing moves. Then each step goes through the adapters as a
``move`` would (planned again from where the arm is, checked by the adapters), and the next
waits until the arm is at rest at the step's goal. A ``stop`` (or an estop, or an adapter's
abort) ends the sequence there: the reply lists the steps done and the one it stopped at, and
why. The request's deadline bounds the planning; the motion is bounded by each step's
duration and ``SETTLE``.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from armd import planning, solvers
from armd.errors import ArmdError, BadRequest
from armd.planning import JointState
from armd.robots import Robot

GRIPPER_WAIT = 0.5  # [s] a gripper is given this long to open or close before the arm moves on
SETTLE = 2.0  # [s] after a step's planned end, how long the arm may take to be at rest at its goal
ARRIVED = 0.01  # [rad] how near its goal a step's end counts as arrived
POLL = 0.02  # [s]
ABOVE = 0.06  # [m] the pre-grasp pose's distance from the target, default
LIFT = 0.06  # [m] how far a pick lifts, a place rises, default
SPEED = 0.5  # fraction of the limits a sequence moves at, default


@dataclass
class Step:
    name: str
    kind: str  # "gripper" or "move"
    opening: float = 0.0  # gripper
    goal: dict[str, Any] = field(default_factory=dict)  # move: the goal ({"target", "approach"})
    path: str = "joint"
    done: bool = False
    duration: float = 0.0
    reached: list[float] | None = None

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {"step": self.name, "done": self.done}
        if self.kind == "gripper":
            out["opening"] = self.opening
        else:
            out.update(target=self.goal["target"], path=self.path, duration=round(self.duration, 4))
            if self.reached is not None:
                out["reached"] = self.reached
        return out


def steps(arm: Robot, verb: str, point: np.ndarray, approach: str, above: float, lift: float) -> list[Step]:
    """The steps of a ``pick`` or ``place`` of ``point`` [m] (base frame)."""
    if approach == "perpendicular":
        back = np.array([0.0, 0.0, 1.0])
    else:  # level: back toward the base's axis
        radial = np.array([point[0], point[1], 0.0])
        r = float(np.linalg.norm(radial))
        if r < 1e-6:
            raise BadRequest("a parallel approach needs a target off the base's axis", field="target")
        back = -radial / r
    up = np.array([0.0, 0.0, 1.0])

    def move(name: str, p: np.ndarray, path: str) -> Step:
        return Step(name, "move", goal={"target": [float(x) for x in p], "approach": approach}, path=path)

    pre = point + above * back
    if verb == "pick":
        return [
            Step("open", "gripper", opening=1.0),
            move("above", pre, "joint"),
            move("descend", point, "line"),
            Step("close", "gripper", opening=0.0),
            move("lift", point + lift * up, "line"),
        ]
    return [
        move("above", pre, "joint"),
        move("descend", point, "line"),
        Step("open", "gripper", opening=1.0),
        move("rise", point + lift * up, "line"),
    ]


class Sequence:
    """One pick or place on ``arm``, through the service's own verbs: ``plan`` (a step planned
    from a start), ``move`` (a step sent, as the verb), ``gripper``, ``present`` (where the arm
    is, as the service knows it), ``stops`` (how many stops the arm has had: one more means
    stop), ``estop`` (the arm stopped again: a step that went out after a stop's estop)."""

    def __init__(
        self,
        arm: Robot,
        todo: list[Step],
        *,
        speed: float,
        plan: Callable[[Mapping[str, Any], JointState], planning.Trajectory],
        move: Callable[[Mapping[str, Any]], dict[str, Any]],
        gripper: Callable[[float], object],
        present: Callable[[], Any],
        stops: Callable[[], int],
        estop: Callable[[], None],
        check: Callable[[], None],
    ) -> None:
        self.arm, self.todo, self.speed = arm, todo, speed
        self._plan, self._move, self._gripper, self._present, self._stops = plan, move, gripper, present, stops
        self._estop = estop
        self._check = check

    def check_all(self, start: JointState) -> None:
        """Every motion step planned from the pose the one before ends at (the first from
        ``start``): :class:`ArmdError` naming the first step that cannot be (nothing moved)."""
        state = start
        for s in self.todo:
            if s.kind != "move":
                continue
            self._check()
            try:
                traj = self._plan({"goal": s.goal, "path": s.path, "speed": self.speed}, state)
            except ArmdError as e:
                e.message = f"{s.name}: {e.message}"
                e.args = (e.message,)
                e.fields.setdefault("step", s.name)
                raise
            state = JointState.at_rest(np.array(traj.position[-1]))

    def run(self, stops: int) -> dict[str, Any]:
        """Each step in turn, unless the arm has had a stop since ``stops`` (its count when the
        sequence was asked); the reply: the steps, whether all were done, where it stopped and why."""
        for s in self.todo:
            why = self._step(s, stops)
            if why is not None:
                return self._reply(s.name, why)
            s.done = True
        return self._reply(None, None)

    def _step(self, s: Step, stops: int) -> str | None:
        if self._stops() != stops:
            return "a stop was asked"
        try:
            if s.kind == "gripper":
                self._gripper(s.opening)
                return "a stop was asked" if self._wait(GRIPPER_WAIT, stops) else None
            r = self._move({"goal": s.goal, "path": s.path, "speed": self.speed})
        except ArmdError as e:
            return f"{e.code}: {e.message}"
        if self._stops() != stops:  # a stop while the step was planned: it may have gone out after the stop's estop
            self._estop()
            return "a stop was asked"
        s.duration = float(r["duration"])
        goal = np.array(r["goal"])
        until = time.monotonic() + s.duration + SETTLE
        while True:
            if self._stops() != stops:
                return "a stop was asked"
            known = self._present()
            here = np.asarray(known.state.position)
            # (arrived: as the adapter says, never the service's guess from what it commanded)
            if known.source == "adapter" and not known.moving and float(np.max(np.abs(here - goal))) <= ARRIVED:
                s.reached = [round(float(x), 6) for x in here]
                return None
            if time.monotonic() > until:
                off = float(np.max(np.abs(here - goal)))
                return f"the arm is not at the step's goal {SETTLE:g} s after its end ({off:.3f} rad off): stopped?"
            time.sleep(POLL)

    def _wait(self, seconds: float, stops: int) -> bool:
        """Wait ``seconds``; True if a stop came meanwhile."""
        until = time.monotonic() + seconds
        while time.monotonic() < until:
            if self._stops() != stops:
                return True
            time.sleep(min(POLL, max(until - time.monotonic(), 0.0)))
        return False

    def _reply(self, stopped_at: str | None, why: str | None) -> dict[str, Any]:
        return {
            "done": stopped_at is None,
            "steps": [s.to_dict() for s in self.todo],
            "stopped_at": stopped_at,
            "reason": why,
        }


def sequence_point(arm: Robot, target: object, q: np.ndarray | None) -> np.ndarray:
    """The base-frame point a pick or place names (a point, or a sensor reading at ``q``)."""
    return solvers.target_point(arm, target, q)


def check_speed(value: object) -> float:
    from armd.planning.plan import MIN_SPEED

    if isinstance(value, bool) or not isinstance(value, (int, float)) or not MIN_SPEED <= value <= 1:
        raise BadRequest(f"speed must be a number in [{MIN_SPEED:g}, 1], got {value!r}", field="speed")
    return float(value)


def check_distance(value: object, name: str, default: float) -> float:
    v = default if value is None else value
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or not 0.0 <= v <= 0.3:
        raise BadRequest(f"{name} must be a distance in [0, 0.3] m, got {v!r}", field=name)
    return float(v)
