"""Reading a published trajectory (``<prefix>/<robot>/trajectory``) on the adapter side, and
checking it by its motion before anything reaches an actuator (defence in depth).

What a message declares (velocities, accelerations, a duration) is not trusted: the adapter
moves the arm through the sampled positions, so those are what is checked. The size is
bounded before the JSON is parsed; the times must start at 0 and be evenly spaced at
``1 / rate_hz`` with ``rate_hz`` in [1, 1000] Hz; the samples and the duration are bounded;
every position within the box and coupled limits and every actuator's range; the
finite-difference velocity ``(q[k+1] - q[k]) * rate`` and acceleration ``(q[k+1] - 2 q[k] +
q[k-1]) * rate^2`` within the limits, the arm held at the last sample afterwards (so a
trajectory must end at rest). One bad sample rejects the whole trajectory. Where the first
sample must be (near the arm) and that an id runs at most once are the adapter's checks
(:class:`clients.adapter.Adapter`): they need its state.

A tracking stream's trajectory (the service's, one a cycle: :mod:`planning.online`) carries
``"splice": {"after": <id>, "at": <s>}``: it takes over from trajectory ``after`` at its time
``at``, a whole number of samples in, where its first sample is ``after``'s sample there (the
same position; the adapter checks that, and the acceleration across the junction), and
``"track": <session>``, the stream it belongs to.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import orjson
from numpy.typing import NDArray

from armd import planning
from armd.errors import BadRequest, LimitError
from armd.robots import Robot
from armd.robots.types import FloatArray

MAX_BYTES = 8 * 1024 * 1024  # [bytes] of one message, checked before parsing (20,000 samples of 6 joints: ~5 MB)
MAX_SAMPLES = 20_000  # the service's default max_samples
MAX_DURATION = 600.0  # [s]
RATE_RANGE = (1.0, 1000.0)  # [Hz]
MAX_ID = 64  # [characters]
SPLICE_FIELDS = ("after", "at")
KINDS = ("move", "stop")
RATE_TOL = 1e-6  # relative slack on the finite-difference limits (rounding of the samples)


@dataclass(frozen=True)
class Command:
    """A trajectory as an adapter executes it: samples, their actuator commands, and its id.
    ``velocity`` and ``acceleration`` are the samples' finite differences (what the motion
    is), not what the message declared."""

    id: str
    kind: str  # "move" or "stop"
    rate_hz: float
    times: FloatArray
    position: FloatArray
    velocity: FloatArray
    acceleration: FloatArray
    commands: NDArray[np.int64]
    after: str | None = None  # a stream's: the trajectory it takes over from ...
    at: float = 0.0  # [s] ... at this time of it
    track: str | None = None  # the tracking stream's session it belongs to

    @property
    def duration(self) -> float:
        return float(self.times[-1])

    def sample_at(self, t: float) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Linear interpolation between samples, held at the ends [s]."""
        t = min(max(t, 0.0), self.duration)
        k = min(int(t * self.rate_hz), len(self.times) - 1)
        if k >= len(self.times) - 1:
            return self.position[-1], self.velocity[-1], self.acceleration[-1]
        w = (t - self.times[k]) * self.rate_hz
        return (
            (1 - w) * self.position[k] + w * self.position[k + 1],
            (1 - w) * self.velocity[k] + w * self.velocity[k + 1],
            (1 - w) * self.acceleration[k] + w * self.acceleration[k + 1],
        )


def motion(position: FloatArray, dt: float) -> tuple[FloatArray, FloatArray]:
    """Per sample: the forward-difference velocity toward the next sample [rad/s] (0 on the
    last: the arm holds there) and the second difference [rad/s^2] (the last one with the arm
    held after the last sample; 0 on the first, whose motion before is the adapter's)."""
    held = np.vstack([position, position[-1:]])
    velocity = np.diff(held, axis=0) / dt
    acceleration = np.zeros_like(position)
    acceleration[1:] = np.diff(velocity, axis=0) / dt
    return velocity, acceleration


def check_size(size: int) -> None:
    """:class:`BadRequest` for a message of ``size`` bytes over ``MAX_BYTES`` (asked before it is
    copied or parsed)."""
    if size > MAX_BYTES:
        raise BadRequest(
            f"trajectory message of {size} bytes; an adapter takes at most {MAX_BYTES}",
            field="trajectory",
            size=size,
            limit=MAX_BYTES,
        )


def parse(robot: Robot, payload: bytes) -> Command:
    """A :class:`Command` from a trajectory message, checked by its motion against every limit
    and actuator range of ``robot`` (:class:`BadRequest` or :class:`LimitError` naming the
    first problem: nothing of a refused trajectory is executed)."""
    check_size(len(payload))
    try:
        msg = orjson.loads(payload)
        if not isinstance(msg, dict):
            raise TypeError("not a JSON object")
        times = np.asarray(msg["times"], dtype=float)
        pos = np.asarray(msg["position"], dtype=float)
        rate = msg["rate_hz"]
        ident = msg.get("id")
        kind = msg.get("kind", "move")
        splice = msg.get("splice")
        track = msg.get("track")
    except (ValueError, KeyError, TypeError) as e:
        raise BadRequest(f"malformed trajectory message: {e}", field="trajectory") from None
    if msg.get("robot") not in (None, robot.name):
        raise BadRequest(f"trajectory for {msg.get('robot')!r} sent to {robot.name}", field="robot")
    if not isinstance(ident, str) or not 0 < len(ident) <= MAX_ID:
        raise BadRequest(f"a trajectory needs an 'id' (a string of 1 to {MAX_ID} characters)", field="id")
    if kind not in KINDS:
        raise BadRequest(f"kind must be one of {', '.join(KINDS)}, got {kind!r}", field="kind")
    if isinstance(rate, bool) or not isinstance(rate, (int, float)) or not RATE_RANGE[0] <= rate <= RATE_RANGE[1]:
        raise BadRequest(
            f"rate_hz must be a number in [{RATE_RANGE[0]:g}, {RATE_RANGE[1]:g}] Hz, got {rate!r}", field="rate_hz"
        )
    n, k = robot.nq, len(times)
    if times.ndim != 1 or k == 0 or pos.shape != (k, n):
        raise BadRequest(f"times must be (k,) and position (k, {n}) for {robot.name}", field="trajectory")
    if k > MAX_SAMPLES:
        raise BadRequest(
            f"{k} samples; an adapter takes at most {MAX_SAMPLES}", field="times", size=k, limit=MAX_SAMPLES
        )
    dt = 1.0 / float(rate)
    if not (
        np.all(np.isfinite(times)) and abs(times[0]) <= 1e-9 and np.allclose(np.diff(times), dt, rtol=0.0, atol=1e-9)
    ):
        raise BadRequest("trajectory times must start at 0 and be evenly spaced at 1 / rate_hz", field="times")
    if times[-1] > MAX_DURATION:
        raise BadRequest(
            f"a trajectory of {times[-1]:.1f} s; an adapter takes at most {MAX_DURATION:g} s", field="times"
        )
    if not np.all(np.isfinite(pos)):
        raise BadRequest("trajectory positions must be finite numbers", field="position")
    vel, acc = motion(pos, dt)
    planning.check_samples(robot, times, pos, np.zeros_like(pos), np.zeros_like(pos), np.zeros_like(pos))
    _within(robot, times, vel, robot.limits.velocity, "velocity", "rad/s")
    _within(robot, times, acc, robot.limits.acceleration, "acceleration", "rad/s^2")
    after, at = _splice(splice, kind, float(rate))
    if track is not None and (not isinstance(track, str) or not 0 < len(track) <= MAX_ID):
        raise BadRequest(f"track must be a session's id (1 to {MAX_ID} characters)", field="track")
    commands = planning.actuator_commands(robot, times, robot.limits.clip(pos))
    return Command(ident, kind, float(rate), times, pos, vel, acc, commands, after, at, track)


def _splice(splice: object, kind: str, rate: float) -> tuple[str | None, float]:
    """``(after, at)`` of a stream's trajectory, or ``(None, 0.0)``; :class:`BadRequest` if
    malformed: ``after`` an id, ``at`` a whole number of samples [s] within ``MAX_DURATION``."""
    if splice is None:
        return None, 0.0
    if kind != "move" or not isinstance(splice, dict) or set(splice) != set(SPLICE_FIELDS):
        raise BadRequest('splice must be {"after": <id>, "at": <s>} (a move\'s)', field="splice")
    after, at = splice["after"], splice["at"]
    if not isinstance(after, str) or not 0 < len(after) <= MAX_ID:
        raise BadRequest(f"splice.after must be a trajectory id (1 to {MAX_ID} characters)", field="splice.after")
    if isinstance(at, bool) or not isinstance(at, (int, float)) or not 0.0 <= at <= MAX_DURATION:
        raise BadRequest(f"splice.at must be a time in [0, {MAX_DURATION:g}] s", field="splice.at")
    k = round(at * rate)
    if abs(k / rate - at) > 1e-9:
        raise BadRequest("splice.at must be a whole number of samples (k / rate_hz)", field="splice.at")
    return after, k / rate


def _within(robot: Robot, times: FloatArray, values: FloatArray, limit: FloatArray, kind: str, unit: str) -> None:
    over = np.abs(values) > limit * (1 + RATE_TOL) + 1e-9
    if over.any():
        k, j = (int(i) for i in np.argwhere(over)[0])
        name = robot.joint_names[j]
        raise LimitError(
            f"joint {name!r} moves at {values[k, j]:.6g} {unit} (the samples' finite difference) at "
            f"t = {times[k]:.4f} s, over its {kind} limit {limit[j]:.6g} {unit}",
            name=name,
            value=float(values[k, j]),
            bounds=(-float(limit[j]), float(limit[j])),
            kind=kind,
            time=float(times[k]),
        )
