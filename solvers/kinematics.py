"""The URDF's serial chain, compiled: the tool's exact pose and its derivatives, any arm.

:class:`Chain` is the chain from the base frame to the tool frame as Pinocchio's model has it
(each joint's placement in the previous one's frame, its axis, revolute or prismatic, the
coordinate of ``q`` it reads, a mimic joint's multiplier and offset) with the arm's limits in
the URDF's angles: the exact model, for the numerical IK and for refining an idealised closed
form, about 0.2 us a pose for six joints. Built by :mod:`solvers.arm` from the Robot; entry
points take it packed (:mod:`solvers.packed`) and :func:`chain_of` unpacks it.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from armd.robots.types import FloatArray

from .jit import entry, jit, register_tuples
from .packed import Packed, float_at, floats1, floats2, floats3, int_at, ints1

IntArray = NDArray[np.int64]


class Chain(NamedTuple):
    """The chain base -> tool (k joints) and the arm's limits (n joints), the URDF's angles."""

    placement: FloatArray  # (k, 4, 4) each joint's frame in the previous joint's (the first: in base)
    axis: FloatArray  # (k, 3) its axis in its own frame (unit)
    prismatic: IntArray  # (k,) 1 prismatic, 0 revolute
    coordinate: IntArray  # (k,) the coordinate of q it reads
    scale: FloatArray  # (k,) its value = scale q[coordinate] + offset (a mimic joint's; else 1, 0)
    offset: FloatArray  # (k,)
    tool: FloatArray  # (4, 4) the tool frame in the last joint's frame
    tool_axis: FloatArray  # (3,) the tool axis in the tool frame (unit)
    lower: FloatArray  # (n,) box limits [rad or m]
    upper: FloatArray
    C: FloatArray  # (c, n) coupled limits clo <= C q <= chi
    clo: FloatArray
    chi: FloatArray
    yaw: int  # the yaw joint whose heading the tool pitch is measured in (-1: the tool axis's own)
    yaw_sign: float  # heading = yaw_sign q[yaw] + yaw_zero [rad]
    yaw_zero: float


CHAIN_FIELDS = (
    ("placement", ("f8", 3)),
    ("axis", ("f8", 2)),
    ("prismatic", ("i8", 1)),
    ("coordinate", ("i8", 1)),
    ("scale", ("f8", 1)),
    ("offset", ("f8", 1)),
    ("tool", ("f8", 2)),
    ("tool_axis", ("f8", 1)),
    ("lower", ("f8", 1)),
    ("upper", ("f8", 1)),
    ("C", ("f8", 2)),
    ("clo", ("f8", 1)),
    ("chi", ("f8", 1)),
    ("yaw", ("i8", 0)),
    ("yaw_sign", ("f8", 0)),
    ("yaw_zero", ("f8", 0)),
)
register_tuples({"Chain": Chain}, {"Chain": CHAIN_FIELDS})


@jit
def chain_of(p: Packed) -> Chain:
    """The :class:`Chain` packed in ``p`` (:mod:`solvers.packed`), on views of its arrays: the
    leaves in field order."""
    return Chain(
        floats3(p, 0),
        floats2(p, 1),
        ints1(p, 2),
        ints1(p, 3),
        floats1(p, 4),
        floats1(p, 5),
        floats2(p, 6),
        floats1(p, 7),
        floats1(p, 8),
        floats1(p, 9),
        floats2(p, 10),
        floats1(p, 11),
        floats1(p, 12),
        int_at(p, 13),
        float_at(p, 14),
        float_at(p, 15),
    )


@jit
def chain_work(ch: Chain, n: int) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray]:
    """Scratch for :func:`chain_pose_with` and :func:`chain_jacobian` (made once per iteration,
    not per evaluation): joint origins and axes (k, 3), the tool placement (4, 4), the tool axis
    (3,) and its derivatives (3, n)."""
    k = ch.axis.shape[0]
    return np.empty((k, 3)), np.empty((k, 3)), np.empty((4, 4)), np.empty(3), np.empty((3, n))


@jit
def chain_frames(
    ch: Chain, q: FloatArray, origins: FloatArray, axes: FloatArray, T: FloatArray, d: FloatArray
) -> float:
    """Each joint's origin and axis in base (rows of ``origins``, ``axes``: (k, 3)), the tool
    frame's placement ``T`` (4, 4) and the tool axis in base ``d`` (3,) at ``q``; returns the
    heading [rad] in which the tool pitch is measured: the arm's yaw's, or (no yaw) the tool
    axis's own horizontal direction. ``T`` carries the running placement.

    (Each array is taken from the tuple once and read element by element: Numba counts a
    reference for every field read and every row view, atomically, which inside the loop was
    most of this function's time.)"""
    for i in range(4):
        for j in range(4):
            T[i, j] = 1.0 if i == j else 0.0
    P, ax, scale, coordinate, offset, prismatic = (
        ch.placement,
        ch.axis,
        ch.scale,
        ch.coordinate,
        ch.offset,
        ch.prismatic,
    )
    for k in range(ax.shape[0]):
        for i in range(3):  # T = T P[k]
            r0, r1, r2 = T[i, 0], T[i, 1], T[i, 2]
            T[i, 3] += r0 * P[k, 0, 3] + r1 * P[k, 1, 3] + r2 * P[k, 2, 3]
            T[i, 0] = r0 * P[k, 0, 0] + r1 * P[k, 1, 0] + r2 * P[k, 2, 0]
            T[i, 1] = r0 * P[k, 0, 1] + r1 * P[k, 1, 1] + r2 * P[k, 2, 1]
            T[i, 2] = r0 * P[k, 0, 2] + r1 * P[k, 1, 2] + r2 * P[k, 2, 2]
        x, y, z = ax[k, 0], ax[k, 1], ax[k, 2]
        for i in range(3):
            axes[k, i] = T[i, 0] * x + T[i, 1] * y + T[i, 2] * z
            origins[k, i] = T[i, 3]
        value = scale[k] * q[coordinate[k]] + offset[k]
        if prismatic[k] == 1:
            for i in range(3):
                T[i, 3] += axes[k, i] * value
        else:  # T's rotation times the turn about the local axis (x, y, z) (Rodrigues)
            c, s = math.cos(value), math.sin(value)
            t = 1.0 - c
            K00, K01, K02 = c + x * x * t, x * y * t - z * s, x * z * t + y * s
            K10, K11, K12 = y * x * t + z * s, c + y * y * t, y * z * t - x * s
            K20, K21, K22 = z * x * t - y * s, z * y * t + x * s, c + z * z * t
            for i in range(3):
                r0, r1, r2 = T[i, 0], T[i, 1], T[i, 2]
                T[i, 0] = r0 * K00 + r1 * K10 + r2 * K20
                T[i, 1] = r0 * K01 + r1 * K11 + r2 * K21
                T[i, 2] = r0 * K02 + r1 * K12 + r2 * K22
    M = ch.tool
    for i in range(3):  # T = T tool
        r0, r1, r2 = T[i, 0], T[i, 1], T[i, 2]
        T[i, 3] += r0 * M[0, 3] + r1 * M[1, 3] + r2 * M[2, 3]
        T[i, 0] = r0 * M[0, 0] + r1 * M[1, 0] + r2 * M[2, 0]
        T[i, 1] = r0 * M[0, 1] + r1 * M[1, 1] + r2 * M[2, 1]
        T[i, 2] = r0 * M[0, 2] + r1 * M[1, 2] + r2 * M[2, 2]
    a = ch.tool_axis
    for i in range(3):
        d[i] = T[i, 0] * a[0] + T[i, 1] * a[1] + T[i, 2] * a[2]
    if ch.yaw >= 0:
        return ch.yaw_sign * q[ch.yaw] + ch.yaw_zero
    return math.atan2(d[1], d[0])


@jit
def chain_pose(ch: Chain, q: FloatArray, point: FloatArray) -> float:
    """Tool point [m] into ``point`` (3,) and tool pitch [rad] in [-pi, pi] at ``q``."""
    return chain_pose_with(ch, q, point, chain_work(ch, q.shape[0]))


@jit
def chain_pose_with(ch: Chain, q: FloatArray, point: FloatArray, work: tuple) -> float:
    """:func:`chain_pose` with the scratch of :func:`chain_work`."""
    origins, axes, T, d, _ = work
    h = chain_frames(ch, q, origins, axes, T, d)
    for i in range(3):
        point[i] = T[i, 3]
    return math.atan2(d[2], d[0] * math.cos(h) + d[1] * math.sin(h))


@jit
def chain_jacobian(
    ch: Chain,
    q: FloatArray,
    point: FloatArray,
    Jp: FloatArray,
    pitch_row: FloatArray,
    work: tuple,
) -> float:
    """At ``q``: the tool point into ``point``, d(point)/dq [m/rad] into ``Jp`` (3, n), the tool
    pitch's gradient into ``pitch_row`` (n,); returns the tool pitch [rad]. ``work``:
    :func:`chain_work`."""
    k = ch.axis.shape[0]
    n = q.shape[0]
    origins, axes, T, d, Jd = work
    h = chain_frames(ch, q, origins, axes, T, d)
    for i in range(3):
        point[i] = T[i, 3]
    for i in range(3):
        for c in range(n):
            Jp[i, c] = 0.0
            Jd[i, c] = 0.0
    coordinate, scale, prismatic = ch.coordinate, ch.scale, ch.prismatic
    for j in range(k):
        w0, w1, w2 = axes[j, 0], axes[j, 1], axes[j, 2]
        c = coordinate[j]
        s = scale[j]
        if prismatic[j] == 1:
            Jp[0, c] += s * w0
            Jp[1, c] += s * w1
            Jp[2, c] += s * w2
            continue
        rx, ry, rz = point[0] - origins[j, 0], point[1] - origins[j, 1], point[2] - origins[j, 2]
        Jp[0, c] += s * (w1 * rz - w2 * ry)
        Jp[1, c] += s * (w2 * rx - w0 * rz)
        Jp[2, c] += s * (w0 * ry - w1 * rx)
        Jd[0, c] += s * (w1 * d[2] - w2 * d[1])
        Jd[1, c] += s * (w2 * d[0] - w0 * d[2])
        Jd[2, c] += s * (w0 * d[1] - w1 * d[0])
    ch_, sh = math.cos(h), math.sin(h)
    b = d[2]
    if ch.yaw >= 0:
        a = d[0] * ch_ + d[1] * sh
        for c in range(n):
            pitch_row[c] = Jd[0, c] * ch_ + Jd[1, c] * sh
        pitch_row[ch.yaw] += ch.yaw_sign * (-d[0] * sh + d[1] * ch_)
        da = pitch_row
    else:
        a = math.hypot(d[0], d[1])
        da = pitch_row
        for c in range(n):
            da[c] = (d[0] * Jd[0, c] + d[1] * Jd[1, c]) / max(a, 1e-300)
    r2 = max(a * a + b * b, 1e-300)
    for c in range(n):
        pitch_row[c] = (a * Jd[2, c] - b * da[c]) / r2
    return math.atan2(b, a)


@entry("f8(Chain, f8[:], f8[:])")
def pose(packed_chain: Packed, q: FloatArray, point: FloatArray) -> float:
    """:func:`chain_pose`, for Python (the chain packed): the tool point [m] into ``point`` and
    the tool pitch [rad]."""
    return chain_pose(chain_of(packed_chain), q, point)
