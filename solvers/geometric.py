"""The closed-form geometric solver for the family "yaw + planar two-link + optional wrist
pitch + fixed tool offsets" (seeds 000-004 are all instances; parameters from
``[geometry]`` in robot.toml, see :mod:`robots.geometry`).

For a target point (and a tool pitch ``phi`` when the arm has a wrist) it gives every
branch: the yaw pointing at the target (``front``) or away from it with the arm reaching
back over the top (``flipped``), times elbow ``up``/``down``. It generalises the seeds:

* yaw with a lateral pivot offset ``v`` (seed 004's ``y_steer``) is exact, not the seed's
  planar approximation: ``u = +-sqrt(x^2 + y^2 - v^2)``, ``yaw = atan2(y, x) - atan2(v, u)``;
* the planar two-link is seed 000 eq. 2-3 / seed 003 eq. 30-33 (law of cosines), after
  subtracting the pivot, the level tool offset and, with a wrist, the hand along ``phi``
  (seed 000 eq. 1 for ``phi`` = 0 and -pi/2);
* the wrist is ``phi - shoulder - elbow`` (seed 000 eq. 12-13).

The functions are compiled with Numba (plain floats and small arrays, no Python objects),
so one closed-form solve costs about a microsecond, and the same code serves the single
and the batch IK. Parameters travel as a :class:`~armd.solvers.arrays.Family` (``P = [px, py,
pz, l1, l2, l3, ox, oz]``, ``J = [yaw, shoulder, elbow, wrist]`` joint indices, ``wrist = -1``:
none), joint angles in the family's (:mod:`armd.solvers.arrays` maps them to the URDF's).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from armd.robots.angles import wrap
from armd.robots.types import FloatArray

from .arrays import Family, arm_of, family_pitch, to_family, view
from .jit import entry, jit
from .packed import Packed

IntArray = NDArray[np.int64]

TWO_PI = 2.0 * math.pi
REACH_EPS = 1e-12  # slack on |cos(elbow)| <= 1 for targets exactly on the workspace boundary

BRANCH_NAMES = ("front/elbow_up", "front/elbow_down", "flipped/elbow_up", "flipped/elbow_down")
_FRONT, _FLIPPED = 0, 2  # branch id = side + (0 up | 1 down)


wrap_angle = entry("f8(f8)")(wrap)  # (armd.robots.angles' wrap, compiled: [-pi, pi))


@jit
def wrap_into(value: float, lower: float, upper: float, ref: float, tol: float) -> tuple[bool, float]:
    """``value + 2 pi k`` inside [lower, upper] (nearest ``ref`` if several): (found, value)."""
    if lower <= value <= upper and upper - lower < TWO_PI - 2.0 * tol:
        return True, value  # the only candidate: no other k fits in an interval narrower than 2 pi
    found = False
    best = value
    k0 = math.floor((lower - value) / TWO_PI)
    for dk in range(3):
        v = value + (k0 + dk) * TWO_PI
        if lower - tol <= v <= upper + tol:
            v = min(max(v, lower), upper)
            if not found or abs(v - ref) < abs(best - ref):
                best = v
                found = True
    return found, best


@jit
def two_link(p: float, q: float, tx: float, ty: float, out: FloatArray) -> int:
    """Planar two-link (lengths p, q) reaching (tx, ty); writes rows (absolute angle 1, relative
    angle 2) into ``out`` (2, 2) and returns how many (0, 1 when straight or folded, or 2)."""
    if p < REACH_EPS or q < REACH_EPS:
        return 0
    c = (tx * tx + ty * ty - p * p - q * q) / (2.0 * p * q)
    if c > 1.0:
        if c > 1.0 + REACH_EPS:
            return 0
        c = 1.0
    elif c < -1.0:
        if c < -1.0 - REACH_EPS:
            return 0
        c = -1.0
    s = math.sqrt(max(0.0, 1.0 - c * c))
    base = math.atan2(ty, tx)
    count = 0
    for sign in (1.0, -1.0):
        s2 = sign * s
        out[count, 0] = base - math.atan2(q * s2, p + q * c)
        out[count, 1] = math.atan2(s2, c)
        count += 1
        if s == 0.0:
            break
    return count


@jit
def branches(P: FloatArray, has_wrist: bool, x: float, y: float, z: float, phi: float, out: FloatArray) -> int:
    """Every branch for target (x, y, z) [m] and tool pitch ``phi`` [rad] (ignored without a wrist).

    Writes rows (branch id, yaw, shoulder, elbow, wrist) into ``out`` (4, 5), angles [rad]
    unwrapped (wrist 0 without one); returns the number of rows (0: out of reach).
    """
    px, py, pz, l1, l2, l3, ox, oz = P[0], P[1], P[2], P[3], P[4], P[5], P[6], P[7]
    h2 = x * x + y * y - py * py
    if h2 < 0.0:
        if h2 < -REACH_EPS:
            return 0
        h2 = 0.0
    h = math.sqrt(h2)
    bearing = math.atan2(y, x)
    b = z - pz - oz
    hand_u = 0.0
    if has_wrist:
        b -= l3 * math.sin(phi)
        hand_u = l3 * math.cos(phi)
    denom = 2.0 * l1 * l2
    count = 0
    for side in (_FRONT, _FLIPPED):
        u = h if side == _FRONT else -h
        if side == _FLIPPED and h == 0.0:
            break
        yaw = bearing - math.atan2(py, u)
        a = u - px - ox - hand_u
        c2 = (a * a + b * b - l1 * l1 - l2 * l2) / denom
        if c2 > 1.0:
            if c2 > 1.0 + REACH_EPS:
                continue
            c2 = 1.0
        elif c2 < -1.0:
            if c2 < -1.0 - REACH_EPS:
                continue
            c2 = -1.0
        base = math.atan2(b, a)
        s2abs = math.sqrt(max(0.0, 1.0 - c2 * c2))
        k = l1 + l2 * c2
        for down in (0, 1):
            # elbow above the shoulder-wrist line: elbow < 0 when the wrist is ahead (a >= 0)
            s2 = -s2abs if ((down == 0) == (a >= 0.0)) else s2abs
            q2 = math.atan2(s2, c2)
            q1 = base - math.atan2(l2 * s2, k)
            out[count, 0] = side + down
            out[count, 1] = yaw
            out[count, 2] = q1
            out[count, 3] = q2
            out[count, 4] = (phi - q1 - q2) if has_wrist else 0.0
            count += 1
            if s2abs == 0.0:
                break  # elbow straight or folded: up and down coincide
    return count


@jit
def family_fk(f: Family, theta: FloatArray, out: FloatArray) -> None:
    """Tool point [m] by the family's formula (:mod:`robots.geometry`) at ``theta`` (the family's
    angles) into ``out`` (3,), in the family's frame (the yaw axis at the origin)."""
    P, J = f.P, f.J
    px, py, pz, l1, l2, l3, ox, oz = P[0], P[1], P[2], P[3], P[4], P[5], P[6], P[7]
    p1 = theta[J[1]]
    p2 = p1 + theta[J[2]]
    u = px + l1 * math.cos(p1) + l2 * math.cos(p2) + ox
    zz = pz + l1 * math.sin(p1) + l2 * math.sin(p2) + oz
    if J[3] >= 0:
        p3 = p2 + theta[J[3]]
        u += l3 * math.cos(p3)
        zz += l3 * math.sin(p3)
    c, s = math.cos(theta[J[0]]), math.sin(theta[J[0]])
    out[0] = c * u - s * py
    out[1] = s * u + c * py
    out[2] = zz


@entry("f8(Arm, f8[:], f8[:])")
def arm_pose(packed_arm: Packed, q: FloatArray, out: FloatArray) -> float:
    """Tool point [m] in ``base`` into ``out`` (3,) and tool pitch [rad] (not wrapped) at ``q``
    (the URDF's angles), by the family's formula and the arm's map (``packed_arm``: the
    :class:`~armd.solvers.arrays.Arm` packed)."""
    arm = arm_of(packed_arm)
    f, zero, offset = view(arm, q)
    theta = np.empty(q.shape[0])
    to_family(arm, zero, q, theta)
    family_fk(f, theta, out)
    out[0] += arm.base[0]
    out[1] += arm.base[1]
    return 0.0 if f.level else family_pitch(f, theta) + offset
