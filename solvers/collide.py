"""An arm's world checked in compiled code: its shapes placed at ``q`` and every checked pair's
distance, in one call.

:class:`Shapes` is what :class:`~armd.robots.collision.CollisionModel` checks with coal, as
arrays (built by :class:`armd.solvers.world.CompiledWorld`): the joint tree
(:class:`~armd.solvers.tree.Tree`), each primitive shape (:mod:`armd.solvers.narrowphase`'s
kinds and sizes) with the joint frame it hangs on and its placement there (the ground and the
obstacles on the base frame's row 0), a capsule about each shape's origin holding it, and the
pairs, in CollisionModel's order (a half-space always a pair's second). A call computes every
joint's frame from ``q`` (the tree's forward kinematics), places the shapes, and goes through
the pairs; a pair whose bounding capsules are farther apart than the question needs is passed
over (first the spheres about them), and GJK stops as soon as a separating plane answers it:

- :func:`first_collision`: the first pair in contact, or -1 (as
  :meth:`CollisionModel.first_contact`: coal's ``computeCollisions`` stopping at the first);
- :func:`first_collisions`: the same for each row of a batch of configurations (the planner's
  samples, the IK's branches: one call);
- :func:`min_distance`: the smallest distance [m] of any pair and that pair (as
  :meth:`CollisionModel.clearance`), or, at the first pair in contact, that pair and its value
  (<= TOUCH: not a penetration depth, where coal's is the deepest pair's); :func:`min_distances`:
  the same for a batch;
- :func:`pair_distances`: every pair's distance; :func:`primitive_distance`: two shapes'.

A contact is a distance at or below :data:`~armd.solvers.narrowphase.TOUCH` (1e-12 m). One
engine, :func:`run`, answers all of them; compiled callers (the IK's branch loop, the planner's
sample loop) call it with the bundle's arrays. The entry points take the bundle packed
(:mod:`armd.solvers.packed`): :func:`shapes_of` unpacks it.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from armd.robots.types import FloatArray

from .jit import entry, jit, register_tuples
from .narrowphase import HALFSPACE, TOUCH, above_halfspace, pair_distance, segments
from .packed import Packed, floats2, floats3, ints1, ints2
from .tree import TREE_LEAVES, Tree, tree_at, tree_frames

IntArray = NDArray[np.int64]


class Shapes(NamedTuple):
    """An arm's primitive shapes and its world's, on its joint tree, and the pairs checked."""

    tree: Tree
    kind: IntArray  # (S,) narrowphase's SPHERE, CAPSULE, BOX, CYLINDER or HALFSPACE
    size: FloatArray  # (S, 4) narrowphase's layout [m]
    joint: IntArray  # (S,) the tree's row the shape hangs on (0: the base frame)
    local: FloatArray  # (S, 4, 4) its placement in that joint's frame
    axis: IntArray  # (S,) the axis (0 x, 1 y, 2 z) in its own frame of a capsule about its origin holding it
    bound: FloatArray  # (S, 2) that capsule's half-length and radius [m] (a half-space: inf, inf)
    pairs: IntArray  # (P, 2) the shapes of each pair checked, in CollisionModel's order


SHAPES_FIELDS = (
    ("tree", "Tree"),
    ("kind", ("i8", 1)),
    ("size", ("f8", 2)),
    ("joint", ("i8", 1)),
    ("local", ("f8", 3)),
    ("axis", ("i8", 1)),
    ("bound", ("f8", 2)),
    ("pairs", ("i8", 2)),
)
register_tuples({"Shapes": Shapes}, {"Shapes": SHAPES_FIELDS})


@jit
def shapes_of(p: Packed) -> Shapes:
    """The :class:`Shapes` packed in ``p`` (:mod:`solvers.packed`), on views of its arrays: the
    tree's leaves first."""
    k = TREE_LEAVES
    return Shapes(
        tree_at(p, 0),
        ints1(p, k),
        floats2(p, k + 1),
        ints1(p, k + 2),
        floats3(p, k + 3),
        ints1(p, k + 4),
        floats2(p, k + 5),
        ints2(p, k + 6),
    )


# What a check asks (one engine, :func:`run`, answers all: see the module's doc)
FIRST, NEAREST, EVERY = 0, 1, 2


# (The engine takes the bundle's arrays one by one, and loops over the configurations and the
# pairs itself: a function that takes arrays and calls a compiled function that is not inlined
# counts a reference to each array on entry and exit, atomically, which costs more than a
# closed form; this way that happens once a call, not once a pair.)


@jit
def run(
    tree: Tree,
    joint: IntArray,
    L: FloatArray,
    kind: IntArray,
    size: FloatArray,
    axis: IntArray,
    bound: FloatArray,
    pairs: IntArray,
    Q: FloatArray,
    ask: int,
    index: IntArray,
    distance: FloatArray,
) -> int:
    """Each row of ``Q`` (m, n) checked (``ask``): FIRST: the first pair in contact into
    ``index`` (m,) (-1: none); NEAREST: the smallest distance [m] into ``distance`` (m,) and its
    pair into ``index`` (at the first pair in contact: that one); EVERY (one row): every pair's
    distance into ``distance`` (P,), the first pair in contact into ``index[0]``. Returns how
    many rows have a pair in contact."""
    frames = np.empty((tree.parent.shape[0], 4, 4))
    M = np.empty((kind.shape[0], 4, 4))
    work = np.empty((7, 4))
    hits = 0
    for i in range(Q.shape[0]):
        tree_frames(tree, Q[i], frames)
        for s in range(joint.shape[0]):  # each shape's placement: its joint's frame times its own
            j = joint[s]
            for r in range(3):
                a0, a1, a2, a3 = frames[j, r, 0], frames[j, r, 1], frames[j, r, 2], frames[j, r, 3]
                for c in range(4):
                    M[s, r, c] = a0 * L[s, 0, c] + a1 * L[s, 1, c] + a2 * L[s, 2, c]
                M[s, r, 3] += a3
            M[s, 3, 0], M[s, 3, 1], M[s, 3, 2], M[s, 3, 3] = 0.0, 0.0, 0.0, 1.0
        best, which, first = math.inf, -1, -1
        for p in range(pairs.shape[0]):
            a, b = pairs[p, 0], pairs[p, 1]
            beyond = TOUCH if ask == FIRST else (best if ask == NEAREST else math.inf)
            if ask != EVERY and apart(axis, bound, M, a, b, beyond):
                continue
            if kind[b] == HALFSPACE:  # (a half-space is a pair's second: the builder's order)
                d = above_halfspace(kind[a], size, a, b, M)
            else:
                d = pair_distance(kind, size, M, a, b, beyond, work)
            if ask == EVERY:
                distance[p] = d
                if d <= TOUCH and first < 0:
                    first = p
                continue
            if d <= TOUCH:  # a contact ends the row
                first, best, which = p, d, p
                break
            if d < best:
                best, which = d, p
        if ask == FIRST:
            index[i] = first
        elif ask == NEAREST:
            index[i], distance[i] = which, best
        else:
            index[0] = first
        hits += first >= 0
    return hits


@jit
def apart(axis: IntArray, bound: FloatArray, M: FloatArray, a: int, b: int, beyond: float) -> bool:
    """Whether shapes ``a`` and ``b`` are proved farther apart than ``beyond`` [m] by their
    bounding capsules (first the spheres about those); never with a half-space."""
    ha, ra, hb, rb = bound[a, 0], bound[a, 1], bound[b, 0], bound[b, 1]
    if ra == math.inf or rb == math.inf:
        return False
    cx, cy, cz = M[a, 0, 3] - M[b, 0, 3], M[a, 1, 3] - M[b, 1, 3], M[a, 2, 3] - M[b, 2, 3]
    reach = ha + ra + hb + rb + beyond
    if cx * cx + cy * cy + cz * cz > reach * reach:
        return True
    ka, kb = axis[a], axis[b]
    ux, uy, uz = ha * M[a, 0, ka], ha * M[a, 1, ka], ha * M[a, 2, ka]
    vx, vy, vz = hb * M[b, 0, kb], hb * M[b, 1, kb], hb * M[b, 2, kb]
    d = segments(
        M[a, 0, 3] - ux,
        M[a, 1, 3] - uy,
        M[a, 2, 3] - uz,
        2.0 * ux,
        2.0 * uy,
        2.0 * uz,
        M[b, 0, 3] - vx,
        M[b, 1, 3] - vy,
        M[b, 2, 3] - vz,
        2.0 * vx,
        2.0 * vy,
        2.0 * vz,
    )
    return d - ra - rb > beyond


@jit
def check(shapes: Shapes, Q: FloatArray, ask: int, index: IntArray, distance: FloatArray) -> int:
    """:func:`run` on the bundle ``shapes``."""
    return run(
        shapes.tree,
        shapes.joint,
        shapes.local,
        shapes.kind,
        shapes.size,
        shapes.axis,
        shapes.bound,
        shapes.pairs,
        Q,
        ask,
        index,
        distance,
    )


@jit
def row(q: FloatArray) -> FloatArray:
    """``q`` as a batch of one configuration (1, n) (a copy: ``q`` may be of any layout)."""
    Q = np.empty((1, q.shape[0]))
    for i in range(q.shape[0]):
        Q[0, i] = q[i]
    return Q


@entry("i8(Shapes, f8[:])")
def first_collision(packed_shapes: Packed, q: FloatArray) -> int:
    """The first pair (its row of the shapes' ``pairs``) in contact at ``q`` [rad, m], or -1:
    clear. ``packed_shapes``: the :class:`Shapes` packed (:func:`solvers.packed.pack`), as
    every entry point here takes them."""
    index = np.empty(1, dtype=np.int64)
    check(shapes_of(packed_shapes), row(q), FIRST, index, np.empty(0))
    return index[0]


@entry("i8(Shapes, f8[:, :], i8[:])")
def first_collisions(packed_shapes: Packed, Q: FloatArray, out: IntArray) -> int:
    """:func:`first_collision` of each row of ``Q`` (m, n) into ``out`` (m,); returns how many
    rows collide."""
    return check(shapes_of(packed_shapes), Q, FIRST, out, np.empty(0))


@entry("Tuple((f8, i8))(Shapes, f8[:])")
def min_distance(packed_shapes: Packed, q: FloatArray) -> tuple[float, int]:
    """The smallest distance [m] between the shapes of a checked pair at ``q`` and that pair (the
    first of equals); at the first pair in contact: its value (<= TOUCH) and that pair. (inf,
    -1): no pair."""
    index, distance = np.empty(1, dtype=np.int64), np.empty(1)
    check(shapes_of(packed_shapes), row(q), NEAREST, index, distance)
    return distance[0], index[0]


@entry("i8(Shapes, f8[:, :], f8[:], i8[:])")
def min_distances(packed_shapes: Packed, Q: FloatArray, distance: FloatArray, index: IntArray) -> int:
    """:func:`min_distance` of each row of ``Q`` (m, n) into ``distance`` and ``index`` (m,);
    returns how many rows have a pair in contact."""
    return check(shapes_of(packed_shapes), Q, NEAREST, index, distance)


@entry("i8(Shapes, f8[:], f8[:])")
def pair_distances(packed_shapes: Packed, q: FloatArray, out: FloatArray) -> int:
    """Every checked pair's distance [m] at ``q`` into ``out`` (P,) (<= TOUCH: in contact);
    returns the first pair in contact, or -1."""
    index = np.full(1, -1, dtype=np.int64)
    check(shapes_of(packed_shapes), row(q), EVERY, index, out)
    return index[0]


@entry("f8(i8[:], f8[:, :], f8[:, :, :])")
def primitive_distance(kind: IntArray, size: FloatArray, M: FloatArray) -> float:
    """The distance [m] between shapes 0 and 1 of ``kind`` (2,), ``size`` (2, 4), placed by ``M``
    (2, 4, 4) (<= TOUCH: in contact)."""
    return pair_distance(kind, size, M, 0, 1, math.inf, np.empty((7, 4)))
