"""Range sensors mounted on an arm (seed 000 section 4): readings to points in ``base``.

A scanning sensor (``mount = "scanner"``) sits at ``position`` in ``base`` and turns in the
horizontal plane; a reading (range [m], bearing [rad] from +x, counter-clockwise) is the
point ``position + range * (cos bearing, sin bearing, 0)``. A sensor on a frame of the arm
(``mount = "frame"``, e.g. the gripper's GP2D120) looks along that frame's x axis; its point
needs the joint vector.

A sensor's model (``model``, a name of ``sensor_models.toml``: the Sharp GP2D12 and GP2D120)
gives its output voltage against distance (:class:`SensorModel`), so that a reading may be
given as the voltage the sensor put out (``volts``) and the simulator's sensors put one out.

A sensor wired to the arm's SSC-32U has the analog input its output goes to (``pin``, "A" to
"H") and, a scanner, the board's channel of its scanning servo (``servo``: bearing = the servo's
angle): the SSC-32 adapter then sweeps and reads it (docs/sensors.md).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import tomllib

from armd.errors import BadRequest

from .actuators import Servo
from .types import FloatArray

MODELS_FILE = Path(__file__).with_name("sensor_models.toml")
TOO_CLOSE_FALL = 1.0  # (V at distance d < min: its peak times d / min; the datasheets' curves fall so, roughly)
NOTHING_SEEN = 3.0  # an object this many times the range's end away gives the output of nothing in sight


@dataclass(frozen=True)
class SensorModel:
    """A range sensor's output voltage ``V = a / (L + b)`` [V] at distance ``L`` [m] over its
    measuring ``range``, through the datasheet's typical output at the range's far end
    (``far_volts``) and its typical change over the range (``span_volts``).

    Closer than the range the output falls again (toward 0 V at contact: an object too close
    reads as one farther off, as the real sensors do); beyond it, it keeps falling toward the
    output of nothing in sight. ``period``: one measurement [s]; ``noise_volts``: a reading's
    noise, 1 sigma [V]."""

    name: str
    range: tuple[float, float]
    far_volts: float
    span_volts: float
    period: float
    noise_volts: float

    @property
    def near_volts(self) -> float:
        return self.far_volts + self.span_volts

    @property
    def ab(self) -> tuple[float, float]:
        lo, hi = self.range
        b = (self.far_volts * hi - self.near_volts * lo) / (self.near_volts - self.far_volts)
        return self.far_volts * (hi + b), b

    def volts(self, distance: float) -> float:
        """The output [V] for an object at ``distance`` [m] (``inf``: nothing in sight)."""
        a, b = self.ab
        lo, hi = self.range
        if distance < lo:
            return self.near_volts * max(distance, 0.0) / lo * TOO_CLOSE_FALL
        return a / (min(distance, NOTHING_SEEN * hi) + b)

    def distance(self, volts: float) -> float | None:
        """The distance [m] an output ``volts`` [V] says, or None if it is outside the measuring
        range's voltages (nothing in range)."""
        if not self.far_volts - 1e-9 <= volts <= self.near_volts + 1e-9:  # (1 nV: the float's own rounding)
            return None
        a, b = self.ab
        lo, hi = self.range
        return min(max(a / volts - b, lo), hi)


@functools.cache
def models() -> dict[str, SensorModel]:
    """The sensor models of ``sensor_models.toml``, by name."""
    with MODELS_FILE.open("rb") as f:
        data = tomllib.load(f)
    return {
        name: SensorModel(
            name,
            (float(t["range"][0]), float(t["range"][1])),
            float(t["far_volts"]),
            float(t["span_volts"]),
            float(t["period"]),
            float(t["noise_volts"]),
        )
        for name, t in data.items()
    }


@dataclass(frozen=True)
class RangeSensor:
    name: str
    model: str
    mount: str  # "scanner" or "frame"
    range: tuple[float, float]  # valid readings [m]
    position: tuple[float, float, float] | None = None  # scanner: in base [m]
    frame: str | None = None  # frame mount: the URDF frame it looks along (+x)
    sweep: tuple[float, float] | None = None  # scanner: its servo's bearings [rad], end to end
    sweep_step: float = 0.035  # scanner: [rad] its servo's turn between readings
    # wired to an SSC-32U: the analog input (pin "A".."H") its output is read on, and a scanner's
    # servo on the board (its angle: the bearing); None: read by something else (the simulator)
    pin: str | None = None
    servo: Servo | None = None

    @property
    def curve(self) -> SensorModel | None:
        """Its model's voltage curve, if ``sensor_models.toml`` has it."""
        return models().get(self.model)

    def range_of_volts(self, volts: object) -> float:
        """The distance [m] a reading given as the sensor's output ``volts`` [V] says; else
        :class:`BadRequest` (a model with no curve, a voltage outside the measuring range's)."""
        curve = self.curve
        if curve is None:
            known = ", ".join(sorted(models()))
            raise BadRequest(
                f"sensor {self.name!r} ({self.model}): no voltage curve for its model (known: {known}); give range [m]",
                field="volts",
            )
        if isinstance(volts, bool) or not (isinstance(volts, (int, float)) and math.isfinite(volts)):
            raise BadRequest(f"sensor {self.name!r}: volts must be a finite number [V], got {volts!r}", field="volts")
        d = curve.distance(float(volts))
        if d is None:
            raise BadRequest(
                f"sensor {self.name!r} ({self.model}) puts out {curve.far_volts:.2f}..{curve.near_volts:.2f} V over "
                f"{curve.range[0]:g}..{curve.range[1]:g} m; {volts:g} V is nothing in range",
                field="volts",
                bounds=[curve.far_volts, curve.near_volts],
            )
        return d

    def check_range(self, distance: float) -> float:
        if not (isinstance(distance, (int, float)) and not isinstance(distance, bool) and math.isfinite(distance)):
            raise BadRequest(
                f"sensor {self.name!r}: range must be a finite number [m], got {distance!r}", field="range"
            )
        lo, hi = self.range
        if not (lo <= distance <= hi):
            raise BadRequest(
                f"sensor {self.name!r} ({self.model}) reads {lo:g}..{hi:g} m; {distance:g} m is not a valid reading",
                field="range",
                bounds=[lo, hi],
            )
        return float(distance)

    def scanner_point(self, distance: float, bearing: float) -> FloatArray:
        """The base-frame point [m] of a scanner reading (seed 000 eq. 5-6, in the base frame)."""
        d = self.check_range(distance)
        if not (isinstance(bearing, (int, float)) and not isinstance(bearing, bool) and math.isfinite(bearing)):
            raise BadRequest(
                f"sensor {self.name!r}: bearing must be a finite number [rad], got {bearing!r}", field="bearing"
            )
        assert self.position is not None
        p = np.array(self.position, dtype=float)
        return p + d * np.array([math.cos(bearing), math.sin(bearing), 0.0])
