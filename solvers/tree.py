"""Every joint frame of the URDF's tree at once, compiled: what the compiled collision stage places
an arm's shapes with.

:class:`Tree` is Pinocchio's joint tree (its ``parents``, ``jointPlacements`` and joint
models) as arrays, row ``j`` for Pinocchio's joint ``j``, row 0 the universe (the base frame):
each joint's frame at zero in its parent's frame, its axis, revolute or prismatic, the
coordinate of ``q`` it reads and a mimic joint's multiplier and offset. :func:`tree_frames`
gives every joint's placement in the base frame at ``q``, as Pinocchio's ``oMi``: the parent's
placement, times the joint's at zero, times its motion (a turn about a coordinate axis as
Pinocchio's RX, RY, RZ joints turn; about another axis by Rodrigues' formula, as
:func:`armd.solvers.kinematics.chain_frames`, which follows the one branch from the base to the
tool). Built from the model by :func:`armd.solvers.world.tree_of`.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from armd.robots.types import FloatArray

from .jit import jit, register_tuples
from .packed import Packed, floats1, floats2, floats3, ints1

IntArray = NDArray[np.int64]

FIXED, REVOLUTE, PRISMATIC = 0, 1, 2  # a joint's kind (FIXED: the universe only)


class Tree(NamedTuple):
    """Pinocchio's joint tree (J joints, the universe first), the URDF's angles."""

    parent: IntArray  # (J,) the parent joint's row (the universe: -1); a parent comes before its children
    placement: FloatArray  # (J, 4, 4) the joint's frame at zero in its parent's frame
    axis: FloatArray  # (J, 3) its axis in its own frame (unit)
    kind: IntArray  # (J,) FIXED, REVOLUTE or PRISMATIC
    coordinate: IntArray  # (J,) the coordinate of q it reads
    scale: FloatArray  # (J,) its value = scale q[coordinate] + offset [rad or m] (a mimic joint's; else 1, 0)
    offset: FloatArray  # (J,)


TREE_FIELDS = (
    ("parent", ("i8", 1)),
    ("placement", ("f8", 3)),
    ("axis", ("f8", 2)),
    ("kind", ("i8", 1)),
    ("coordinate", ("i8", 1)),
    ("scale", ("f8", 1)),
    ("offset", ("f8", 1)),
)
register_tuples({"Tree": Tree}, {"Tree": TREE_FIELDS})
TREE_LEAVES = len(TREE_FIELDS)  # its leaves in a packed bundle (solvers.packed)


@jit
def tree_at(p: Packed, k: int) -> Tree:
    """The :class:`Tree` whose leaves start at leaf ``k`` of the packed bundle ``p`` (0: a packed
    Tree, or a Shapes'), on views of ``p``'s arrays: the leaves in field order."""
    return Tree(
        ints1(p, k),
        floats3(p, k + 1),
        floats2(p, k + 2),
        ints1(p, k + 3),
        ints1(p, k + 4),
        floats1(p, k + 5),
        floats1(p, k + 6),
    )


@jit
def tree_frames(tree: Tree, q: FloatArray, out: FloatArray) -> None:
    """Every joint's placement in the base frame at ``q`` into ``out`` (J, 4, 4): out[j] =
    out[parent] placement[j] (the joint's motion about or along its axis)."""
    parent, P, ax, kind, coordinate, scale, offset = (
        tree.parent,
        tree.placement,
        tree.axis,
        tree.kind,
        tree.coordinate,
        tree.scale,
        tree.offset,
    )
    for j in range(parent.shape[0]):
        p = parent[j]
        if p < 0:  # the base frame: the joint's placement itself
            for r in range(4):
                for k in range(4):
                    out[j, r, k] = P[j, r, k]
        else:  # out[j] = out[p] P[j]
            for r in range(3):
                a0, a1, a2, a3 = out[p, r, 0], out[p, r, 1], out[p, r, 2], out[p, r, 3]
                for k in range(4):
                    out[j, r, k] = a0 * P[j, 0, k] + a1 * P[j, 1, k] + a2 * P[j, 2, k]
                out[j, r, 3] += a3
            out[j, 3, 0], out[j, 3, 1], out[j, 3, 2], out[j, 3, 3] = 0.0, 0.0, 0.0, 1.0
        if kind[j] == FIXED:
            continue
        value = scale[j] * q[coordinate[j]] + offset[j]
        x, y, z = ax[j, 0], ax[j, 1], ax[j, 2]
        if kind[j] == PRISMATIC:
            for r in range(3):
                out[j, r, 3] += (out[j, r, 0] * x + out[j, r, 1] * y + out[j, r, 2] * z) * value
            continue
        c, s = math.cos(value), math.sin(value)
        if x == 0.0 and y == 0.0:  # about +-z: the first two columns turn
            s *= z
            for r in range(3):
                r0, r1 = out[j, r, 0], out[j, r, 1]
                out[j, r, 0] = r0 * c + r1 * s
                out[j, r, 1] = r1 * c - r0 * s
        elif x == 0.0 and z == 0.0:  # about +-y
            s *= y
            for r in range(3):
                r0, r2 = out[j, r, 0], out[j, r, 2]
                out[j, r, 0] = r0 * c - r2 * s
                out[j, r, 2] = r0 * s + r2 * c
        elif y == 0.0 and z == 0.0:  # about +-x
            s *= x
            for r in range(3):
                r1, r2 = out[j, r, 1], out[j, r, 2]
                out[j, r, 1] = r1 * c + r2 * s
                out[j, r, 2] = r2 * c - r1 * s
        else:  # the rotation times the turn about (x, y, z) (Rodrigues)
            t = 1.0 - c
            K00, K01, K02 = c + x * x * t, x * y * t - z * s, x * z * t + y * s
            K10, K11, K12 = y * x * t + z * s, c + y * y * t, y * z * t - x * s
            K20, K21, K22 = z * x * t - y * s, z * y * t + x * s, c + z * z * t
            for r in range(3):
                r0, r1, r2 = out[j, r, 0], out[j, r, 1], out[j, r, 2]
                out[j, r, 0] = r0 * K00 + r1 * K10 + r2 * K20
                out[j, r, 1] = r0 * K01 + r1 * K11 + r2 * K21
                out[j, r, 2] = r0 * K02 + r1 * K12 + r2 * K22
