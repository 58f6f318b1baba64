"""One arm as the compiled code takes it: two named tuples of arrays, built once per arm.

:class:`Family` is the closed-form family's numbers in the family's own joint angles (each
pitch link horizontal at 0, positive lifting; the yaw about +z through the origin); every
compiled solver works in it. :class:`Arm` is what Python hands over: the family, and the map
between the family's angles and the URDF's (``family = sign q + zero``, the yaw axis's place in
``base``, the tool pitch's offset from the family's, and a wrist roll that moves the tool),
so that joint angles stay the URDF's; entry points take them packed (:mod:`solvers.packed`),
and :func:`arm_of` and :func:`family_at` unpack them. :func:`view` gives the family for a joint vector (a roll
that moves the tool point changes the last link), :func:`to_family` and :func:`from_family` map
joint vectors. Built by :func:`armd.solvers.arm.arm_state` from the arm's
:class:`~armd.robots.geometry.Geometry`.

Every array is C-contiguous (its signature says ``::1``): a view the compiled code makes of one
is of the same type as the arm's own, so one compiled version serves both.
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from armd.robots.types import FloatArray

from .jit import jit, register_tuples
from .packed import Packed, bool_at, float_at, floats1, floats2, int_at, ints1

IntArray = NDArray[np.int64]

# P's entries: pivot (u, v, z) in the yaw frame, link lengths, level tool offset (outward, upward) [m]
PX, PY, PZ, L1, L2, L3, OX, OZ = range(8)
# J's entries: joint indices of the family's joints (wrist -1: none)
YAW, SHOULDER, ELBOW, WRIST = range(4)


class Family(NamedTuple):
    """The closed-form family in its own joint angles (see :mod:`armd.robots.geometry`)."""

    P: FloatArray  # (8,) px, py, pz, l1, l2, l3, ox, oz [m]
    J: IntArray  # (4,) yaw, shoulder, elbow, wrist joint indices; wrist -1 when there is none
    lower: FloatArray  # (n,) box limits [rad], in the family's angles
    upper: FloatArray
    weights: FloatArray  # (n,) 1 / vmax [s/rad]: joint distance ~ time to get there
    C: FloatArray  # (k, n) coupled limits clo <= C theta <= chi, in the family's angles
    clo: FloatArray
    chi: FloatArray
    exact_pitch_search: bool  # no coupled limit touches a pitch joint: boundary pitches are exact
    level: bool  # the tool is held level by a linkage: its pitch is always 0


class Arm(NamedTuple):
    """:class:`Family` and its map to the URDF's joint angles, tool point and tool pitch."""

    family: Family  # at the roll joint's 0 (or for any roll, where the roll does not move the tool)
    sign: FloatArray  # (n,) family angle = sign q + zero; 1 and 0 for joints outside the family
    zero: FloatArray  # (n,) [rad]
    lower: FloatArray  # (n,) box limits [rad], the URDF's angles
    upper: FloatArray
    base: FloatArray  # (2,) the yaw axis in base (x, y) [m]
    pitch_offset: float  # [rad] tool pitch = the family's (sum of the pitch angles) + this
    roll: int  # joint index of a wrist roll that moves the tool point or pitch, else -1
    roll_model: FloatArray  # (4, 3) a, d, w, x0 in the last link's frame (robots.geometry.RollModel)


# What each field is, for the checks of native calls and the build's signatures (solvers.jit):
# (dtype, number of dimensions) or a nested tuple's name.
FIELDS: dict[str, tuple[tuple[str, Any], ...]] = {
    "Family": (
        ("P", ("f8", 1)),
        ("J", ("i8", 1)),
        ("lower", ("f8", 1)),
        ("upper", ("f8", 1)),
        ("weights", ("f8", 1)),
        ("C", ("f8", 2)),
        ("clo", ("f8", 1)),
        ("chi", ("f8", 1)),
        ("exact_pitch_search", ("b1", 0)),
        ("level", ("b1", 0)),
    ),
    "Arm": (
        ("family", "Family"),
        ("sign", ("f8", 1)),
        ("zero", ("f8", 1)),
        ("lower", ("f8", 1)),
        ("upper", ("f8", 1)),
        ("base", ("f8", 1)),
        ("pitch_offset", ("f8", 0)),
        ("roll", ("i8", 0)),
        ("roll_model", ("f8", 2)),
    ),
}
CLASSES = {"Family": Family, "Arm": Arm}
register_tuples(CLASSES, FIELDS)
FAMILY_LEAVES = 10  # a Family's leaves in a packed bundle (solvers.packed): an Arm's first ten


@jit
def family_at(p: Packed, k: int) -> Family:
    """The :class:`Family` whose leaves start at leaf ``k`` of the packed bundle ``p`` (0: a packed
    Family, or an Arm's), on views of ``p``'s arrays: the leaves in field order."""
    return Family(
        floats1(p, k),
        ints1(p, k + 1),
        floats1(p, k + 2),
        floats1(p, k + 3),
        floats1(p, k + 4),
        floats2(p, k + 5),
        floats1(p, k + 6),
        floats1(p, k + 7),
        bool_at(p, k + 8),
        bool_at(p, k + 9),
    )


@jit
def arm_of(p: Packed) -> Arm:
    """The :class:`Arm` packed in ``p``, on views of its arrays: the family's leaves first."""
    k = FAMILY_LEAVES
    return Arm(
        family_at(p, 0),
        floats1(p, k),
        floats1(p, k + 1),
        floats1(p, k + 2),
        floats1(p, k + 3),
        floats1(p, k + 4),
        float_at(p, k + 5),
        int_at(p, k + 6),
        floats2(p, k + 7),
    )


@jit
def rotate(d: FloatArray, angle: float, v: FloatArray, out: FloatArray) -> None:
    """``v`` turned by ``angle`` about the unit axis ``d`` (Rodrigues) into ``out`` (3,)."""
    c, s = math.cos(angle), math.sin(angle)
    dv = d[0] * v[0] + d[1] * v[1] + d[2] * v[2]
    cx = d[1] * v[2] - d[2] * v[1]
    cy = d[2] * v[0] - d[0] * v[2]
    cz = d[0] * v[1] - d[1] * v[0]
    out[0] = v[0] * c + cx * s + d[0] * dv * (1.0 - c)
    out[1] = v[1] * c + cy * s + d[1] * dv * (1.0 - c)
    out[2] = v[2] * c + cz * s + d[2] * dv * (1.0 - c)


@jit
def last_link(arm: Arm, roll: float) -> tuple[float, float, float, float]:
    """The last pitch link at this roll: (length [m], angle in the link's frame [rad], lateral
    offset [m], tool pitch's offset from the link's angle [rad])."""
    m = arm.roll_model
    t = np.empty(3)
    x = np.empty(3)
    rotate(m[1], roll, m[2], t)
    rotate(m[1], roll, m[3], x)
    tu, tv, tz = m[0, 0] + t[0], m[0, 1] + t[1], m[0, 2] + t[2]
    angle = math.atan2(tz, tu)
    return math.hypot(tu, tz), angle, tv, math.atan2(x[2], x[0]) - angle


@jit
def view(arm: Arm, q: FloatArray) -> tuple[Family, FloatArray, float]:
    """The family at joint vector ``q`` (URDF angles), its zeros and its tool pitch offset: the
    arm's own where no roll moves the tool; else with the last link as the roll ``q`` puts it."""
    f = arm.family
    if arm.roll < 0:
        return f, arm.zero, arm.pitch_offset
    _, angle0, lateral0, _ = last_link(arm, 0.0)
    length, angle, lateral, offset = last_link(arm, q[arm.roll])
    last = f.J[WRIST] if f.J[WRIST] >= 0 else f.J[ELBOW]
    turn = angle - angle0  # the last link's angle moves: its joint's zero with it
    P = f.P.copy()
    P[L3 if f.J[WRIST] >= 0 else L2] = length
    P[PY] = f.P[PY] + lateral - lateral0
    zero = arm.zero.copy()
    zero[last] += turn
    lower = f.lower.copy()
    upper = f.upper.copy()
    lower[last] += turn
    upper[last] += turn
    clo = f.clo.copy()
    chi = f.chi.copy()
    for r in range(f.C.shape[0]):
        clo[r] += f.C[r, last] * turn
        chi[r] += f.C[r, last] * turn
    g = Family(P, f.J, lower, upper, f.weights, f.C, clo, chi, f.exact_pitch_search, f.level)
    return g, zero, offset


@jit
def to_family(arm: Arm, zero: FloatArray, q: FloatArray, out: FloatArray) -> None:
    """Joint vector ``q`` (URDF angles) in the family's angles, into ``out``."""
    for i in range(q.shape[0]):
        out[i] = arm.sign[i] * q[i] + zero[i]


@jit
def from_family(arm: Arm, zero: FloatArray, theta: FloatArray, out: FloatArray) -> None:
    """Joint vector ``theta`` (the family's angles) in the URDF's, into ``out`` (may be ``theta``),
    kept in the URDF's box: the map's rounding never takes a joint on its limit past it."""
    for i in range(theta.shape[0]):
        v = arm.sign[i] * (theta[i] - zero[i])
        out[i] = min(max(v, arm.lower[i]), arm.upper[i])


@jit
def family_pitch(f: Family, theta: FloatArray) -> float:
    """The family's tool pitch at ``theta`` [rad], not wrapped: the sum of the pitch joints (0 for
    a level arm)."""
    if f.level:
        return 0.0
    s = 0.0
    for k in range(SHOULDER, WRIST + 1):
        if f.J[k] >= 0:
            s += theta[f.J[k]]
    return s
