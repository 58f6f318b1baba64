"""Reading a published trajectory (``<prefix>/<robot>/trajectory``) on the adapter side, and
checking it again before anything reaches an actuator (defence in depth)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import orjson
from numpy.typing import NDArray

import planning
from robots import BadRequest, Robot

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class Command:
    """A trajectory as an adapter executes it: samples, their actuator commands, and its id."""

    id: str
    kind: str  # "move" or "stop"
    rate_hz: float
    times: FloatArray
    position: FloatArray
    velocity: FloatArray
    acceleration: FloatArray
    commands: NDArray[np.int64]

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
        return ((1 - w) * self.position[k] + w * self.position[k + 1],
                (1 - w) * self.velocity[k] + w * self.velocity[k + 1],
                (1 - w) * self.acceleration[k] + w * self.acceleration[k + 1])


def parse(robot: Robot, payload: bytes) -> Command:
    """A :class:`Command` from a trajectory message, every sample re-checked against every
    limit and actuator range of ``robot``: one bad sample rejects the whole trajectory."""
    try:
        msg = orjson.loads(payload)
        times = np.asarray(msg["times"], dtype=float)
        pos = np.asarray(msg["position"], dtype=float)
        vel = np.asarray(msg["velocity"], dtype=float)
        acc = np.asarray(msg["acceleration"], dtype=float)
        rate = float(msg["rate_hz"])
        ident = str(msg.get("id", ""))
        kind = str(msg.get("kind", "move"))
    except (ValueError, KeyError, TypeError) as e:
        raise BadRequest(f"malformed trajectory message: {e}", field="trajectory") from None
    n = robot.nq
    k = len(times)
    if k == 0 or pos.shape != (k, n) or vel.shape != (k, n) or acc.shape != (k, n):
        raise BadRequest(f"trajectory arrays must be ({k}, {n}) for {robot.name}", field="trajectory")
    if not (np.isfinite(rate) and rate > 0) or not np.allclose(np.diff(times), 1.0 / rate, atol=1e-9):
        raise BadRequest("trajectory times must be evenly spaced at 1 / rate_hz", field="trajectory")
    if msg.get("robot") not in (None, robot.name):
        raise BadRequest(f"trajectory for {msg.get('robot')!r} sent to {robot.name}", field="robot")
    jerk = planning.trajectory.forward_jerk(acc, 1.0 / rate)
    planning.check_samples(robot, times, pos, vel, acc, jerk)
    commands = planning.actuator_commands(robot, times, np.clip(pos, robot.limits.lower, robot.limits.upper))
    return Command(ident, kind, rate, times, pos, vel, acc, commands)

