"""The analytic stage of the IK for one target or many: the closed form with its pitch rule.

``solve_one`` returns every branch within limits at the chosen pitch, nearest the seed
first, with a code: ``EXACT`` (at the first preferred pitch that works, or any pitch on an
arm without a wrist), ``NEAREST_PITCH`` (no preferred pitch works; at the reachable pitch
nearest them), ``NONE`` (no branch within limits at any pitch: the QP takes over). It works in
the family's angles; ``solve_point`` (one target) and ``solve_many`` (the batch IK, compiled
in a loop) take and give the URDF's (:mod:`solvers.arrays`). The entry points take the arm (and
its world) packed (:mod:`solvers.packed`).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from armd.robots.types import FloatArray

from .arrays import Arm, Family, arm_of, family_pitch, from_family, to_family, view
from .collide import FIRST, check, shapes_of
from .family import configs_at, formula_errors, rank_by_distance
from .geometric import family_fk
from .jit import entry, jit
from .packed import Packed
from .pitch import BOUNDARY_TOL, boundary_pitch, grid_pitch

IntArray = NDArray[np.int64]

EXACT, NEAREST_PITCH, NONE = 0, 1, 2


@jit
def solve_one(
    f: Family,
    ref: FloatArray,
    x: float,
    y: float,
    z: float,
    prefs: FloatArray,
    qs: FloatArray,
    ids: IntArray,
    errs: FloatArray,
    work: FloatArray,
) -> tuple[int, int, float]:
    """(code, number of branches in ``qs``/``ids``/``errs``, pitch [rad] used), all in the
    family's angles and frame."""
    code, m, phi = ranked_branches(f, ref, x, y, z, prefs, qs, ids, work)
    if m > 0:
        formula_errors(f, qs, m, x, y, z, errs)
    return code, m, phi


@jit
def beyond_reach(f: Family, x: float, y: float, z: float) -> bool:
    """Whether the target is provably out of reach at any pitch (no lateral pivot offset: the
    tool stays within reach of the pivot's circle); False where that cannot be told so cheaply."""
    P, J = f.P, f.J
    if P[1] != 0.0:
        return False
    reach = P[3] + P[4] + (P[5] if J[3] >= 0 else 0.0)
    dh = math.sqrt(x * x + y * y) - abs(P[0] + P[6])
    dz = z - (P[2] + P[7])
    return dh * dh + dz * dz > (reach * (1.0 + 1e-9) + 1e-12) ** 2


@jit
def ranked_branches(
    f: Family,
    ref: FloatArray,
    x: float,
    y: float,
    z: float,
    prefs: FloatArray,
    qs: FloatArray,
    ids: IntArray,
    work: FloatArray,
) -> tuple[int, int, float]:
    """:func:`solve_one` without the formula's errors (a batch asks for its chosen branch's
    only)."""
    J = f.J
    if beyond_reach(f, x, y, z):
        return NONE, 0, 0.0  # no branch at any pitch (and no pitch search)
    if J[3] < 0:
        m = configs_at(f, ref, x, y, z, 0.0, 0.0, qs, ids, work)
        if m == 0:
            return NONE, 0, 0.0
        rank_by_distance(qs, ids, m, ref, f.weights)
        return EXACT, m, 0.0
    for k in range(prefs.shape[0]):
        m = configs_at(f, ref, x, y, z, prefs[k], 0.0, qs, ids, work)
        if m > 0:
            rank_by_distance(qs, ids, m, ref, f.weights)
            return EXACT, m, prefs[k]
    if f.exact_pitch_search:
        found, phi = boundary_pitch(f, ref, x, y, z, prefs)
    else:
        found, phi = grid_pitch(f, ref, x, y, z, prefs)
    if not found:
        return NONE, 0, 0.0
    m = configs_at(f, ref, x, y, z, phi, BOUNDARY_TOL, qs, ids, work)
    if m == 0:
        return NONE, 0, 0.0
    rank_by_distance(qs, ids, m, ref, f.weights)
    return NEAREST_PITCH, m, phi


@jit
def _solve_mapped(
    arm: Arm,
    f: Family,
    zero: FloatArray,
    offset: float,
    ref: FloatArray,
    point: FloatArray,
    prefs: FloatArray,
    qs: FloatArray,
    ids: IntArray,
    errs: FloatArray,
    work: FloatArray,
    reached: FloatArray,
) -> tuple[int, int, float, float]:
    """:func:`solve_one` in the URDF's angles and ``base``: the seed, the target and the preferred
    pitches mapped into the family's, the branches back; the first (chosen) branch's tool point
    into ``reached``. (code, branches, pitch used, the chosen branch's tool pitch, not wrapped).
    ``f``, ``zero``, ``offset``: the arm's view at ``ref`` (:func:`solvers.arrays.view`)."""
    n = ref.shape[0]
    ref_f = np.empty(n)
    to_family(arm, zero, ref, ref_f)
    prefs_f = np.empty(prefs.shape[0])
    for k in range(prefs.shape[0]):
        prefs_f[k] = prefs[k] - offset
    code, m, phi = solve_one(
        f, ref_f, point[0] - arm.base[0], point[1] - arm.base[1], point[2], prefs_f, qs, ids, errs, work
    )
    pitch = 0.0
    if m > 0:
        family_fk(f, qs[0], reached)
        reached[0] += arm.base[0]
        reached[1] += arm.base[1]
        pitch = 0.0 if f.level else family_pitch(f, qs[0]) + offset
        for r in range(m):
            from_family(arm, zero, qs[r], qs[r])
    return code, m, phi + offset, pitch


@entry("Tuple((i8, i8, f8, f8))(Arm, f8[:], f8[:], f8[:], f8[:, :], i8[:], f8[:], f8[:, :], f8[:])")
def solve_point(
    packed_arm: Packed,
    ref: FloatArray,
    point: FloatArray,
    prefs: FloatArray,
    qs: FloatArray,
    ids: IntArray,
    errs: FloatArray,
    work: FloatArray,
    reached: FloatArray,
) -> tuple[int, int, float, float]:
    """The whole closed-form stage of a single-target IK in one call (Python's part is only the
    answer's objects): every branch within limits at the pitch the rule picks, for seed ``ref``,
    ``point`` (3,) in ``base`` and preferred tool pitches ``prefs``, nearest the seed first, into
    ``qs`` (4, n) (the URDF's angles), ``ids`` and ``errs`` (the formula's errors); the first
    branch's tool point into ``reached``. Returns (code, branches, pitch used, the first branch's
    tool pitch, not wrapped). ``work`` (4, 5) is scratch. ``packed_arm``: the :class:`Arm`
    packed (:func:`solvers.packed.pack`), as every entry point here takes it."""
    arm = arm_of(packed_arm)
    f, zero, offset = view(arm, ref)
    return _solve_mapped(arm, f, zero, offset, ref, point, prefs, qs, ids, errs, work, reached)


@entry("void(Arm, f8[:, :], f8[:, :], f8[:, :], f8[:, :], i8[:], f8[:], i8[:], f8[:], f8[:, :])")
def solve_many(
    packed_arm: Packed,
    refs: FloatArray,
    points: FloatArray,
    prefs: FloatArray,
    q_out: FloatArray,
    code_out: IntArray,
    pitch_out: FloatArray,
    branch_out: IntArray,
    err_out: FloatArray,
    reached_out: FloatArray,
) -> None:
    """:func:`solve_point` for each row of ``points`` (m, 3) with seed ``refs`` row (m, n) and
    preferred pitches ``prefs`` row (m, k): the nearest branch into ``q_out``, its code, its tool
    pitch (not wrapped; the pitch used where there is no branch), branch id, formula error and
    tool point."""
    arm = arm_of(packed_arm)
    n = refs.shape[1]
    qs = np.empty((4, n))
    ids = np.empty(4, dtype=np.int64)
    work = np.empty((4, 5))
    ref_f = np.empty(n)
    prefs_f = np.empty(prefs.shape[1])
    p = np.empty(3)
    f, zero, offset = view(arm, refs[0])
    for i in range(points.shape[0]):
        if arm.roll >= 0 and i > 0 and refs[i, arm.roll] != refs[i - 1, arm.roll]:
            f, zero, offset = view(arm, refs[i])  # (a roll that moves the tool: the view is the roll's)
        # (as _solve_mapped, its scratch made once and only the chosen branch's FK: its tool point
        # and formula error, from the same numbers)
        x, y, z = _in_family(arm, zero, offset, refs[i], points[i], prefs[i], ref_f, prefs_f)
        code, m, phi = ranked_branches(f, ref_f, x, y, z, prefs_f, qs, ids, work)
        code_out[i] = code
        if m > 0:
            family_fk(f, qs[0], p)
            err_out[i] = ((p[0] - x) ** 2 + (p[1] - y) ** 2 + (p[2] - z) ** 2) ** 0.5
            reached_out[i, 0] = p[0] + arm.base[0]
            reached_out[i, 1] = p[1] + arm.base[1]
            reached_out[i, 2] = p[2]
            pitch_out[i] = 0.0 if f.level else family_pitch(f, qs[0]) + offset
            from_family(arm, zero, qs[0], q_out[i])
            branch_out[i] = ids[0]
        else:
            for c in range(n):
                q_out[i, c] = refs[i, c]
            branch_out[i] = -1
            err_out[i] = np.inf
            pitch_out[i] = phi + offset


@jit
def _in_family(
    arm: Arm,
    zero: FloatArray,
    offset: float,
    ref: FloatArray,
    point: FloatArray,
    prefs: FloatArray,
    ref_f: FloatArray,
    prefs_f: FloatArray,
) -> tuple[float, float, float]:
    """The seed and the preferred pitches in the family's angles (into ``ref_f``, ``prefs_f``),
    and the target in its frame."""
    to_family(arm, zero, ref, ref_f)
    for k in range(prefs.shape[0]):
        prefs_f[k] = prefs[k] - offset
    return point[0] - arm.base[0], point[1] - arm.base[1], point[2]


@entry("void(Arm, Shapes, f8[:, :], f8[:, :], f8[:, :], f8[:], f8, i8[:], f8[:, :], i8[:])")
def clear_branches(
    packed_arm: Packed,
    packed_shapes: Packed,
    refs: FloatArray,
    points: FloatArray,
    prefs: FloatArray,
    others: FloatArray,
    tol: float,
    rows: IntArray,
    q_out: FloatArray,
    branch_out: IntArray,
) -> None:
    """For each row of :func:`solve_many`'s in ``rows`` whose answer collides (in ``shapes``,
    every pair compiled), the clear branch the single-target IK chooses
    (:func:`solvers.clearance.clear`): the first clear one of the other branches at the same
    pitch, nearest the seed first; else, at each pitch of ``others`` in turn (with a free
    pitch, those :func:`solvers.ik._alternatives` tries; else none), the first clear one of the
    branches within ``tol`` [m]. Into the row of ``q_out`` and ``branch_out`` (-1 where none
    is: the single-target path's, with its other starts)."""
    arm, shapes = arm_of(packed_arm), shapes_of(packed_shapes)
    n = refs.shape[1]
    qs = np.empty((4, n))
    ids = np.empty(4, dtype=np.int64)
    errs = np.empty(4)
    work = np.empty((4, 5))
    ref_f = np.empty(n)
    prefs_f = np.empty(prefs.shape[1])
    Q = np.empty((1, n))
    index = np.empty(1, dtype=np.int64)
    nothing = np.empty(0)
    for t in range(rows.shape[0]):
        i = rows[t]
        branch_out[i] = -1
        f, zero, offset = view(arm, refs[i])
        x, y, z = _in_family(arm, zero, offset, refs[i], points[i], prefs[i], ref_f, prefs_f)
        _, m, _ = ranked_branches(f, ref_f, x, y, z, prefs_f, qs, ids, work)
        for r in range(1, m):
            from_family(arm, zero, qs[r], Q[0])
            check(shapes, Q, FIRST, index, nothing)
            if index[0] < 0:
                q_out[i, :] = Q[0]
                branch_out[i] = ids[r]
                break
        for k in range(others.shape[0]):
            if branch_out[i] >= 0 or beyond_reach(f, x, y, z):
                break
            phi = others[k] - offset if f.J[3] >= 0 else 0.0
            m = configs_at(f, ref_f, x, y, z, phi, 0.0, qs, ids, work)
            rank_by_distance(qs, ids, m, ref_f, f.weights)
            formula_errors(f, qs, m, x, y, z, errs)
            for r in range(m):
                if errs[r] > tol:
                    continue
                from_family(arm, zero, qs[r], Q[0])
                check(shapes, Q, FIRST, index, nothing)
                if index[0] < 0:
                    q_out[i, :] = Q[0]
                    branch_out[i] = ids[r]
                    break


@entry("i8(Arm, f8[:], f8[:], f8[:], f8[:, :], i8[:], f8[:], i8[:])")
def solve_pitches(
    packed_arm: Packed,
    ref: FloatArray,
    point: FloatArray,
    pitches: FloatArray,
    qs: FloatArray,
    ids: IntArray,
    errs: FloatArray,
    counts: IntArray,
) -> int:
    """:func:`solve_point` at each of ``pitches`` (k,) on its own (an exact pitch, not a
    preference among them): the branches of each, nearest the seed first, one after the other
    into ``qs`` (4 k, n), ``ids`` and ``errs``, how many at each into ``counts`` (k,) (0: that
    pitch does not reach ``point``, or not exactly). Returns how many in all. (When every branch
    on a target collides, the other pitches' in one call.)"""
    arm = arm_of(packed_arm)
    n = ref.shape[0]
    q4, id4, err4 = np.empty((4, n)), np.empty(4, dtype=np.int64), np.empty(4)
    work, reached, one = np.empty((4, 5)), np.empty(3), np.empty(1)
    f, zero, offset = view(arm, ref)
    total = 0
    for k in range(pitches.shape[0]):
        one[0] = pitches[k]
        code, m, _, _ = _solve_mapped(arm, f, zero, offset, ref, point, one, q4, id4, err4, work, reached)
        counts[k] = m if code == EXACT else 0
        for r in range(counts[k]):
            for j in range(n):
                qs[total, j] = q4[r, j]
            ids[total], errs[total] = id4[r], err4[r]
            total += 1
    return total


@entry("Tuple((i8, i8, f8, f8))(Arm, Shapes, f8[:], f8[:], f8[:], f8[:, :], i8[:], f8[:], f8[:, :], f8[:], i8[:])")
def solve_point_clear(
    packed_arm: Packed,
    packed_shapes: Packed,
    ref: FloatArray,
    point: FloatArray,
    prefs: FloatArray,
    qs: FloatArray,
    ids: IntArray,
    errs: FloatArray,
    work: FloatArray,
    reached: FloatArray,
    hits: IntArray,
) -> tuple[int, int, float, float]:
    """:func:`solve_point`, and each branch found checked against the arm's world ``shapes``
    in the same call: the first pair in contact of each into ``hits`` (4,) (-1: clear). The
    solver's common case, a clear answer on an arm whose world is all primitive shapes, in one
    call (:mod:`armd.solvers.collide`)."""
    arm, shapes = arm_of(packed_arm), shapes_of(packed_shapes)
    f, zero, offset = view(arm, ref)
    code, m, phi, pitch = _solve_mapped(arm, f, zero, offset, ref, point, prefs, qs, ids, errs, work, reached)
    if m > 0 and shapes.pairs.shape[0] > 0:
        check(shapes, qs[:m], FIRST, hits, np.empty(0))
    else:
        for r in range(4):
            hits[r] = -1
    return code, m, phi, pitch
