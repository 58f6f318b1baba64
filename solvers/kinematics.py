"""The URDF's serial chain, compiled: the tool's exact pose and its derivatives, any arm.

:class:`Chain` is the chain from the base frame to the tool frame as Pinocchio's model has it
(each joint's placement in the previous one's frame, its axis, revolute or prismatic, the
coordinate of ``q`` it reads, a mimic joint's multiplier and offset) with the arm's limits in
the URDF's angles: the exact model, for the numerical IK and for refining an idealised closed
form, about 0.2 us a pose for six joints. Built by :mod:`solvers.arm` from the Robot.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from armd.robots.types import FloatArray

from .jit import entry, jit, register_tuples

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
def chain_work(ch: Chain, n: int) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray, FloatArray]:
    """Scratch for :func:`chain_pose_with` and :func:`chain_jacobian` (made once per iteration,
    not per evaluation): joint origins and axes (k, 3), the tool placement (4, 4), the tool axis
    (3,), its derivatives (3, n) and a (3, 3)."""
    k = ch.axis.shape[0]
    return np.empty((k, 3)), np.empty((k, 3)), np.empty((4, 4)), np.empty(3), np.empty((3, n)), np.empty((3, 3))


@jit
def chain_frames(ch: Chain, q: FloatArray, origins: FloatArray, axes: FloatArray, T: FloatArray, A: FloatArray) -> None:
    """Each joint's origin and axis in base (rows of ``origins``, ``axes``: (k, 3)) and the tool
    frame's placement ``T`` (4, 4) at ``q``. ``T`` carries the running placement; ``A`` (3, 3) is
    scratch."""
    for i in range(4):
        for j in range(4):
            T[i, j] = 1.0 if i == j else 0.0
    for k in range(ch.axis.shape[0]):
        _compose(T, ch.placement[k], A)
        a = ch.axis[k]
        for i in range(3):
            axes[k, i] = T[i, 0] * a[0] + T[i, 1] * a[1] + T[i, 2] * a[2]
            origins[k, i] = T[i, 3]
        value = ch.scale[k] * q[ch.coordinate[k]] + ch.offset[k]
        if ch.prismatic[k] == 1:
            for i in range(3):
                T[i, 3] += axes[k, i] * value
        else:  # T's rotation times the turn about the local axis a (Rodrigues)
            c, s = math.cos(value), math.sin(value)
            t = 1.0 - c
            x, y, z = a[0], a[1], a[2]
            K00, K01, K02 = c + x * x * t, x * y * t - z * s, x * z * t + y * s
            K10, K11, K12 = y * x * t + z * s, c + y * y * t, y * z * t - x * s
            K20, K21, K22 = z * x * t - y * s, z * y * t + x * s, c + z * z * t
            for i in range(3):
                r0, r1, r2 = T[i, 0], T[i, 1], T[i, 2]
                T[i, 0] = r0 * K00 + r1 * K10 + r2 * K20
                T[i, 1] = r0 * K01 + r1 * K11 + r2 * K21
                T[i, 2] = r0 * K02 + r1 * K12 + r2 * K22
    _compose(T, ch.tool, A)


@jit
def _compose(T: FloatArray, M: FloatArray, A: FloatArray) -> None:
    """``T`` = T M in place (both rigid placements, 4 x 4); ``A`` (3, 3) is scratch."""
    for i in range(3):
        T[i, 3] += T[i, 0] * M[0, 3] + T[i, 1] * M[1, 3] + T[i, 2] * M[2, 3]
    for i in range(3):
        for j in range(3):
            A[i, j] = T[i, 0] * M[0, j] + T[i, 1] * M[1, j] + T[i, 2] * M[2, j]
    for i in range(3):
        for j in range(3):
            T[i, j] = A[i, j]


@jit
def tool_direction(ch: Chain, T: FloatArray, d: FloatArray) -> None:
    """The tool axis in base at tool placement ``T`` into ``d`` (3,)."""
    for i in range(3):
        d[i] = T[i, 0] * ch.tool_axis[0] + T[i, 1] * ch.tool_axis[1] + T[i, 2] * ch.tool_axis[2]


@jit
def heading_of(ch: Chain, q: FloatArray, d: FloatArray) -> float:
    """The direction [rad] in which the tool pitch is measured: the arm's yaw heading, or (no
    yaw) the tool axis's own horizontal direction."""
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
    origins, axes, T, d, _, A = work
    chain_frames(ch, q, origins, axes, T, A)
    tool_direction(ch, T, d)
    for i in range(3):
        point[i] = T[i, 3]
    h = heading_of(ch, q, d)
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
    origins, axes, T, d, Jd, A = work
    chain_frames(ch, q, origins, axes, T, A)
    tool_direction(ch, T, d)
    for i in range(3):
        point[i] = T[i, 3]
    Jp[:, :] = 0.0
    Jd[:, :] = 0.0
    for j in range(k):
        w = axes[j]
        c = ch.coordinate[j]
        s = ch.scale[j]
        if ch.prismatic[j] == 1:
            for i in range(3):
                Jp[i, c] += s * w[i]
            continue
        rx, ry, rz = point[0] - origins[j, 0], point[1] - origins[j, 1], point[2] - origins[j, 2]
        Jp[0, c] += s * (w[1] * rz - w[2] * ry)
        Jp[1, c] += s * (w[2] * rx - w[0] * rz)
        Jp[2, c] += s * (w[0] * ry - w[1] * rx)
        Jd[0, c] += s * (w[1] * d[2] - w[2] * d[1])
        Jd[1, c] += s * (w[2] * d[0] - w[0] * d[2])
        Jd[2, c] += s * (w[0] * d[1] - w[1] * d[0])
    h = heading_of(ch, q, d)
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
def pose(ch: Chain, q: FloatArray, point: FloatArray) -> float:
    """:func:`chain_pose`, for Python: the tool point [m] into ``point`` and the tool pitch [rad]."""
    return chain_pose(ch, q, point)
