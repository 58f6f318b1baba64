"""The closed form's branches that respect every joint limit, nearest the seed first.

Compiled with Numba, like :mod:`solvers.geometric`, which it builds on. Joint angles are the
family's (:mod:`solvers.arrays`).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from armd.robots.types import FloatArray

from .arrays import Family
from .geometric import branches, family_fk, wrap_into
from .jit import jit
from .limits import limits_ok

IntArray = NDArray[np.int64]


@jit
def configs_at(
    f: Family,
    ref: FloatArray,
    x: float,
    y: float,
    z: float,
    phi: float,
    tol: float,
    qs: FloatArray,
    ids: IntArray,
    work: FloatArray,
) -> int:
    """Branches at pitch ``phi`` wrapped into the limits and within every limit.

    Joint values come from ``ref`` for joints outside the family (the wrist roll). Writes
    full joint vectors into ``qs`` (4, n) and branch ids into ``ids``; returns the count.
    ``tol`` [rad] of box slack is clamped away (used at boundary pitches).
    """
    J = f.J
    count = branches(f.P, J[3] >= 0, x, y, z, phi, work)
    m = 0
    wrap_tol = tol if tol > 0.0 else 1e-12
    for r in range(count):
        ok = True
        for c in range(ref.shape[0]):
            qs[m, c] = ref[c]
        for c in range(4):
            j = J[c]
            if j < 0:
                continue
            found, v = wrap_into(work[r, c + 1], f.lower[j], f.upper[j], ref[j], wrap_tol)
            if not found:
                ok = False
                break
            qs[m, j] = v
        if ok and limits_ok(qs[m], f, 0.0):
            ids[m] = int(work[r, 0])
            m += 1
    return m


@jit
def rank_by_distance(qs: FloatArray, ids: IntArray, m: int, ref: FloatArray, weights: FloatArray) -> None:
    """Sort the first ``m`` rows nearest ``ref`` first (joint distance weighted by 1 / vmax);
    stable, so ties keep the fixed branch order: the same input always gives the same output."""
    n = ref.shape[0]
    d = np.empty(m)
    for r in range(m):
        s = 0.0
        for i in range(n):
            s += abs(qs[r, i] - ref[i]) * weights[i]
        d[r] = s
    for i in range(1, m):
        j = i
        while j > 0 and d[j - 1] > d[j]:
            d[j - 1], d[j] = d[j], d[j - 1]
            ids[j - 1], ids[j] = ids[j], ids[j - 1]
            for c in range(n):
                qs[j - 1, c], qs[j, c] = qs[j, c], qs[j - 1, c]
            j -= 1


@jit
def formula_errors(f: Family, qs: FloatArray, m: int, x: float, y: float, z: float, errs: FloatArray) -> None:
    """Distance [m] from each row's tool point (family formula) to the target."""
    p = np.empty(3)
    for r in range(m):
        family_fk(f, qs[r], p)
        errs[r] = ((p[0] - x) ** 2 + (p[1] - y) ** 2 + (p[2] - z) ** 2) ** 0.5
