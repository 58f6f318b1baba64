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
ends satisfied everywhere between them.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import ruckig
from numpy.typing import NDArray

from robots import ArmdError, BadRequest, Robot

from .state import JointState

FloatArray = NDArray[np.float64]


class PlannerError(ArmdError):
    """Ruckig could not compute a segment (reported as ``internal``: a bug or a corner case)."""


@dataclass(frozen=True)
class Limits:
    """Kinematic limits for Ruckig, scaled by ``speed`` in (0, 1] (time scaling: v*s, a*s^2, j*s^3)."""

    velocity: FloatArray
    acceleration: FloatArray
    jerk: FloatArray

    @classmethod
    def of(cls, robot: Robot, speed: float) -> Limits:
        lim = robot.limits
        return cls(lim.velocity * speed, lim.acceleration * speed**2, lim.jerk * speed**3)


class RuckigPath:
    """A chain of Ruckig segments, evaluated at any time [s] from the start."""

    def __init__(self, segments: Sequence[ruckig.Trajectory], nq: int) -> None:
        self.segments = list(segments)
        self.nq = nq
        self.starts = np.cumsum([0.0] + [s.duration for s in self.segments[:-1]])
        self.duration = float(sum(s.duration for s in self.segments))

    def at(self, t: float) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Position [rad], velocity [rad/s], acceleration [rad/s^2] at time ``t`` (clamped to the path)."""
        t = min(max(t, 0.0), self.duration)
        k = int(np.searchsorted(self.starts, t, side="right")) - 1
        k = min(max(k, 0), len(self.segments) - 1)
        p, v, a = self.segments[k].at_time(t - self.starts[k])
        return np.array(p), np.array(v), np.array(a)

    def sample(self, times: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Position, velocity, acceleration at every time (sorted) [s]: each segment's jerk
        phases integrated in closed form, vectorised over the samples (what ``at_time``
        computes one call at a time)."""
        n = len(times)
        P, V, A = np.empty((n, self.nq)), np.empty((n, self.nq)), np.empty((n, self.nq))
        t = np.clip(times, 0.0, self.duration)
        seg = np.clip(np.searchsorted(self.starts, t, side="right") - 1, 0, len(self.segments) - 1)
        for k, traj in enumerate(self.segments):
            rows = np.flatnonzero(seg == k)
            if len(rows) == 0:
                continue
            local = np.minimum(t[rows] - self.starts[k], traj.duration)
            p, v, a = _evaluate(_phase_table(traj.profiles[0]), local)
            P[rows], V[rows], A[rows] = p, v, a
        return P, V, A


def _phases(prof: ruckig.Profile) -> FloatArray:
    """Rows (duration, jerk, a0, v0, p0) of one degree of freedom's profile: the brake
    pre-profile, the seven main phases, the acceleration post-profile, then the end state
    carried on at constant acceleration (as Ruckig's ``at_time`` does past the end)."""
    main = np.array((prof.t, prof.j, prof.a[:7], prof.v[:7], prof.p[:7])).T
    brake, accel = prof.brake, prof.accel
    parts = [main]
    if brake.duration > 0:
        parts.insert(0, np.array((brake.t, brake.j, brake.a, brake.v, brake.p)).T)
    if accel.duration > 0:
        parts.append(np.array((accel.t, accel.j, accel.a, accel.v, accel.p)).T)
    rows = parts[0] if len(parts) == 1 else np.concatenate(parts)
    T, j, a0, v0, p0 = rows[-1].tolist()
    end = (np.inf, 0.0, a0 + T * j, v0 + T * (a0 + T * j / 2), p0 + T * (v0 + T * (a0 / 2 + T * j / 6)))
    out = np.empty((len(rows) + 1, 5))
    out[:-1] = rows
    out[-1] = end
    return out


def _phase_table(profiles: Sequence[ruckig.Profile]) -> FloatArray:
    """Every degree of freedom's phase rows, padded in front with empty phases to one length:
    shape (dofs, phases, 5)."""
    tables = [_phases(p) for p in profiles]
    width = max(len(t) for t in tables)
    out = np.zeros((len(tables), width, 5))
    for d, t in enumerate(tables):
        out[d, width - len(t):] = t  # zero-length phases first: they start where the next one does
    return out


def _evaluate(table: FloatArray, t: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Integrate every degree of freedom's constant-jerk phases to the times ``t`` [s]:
    position, velocity, acceleration, each (len(t), dofs)."""
    starts = np.concatenate([np.zeros((table.shape[0], 1)), np.cumsum(table[:, :-1, 0], axis=1)], axis=1)
    k = (t[None, :, None] >= starts[:, None, :]).sum(axis=2) - 1  # (dofs, samples): the phase each is in
    d = np.arange(table.shape[0])[:, None]
    row = table[d, k]  # (dofs, samples, 5)
    dt = t[None, :] - starts[d, k]
    j, a0, v0, p0 = row[..., 1], row[..., 2], row[..., 3], row[..., 4]
    p = p0 + dt * (v0 + dt * (a0 / 2 + dt * j / 6))
    v = v0 + dt * (a0 + dt * j / 2)
    a = a0 + dt * j
    return p.T, v.T, a.T


def _segment(otg: ruckig.Ruckig, start: JointState, goal: FloatArray, goal_velocity: FloatArray,
             limits: Limits, interface_velocity: bool = False, synchronise: bool = True) -> ruckig.Trajectory:
    n = len(goal)
    inp = ruckig.InputParameter(n)
    inp.current_position = start.position.tolist()
    inp.current_velocity = start.velocity.tolist()
    inp.current_acceleration = start.acceleration.tolist()
    inp.max_velocity = limits.velocity.tolist()
    inp.max_acceleration = limits.acceleration.tolist()
    inp.max_jerk = limits.jerk.tolist()
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
        at_rest = not start.moving and not np.any(goal_velocity)
        if not synchronise:
            inp.synchronization = ruckig.Synchronization.No
        else:
            inp.synchronization = ruckig.Synchronization.Phase if at_rest else ruckig.Synchronization.Time
    traj = ruckig.Trajectory(n)
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
            raise BadRequest("the motion would last longer than Ruckig can time (about 7,600 s): raise speed",
                             field="speed") from None
        raise PlannerError(f"Ruckig could not compute the segment: {e}") from None
    if result not in (ruckig.Result.Working, ruckig.Result.Finished):
        raise PlannerError(f"Ruckig could not compute the segment: {result}")


def _within(traj: ruckig.Trajectory, robot: Robot, dt: float) -> bool:
    """The segment's position extrema stay inside the box limits, and its samples inside the
    coupled limits."""
    lim = robot.limits
    if not all(lim.lower[i] - 1e-9 <= e.min and e.max <= lim.upper[i] + 1e-9
               for i, e in enumerate(traj.position_extrema)):
        return False
    if lim.coupled:
        for t in np.arange(0.0, traj.duration + dt / 2, dt).tolist():
            if not lim.contains(np.array(traj.at_time(min(t, traj.duration))[0]), tol=1e-9):
                return False
    return True


def _pass_velocity(prev: FloatArray, via: FloatArray, nxt: FloatArray, limits: Limits) -> FloatArray:
    """Pass-through velocity at ``via`` [rad/s]: zero where the joint turns back or rests,
    otherwise the smaller of the two neighbouring segments' rough mean speeds (each segment
    timed by its slowest joint), capped at half the velocity limit."""
    d1, d2 = via - prev, nxt - via
    t1 = float(np.max(np.abs(d1) / limits.velocity)) or 1.0
    t2 = float(np.max(np.abs(d2) / limits.velocity)) or 1.0
    same = (np.sign(d1) == np.sign(d2)) & (d1 != 0) & (d2 != 0)
    speed = np.minimum(np.abs(d1) / t1, np.abs(d2) / t2)
    return np.where(same, np.sign(d2) * np.minimum(speed, 0.5 * limits.velocity), 0.0)


def joint_path(robot: Robot, start: JointState, goals: Sequence[FloatArray], speed: float,
               dt: float) -> RuckigPath:
    """Through every goal in order, ending at rest on the last; waypoints passed without
    stopping where that is possible."""
    limits = Limits.of(robot, speed)
    otg = ruckig.Ruckig(robot.nq, dt)
    segments: list[ruckig.Trajectory] = []
    state = start
    prev = start.position
    if start.moving:  # from a moving state: straight on if that stays inside the limits
        first_v = np.zeros(robot.nq) if len(goals) == 1 else _pass_velocity(prev, goals[0], goals[1], limits)
        faster = bool(np.any(np.abs(start.velocity) > limits.velocity)
                      or np.any(np.abs(start.acceleration) > limits.acceleration))
        try:
            direct: ruckig.Trajectory | None = _segment(otg, start, goals[0], first_v, limits)
        except (PlannerError, BadRequest):
            if not faster:
                raise
            # moving faster than ``speed`` allows, and braking within the slowed limits is more
            # than Ruckig can time (at speed 0.01, hours): brake with the full limits instead
            direct = None
        if direct is None or not _within(direct, robot, dt):  # brake to rest first, then go (never through a limit)
            brake = _brake(otg, robot, start, dt)
            segments.append(brake)
            p, _, _ = brake.at_time(brake.duration)
            state = JointState.at_rest(np.array(p))
            prev = state.position
    for k, goal in enumerate(goals):
        last = k == len(goals) - 1
        v = np.zeros(robot.nq) if last else _pass_velocity(prev, goal, goals[k + 1], limits)
        traj = _segment(otg, state, goal, v, limits)
        if np.any(v) and not _within(traj, robot, dt):  # passing through would overshoot: stop there
            v = np.zeros(robot.nq)
            traj = _segment(otg, state, goal, v, limits)
        segments.append(traj)
        p, vel, acc = traj.at_time(traj.duration)
        state = JointState(np.array(p), np.array(vel), np.array(acc))
        prev = goal
    return RuckigPath(segments, robot.nq)


def _brake(otg: ruckig.Ruckig, robot: Robot, start: JointState, dt: float) -> ruckig.Trajectory:
    """To rest, each joint as fast as its (full) limits allow. The fastest stop is not always
    the shortest: where it would cross a position limit, stop instead at the nearest point
    inside the limits, still unsynchronised."""
    limits = Limits.of(robot, 1.0)
    zero = np.zeros(robot.nq)
    traj = _segment(otg, start, start.position, zero, limits, interface_velocity=True)
    if _within(traj, robot, dt):
        return traj
    end = np.clip(np.array(traj.at_time(traj.duration)[0]), robot.limits.lower, robot.limits.upper)
    held = _segment(otg, start, end, zero, limits, synchronise=False)
    return held if _within(held, robot, dt) else traj  # (the safety gate reports the latter)


def stop_path(robot: Robot, start: JointState, dt: float) -> RuckigPath:
    """From ``start`` to rest as fast as the (full) limits allow, jerk-limited."""
    return RuckigPath([_brake(ruckig.Ruckig(robot.nq, dt), robot, start, dt)], robot.nq)


def whole_cycles(duration: float, dt: float) -> int:
    """Number of control cycles covering ``duration`` [s] (rounded up, robust to rounding)."""
    return max(0, math.ceil(duration / dt - 1e-9))
