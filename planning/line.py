"""Straight Cartesian lines: the tool point moves on the segment from start to goal.

1. The geometric path: IK on a grid along the segment (every ``GRID_STEP`` m), each seeded
   by the previous answer, with the tool pitch interpolated from the start's to the goal's
   (wrist arms), and where the goal asks a tool roll, the wrist roll joint's angle from the
   start's to the one that gives it (the turn nearest the start's, within its limits). A grid
   point the IK cannot reach exactly, or a jump in joint space (a branch flip: elbow up to
   down, the yaw swinging round), rejects the line with the reason and where it happens.
2. The timing: a jerk-limited profile of the path parameter s (Ruckig, one degree of
   freedom, from rest to rest), its velocity, acceleration and jerk limits derived from the
   joints' limits and the path's joint-space derivatives, scaled by ``speed``.
3. The samples: IK at each control cycle's s (on the line to the IK's 1e-9 m), joint
   velocity, acceleration and jerk by finite differences. If any exceeds a limit, the whole
   profile is slowed (time scaling) and sampled again.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import ruckig

from armd.errors import BadRequest, PlanRejected, TrajectoryTooLong
from armd.robots import Robot
from armd.robots.angles import wrap, wrap_array
from armd.robots.types import FloatArray
from armd.solvers import solve_ik, solve_ik_batch

from .ruckig_path import RuckigPath, calculate, whole_cycles
from .state import JointState
from .trajectory import Evaluator, forward_jerk

GRID_STEP = 0.005  # [m] spacing of the geometric pass
MAX_JUMP = 0.25  # [rad] a joint moving more than this between grid points: a branch flip
SLOWDOWNS = 16  # how many times the timing may be slowed by SLOWDOWN before giving up
SLOWDOWN = 0.8


class LinePath:
    """The line's geometry: endpoints, pitch and roll interpolation, and IK at any path parameter."""

    def __init__(
        self,
        robot: Robot,
        start: JointState,
        goal: FloatArray,
        goal_pitch: float | None,
        goal_roll: float | None = None,
    ) -> None:
        self.robot = robot
        self.q0 = start.position
        self.p0 = robot.fk(self.q0)
        self.p1 = np.asarray(goal, dtype=float)
        self.length = float(np.linalg.norm(self.p1 - self.p0))
        g = robot.geometry
        self.has_pitch = g is not None and g.has_wrist
        self.pitch0 = robot.tool_pitch(self.q0) if self.has_pitch else 0.0
        asked = self.pitch0 if goal_pitch is None else goal_pitch
        self.dpitch = wrap(asked - self.pitch0) if self.has_pitch else 0.0
        # the asked roll: the roll joint's angle held along the line, from the start's to the goal's
        self.roll_index = -1
        self.roll0 = self.roll1 = 0.0
        if goal_roll is not None:
            self.roll1 = robot.roll_angle(goal_roll, self.q0)  # (BadRequest: no such roll, or out of its reach)
            assert robot.roll_joint is not None
            self.roll_index = robot.roll_joint.index
            self.roll0 = float(self.q0[self.roll_index])
            if self.length == 0.0 and abs(self.roll1 - self.roll0) > 1e-12:
                raise BadRequest(
                    "a line that does not move the tool point cannot turn the roll: plan a joint path", field="goal"
                )

    def rolls(self, ss: FloatArray) -> FloatArray:
        """The roll joint's angle [rad] at each path parameter (an asked roll only)."""
        f = np.zeros_like(ss) if self.length == 0 else ss / self.length
        return self.roll0 + f * (self.roll1 - self.roll0)

    def point(self, s: float) -> FloatArray:
        f = 0.0 if self.length == 0 else s / self.length
        return self.p0 + f * (self.p1 - self.p0)

    def pitch(self, s: float) -> float | None:
        if not self.has_pitch:
            return None
        f = 0.0 if self.length == 0 else s / self.length
        return wrap(self.pitch0 + f * self.dpitch)

    def points(self, ss: FloatArray) -> FloatArray:
        f = np.zeros_like(ss) if self.length == 0 else ss / self.length
        return self.p0 + f[:, None] * (self.p1 - self.p0)

    def pitches(self, ss: FloatArray) -> FloatArray | None:
        if not self.has_pitch:
            return None
        f = np.zeros_like(ss) if self.length == 0 else ss / self.length
        return wrap_array(self.pitch0 + f * self.dpitch)

    def ik_many(self, ss: FloatArray, seeds: FloatArray) -> FloatArray:
        """IK at every path parameter (batch), each from its seed row; refuses the line at the
        first point that is not reached exactly (with the asked roll: the batch keeps each
        seed's roll where the target is reachable with it, and the seeds hold the line's)."""
        ri = self.roll_index
        if ri >= 0:
            seeds = np.array(seeds, dtype=float)
            seeds[:, ri] = self.rolls(ss)
        # (IK as if the arm had no world: the line's motion is checked whole once timed, and a
        # branch the world would pick instead would be a branch flip)
        r = solve_ik_batch(self.robot, self.points(ss), approach=self.pitches(ss), seeds=seeds, collisions=False)
        ok = r.status == "ok"
        if ri >= 0:
            ok &= np.abs(r.q[:, ri] - seeds[:, ri]) <= 1e-9
        bad = np.flatnonzero(~ok)
        if len(bad):
            i = int(bad[0])
            self.ik(float(ss[i]), seeds[i])  # raises with the single solver's reason
        return r.q

    def ik(self, s: float, seed: FloatArray) -> FloatArray:
        roll = None
        if self.roll_index >= 0:
            seed = np.array(seed, dtype=float)
            seed[self.roll_index] = self.rolls(np.array([s]))[0]
            roll = self.robot.tool_roll(seed)
        r = solve_ik(self.robot, self.point(s), approach=self.pitch(s), seed=seed, roll=roll, collisions=False)
        if r.status != "ok":
            raise PlanRejected(
                f"the line leaves the reachable space {s:.4f} m from the start at {self.point(s).round(4).tolist()}: "
                f"{r.reason}",
                s=s,
                point=self.point(s).tolist(),
            )
        return r.q


def _jump(qs: FloatArray) -> tuple[int, int, float] | None:
    """The first consecutive pair of rows more than MAX_JUMP apart: (row, joint, jump), or None."""
    jumps = np.abs(np.diff(qs, axis=0))
    over = np.argwhere(jumps > MAX_JUMP)
    if not len(over):
        return None
    k, j = (int(v) for v in over[0])
    return k + 1, j, float(jumps[k, j])


def _grid(line: LinePath) -> tuple[FloatArray, FloatArray]:
    """IK on the grid: all at once from the start's configuration (the branch nearest it), and
    where that is not continuous, point by point, each seeded by the last."""
    n = max(2, math.ceil(line.length / GRID_STEP) + 1)
    n = max(n, math.ceil(abs(line.roll1 - line.roll0) / (0.5 * MAX_JUMP)) + 1)  # an asked roll: small turns too
    ss = np.linspace(0.0, line.length, n)
    qs = line.ik_many(ss, np.broadcast_to(line.q0, (n, line.robot.nq)))
    qs[0] = line.q0
    if _jump(qs) is None:
        return ss, qs
    for k in range(1, n):
        qs[k] = line.ik(float(ss[k]), qs[k - 1])
    flip = _jump(qs)
    if flip is not None:
        k, j, size = flip
        raise PlanRejected(
            f"the line needs a branch flip {ss[k]:.4f} m from the start: joint "
            f"{line.robot.joint_names[j]!r} would jump {size:.3f} rad (elbow or yaw turning over)",
            s=float(ss[k]),
            joint=line.robot.joint_names[j],
        )
    return ss, qs


def _path_limits(robot: Robot, ss: FloatArray, qs: FloatArray, speed: float) -> tuple[float, float, float]:
    """Velocity [m/s], acceleration [m/s^2] and jerk [m/s^3] limits of s that keep each joint
    within its limits, from the path derivatives dq/ds, d2q/ds2 on the grid."""
    lim = robot.limits
    if len(ss) < 3:
        return 1.0, 1.0, 1.0
    d1 = np.abs(np.gradient(qs, ss, axis=0)).max(axis=0) + 1e-9
    d2 = np.abs(np.gradient(np.gradient(qs, ss, axis=0), ss, axis=0)).max(axis=0) + 1e-9
    v = float(np.min(lim.velocity / d1))
    v = min(v, float(np.min(np.sqrt(0.5 * lim.acceleration / d2))))
    a = float(np.min(0.5 * lim.acceleration / d1))
    j = float(np.min(0.3 * lim.jerk / d1))
    return v * speed, a * speed**2, j * speed**3


def _profile(length: float, v: float, a: float, j: float, dt: float) -> ruckig.Trajectory:
    otg = ruckig.Ruckig(1, dt)
    inp = ruckig.InputParameter(1)
    inp.current_position, inp.current_velocity, inp.current_acceleration = [0.0], [0.0], [0.0]
    inp.target_position, inp.target_velocity, inp.target_acceleration = [length], [0.0], [0.0]
    inp.max_velocity, inp.max_acceleration, inp.max_jerk = [v], [a], [j]
    inp.duration_discretization = ruckig.DurationDiscretization.Discrete
    traj = ruckig.Trajectory(1)
    calculate(otg, inp, traj)
    return traj


def _derivatives(P: FloatArray, dt: float) -> tuple[FloatArray, FloatArray]:
    """Velocity and acceleration by central differences, the arm at rest before and after."""
    padded = np.vstack([P[:1], P, P[-1:]])
    V = (padded[2:] - padded[:-2]) / (2 * dt)
    A = (padded[2:] - 2 * padded[1:-1] + padded[:-2]) / (dt * dt)
    return V, A


def line_samples(
    robot: Robot,
    start: JointState,
    goal: FloatArray,
    goal_pitch: float | None,
    speed: float,
    rate_hz: float,
    *,
    max_samples: int | None = None,
    check: Callable[[], None] | None = None,
    goal_roll: float | None = None,
) -> tuple[float, FloatArray, FloatArray, FloatArray, FloatArray, Evaluator]:
    """(duration, times, position, velocity, acceleration, evaluator) of the line.

    ``goal_roll``: the tool roll [rad] to end at (an arm with a wrist roll), turned evenly
    along the line; None keeps the start's.

    ``max_samples``: refuse (:class:`TrajectoryTooLong`) a timing with more samples, before
    sampling it. ``check``: called between the passes (each an IK batch over every sample);
    whatever it raises abandons the line.
    """
    if start.moving:
        raise PlanRejected("a line starts with the arm at rest: stop first, or plan a joint path", field="start")
    line = LinePath(robot, start, goal, goal_pitch, goal_roll)
    dt = 1.0 / rate_hz
    ss, qs = _grid(line)
    v, a, j = _path_limits(robot, ss, qs, speed)
    lim = robot.limits
    for _ in range(SLOWDOWNS):
        if check is not None:
            check()
        prof = _profile(line.length, v, a, j, dt)
        k = whole_cycles(prof.duration, dt)
        if max_samples is not None and k + 1 > max_samples:
            raise TrajectoryTooLong(k + 1, max_samples, k * dt, rate_hz)
        times = np.arange(k + 1, dtype=float) * dt
        svals = RuckigPath([prof], 1).sample(times)[0][:, 0]
        nearest = np.clip(np.searchsorted(ss, svals), 0, len(ss) - 1)  # seed each sample from the grid
        P = line.ik_many(svals, qs[nearest])
        P[0] = line.q0
        V, A = _derivatives(P, dt)
        J = forward_jerk(A, dt)
        # the forward differences too: a controller that interpolates linearly between samples
        # (the SSC-32) moves at exactly those, and adapters check them (by motion, not as declared)
        if (
            np.all(np.abs(V) <= lim.velocity)
            and np.all(np.abs(A) <= lim.acceleration)
            and np.all(np.abs(J) <= lim.jerk)
            and np.all(np.abs(np.diff(P, axis=0)) <= lim.velocity * dt)
        ):
            break
        v, a, j = v * SLOWDOWN, a * SLOWDOWN**2, j * SLOWDOWN**3
    else:
        raise PlanRejected("the line cannot be timed within the joint limits (too close to a singularity)")

    duration = float(times[-1])

    def evaluate(t: float) -> tuple[FloatArray, FloatArray, FloatArray]:
        s = prof.at_time(min(max(t, 0.0), prof.duration))[0][0]
        i = min(round(t / dt), k)
        q = line.ik(s, P[i])
        f = min(max(t / dt, 0.0), float(k))
        lo = min(int(f), k - 1) if k > 0 else 0
        w = f - lo
        hi = min(lo + 1, k)
        return q, (1 - w) * V[lo] + w * V[hi], (1 - w) * A[lo] + w * A[hi]

    return duration, times, P, V, A, evaluate
