"""What an adapter publishes for a range sensor (``<prefix>/<robot>/sensors/<name>``,
docs/sensors.md), and how a scanner steps through its sweep: shared by the simulator's sensors
and the SSC-32's wired ones, so that both stream the same readings the same way.

A reading (JSON): ``sensor``, ``model``, ``time`` [s, the epoch], ``adapter`` (its id),
``volts`` [V] (the sensor's output), ``range`` [m] (what that says by the model's curve, or
null: nothing in range), ``bearing`` [rad] (a scanner's servo angle when it read; null for a
sensor on the arm), and for a scanner ``sweep`` (one more at each reversal) and ``direction``.
"""

from __future__ import annotations

import threading
import time
from typing import Any

from armd.robots.sensors import RangeSensor


class Sweep:
    """A scanner's servo going to and fro over its ``sweep`` in ``sweep_step`` turns."""

    def __init__(self, sensor: RangeSensor) -> None:
        assert sensor.sweep is not None
        self.sensor = sensor
        self.bearing = sensor.sweep[0]  # [rad]
        self.direction = 1
        self.count = 0

    def step(self) -> float:
        """Turn a step (back the other way at an end, the sweep counted); the new bearing."""
        lo, hi = self.sensor.sweep or (0.0, 0.0)
        nxt = self.bearing + self.direction * self.sensor.sweep_step
        if not lo <= nxt <= hi:
            self.direction *= -1
            self.count += 1
            nxt = min(max(nxt, lo), hi)
        self.bearing = nxt
        return nxt


class Numbering:
    """An adapter's numbers for its readings (``seq``): each sensor's 1, 2, ..., one a reading."""

    def __init__(self) -> None:
        self._last: dict[str, int] = {}
        self._lock = threading.Lock()

    def next(self, sensor: str) -> int:
        with self._lock:
            n = self._last[sensor] = self._last.get(sensor, 0) + 1
        return n


def reading(sensor: RangeSensor, volts: float, adapter: str, seq: int, sweep: Sweep | None = None) -> dict[str, Any]:
    """The message for ``sensor`` having put out ``volts`` now (a scanner: at ``sweep``'s
    bearing), the adapter's ``seq``-th reading of it."""
    curve = sensor.curve
    assert curve is not None
    rng = curve.distance(volts)
    msg: dict[str, Any] = {
        "sensor": sensor.name,
        "model": sensor.model,
        "time": time.time(),
        "adapter": adapter,
        "seq": seq,
        "volts": round(volts, 4),
        "range": None if rng is None else round(rng, 4),
        "bearing": None,
    }
    if sweep is not None:
        msg.update(bearing=round(sweep.bearing, 6), sweep=sweep.count, direction=sweep.direction)
    return msg
