"""Parameters of the closed-form solver's arm family: found from the URDF's chain
(:mod:`robots.chain`), or given by ``[geometry]`` in robot.toml.

The family (all four seeds are instances): a yaw joint about a vertical axis; in the vertical
plane it turns, a shoulder pivot at ``pivot`` (outward u, lateral v, height z in the yaw frame
[m]), an upper arm and a forearm on two pitch joints, an optional wrist pitch joint carrying a
hand of length ``hand``, and a fixed ``tool_offset`` (outward, upward) [m] in the level frame
(a level-keeping linkage, the desk4's). With ``pitch = "level"`` the tool is held horizontal by
a linkage; otherwise its pitch is the sum of the pitch joints' family angles plus
``pitch_offset``.

The family's angles are the URDF's mapped: ``theta = sign q + zero`` for the yaw, shoulder,
elbow and wrist (``sign`` -1 where the URDF's axis turns the other way, ``zero`` the family's
angle at the URDF's 0), so that each link is horizontal at theta = 0 and positive lifts; the
yaw's axis is at ``base`` (x, y) in the base frame. With ``phi_k`` the sums of the pitch angles
up to link k, the exact FK of the family is::

    u = pivot_u + upper_arm c(phi_1) + forearm c(phi_2) + hand c(phi_3) + offset_out
    v = pivot_v
    z = pivot_z + upper_arm s(phi_1) + forearm s(phi_2) + hand s(phi_3) + offset_up
    x = base_x + c(yaw) u - s(yaw) v,   y = base_y + s(yaw) u + c(yaw) v

A wrist roll joint after the last pitch joint whose axis misses the tool point (or is not the
tool axis) moves the last link: :class:`RollModel` gives the last link's length, angle, lateral
offset and the tool pitch's offset at any roll (the compiled solver's ``solvers.arrays.view``
does the same).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

Vector = tuple[float, float, float]


@dataclass(frozen=True)
class RollModel:
    """How a wrist roll moves the tool, in the last pitch link's frame at q = 0 (u outward, v
    lateral, z up; origin on the last pitch joint's axis, v measured from the yaw axis)."""

    point: Vector  # a point of the roll axis [m]
    axis: Vector  # the roll axis (unit; positive roll turns about it)
    tool: Vector  # the tool point from ``point`` at roll 0 [m]
    tool_axis: Vector  # the tool axis at roll 0 (unit)

    @property
    def reach(self) -> float:
        """How far [m] the roll can move the tool point: twice its distance from the roll axis."""
        w, d = np.array(self.tool), np.array(self.axis)
        return 2.0 * float(np.linalg.norm(w - d * float(d @ w)))

    def last_link(self, roll: float) -> tuple[float, float, float, float]:
        """(length [m], angle [rad], lateral offset [m], tool pitch minus link angle [rad]) at ``roll``."""
        d = np.array(self.axis)
        t = np.array(self.point) + _rotate(d, roll, np.array(self.tool))
        x = _rotate(d, roll, np.array(self.tool_axis))
        angle = math.atan2(t[2], t[0])
        return math.hypot(t[0], t[2]), angle, float(t[1]), math.atan2(x[2], x[0]) - angle


def _rotate(d: NDArray[np.float64], angle: float, v: NDArray[np.float64]) -> NDArray[np.float64]:
    c, s = math.cos(angle), math.sin(angle)
    return v * c + np.cross(d, v) * s + d * float(d @ v) * (1.0 - c)


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
    sign: tuple[float, float, float, float] = (1.0, 1.0, 1.0, 1.0)  # yaw, shoulder, elbow, wrist
    zero: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)  # [rad]
    base: tuple[float, float] = (0.0, 0.0)  # the yaw axis in the base frame [m]
    pitch_offset: float = 0.0  # [rad]
    roll: int | None = None  # a wrist roll joint that moves the tool point or the tool axis
    roll_model: RollModel | None = None
    source: str = "robot.toml [geometry]"  # where the numbers come from (said by `armd catalogue`)

    @property
    def has_wrist(self) -> bool:
        return self.wrist is not None

    @property
    def joints(self) -> tuple[int, ...]:
        """The family's joints: yaw, shoulder, elbow (and wrist)."""
        return (self.yaw, self.shoulder, self.elbow) + (() if self.wrist is None else (self.wrist,))

    def family_angles(self, q: NDArray[np.float64]) -> list[float]:
        """(yaw, shoulder, elbow, wrist) in the family's angles at ``q`` (wrist 0 without one),
        with the last link's change at ``q``'s roll."""
        out = [s * float(q[j]) + z for s, z, j in zip(self.sign, self.zero, self.joints, strict=False)]
        if len(out) == 3:
            out.append(0.0)
        if self.roll_model is not None and self.roll is not None:
            turn = self.roll_model.last_link(float(q[self.roll]))[1] - self.roll_model.last_link(0.0)[1]
            out[3 if self.wrist is not None else 2] += turn
        return out

    def heading(self, q: NDArray[np.float64]) -> float:
        """The direction [rad] in ``base`` the arm's vertical plane faces (outward) at ``q``."""
        return self.sign[0] * float(q[self.yaw]) + self.zero[0]

    def fk(self, q: NDArray[np.float64]) -> NDArray[np.float64]:
        """Tool point [m] by the family's formula (module docstring), for joint vector ``q``."""
        yaw, p1, t2, t3 = self.family_angles(q)
        hand, forearm, py = self.hand, self.forearm, self.pivot[1]
        if self.roll_model is not None and self.roll is not None:
            length, _, lateral, _ = self.roll_model.last_link(float(q[self.roll]))
            py += lateral - self.roll_model.last_link(0.0)[2]
            if self.wrist is not None:
                hand = length
            else:
                forearm = length
        p2 = p1 + t2
        px, _, pz = self.pivot
        u = px + self.upper_arm * math.cos(p1) + forearm * math.cos(p2) + self.tool_offset[0]
        z = pz + self.upper_arm * math.sin(p1) + forearm * math.sin(p2) + self.tool_offset[1]
        if self.wrist is not None:
            p3 = p2 + t3
            u += hand * math.cos(p3)
            z += hand * math.sin(p3)
        c, s = math.cos(yaw), math.sin(yaw)
        return np.array([self.base[0] + c * u - s * py, self.base[1] + s * u + c * py, z])
