"""Range sensors mounted on an arm (seed 000 section 4): readings to points in ``base``.

A scanning sensor (``mount = "scanner"``) sits at ``position`` in ``base`` and turns in the
horizontal plane; a reading (range [m], bearing [rad] from +x, counter-clockwise) is the
point ``position + range * (cos bearing, sin bearing, 0)``. A sensor on a frame of the arm
(``mount = "frame"``, e.g. the gripper's GP2D120) looks along that frame's x axis; its point
needs the joint vector.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from armd.errors import BadRequest

from .types import FloatArray


@dataclass(frozen=True)
class RangeSensor:
    name: str
    model: str
    mount: str  # "scanner" or "frame"
    range: tuple[float, float]  # valid readings [m]
    position: tuple[float, float, float] | None = None  # scanner: in base [m]
    frame: str | None = None  # frame mount: the URDF frame it looks along (+x)

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
