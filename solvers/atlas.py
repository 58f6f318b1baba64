"""The atlas: fixed configurations within every limit and their tool points, on a grid.

The numerical IK (:func:`solvers.lm.solve_chain`) and the closest-point search
(:func:`solvers.closest.closest_family`) start from the atlas configurations whose tool points
are nearest the target. A scan of all 4,096 points took 7-10 us a call, longer than a whole
IK of a reachable target on a family arm; the points are therefore kept sorted by the cell of
a cubic grid over the arm's reach (``G`` cells a side), and :func:`nearest` reads the cells
around the target's, ring by ring, until no unread cell can hold a nearer point: a few
hundred points instead of all of them, with the same answer as the scan.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from armd.robots.types import FloatArray

from .jit import jit, register_tuples
from .packed import Packed, float_at, floats1, floats2, ints1

G = 8  # grid cells a side


class Atlas(NamedTuple):
    """In-limit configurations and their tool points, sorted by grid cell."""

    q: FloatArray  # (k, n) configurations [rad or m]
    p: FloatArray  # (k, 3) their tool points [m] in base
    start: NDArray[np.int64]  # (G^3 + 1,) the points of cell c are rows start[c]:start[c + 1]
    lo: FloatArray  # (3,) the grid's lowest corner [m]
    size: float  # [m] a cell's side


ATLAS_FIELDS = (
    ("q", ("f8", 2)),
    ("p", ("f8", 2)),
    ("start", ("i8", 1)),
    ("lo", ("f8", 1)),
    ("size", ("f8", 0)),
)
register_tuples({"Atlas": Atlas}, {"Atlas": ATLAS_FIELDS})


@jit
def atlas_of(p: Packed) -> Atlas:
    """The :class:`Atlas` packed in ``p`` (:mod:`solvers.packed`), on views of its arrays."""
    return Atlas(floats2(p, 0), floats2(p, 1), ints1(p, 2), floats1(p, 3), float_at(p, 4))


def make_atlas(q: FloatArray, p: FloatArray) -> Atlas:
    """The atlas of configurations ``q`` with tool points ``p``: sorted by cell, indexed."""
    lo = p.min(axis=0)
    size = max(float(np.max(p.max(axis=0) - lo)) / G, 1e-9) * (1.0 + 1e-9)
    cell = _cells(p, lo, size)
    by_cell = np.argsort(cell, kind="stable")
    start = np.searchsorted(cell[by_cell], np.arange(G**3 + 1)).astype(np.int64)
    return Atlas(np.ascontiguousarray(q[by_cell]), np.ascontiguousarray(p[by_cell]), start, lo.copy(), size)


def _cells(p: FloatArray, lo: FloatArray, size: float) -> NDArray[np.int64]:
    ijk = np.clip(np.floor((p - lo) / size).astype(np.int64), 0, G - 1)
    return (ijk[:, 0] * G + ijk[:, 1]) * G + ijk[:, 2]


@jit
def nearest(atlas: Atlas, target: FloatArray, order: NDArray[np.int64]) -> None:
    """The indices of the ``len(order)`` atlas points nearest ``target``, nearest first (-1
    where the atlas has fewer)."""
    k_max = order.shape[0]
    if k_max == 0:
        return
    dist = np.full(k_max, np.inf)
    p, start, lo, size = atlas.p, atlas.start, atlas.lo, atlas.size
    c = np.empty(3, dtype=np.int64)  # the target's cell (clamped into the grid)
    for a in range(3):
        c[a] = min(max(int(np.floor((target[a] - lo[a]) / size)), 0), G - 1)
    for ring in range(G):
        # no unread cell holds a point nearer than the ring's inner distance from the target
        gap = np.inf
        for a in range(3):  # how far the target is inside the ring's box, on its nearest side
            inner_lo = target[a] - (lo[a] + (c[a] - ring) * size)
            inner_hi = lo[a] + (c[a] + ring + 1) * size - target[a]
            gap = min(gap, inner_lo if c[a] - ring > 0 else np.inf, inner_hi if c[a] + ring < G - 1 else np.inf)
        for i in range(max(c[0] - ring, 0), min(c[0] + ring, G - 1) + 1):
            for j in range(max(c[1] - ring, 0), min(c[1] + ring, G - 1) + 1):
                for k in range(max(c[2] - ring, 0), min(c[2] + ring, G - 1) + 1):
                    if max(abs(i - c[0]), abs(j - c[1]), abs(k - c[2])) != ring:
                        continue  # read in an earlier ring
                    # the cell's nearest point to the target: farther than the worst kept, skip it
                    near = 0.0
                    for a, ia in ((0, i), (1, j), (2, k)):
                        below = lo[a] + ia * size - target[a]
                        above = target[a] - (lo[a] + (ia + 1) * size)
                        out = max(below, above, 0.0)
                        near += out * out
                    if near >= dist[k_max - 1]:
                        continue
                    cell = (i * G + j) * G + k
                    for r in range(start[cell], start[cell + 1]):
                        d = (p[r, 0] - target[0]) ** 2 + (p[r, 1] - target[1]) ** 2 + (p[r, 2] - target[2]) ** 2
                        if d < dist[k_max - 1]:
                            m = k_max - 1
                            while m > 0 and dist[m - 1] > d:
                                dist[m] = dist[m - 1]
                                order[m] = order[m - 1]
                                m -= 1
                            dist[m] = d
                            order[m] = r
        if max(gap, 0.0) ** 2 >= dist[k_max - 1]:
            return
