"""One cycle of a tracking stream: Ruckig's online generation from the commanded state to the
latest goal, cut at a horizon and braked to rest there.

A stream's trajectory always ends at rest: followed to its end with nothing newer, the arm
stops. The horizon is when the stream's deadman runs out, so that if nothing (a put, the
service itself) comes in time, the adapter, which needs nothing from the service to finish a
trajectory, brakes the arm where the deadman says, jerk-limited, within every limit. Each
cycle's trajectory starts from a sample of the previous one (the state there exactly: its
position, velocity and acceleration), so that the adapter can splice them with no jump
(:mod:`adapters.trajectory_message`'s ``splice``).

A goal that moves (a stream's targets along a path) is followed, not chased: Ruckig to a goal
at rest lags it by the braking distance (29 mm at 0.2 m/s on the insomniac, measured), and
Ruckig to the goal's moving state, replanned every cycle, hunts round it (it meets where the
goal was, time-optimally, from one side and then the other: 20-50 mm). Instead the arm moves
as the goal's reference motion (its position, velocity and acceleration, fitted to the latest
goals by the caller) plus an error that Ruckig takes to zero as fast as the limits left
beside the reference's own motion allow (:func:`_follow`): on the reference, no lag at all;
off it, the fastest way on. After the time the next put should take (``cruise``) the arm goes
to the goal itself, at rest: a stream that stops ends on its last goal.

The motion is checked against the arm's world (:func:`planning.clearance.check_clear`):
where it would touch something, the horizon is brought in (halved, down to braking at once)
until the motion is clear; a stop is never refused, so braking at once is the last answer
whatever it touches.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from armd.errors import BadRequest, CollisionError, LimitError, PlannerError
from armd.robots import Robot
from armd.robots.types import FloatArray

from .clearance import check_clear
from .compiled import evaluate_part
from .ruckig_path import Limits, RuckigPath, _otg, _segment, joint_path, stop_path, whole_cycles
from .state import JointState
from .trajectory import Trajectory, build

ROOM = 0.05  # a reference is followed if it leaves at least this share of each velocity and acceleration limit


@dataclass(frozen=True)
class Step:
    """A stream's cycle: the trajectory, whether it was cut short of the goal at the horizon
    (``braked``: it ends at rest elsewhere), and what it would have touched (``hit``: the
    horizon was brought in for it), else None."""

    trajectory: Trajectory
    braked: bool
    hit: CollisionError | None
    followed: bool = False  # it follows a moving goal's reference first


class _Path:
    """A Ruckig path, or (``reference``) a reference carried on at its acceleration plus a
    Ruckig path of the error from it (held at its end: zero): evaluated at any time."""

    def __init__(self, path: RuckigPath, reference: JointState | None = None) -> None:
        self.path = path
        self.reference = reference
        self.duration = path.duration if reference is None else math.inf
        # (the reference's rows as the compiled sampling takes them: zeros, none)
        self.motion = (
            np.zeros((3, path.nq))
            if reference is None
            else np.array([reference.position, reference.velocity, reference.acceleration], dtype=float)
        )

    def at(self, t: float) -> tuple[FloatArray, FloatArray, FloatArray]:
        p, v, a = self.path.at(t)
        ref = self.reference
        if ref is None:
            return p, v, a
        return (
            ref.position + ref.velocity * t + ref.acceleration * (t * t / 2) + p,
            ref.velocity + ref.acceleration * t + v,
            ref.acceleration + a,
        )

    def state(self, t: float) -> JointState:
        return JointState(*self.at(t))


Part = tuple[_Path, int | None]  # a path and how many of its cycles (None: to its end)


def track_step(
    robot: Robot,
    start: JointState,
    goal: FloatArray,
    *,
    horizon: float,
    speed: float,
    rate_hz: float,
    reference: JointState | None = None,
    cruise: float = 0.0,
) -> Step:
    """From ``start`` (moving or not) toward ``goal``, within every limit at ``speed`` (a
    fraction of the velocity limits, as :func:`planning.plan`), braking to rest from ``horizon``
    [s] on (at the full limits) if the goal is not reached by then; clear of the arm's world.

    A moving goal (``reference``: where the stream's goal is at the trajectory's start, and its
    velocity and acceleration) is followed for ``cruise`` [s] (:func:`_follow`), then the arm
    goes to ``goal`` at rest. A reference the limits cannot follow is taken as a goal at rest."""
    dt = 1.0 / rate_hz
    goal = np.asarray(goal, dtype=float)
    cycles = whole_cycles(max(horizon, 0.0), dt)
    if reference is not None and cruise > 0.0:
        follow = _follow(robot, start, reference, speed, dt)
        on = min(whole_cycles(cruise, dt), cycles)
        if follow is not None and on > 0:
            try:
                there = follow.state(on * dt)
                go = _Path(joint_path(robot, there, [goal], speed, dt))
                step = _cut(robot, [(follow, on)], go, cycles - on, dt, rate_hz)
                return Step(step.trajectory, step.braked, step.hit, True)
            except (LimitError, CollisionError, PlannerError, BadRequest):
                pass  # (the reference breaks a limit, or touches something: the goal at rest, from here)
    go = _Path(joint_path(robot, start, [goal], speed, dt))
    return _cut(robot, [], go, cycles, dt, rate_hz)


def _cut(robot: Robot, head: list[Part], go: _Path, cycles: int, dt: float, rate_hz: float) -> Step:
    """``head``, then ``go`` to its end if it ends within ``cycles``, else for ``cycles`` and
    braked; without ``head`` cut sooner, halving, until the motion is clear (at the last,
    braking at once). With ``head``: :class:`LimitError` or :class:`CollisionError` if it breaks
    a limit or touches something."""
    hit: CollisionError | None = None
    whole = go.duration <= cycles * dt + 1e-12
    while True:
        if whole:
            parts: list[Part] = [*head, (go, None)]
        else:
            brake = _Path(stop_path(robot, go.state(cycles * dt), dt))
            parts = [*head, (go, cycles), (brake, None)]
        traj = _chain(robot, parts, dt, rate_hz)
        try:
            check_clear(robot, traj.times, traj.position, "the stream's motion")
            return Step(traj, not whole, hit)
        except CollisionError as e:
            if head:
                raise
            hit = hit or e
            if not whole and cycles == 0:
                return Step(traj, True, hit)  # (braking at once: never refused)
            touch = whole_cycles(e.time or 0.0, dt)
            cycles = max(0, min(touch - 1, cycles if whole else cycles // 2))
            whole = False


def _follow(robot: Robot, start: JointState, ref: JointState, speed: float, dt: float) -> _Path | None:
    """The reference ``ref`` (at time 0, carried on at its acceleration) plus the error from it,
    taken to zero by Ruckig within what the limits leave beside the reference's motion; None
    if they leave nothing (the reference is as fast as the arm)."""
    limits = Limits.of(robot, speed)
    vr, ar = ref.velocity, ref.acceleration
    v_room = limits.velocity - np.abs(vr) - np.abs(ar) * FOLLOW_S
    a_room = limits.acceleration - np.abs(ar)
    if np.any(v_room < ROOM * limits.velocity) or np.any(a_room < ROOM * limits.acceleration):
        return None
    error = JointState(start.position - ref.position, start.velocity - vr, start.acceleration - ar)
    room = Limits(v_room, a_room, limits.jerk)
    zero = np.zeros(robot.nq)
    try:  # (each joint on its own: the error of each taken out as fast as it may)
        fix = _segment(_otg(robot.nq, dt), error, zero, zero, room, synchronise=False)
    except (PlannerError, BadRequest):
        return None
    return _Path(RuckigPath([fix], robot.nq), reference=ref)


FOLLOW_S = 0.1  # [s] the longest a reference is followed (its acceleration carried on that long)


def _chain(robot: Robot, parts: Sequence[Part], dt: float, rate_hz: float) -> Trajectory:
    """The parts one after the other, sampled every ``dt``: each for its cycles (the next one
    starts at the state it reaches), the last to its end; checked by the gate
    (:func:`planning.trajectory.build`): :class:`LimitError` if a sample breaks a limit."""
    counts = [
        whole_cycles(path.duration, dt) + 1 if k == len(parts) - 1 or cycles is None else cycles
        for k, (path, cycles) in enumerate(parts)
    ]
    total = sum(counts)
    P, V, A = np.empty((total, robot.nq)), np.empty((total, robot.nq)), np.empty((total, robot.nq))
    starts: list[tuple[float, _Path]] = []
    row = 0
    for (path, _), n in zip(parts, counts, strict=True):
        ruck = path.path
        evaluate_part(ruck.tables, ruck.starts, ruck.durations, n, dt, path.motion, P, V, A, row)
        starts.append((row * dt, path))
        row += n
    times = np.arange(total, dtype=float) * dt

    def at(t: float) -> tuple[FloatArray, FloatArray, FloatArray]:
        for begin, path in reversed(starts):
            if t >= begin:
                return path.at(t - begin)
        return starts[0][1].at(t)

    return build(robot, "track", rate_hz, float(times[-1]), times, P, V, A, at)


__all__ = ["Step", "track_step"]
