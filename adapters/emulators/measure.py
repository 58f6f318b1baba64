"""Measuring what reached a controller against the arm's limits (test and benchmark tools).

An emulator records what its board output (the SSC-32's exact pulse segments, GRBL's trace of
positions); these functions turn that into the arm's joint motion and say how it compares to
the limits: the promise an adapter keeps is that every joint stays within its position,
velocity and acceleration limits at every moment.

- :func:`ssc32_motion`: the joint path the SSC-32 emulator's channels drew, as breakpoints
  (the board's group moves are piecewise linear in pulses, hence in joints), with its jumps.
- :func:`grbl_motion`, :func:`fitted_peaks`: GRBL's trace of the arm, and its peak speed and
  acceleration fitted over a window (a stepper's whole steps are not its motion).
- :func:`ratios`: the worst velocity (exact, per linear piece) and acceleration (the change of
  speed between pieces) of a piecewise-linear joint path, as ratios of the limits, and the
  worst position excursion beyond the limits.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from armd.robots import Robot, Servo, Stepper
from armd.robots.types import FloatArray

from .grbl import GrblEmulator
from .ssc32 import SSC32Emulator

MIN_PIECE = 1e-4  # [s] pieces shorter than this are not counted as pieces of motion


@dataclass(frozen=True)
class Motion:
    """A joint path: positions [rad] at ``times`` [s], linear in between; ``jumps``: how many
    zero-time changes of position it has (a channel's first pulse, an immediate move)."""

    times: FloatArray
    position: FloatArray
    jumps: int

    def moving(self) -> tuple[float, float]:
        """When the path first and last changes [s] (both the first time if it never does)."""
        if len(self.times) < 2:
            return (float(self.times[0]), float(self.times[0])) if len(self.times) else (0.0, 0.0)
        changes = np.flatnonzero(np.any(np.abs(np.diff(self.position, axis=0)) > 1e-12, axis=1))
        if not len(changes):
            return float(self.times[0]), float(self.times[0])
        return float(self.times[changes[0]]), float(self.times[changes[-1] + 1])


@dataclass(frozen=True)
class Ratios:
    """The worst of a motion against the limits: ``velocity`` and ``acceleration`` as
    fractions of the limits (1.0: at a limit), the joints they were on, and ``outside`` [rad]:
    the farthest any joint went beyond its position limits (0 if never)."""

    velocity: float
    velocity_joint: str
    acceleration: float
    acceleration_joint: str
    outside: float


def ssc32_motion(robot: Robot, emulator: SSC32Emulator, since: float = -np.inf) -> Motion:
    """The joint path the emulator's output drew for ``robot``'s servo channels, from ``since``
    [s, the emulator's clock] to now; jumps (zero-length segments that change a pulse) counted."""
    servos = [a for a in robot.actuators.actuators if isinstance(a, Servo)]
    segs = {a.channel: emulator.segments(a.channel) for a in servos}
    edges = sorted({t for ss in segs.values() for s in ss for t in (s[0], s[1]) if t >= since})
    jumps = sum(1 for ss in segs.values() for s in ss if s[0] == s[1] and s[2] != s[3] and s[0] >= since)
    if not edges:
        return Motion(np.zeros(0), np.zeros((0, robot.nq)), jumps)
    times = np.array(edges, dtype=float)
    pulses = np.column_stack([_pulse_at(segs[a.channel], times) for a in servos])
    q = robot.actuators.joints_from_commands(pulses, tol=np.inf)
    return Motion(times, q, jumps)


def ssc32_speed_noise(robot: Robot, emulator: SSC32Emulator, since: float = -np.inf) -> FloatArray:
    """Per joint [rad/s]: how far rounding a group move's target to a whole microsecond (half a
    microsecond at most) moves its speed, over the shortest ``T`` the emulator received since
    ``since``: the rounding :func:`ratios` allows for."""
    times = [m.duration_ms for m in emulator.history if m.time >= since and m.duration_ms]
    shortest = min(times, default=1000) / 1000.0
    return 0.5 * pulse_resolution(robot) / shortest


def pulse_resolution(robot: Robot) -> FloatArray:
    """Per joint, how far one microsecond of any servo that moves it moves the joint [rad]."""
    M = np.abs(robot.actuators.M)
    res = np.array([a.resolution for a in robot.actuators.actuators])
    moved = M > 0
    return np.array(
        [float(np.max(res[moved[:, j]] / M[moved[:, j], j])) if moved[:, j].any() else 0.0 for j in range(robot.nq)]
    )


def _pulse_at(segments: list[tuple[float, float, float, float]], times: FloatArray) -> FloatArray:
    """A channel's pulse at each time: the last segment that covers it (after a jump, its end)."""
    out = np.zeros(len(times))
    if not segments:
        return out
    t0 = np.array([s[0] for s in segments])
    for i, t in enumerate(times):
        k = int(np.searchsorted(t0, t, side="right")) - 1
        if k < 0:
            out[i] = segments[0][2]
            continue
        a, b, p0, p1 = segments[k]
        out[i] = p1 if b <= a or t >= b else p0 + (p1 - p0) * (t - a) / (b - a)
    return out


def ratios(robot: Robot, motion: Motion, period: float, speed_noise: FloatArray | float = 0.0) -> Ratios:
    """The worst velocity and acceleration of ``motion`` against ``robot``'s limits.

    Velocity: exact, per linear piece. Acceleration: each change of speed (at a piece's end)
    over the time since the previous change, counted at most ``period`` [s] (the stream's sample
    period): the backward difference of the speed at the pieces' own spacing, where a piece held
    longer (the board idle, waiting for a late command) counts as one period, so that a restart
    at speed after a stall shows as the jump it is.

    ``speed_noise`` [rad/s], per joint: how far the controller's own rounding may move a piece's
    speed (the SSC-32's whole-microsecond targets: :func:`ssc32_speed_noise`); a change of speed
    is counted beyond twice that only.
    """
    lim = robot.limits
    names = robot.joint_names
    t, q = motion.times, motion.position
    outside = float(np.max(np.maximum(q - lim.upper, lim.lower - q), initial=0.0)) if len(q) else 0.0
    dt = np.diff(t)
    keep = dt > MIN_PIECE  # (two commands a few microseconds apart: one change, not a spike)
    if len(t) < 2 or not keep.any():
        return Ratios(0.0, names[0], 0.0, names[0], max(outside, 0.0))
    d = dt[keep]
    v = np.diff(q, axis=0)[keep] / d[:, None]
    vr = np.abs(v) / lim.velocity
    vj = int(np.argmax(np.max(vr, axis=0)))
    if len(d) < 2:
        return Ratios(float(np.max(vr)), names[vj], 0.0, names[0], max(outside, 0.0))
    dv = np.maximum(np.abs(np.diff(v, axis=0)) - 2.0 * np.asarray(speed_noise, dtype=float), 0.0)
    a = dv / np.minimum(d[:-1], period)[:, None]
    ar = np.abs(a) / lim.acceleration
    aj = int(np.argmax(np.max(ar, axis=0)))
    return Ratios(float(np.max(vr)), names[vj], float(np.max(ar)), names[aj], max(outside, 0.0))


def grbl_motion(robot: Robot, emulator: GrblEmulator) -> tuple[FloatArray, FloatArray]:
    """The GRBL emulator's record of the arm's physical motion: times [s] and each actuator's
    angle [deg] (GRBL's units), in the robot's actuator order."""
    trace = emulator.trace
    cols = [emulator.axes.index(a.axis) for a in robot.actuators.actuators if isinstance(a, Stepper)]
    return np.array([t for t, _ in trace]), np.array([[p[c] for c in cols] for _, p in trace]).reshape(-1, len(cols))


def span(t: FloatArray, p: FloatArray) -> tuple[float, float]:
    """When a recorded motion began and ended [s] (the first and last change of any column)."""
    if len(t) < 2:
        return (float(t[0]), float(t[0])) if len(t) else (0.0, 0.0)
    changes = np.flatnonzero(np.any(np.abs(np.diff(p, axis=0)) > 1e-12, axis=1))
    if not len(changes):
        return float(t[0]), float(t[0])
    return float(t[changes[0]]), float(t[changes[-1] + 1])


def fitted_peaks(t: FloatArray, p: FloatArray, window: float, dt: float = 0.002) -> tuple[FloatArray, FloatArray]:
    """Per column, the largest |velocity| and |acceleration| of a recorded motion: resampled every
    ``dt`` [s], then a least-squares parabola over each ``window`` [s]. (A stepper moves in whole
    steps: plain differences of its position measure the steps, not the motion.)"""
    t0, t1 = span(t, p)
    grid = np.arange(t0 - window, t1 + window, dt)
    q = np.column_stack([np.interp(grid, t, p[:, j]) for j in range(p.shape[1])])
    half = round(window / dt / 2)
    x = np.arange(-half, half + 1) * dt
    fit = np.linalg.pinv(np.vander(x, 3))  # rows: the parabola's a, b, c (a x^2 + b x + c)
    vel = np.column_stack([np.convolve(q[:, j], fit[1][::-1], mode="valid") for j in range(q.shape[1])])
    acc = np.column_stack([np.convolve(q[:, j], 2.0 * fit[0][::-1], mode="valid") for j in range(q.shape[1])])
    return np.max(np.abs(vel), axis=0), np.max(np.abs(acc), axis=0)


def actuator_limits_deg(robot: Robot) -> tuple[FloatArray, FloatArray]:
    """Each actuator's velocity [deg/s] and acceleration [deg/s^2] bound: ``|M| @`` the joints' limits."""
    m = np.abs(robot.actuators.M)
    return np.degrees(m @ robot.limits.velocity), np.degrees(m @ robot.limits.acceleration)
