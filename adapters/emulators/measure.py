"""Measuring what reached a controller against the arm's limits (test and benchmark tools).

An emulator records what its board output (the SSC-32's exact pulse segments, GRBL's trace of
positions); these functions turn that into the arm's joint motion and say how it compares to
the limits: the promise an adapter keeps is that every joint stays within its position,
velocity and acceleration limits at every moment.

- :func:`ssc32_motion`: the joint path the SSC-32 emulator's channels drew, as breakpoints
  (the board's group moves are piecewise linear in pulses, hence in joints, unless a linkage
  curves them: then sampled finely), with its jumps; :func:`peaks`, such a path's fastest speed
  and largest change of speed over a window.
- :func:`grbl_motion`, :func:`fitted_peaks`: GRBL's trace of the arm, and its peak speed and
  acceleration fitted over a window (a stepper's whole steps are not its motion);
  :func:`grbl_exact_motion`: GRBL's motion before its whole steps, as its planner made it.
- :func:`bus_joint_traces`, :func:`braking`: a bus-servo arm's joints as its servos moved
  (the bus emulators' model, every step), and how a joint came to rest after a moment (a
  fault): its speed then, how far it ran on, how far back against its way, how hard it braked.
- :func:`ratios`: the worst velocity (exact, per linear piece) and acceleration (the change of
  speed between pieces) of a piecewise-linear joint path, as ratios of the limits, and the
  worst position excursion beyond the limits.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from typing import Any

import numpy as np

from armd.robots import BusServo, Robot, Servo, Stepper
from armd.robots.types import FloatArray

from .grbl import GrblEmulator
from .ssc32 import SSC32Emulator

MIN_PIECE = 1e-4  # [s] pieces shorter than this are not counted as pieces of motion
HELD_DELAY = 0.75  # periods: the longest a host may hold a line on its way, for ratios(held=True)
HELD_TOL = 5e-4  # [s] the slack on a line's time against the rhythm of the lines before it
SAME_SPEED = 1e-6  # of a velocity limit: a smaller change of speed is none (the float noise of differences)


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
    held: int = 0  # changes counted at the period: their line was held on its way (``ratios(held=True)``)


def ssc32_motion(robot: Robot, emulator: SSC32Emulator, since: float = -np.inf, dense: float = 0.0) -> Motion:
    """The joint path the emulator's output drew for ``robot``'s servo channels, from ``since``
    [s, the emulator's clock] to now; jumps (zero-length segments that change a pulse) counted.

    Breakpoints: the board's pieces are linear in pulses, hence in joints, unless a servo turns
    its joint through a linkage (desk4's minor): then a piece is curved in joints, and ``dense``
    [s] samples every piece at least that finely (for :func:`peaks`)."""
    servos = [a for a in robot.actuators.actuators if isinstance(a, Servo)]
    segs = {a.channel: emulator.segments(a.channel) for a in servos}
    edges = sorted({t for ss in segs.values() for s in ss for t in (s[0], s[1]) if t >= since})
    jumps = sum(1 for ss in segs.values() for s in ss if s[0] == s[1] and s[2] != s[3] and s[0] >= since)
    if not edges:
        return Motion(np.zeros(0), np.zeros((0, robot.nq)), jumps)
    if dense > 0.0:
        fine = [np.linspace(a, b, max(2, int(np.ceil((b - a) / dense)) + 1))[:-1] for a, b in itertools.pairwise(edges)]
        edges = sorted({*edges, *(float(t) for f in fine for t in f)})
    times = np.array(edges, dtype=float)
    pulses = np.column_stack([_pulse_at(segs[a.channel], times) for a in servos])
    q = robot.actuators.joints_from_commands(pulses, tol=np.inf)
    return Motion(times, q, jumps)


def peaks(robot: Robot, motion: Motion, window: float) -> tuple[FloatArray, FloatArray]:
    """Per joint, the fastest speed [rad/s] of a finely sampled ``motion`` (:func:`ssc32_motion`
    with ``dense``) and its largest change of speed over any ``window`` [s] (a stream's period)
    divided by the window [rad/s^2]: the acceleration a servo behind a linkage has along the
    board's curved pieces, and at their joins, at the stream's own time scale."""
    t, q = motion.times, motion.position
    keep = np.diff(t) > 1e-9
    mid = (t[:-1] + t[1:])[keep] / 2.0
    v = (np.diff(q, axis=0)[keep]) / np.diff(t)[keep][:, None]
    fastest = np.max(np.abs(v), axis=0) if len(v) else np.zeros(robot.nq)
    before = np.clip(np.searchsorted(mid, mid - window, side="right") - 1, 0, None)
    change = np.max(np.abs(v - v[before]), axis=0) / window if len(v) else np.zeros(robot.nq)
    return fastest, change


def ssc32_speed_noise(robot: Robot, emulator: SSC32Emulator, since: float = -np.inf) -> FloatArray:
    """Per joint [rad/s]: how far the board's whole microseconds may move a piece's speed, for the
    group moves the emulator received since ``since``: the rounding :func:`ratios` allows for.

    A move timed by ``T`` reaches a whole-microsecond target in ``T``: its speed is off by up to
    half a microsecond over ``T`` (the shortest ``T`` counts). A move of speeds ``S`` (whole
    microseconds a second) is off by half of one, twice for a group of several servos (they
    start and end together: each one's speed is its distance over the slowest one's time)."""
    moves = [m for m in emulator.history if m.time >= since]
    times = [m.duration_ms for m in moves if m.duration_ms]
    noise = 0.5 / (min(times) / 1000.0) if times else 0.0  # [us/s]
    if any(m.speeds and not m.duration_ms for m in moves):
        noise = max(noise, 1.0)
    return noise * pulse_resolution(robot)


def pulse_resolution(robot: Robot) -> FloatArray:
    """Per joint, how far one microsecond of any servo that moves it moves the joint [rad]."""
    M = robot.actuators.gentlest  # (a linkage's |da/dq| where a microsecond moves the joint most)
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


def ratios(
    robot: Robot, motion: Motion, period: float, speed_noise: FloatArray | float = 0.0, held: bool = False
) -> Ratios:
    """The worst velocity and acceleration of ``motion`` against ``robot``'s limits.

    Velocity: exact, per linear piece. Acceleration, per joint: each change of its speed (at a
    piece's end) over the time since its previous change, counted at most ``period`` [s] (the
    stream's sample period): the backward difference of the speed at the changes' own spacing,
    where a speed held longer (the board idle, waiting for a late command) counts as one
    period, so that a restart at speed after a stall shows as the jump it is. (Per joint: the
    servos of different joints may change speed at different moments, as the bytes of one
    line reach the board one after another.)

    ``speed_noise`` [rad/s], per joint: how far the controller's own rounding may move a piece's
    speed (the SSC-32's whole microseconds: :func:`ssc32_speed_noise`); a change of speed is
    counted beyond twice that only, and a smaller one is no change.

    ``held``: a line held after it was written (by the host's USB link, or the kernel thread
    that carries a pseudo-terminal's bytes) reaches the board late, and no command can say so;
    the next one, on the stream's rhythm, then comes less than a period after it. With
    ``held``, a change that comes short of a period after the previous one, in a sequence of
    changes that a stream of one line a period explains with lines held up to ``HELD_DELAY``
    periods each (each line no sooner than a period after the one before, as the adapter aimed
    them, and each one reaching the board no earlier than so, no later than held), is counted
    over the period (the host's timing, not the adapter's) and in ``Ratios.held`` (the most of
    any joint). An adapter that sends lines too close together soon leaves that explanation,
    and every such change counts at its spacing (the adapter's own timing is checked exactly
    in tests/test_adapter_ssc32.py, test_the_adapters_own_model_keeps_the_limits).
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
    ends = np.cumsum(d)  # [s] the pieces' ends, from the first piece's start
    noise = np.broadcast_to(np.asarray(speed_noise, dtype=float), (robot.nq,))
    worst = np.zeros(robot.nq)
    excused = 0
    for j in range(robot.nq):
        dv = np.abs(np.diff(v[:, j])) - 2.0 * noise[j]  # at the end of each piece but the last
        last = -np.inf  # [s] when this joint's speed last changed (before the motion: held, a period at least)
        aimed = -np.inf  # [s] the earliest its line could have been aimed for, by the lines before
        count = 0
        for i in np.flatnonzero(dv > SAME_SPEED * lim.velocity[j]):
            gap = ends[i] - last
            aimed = max(ends[i] - HELD_DELAY * period, aimed + period)
            explained = aimed <= ends[i] + HELD_TOL
            late = held and gap < period - HELD_TOL and explained
            count += late
            worst[j] = max(worst[j], dv[i] / (period if late else min(gap, period)) / lim.acceleration[j])
            last = ends[i]
            if not explained:  # (the stream rushed: its rhythm from here on, the line as it came)
                aimed = ends[i]
        excused = max(excused, count)
    aj = int(np.argmax(worst))
    return Ratios(float(np.max(vr)), names[vj], float(worst[aj]), names[aj], max(outside, 0.0), int(excused))


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


def grbl_exact_motion(robot: Robot, emulator: GrblEmulator, times: FloatArray) -> FloatArray:
    """The arm's actuator angles [deg] at ``times`` [s, the emulator's clock], from the emulator's
    exact motion (:attr:`GrblEmulator.pieces`: GRBL's planner and stepper profiles before their
    whole steps), held before its first piece and after its last. Rows: times; columns: actuators."""
    pieces = emulator.pieces
    cols = [emulator.axes.index(a.axis) for a in robot.actuators.actuators if isinstance(a, Stepper)]
    start = np.array([p[0] for p in pieces])
    k = np.clip(np.searchsorted(start, times, side="right") - 1, 0, None)
    tau = np.clip(times - start[k], 0.0, np.array([p[1] for p in pieces])[k])[:, None]
    p0 = np.array([[p[2][c] for c in cols] for p in pieces])[k]
    v0 = np.array([[p[3][c] for c in cols] for p in pieces])[k]
    a0 = np.array([[p[4][c] for c in cols] for p in pieces])[k]
    out: FloatArray = p0 + v0 * tau + 0.5 * a0 * tau**2
    return out


def actuator_limits_deg(robot: Robot) -> tuple[FloatArray, FloatArray]:
    """Each actuator's velocity [deg/s] and acceleration [deg/s^2] bound over the joints' limits
    (``|M| @`` them; a linkage's with its curvature: ActuatorMap.rate_bounds)."""
    speed, accel = robot.actuators.rate_bounds(robot.limits.velocity, robot.limits.acceleration)
    return np.degrees(speed), np.degrees(accel)


def bus_joint_traces(robot: Robot, emulator: Any) -> list[FloatArray]:
    """Each joint's angle [rad] over time at a bus emulator's servos (``trace``: every model
    step a servo moved; one servo a joint): rows (t [s], q [rad])."""
    out = []
    for act in robot.actuators.actuators:
        assert isinstance(act, BusServo)
        trace = np.array(emulator.trace(act.id))
        out.append(np.column_stack([trace[:, 0], (trace[:, 1] - act.zero) * act.direction / act.counts_per_rad]))
    return out


@dataclass(frozen=True)
class Braking:
    """How a joint came to rest after a moment: its ``speed`` then [rad/s], how far it ran on
    (``travel`` [rad], along its way), how far ``back`` against its way it went [rad] after the
    farthest point, and its hardest ``acceleration`` [rad/s^2] over ``window`` from 50 ms before."""

    speed: float
    travel: float
    back: float
    acceleration: float


def braking(trace: FloatArray, since: float, until: float, window: float = 0.01) -> Braking:
    """:class:`Braking` of a joint's ``trace`` (:func:`bus_joint_traces`) from ``since`` to ``until`` [s]."""
    step = 0.001
    t = np.arange(since - 0.05, until, step)
    q = np.interp(t, trace[:, 0], trace[:, 1])
    k = round(0.05 / step)
    half = round(window / step / 2)
    speed = (q[k + half] - q[k - half]) / window
    way = np.sign(speed) if abs(speed) > 0.2 else np.sign(q[-1] - q[k])
    ahead = way * (q[k:] - q[k])
    back = float(np.max(np.maximum.accumulate(ahead) - ahead)) if way != 0 else float(np.ptp(q[k:]))
    coarse = q[:: round(window / step)]
    a = np.diff(coarse, 2) / window**2
    return Braking(float(speed), float(np.max(ahead)), back, float(np.max(np.abs(a))))
