"""The closed-form geometric solver for the family "yaw + planar two-link + optional wrist
pitch + fixed tool offsets" (seeds 000-004 are all instances; parameters from
``[geometry]`` in robot.toml, see :mod:`robots.geometry`).

For a target point (and a tool pitch ``phi`` when the arm has a wrist) it returns every
branch: the yaw pointing at the target (``front``) or away from it with the arm reaching
back over the top (``flipped``), times elbow ``up``/``down``. It generalises the seeds:

* yaw with a lateral pivot offset ``v`` (seed 004's ``y_steer``) is exact, not the seed's
  planar approximation: ``u = +-sqrt(x^2 + y^2 - v^2)``, ``yaw = atan2(y, x) - atan2(v, u)``;
* the planar two-link is seed 000 eq. 2-3 / seed 003 eq. 30-33 (law of cosines), after
  subtracting the pivot, the level tool offset and, with a wrist, the hand along ``phi``
  (seed 000 eq. 1 for ``phi`` = 0 and -pi/2);
* the wrist is ``phi - shoulder - elbow`` (seed 000 eq. 12-13).

Joint values are wrapped by multiples of 2 pi into the joint limits where possible; the
caller checks the limits. :func:`branches` is the scalar path (one target, fast in plain
Python); :func:`branches_batch` is the same mathematics vectorised with NumPy.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from robots import Robot

FloatArray = NDArray[np.float64]

TWO_PI = 2.0 * math.pi
_REACH_EPS = 1e-12  # slack on |cos(elbow)| <= 1 for targets exactly on the workspace boundary

BRANCH_NAMES = ("front/elbow_up", "front/elbow_down", "flipped/elbow_up", "flipped/elbow_down")


@dataclass(frozen=True)
class FamilyParams:
    """The family's numbers as plain floats and joint indices (read once per robot)."""

    n: int
    yaw: int
    shoulder: int
    elbow: int
    wrist: int | None
    px: float
    py: float
    pz: float
    l1: float
    l2: float
    l3: float
    ox: float
    oz: float

    @classmethod
    def of(cls, robot: Robot) -> FamilyParams:
        g = robot.geometry
        if g is None:
            raise ValueError(f"{robot.name} has no [geometry]: it is not of the closed-form family")
        return cls(
            n=robot.nq, yaw=g.yaw, shoulder=g.shoulder, elbow=g.elbow, wrist=g.wrist,
            px=g.pivot[0], py=g.pivot[1], pz=g.pivot[2], l1=g.upper_arm, l2=g.forearm,
            l3=g.hand if g.wrist is not None else 0.0, ox=g.tool_offset[0], oz=g.tool_offset[1],
        )


def branches(
    fp: FamilyParams, x: float, y: float, z: float, phi: float | None
) -> list[tuple[str, float, float, float, float]]:
    """Every branch for target (x, y, z) [m] and tool pitch ``phi`` [rad] (ignored without a wrist).

    Returns (name, yaw, shoulder, elbow, wrist) tuples, angles [rad] unwrapped; ``wrist`` is
    0.0 for arms without one. Empty when the target is out of reach for this pitch.
    """
    out: list[tuple[str, float, float, float, float]] = []
    r2 = x * x + y * y
    py = fp.py
    h2 = r2 - py * py
    if h2 < 0.0:
        if h2 < -_REACH_EPS:
            return out
        h2 = 0.0
    h = math.sqrt(h2)
    bearing = math.atan2(y, x)
    l1, l2 = fp.l1, fp.l2
    b = z - fp.pz - fp.oz
    if fp.wrist is not None and phi is not None:
        cphi, sphi = math.cos(phi), math.sin(phi)
        b -= fp.l3 * sphi
        hand_u = fp.l3 * cphi
    else:
        hand_u = 0.0
    denom = 2.0 * l1 * l2
    for side, u in (("front", h), ("flipped", -h)):
        if side == "flipped" and h == 0.0:
            break
        yaw = bearing - math.atan2(py, u)
        a = u - fp.px - fp.ox - hand_u
        c2 = (a * a + b * b - l1 * l1 - l2 * l2) / denom
        if c2 > 1.0:
            if c2 > 1.0 + _REACH_EPS:
                continue
            c2 = 1.0
        elif c2 < -1.0:
            if c2 < -1.0 - _REACH_EPS:
                continue
            c2 = -1.0
        base = math.atan2(b, a)
        s2abs = math.sqrt(max(0.0, 1.0 - c2 * c2))
        k = l1 + l2 * c2
        for up in (True, False):
            # elbow above the shoulder-wrist line: elbow < 0 when the wrist is ahead (a >= 0)
            s2 = -s2abs if (up == (a >= 0.0)) else s2abs
            q2 = math.atan2(s2, c2)
            q1 = base - math.atan2(l2 * s2, k)
            q3 = (phi - q1 - q2) if (fp.wrist is not None and phi is not None) else 0.0
            out.append((f"{side}/elbow_{'up' if up else 'down'}", yaw, q1, q2, q3))
            if s2abs == 0.0:
                break  # elbow straight: up and down coincide
    return out


def wrap_into(value: float, lower: float, upper: float, ref: float, tol: float = 1e-12) -> float | None:
    """``value + 2 pi k`` inside [lower, upper] (nearest ``ref`` if several), or None."""
    if lower <= value <= upper and upper - lower < TWO_PI - 2 * tol:
        return value  # the only candidate: no other k fits in an interval narrower than 2 pi
    best: float | None = None
    k0 = math.floor((lower - value) / TWO_PI)
    for k in range(k0, k0 + 3):
        v = value + k * TWO_PI
        if lower - tol <= v <= upper + tol:
            v = min(max(v, lower), upper)
            if best is None or abs(v - ref) < abs(best - ref):
                best = v
    return best


def branches_batch(fp: FamilyParams, points: FloatArray, phi: FloatArray | None) -> dict[str, FloatArray]:
    """Vectorised :func:`branches`: points (m, 3) [m], phi (m,) or None.

    Returns, per branch name, an (m, 4) array of (yaw, shoulder, elbow, wrist) [rad], NaN
    where the branch does not exist for that target.
    """
    x, y, z = points[:, 0], points[:, 1], points[:, 2]
    h2 = x * x + y * y - fp.py * fp.py
    h2 = np.where((h2 < 0) & (h2 >= -_REACH_EPS), 0.0, h2)
    with np.errstate(invalid="ignore"):
        h = np.sqrt(h2)  # NaN where out of reach
    bearing = np.arctan2(y, x)
    b = z - fp.pz - fp.oz
    has_wrist = fp.wrist is not None and phi is not None
    if has_wrist:
        assert phi is not None
        b = b - fp.l3 * np.sin(phi)
        hand_u = fp.l3 * np.cos(phi)
    else:
        hand_u = np.zeros_like(x)
    out: dict[str, FloatArray] = {}
    for side, u in (("front", h), ("flipped", -h)):
        yaw = bearing - np.arctan2(fp.py, u)
        a = u - fp.px - fp.ox - hand_u
        c2 = (a * a + b * b - fp.l1 ** 2 - fp.l2 ** 2) / (2 * fp.l1 * fp.l2)
        c2 = np.where((np.abs(c2) > 1.0) & (np.abs(c2) <= 1.0 + _REACH_EPS), np.sign(c2), c2)
        with np.errstate(invalid="ignore"):
            s2abs = np.sqrt(1.0 - c2 * c2)  # NaN where out of reach
        base = np.arctan2(b, a)
        k = fp.l1 + fp.l2 * c2
        for up in (True, False):
            s2 = np.where((a >= 0.0) == up, -s2abs, s2abs)
            q2 = np.arctan2(s2, c2)
            q1 = base - np.arctan2(fp.l2 * s2, k)
            q3 = (phi - q1 - q2) if has_wrist else np.zeros_like(q1)
            arr = np.stack([yaw, q1, q2, q3], axis=1)
            arr[np.isnan(s2abs) | np.isnan(h)] = np.nan
            if side == "flipped":
                arr[h == 0.0] = np.nan
            out[f"{side}/elbow_{'up' if up else 'down'}"] = arr
    return out


def wrap_into_batch(values: FloatArray, lower: float, upper: float, ref: FloatArray | float,
                    tol: float = 1e-12) -> FloatArray:
    """Vectorised :func:`wrap_into`: NaN where no ``value + 2 pi k`` fits in the limits."""
    best = np.full_like(values, np.nan)
    best_d = np.full_like(values, np.inf)
    k0 = np.floor((lower - values) / TWO_PI)
    for dk in range(3):
        v = values + (k0 + dk) * TWO_PI
        inside = (v >= lower - tol) & (v <= upper + tol)
        v = np.clip(v, lower, upper)
        d = np.abs(v - ref)
        take = inside & (d < best_d)
        best = np.where(take, v, best)
        best_d = np.where(take, d, best_d)
    return best
