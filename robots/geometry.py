"""Parameters of the closed-form solver's arm family, read from ``[geometry]`` in robot.toml.

The family (all four seeds are instances): a yaw joint about +z; in the vertical plane it
turns, a shoulder pivot at ``pivot`` (x, y, z in the yaw frame [m]), an upper arm and a
forearm on two pitch joints, an optional wrist pitch joint carrying a hand of length
``hand`` along the tool axis, and a fixed ``tool_offset`` (outward, upward) [m] in the level
frame (a level-keeping linkage, the desk4's). With ``pitch = "level"`` the tool is held
horizontal by a linkage; with ``pitch = "joints"`` its pitch is the sum of the pitch joints.

Exact FK of the family, with ``phi_k`` the sums of the pitch joints up to link k::

    u = pivot_x + upper_arm c(phi_1) + forearm c(phi_2) + hand c(phi_3) + offset_out
    v = pivot_y
    z = pivot_z + upper_arm s(phi_1) + forearm s(phi_2) + hand s(phi_3) + offset_up
    x = c(yaw) u - s(yaw) v,   y = s(yaw) u + c(yaw) v
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray


@dataclass(frozen=True)
class Geometry:
    """The family's parameters; joint fields are indices into the joint vector ``q``."""

    yaw: int
    shoulder: int
    elbow: int
    wrist: int | None
    pivot: tuple[float, float, float]
    upper_arm: float
    forearm: float
    hand: float
    tool_offset: tuple[float, float]
    level: bool

    @property
    def has_wrist(self) -> bool:
        return self.wrist is not None

    def fk(self, q: NDArray[np.float64]) -> NDArray[np.float64]:
        """Tool point [m] by the family's formula (module docstring), for joint vector ``q``."""
        yaw = q[self.yaw]
        p1 = q[self.shoulder]
        p2 = p1 + q[self.elbow]
        px, py, pz = self.pivot
        u = px + self.upper_arm * math.cos(p1) + self.forearm * math.cos(p2) + self.tool_offset[0]
        z = pz + self.upper_arm * math.sin(p1) + self.forearm * math.sin(p2) + self.tool_offset[1]
        if self.wrist is not None:
            p3 = p2 + q[self.wrist]
            u += self.hand * math.cos(p3)
            z += self.hand * math.sin(p3)
        c, s = math.cos(yaw), math.sin(yaw)
        return np.array([c * u - s * py, s * u + c * py, z])
