"""Joint-space motion with Ruckig: point to point, waypoint chains, and stops.

Ruckig Community computes one time-optimal, jerk-limited segment from any state (the arm
may be moving) to a target state. Its intermediate waypoints call a cloud service (Pro),
so armd chains segments itself: each waypoint becomes a segment target with a pass-through
velocity chosen so the arm does not stop where it need not (same direction of travel on
both sides), and with zero velocity where it must (direction changes, or the pass-through
would overshoot a position limit). Segment durations are whole control cycles
(``DurationDiscretization.Discrete``), so a trajectory ends on a sample.

Rest-to-rest segments use phase synchronisation: all joints move on the straight line in
joint space between start and goal, which keeps linear (coupled) limits that hold at both
ends satisfied everywhere between them. Where Ruckig cannot synchronise the phases it falls
back to time synchronisation, off the line (the safety gate checks every sample regardless);
:func:`straight_path` times segments exactly on their lines (paths round obstacles).
"""

from __future__ import annotations

import functools
import math
import threading
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import ruckig

from armd.errors import BadRequest, PlannerError
from armd.robots import Robot
from armd.robots.types import FloatArray

from .compiled import evaluate, inside
from .state import JointState


@dataclass(frozen=True)
class Limits:
    """Kinematic limits for Ruckig, scaled by ``speed`` in (0, 1] (time scaling: v*s, a*s^2, j*s^3)."""

    velocity: FloatArray
    acceleration: FloatArray
    jerk: FloatArray

    @functools.cached_property
    def lists(self) -> tuple[list[float], list[float], list[float]]:
        """The three as lists, as Ruckig's input takes them (the instances are cached per speed)."""
        return self.velocity.tolist(), self.acceleration.tolist(), self.jerk.tolist()

    @classmethod
    def of(cls, robot: Robot, speed: float) -> Limits:
        key = (id(robot), speed)
        held = _limits.get(key)
        if held is not None and held[0] is robot:
            return held[1]
        lim = robot.limits
        limits = cls(lim.velocity * speed, lim.acceleration * speed**2, lim.jerk * speed**3)
        if len(_limits) > 1024:  # speeds are free numbers: keep the cache small
            _limits.clear()
        _limits[key] = (robot, limits)
        return limits


_limits: dict[tuple[int, float], tuple[Robot, Limits]] = {}


class RuckigPath:
    """A chain of Ruckig segments, evaluated at any time [s] from the start."""

    def __init__(self, segments: Sequence[ruckig.Trajectory], nq: int, tables: FloatArray | None = None) -> None:
        self.segments = list(segments)
        self.nq = nq
        durations = [s.duration for s in self.segments]
        starts = [0.0]
        for d in durations[:-1]:
            starts.append(starts[-1] + d)
        self.durations = np.array(durations)
        self.starts = np.array(starts)
        self.duration = float(sum(durations))
        self._tables: FloatArray | None = tables  # (the segments' own, when the caller read them already)

    def at(self, t: float) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Position [rad], velocity [rad/s], acceleration [rad/s^2] at time ``t`` (clamped to the path)."""
        t = min(max(t, 0.0), self.duration)
        k = int(np.searchsorted(self.starts, t, side="right")) - 1
        k = min(max(k, 0), len(self.segments) - 1)
        p, v, a = self.segments[k].at_time(t - self.starts[k])
        return np.array(p), np.array(v), np.array(a)

    def sample(
        self, times: FloatArray, dt: float | None = None
    ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
        """Position, velocity, acceleration at every time (sorted) [s], and the jerk as the
        forward difference of the acceleration over ``dt`` (default: the times' spacing):
        each segment's jerk phases integrated in closed form (what ``at_time`` computes one
        call at a time), compiled (:func:`planning.compiled.evaluate`)."""
        n = len(times)
        if dt is None:
            dt = float(times[1] - times[0]) if n > 1 else 1.0
        P, V, A, Jk = (np.empty((n, self.nq)) for _ in range(4))
        evaluate(self.tables, self.starts, self.durations, np.asarray(times, dtype=float), dt, P, V, A, Jk)
        return P, V, A, Jk

    @property
    def tables(self) -> FloatArray:
        """Every segment's phase table, padded to one width: (segments, dofs, phases, 5)."""
        if self._tables is None:
            self._tables = self._phase_tables()
        return self._tables

    def _phase_tables(self) -> FloatArray:
        return phase_tables(self.segments, self.nq)


def phase_tables(segments: Sequence[Any], nq: int) -> FloatArray:
    """Every segment's phase table, padded to one width: (segments, dofs, phases, 5), rows
    (duration, jerk, a0, v0, p0), what :func:`planning.compiled.evaluate` takes."""
    profiles = [seg.profiles[0] for seg in segments]
    if all(p.brake.duration <= 0 and p.accel.duration <= 0 for ps in profiles for p in ps):
        flat: list[float] = []  # the common case: seven phases per dof, read as five lists each
        for ps in profiles:
            for p in ps:
                flat += p.t
                flat += p.j
                flat += p.a[:7]
                flat += p.v[:7]
                flat += p.p[:7]
        # (contiguous, as the general case below: one compiled specialisation, not two)
        return np.ascontiguousarray(np.array(flat).reshape(len(profiles), nq, 5, 7).transpose(0, 1, 3, 2))
    rows = [[_phases(prof) for prof in ps] for ps in profiles]
    width = max(len(r) for seg in rows for r in seg)
    flat = []
    for seg in rows:
        for r in seg:  # zero-length phases first: they start where the next one does
            flat += [0.0] * (5 * (width - len(r)))
            for row in r:
                flat += row
    return np.array(flat).reshape(len(rows), nq, width, 5)


def _phases(prof: ruckig.Profile) -> list[tuple[float, float, float, float, float]]:
    """Rows (duration, jerk, a0, v0, p0) of one degree of freedom's profile: the brake
    pre-profile, the seven main phases, then the acceleration post-profile. (Past the last
    row, :func:`planning.compiled.evaluate` carries the end state on.)"""
    rows: list[tuple[float, float, float, float, float]] = []
    brake = prof.brake
    if brake.duration > 0:
        rows += zip(brake.t, brake.j, brake.a, brake.v, brake.p, strict=False)
    rows += zip(prof.t, prof.j, prof.a, prof.v, prof.p, strict=False)  # a, v, p have an 8th entry (the end)
    accel = prof.accel
    if accel.duration > 0:
        rows += zip(accel.t, accel.j, accel.a, accel.v, accel.p, strict=False)
    return rows


def _segment(
    otg: ruckig.Ruckig,
    start: JointState,
    goal: FloatArray,
    goal_velocity: FloatArray,
    limits: Limits,
    interface_velocity: bool = False,
    synchronise: bool = True,
) -> ruckig.Trajectory:
    n = len(goal)
    inp = ruckig.InputParameter(n)
    inp.current_position = start.position.tolist()
    inp.current_velocity = start.velocity.tolist()
    inp.current_acceleration = start.acceleration.tolist()
    inp.max_velocity, inp.max_acceleration, inp.max_jerk = limits.lists
    inp.duration_discretization = ruckig.DurationDiscretization.Discrete
    if interface_velocity:  # a stop: every joint brakes as hard as it may, not waiting for the others
        inp.control_interface = ruckig.ControlInterface.Velocity
        inp.synchronization = ruckig.Synchronization.No
        inp.target_velocity = [0.0] * n
        inp.target_acceleration = [0.0] * n
    else:
        inp.target_position = goal.tolist()
        inp.target_velocity = goal_velocity.tolist()
        inp.target_acceleration = [0.0] * n
        at_rest = not start.moving and not any(goal_velocity.tolist())
        if not synchronise:
            inp.synchronization = ruckig.Synchronization.No
        else:
            inp.synchronization = ruckig.Synchronization.Phase if at_rest else ruckig.Synchronization.Time
    traj = ruckig.Trajectory(n)
    try:
        calculate(otg, inp, traj)
    except PlannerError:  # (Ruckig's whole-cycle search fails on some states at a limit exactly: timed freely)
        inp.duration_discretization = ruckig.DurationDiscretization.Continuous
        calculate(otg, inp, traj)
    return traj


def calculate(otg: ruckig.Ruckig, inp: ruckig.InputParameter, traj: ruckig.Trajectory) -> None:
    """``otg.calculate``, its failures turned into armd's errors: a motion too slow for Ruckig
    to time is the caller's :class:`BadRequest` (``speed``), anything else a :class:`PlannerError`."""
    try:
        result = otg.calculate(inp, traj)
    except (RuntimeError, ruckig.RuckigError) as e:  # Ruckig raises on input it cannot handle
        raise PlannerError(f"Ruckig rejected the segment: {e}") from None
    except ValueError as e:  # a result code the binding has no name for: "-101 is not a valid Result"
        if str(e).startswith("-101 "):  # ErrorTrajectoryDuration: longer than Ruckig's numerical range
            raise BadRequest(
                "the motion would last longer than Ruckig can time (about 7,600 s): raise speed", field="speed"
            ) from None
        raise PlannerError(f"Ruckig could not compute the segment: {e}") from None
    if result not in (ruckig.Result.Working, ruckig.Result.Finished):
        raise PlannerError(f"Ruckig could not compute the segment: {result}")


def _within(traj: Any, robot: Robot, dt: float) -> FloatArray | None:
    """The segment's phase tables (:func:`phase_tables`) if its positions stay inside the box
    limits (its extrema, exactly) and its samples inside the coupled limits; else None."""
    tables = phase_tables([traj], robot.nq)
    lim = robot.limits
    if not inside(tables, lim.lower, lim.upper, 1e-9):
        return None
    if lim.coupled:
        n = whole_cycles(traj.duration, dt) + 1
        P, V, A, J = (np.empty((n, robot.nq)) for _ in range(4))
        zero = np.zeros(1)
        evaluate(tables, zero, np.array([traj.duration]), np.arange(n, dtype=float) * dt, dt, P, V, A, J)
        if not lim.contains_batch(P).all():
            return None
    return tables


def _pass_velocity(prev: FloatArray, via: FloatArray, nxt: FloatArray, limits: Limits) -> FloatArray:
    """Pass-through velocity at ``via`` [rad/s]: along the path's tangent there (the way from
    ``prev`` to ``nxt`` over the two segments' rough times, each timed by its slowest joint at
    its velocity limit), slowed as a whole to half the velocity limits and so that each joint
    could brake from it to rest within a quarter of the shorter of its two segments (a faster
    pass overshoots the waypoint and comes back to it, slower overall and off the path); zero
    for a joint that turns back or rests there."""
    d1, d2 = via - prev, nxt - via
    t1 = float(np.max(np.abs(d1) / limits.velocity)) or 1.0
    t2 = float(np.max(np.abs(d2) / limits.velocity)) or 1.0
    same = (np.sign(d1) == np.sign(d2)) & (d1 != 0) & (d2 != 0)
    v = np.where(same, (d1 + d2) / (t1 + t2), 0.0)
    room = np.minimum(np.abs(d1), np.abs(d2))
    cap = np.minimum(0.5 * limits.velocity, np.sqrt(0.5 * limits.acceleration * room))  # (v^2 / 2a = room / 4)
    moving = np.abs(v) > 0.0
    scale = float(np.min(cap[moving] / np.abs(v[moving]), initial=1.0)) if np.any(moving) else 1.0
    return v * min(scale, 1.0)


class _Calculators(threading.local):
    def __init__(self) -> None:
        self.by_size: dict[tuple[int, float], ruckig.Ruckig] = {}


_calculators = _Calculators()


def _otg(nq: int, dt: float) -> ruckig.Ruckig:
    """This thread's Ruckig calculator for ``nq`` dofs at cycle ``dt`` (one per thread: it
    keeps scratch state between calls)."""
    otg = _calculators.by_size.get((nq, dt))
    if otg is None:
        otg = _calculators.by_size[(nq, dt)] = ruckig.Ruckig(nq, dt)
    return otg


class _ScaledProfile:
    """One joint's phases on a straight segment: the path parameter's profile times the joint's
    share of the move (what RuckigPath's phase tables read of a Ruckig profile)."""

    def __init__(self, base: ruckig.Profile, start: float, delta: float) -> None:
        self.t = list(base.t)
        self.j = [delta * x for x in base.j]
        self.a = [delta * x for x in base.a]
        self.v = [delta * x for x in base.v]
        self.p = [start + delta * x for x in base.p]
        self.brake, self.accel = base.brake, base.accel


class _Straight:
    """A rest-to-rest segment exactly on the straight joint move from ``start`` to ``goal``: one
    jerk-limited Ruckig profile of the path parameter s in [0, 1] (q = start + s (goal - start)),
    its limits the tightest of the joints' (each joint's v, a, j over its share). Ruckig's own
    phase synchronisation falls back to time synchronisation, off the line, when it cannot
    synchronise the phases (seen 0.06 rad off); a path round an obstacle must stay on it."""

    def __init__(self, start: FloatArray, goal: FloatArray, limits: Limits, dt: float) -> None:
        self.start, self.delta = np.array(start, dtype=float), np.asarray(goal, dtype=float) - start
        share = np.abs(self.delta)
        moving = share > 0.0
        inp = ruckig.InputParameter(1)
        inp.current_position, inp.target_position = [0.0], [1.0]
        inp.max_velocity = [float(np.min(limits.velocity[moving] / share[moving]))]
        inp.max_acceleration = [float(np.min(limits.acceleration[moving] / share[moving]))]
        inp.max_jerk = [float(np.min(limits.jerk[moving] / share[moving]))]
        inp.duration_discretization = ruckig.DurationDiscretization.Discrete
        self.scalar = ruckig.Trajectory(1)
        calculate(_otg(1, dt), inp, self.scalar)
        self.duration = self.scalar.duration
        base = self.scalar.profiles[0][0]
        self.profiles = [
            [_ScaledProfile(base, float(p0), float(d)) for p0, d in zip(self.start, self.delta, strict=True)]
        ]

    def at_time(self, t: float) -> tuple[list[float], list[float], list[float]]:
        p, v, a = self.scalar.at_time(t)
        return (
            (self.start + p[0] * self.delta).tolist(),
            (v[0] * self.delta).tolist(),
            (a[0] * self.delta).tolist(),
        )


def straight_path(robot: Robot, start: FloatArray, points: Sequence[FloatArray], speed: float, dt: float) -> RuckigPath:
    """From rest at ``start`` through every point at rest, each segment exactly the straight joint
    move between its ends (:class:`_Straight`): a joint path the clearance of whose straight
    moves was checked keeps it once timed."""
    limits = Limits.of(robot, speed)
    segments: list[Any] = []
    prev = np.asarray(start, dtype=float)
    for point in points:
        if np.any(np.asarray(point) != prev):
            segments.append(_Straight(prev, point, limits, dt))
            prev = np.asarray(point, dtype=float)
    return RuckigPath(segments, robot.nq)


def joint_path(robot: Robot, start: JointState, goals: Sequence[FloatArray], speed: float, dt: float) -> RuckigPath:
    """Through every goal in order, ending at rest on the last; waypoints passed without
    stopping where that is possible."""
    limits = Limits.of(robot, speed)
    otg = _otg(robot.nq, dt)
    segments: list[ruckig.Trajectory] = []
    tables: list[FloatArray | None] = []  # (each segment's, where read already)
    state = start
    prev = start.position
    direct: ruckig.Trajectory | None = None
    if start.moving:  # from a moving state: straight on if that stays inside the limits
        first_v = np.zeros(robot.nq) if len(goals) == 1 else _pass_velocity(prev, goals[0], goals[1], limits)
        faster = bool(
            np.any(np.abs(start.velocity) > limits.velocity) or np.any(np.abs(start.acceleration) > limits.acceleration)
        )
        try:
            direct = _segment(otg, start, goals[0], first_v, limits)
        except (PlannerError, BadRequest):
            if not faster:
                raise
            # moving faster than ``speed`` allows, and braking within the slowed limits is more
            # than Ruckig can time (at speed 0.01, hours): brake with the full limits instead
            direct = None
        direct_tables = _within(direct, robot, dt) if direct is not None else None
        if direct_tables is None:  # brake to rest first, then go (never through a limit)
            direct = None
            brake, brake_tables = _brake(otg, robot, start, dt)
            segments.append(brake)
            tables.append(brake_tables)
            p, _, _ = brake.at_time(brake.duration)
            state = JointState.at_rest(np.array(p))
            prev = state.position
    for k, goal in enumerate(goals):
        last = k == len(goals) - 1
        if k == 0 and direct is not None:  # (straight on from the moving start: computed above, and inside)
            segments.append(direct)
            tables.append(direct_tables)
            traj = direct
        else:
            v = np.zeros(robot.nq) if last else _pass_velocity(prev, goal, goals[k + 1], limits)
            traj = _segment(otg, state, goal, v, limits)
            held = None
            if not last and any(v.tolist()):
                held = _within(traj, robot, dt)
                if held is None:  # passing would overshoot: stop there
                    traj = _segment(otg, state, goal, np.zeros(robot.nq), limits)
            segments.append(traj)
            tables.append(held)
        if not last:  # where the next segment starts
            p, vel, acc = traj.at_time(traj.duration)
            state = JointState(np.array(p), np.array(vel), np.array(acc))
        prev = goal
    known = tables[0] if len(tables) == 1 else None
    return RuckigPath(segments, robot.nq, known)


def _brake(
    otg: ruckig.Ruckig, robot: Robot, start: JointState, dt: float
) -> tuple[ruckig.Trajectory, FloatArray | None]:
    """To rest, each joint as fast as its (full) limits allow. The fastest stop is not always
    the shortest: where it would cross a position limit, stop instead at the nearest point
    inside the limits, still unsynchronised. With its phase tables, if they were read."""
    limits = Limits.of(robot, 1.0)
    zero = np.zeros(robot.nq)
    traj = _segment(otg, start, start.position, zero, limits, interface_velocity=True)
    tables = _within(traj, robot, dt)
    if tables is not None:
        return traj, tables
    end = robot.limits.clip(np.array(traj.at_time(traj.duration)[0]))
    held = _segment(otg, start, end, zero, limits, synchronise=False)
    tables = _within(held, robot, dt)
    return (held, tables) if tables is not None else (traj, None)  # (the safety gate reports the latter)


def stop_path(robot: Robot, start: JointState, dt: float) -> RuckigPath:
    """From ``start`` to rest as fast as the (full) limits allow, jerk-limited."""
    traj, tables = _brake(_otg(robot.nq, dt), robot, start, dt)
    return RuckigPath([traj], robot.nq, tables)


def whole_cycles(duration: float, dt: float) -> int:
    """Number of control cycles covering ``duration`` [s] (rounded up, robust to rounding)."""
    return max(0, math.ceil(duration / dt - 1e-9))
