"""The analytic stage of the IK for one target or many: the closed form with its pitch rule.

``solve_one`` returns every branch within limits at the chosen pitch, nearest the seed
first, with a code: ``EXACT`` (at the first preferred pitch that works, or any pitch on an
arm without a wrist), ``NEAREST_PITCH`` (no preferred pitch works; at the reachable pitch
nearest them), ``NONE`` (no branch within limits at any pitch: the QP takes over).
``solve_many`` loops it over targets, compiled, for the batch IK.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from armd.robots.types import FloatArray

from .family import configs_at, formula_errors, rank_by_distance
from .geometric import family_fk
from .jit import entry, jit
from .pitch import BOUNDARY_TOL, boundary_pitch, grid_pitch

IntArray = NDArray[np.int64]

EXACT, NEAREST_PITCH, NONE = 0, 1, 2


@jit
def solve_one(
    P: FloatArray,
    J: IntArray,
    lower: FloatArray,
    upper: FloatArray,
    weights: FloatArray,
    C: FloatArray,
    clo: FloatArray,
    chi: FloatArray,
    exact_pitch_search: bool,
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
    """(code, number of branches in ``qs``/``ids``/``errs``, pitch [rad] used)."""
    if P[1] == 0.0:  # no lateral pivot offset: the tool stays within reach of the pivot's circle
        reach = P[3] + P[4] + (P[5] if J[3] >= 0 else 0.0)
        dh = math.sqrt(x * x + y * y) - abs(P[0] + P[6])
        dz = z - (P[2] + P[7])
        if dh * dh + dz * dz > (reach * (1.0 + 1e-9) + 1e-12) ** 2:
            return NONE, 0, 0.0  # beyond reach: no branch at any pitch (and no pitch search)
    if J[3] < 0:
        m = configs_at(P, J, lower, upper, C, clo, chi, ref, x, y, z, 0.0, 0.0, qs, ids, work)
        if m == 0:
            return NONE, 0, 0.0
        rank_by_distance(qs, ids, m, ref, weights)
        formula_errors(P, J, qs, m, x, y, z, errs)
        return EXACT, m, 0.0
    for k in range(prefs.shape[0]):
        m = configs_at(P, J, lower, upper, C, clo, chi, ref, x, y, z, prefs[k], 0.0, qs, ids, work)
        if m > 0:
            rank_by_distance(qs, ids, m, ref, weights)
            formula_errors(P, J, qs, m, x, y, z, errs)
            return EXACT, m, prefs[k]
    if exact_pitch_search:
        found, phi = boundary_pitch(P, J, lower, upper, C, clo, chi, ref, x, y, z, prefs)
    else:
        found, phi = grid_pitch(P, J, lower, upper, C, clo, chi, ref, x, y, z, prefs)
    if not found:
        return NONE, 0, 0.0
    m = configs_at(P, J, lower, upper, C, clo, chi, ref, x, y, z, phi, BOUNDARY_TOL, qs, ids, work)
    if m == 0:
        return NONE, 0, 0.0
    rank_by_distance(qs, ids, m, ref, weights)
    formula_errors(P, J, qs, m, x, y, z, errs)
    return NEAREST_PITCH, m, phi


@jit
def solve_point(
    P: FloatArray,
    J: IntArray,
    lower: FloatArray,
    upper: FloatArray,
    weights: FloatArray,
    C: FloatArray,
    clo: FloatArray,
    chi: FloatArray,
    exact_pitch_search: bool,
    level: bool,
    ref: FloatArray,
    point: FloatArray,
    prefs: FloatArray,
    qs: FloatArray,
    ids: IntArray,
    errs: FloatArray,
    work: FloatArray,
    reached: FloatArray,
) -> tuple[int, int, float, float]:
    """:func:`solve_one` for ``point`` (3,), then the first (chosen) branch's tool point into
    ``reached`` and the sum of its pitch joints (the tool pitch, not wrapped; 0 for a level
    arm): (code, branches, pitch used, pitch joints' sum). One call for
    the whole closed-form stage of a single-target IK: Python's part is only the answer's objects."""
    code, m, phi = solve_one(
        P,
        J,
        lower,
        upper,
        weights,
        C,
        clo,
        chi,
        exact_pitch_search,
        ref,
        point[0],
        point[1],
        point[2],
        prefs,
        qs,
        ids,
        errs,
        work,
    )
    pitch = 0.0
    if m > 0:
        family_fk(P, J, qs[0], reached)
        if not level:
            for k in range(1, 4):
                if J[k] >= 0:
                    pitch += qs[0, J[k]]
    return code, m, phi, pitch


def pack(
    P: FloatArray,
    J: IntArray,
    lower: FloatArray,
    upper: FloatArray,
    weights: FloatArray,
    C: FloatArray,
    clo: FloatArray,
    chi: FloatArray,
    exact_pitch_search: bool,
    level: bool,
) -> tuple[FloatArray, IntArray]:
    """An arm's arguments to :func:`solve_point` as one float and one int array, for
    :func:`solve_packed`: (P, lower, upper, weights, clo, chi, C by rows, the two flags) and
    (J, n, number of coupled limits)."""
    n, nc = lower.shape[0], clo.shape[0]
    K = np.concatenate(
        [
            P,
            lower,
            upper,
            weights,
            clo,
            chi,
            np.ascontiguousarray(C, dtype=np.float64).reshape(-1),
            [float(exact_pitch_search), float(level)],
        ]
    ).astype(np.float64)
    JI = np.concatenate([J, [n, nc]]).astype(np.int64)
    return K, JI


def packed_outputs(n: int) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """The output buffer of :func:`solve_packed` for an arm of ``n`` joints, and its views:
    (out, qs (4, n), errs (4,), reached (3,))."""
    out = np.zeros(4 * n + 7)
    return out, out[: 4 * n].reshape(4, n), out[4 * n : 4 * n + 4], out[4 * n + 4 :]


@entry("Tuple((i8, i8, f8, f8))(f8[::1], i8[:], f8[:], f8[:], f8[:], f8[::1], i8[:], f8[:, :])")  # (K, out: reshaped)
def solve_packed(
    K: FloatArray,
    JI: IntArray,
    ref: FloatArray,
    point: FloatArray,
    prefs: FloatArray,
    out: FloatArray,
    ids: IntArray,
    work: FloatArray,
) -> tuple[int, int, float, float]:
    """:func:`solve_point` with the arm's arrays packed by :func:`pack` and the outputs in one
    buffer (:func:`packed_outputs`): eight arguments for Python to hand over instead of
    eighteen (about 80 ns each, per call)."""
    n, nc = JI[4], JI[5]
    lower = K[8 : 8 + n]
    upper = K[8 + n : 8 + 2 * n]
    weights = K[8 + 2 * n : 8 + 3 * n]
    o = 8 + 3 * n
    clo = K[o : o + nc]
    chi = K[o + nc : o + 2 * nc]
    o += 2 * nc
    C = K[o : o + nc * n].reshape((nc, n))
    o += nc * n
    return solve_point(
        K[:8],
        JI[:4],
        lower,
        upper,
        weights,
        C,
        clo,
        chi,
        K[o] != 0.0,
        K[o + 1] != 0.0,
        ref,
        point,
        prefs,
        out[: 4 * n].reshape((4, n)),
        ids,
        out[4 * n : 4 * n + 4],
        work,
        out[4 * n + 4 : 4 * n + 7],
    )


@entry(
    "void(f8[:], i8[:], f8[:], f8[:], f8[:], f8[:, :], f8[:], f8[:], b1, f8[:, :], "
    "f8[:, :], f8[:, :], f8[:, :], i8[:], f8[:], i8[:], f8[:], f8[:, :])"
)
def solve_many(
    P: FloatArray,
    J: IntArray,
    lower: FloatArray,
    upper: FloatArray,
    weights: FloatArray,
    C: FloatArray,
    clo: FloatArray,
    chi: FloatArray,
    exact_pitch_search: bool,
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
    """:func:`solve_one` for each row of ``points`` (m, 3) with seed ``refs`` row (m, n) and
    preferred pitches ``prefs`` row (m, k): the nearest branch into ``q_out``, its code, pitch,
    branch id, formula error and tool point."""
    n = refs.shape[1]
    qs = np.empty((4, n))
    ids = np.empty(4, dtype=np.int64)
    errs = np.empty(4)
    work = np.empty((4, 5))
    for i in range(points.shape[0]):
        code, m, phi = solve_one(
            P,
            J,
            lower,
            upper,
            weights,
            C,
            clo,
            chi,
            exact_pitch_search,
            refs[i],
            points[i, 0],
            points[i, 1],
            points[i, 2],
            prefs[i],
            qs,
            ids,
            errs,
            work,
        )
        code_out[i] = code
        pitch_out[i] = phi
        if m > 0:
            for c in range(n):
                q_out[i, c] = qs[0, c]
            branch_out[i] = ids[0]
            err_out[i] = errs[0]
            family_fk(P, J, qs[0], reached_out[i])
        else:
            for c in range(n):
                q_out[i, c] = refs[i, c]
            branch_out[i] = -1
            err_out[i] = np.inf
