"""The planner's per-sample arithmetic, compiled: Ruckig phases to samples, and the gate's fast "all clear".

A trajectory has tens to hundreds of samples of a few joints, where NumPy spends its time
in call overhead rather than arithmetic. Two compiled loops do the work:

* :func:`evaluate`: every sample's position, velocity and acceleration from the segments'
  constant-jerk phase tables (:func:`planning.ruckig_path.phase_table`), the same
  expressions in the same order as Ruckig's ``at_time``, and the forward-difference jerk;
* :func:`all_clear`: True when every sample is finite and inside every limit (box,
  coupled, velocity, acceleration, jerk, actuator angle and command ranges) with a margin,
  writing the actuator commands as it goes;
* :func:`clear_walk`: the clearance walk of :func:`planning.clearance.check_clear` along a
  trajectory's samples, each check the compiled collision stage's (:mod:`armd.solvers.collide`),
  where every pair of the arm's world is a primitive one.

``all_clear`` only answers "clearly fine". Anything else (a violation, or a value within a
hair of a limit) goes to the exact checks of :mod:`planning.checks`, which decide and name
the joint, time and value: the compiled loop can make a plan faster, never let one through
that the checks would refuse.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from armd.robots.types import FloatArray
from armd.solvers.collide import NEAREST, check, shapes_of
from armd.solvers.jit import entry, jit
from armd.solvers.packed import Packed

IntArray = NDArray[np.int64]

MARGIN = 1e-12  # [rad, rad/s ...]: all_clear is stricter than the checks by this much


@entry("void(f8[:, :, :, :], f8[:], f8[:], f8[:], f8, f8[:, :], f8[:, :], f8[:, :], f8[:, :])")
def evaluate(
    tables: FloatArray,
    seg_starts: FloatArray,
    seg_durations: FloatArray,
    times: FloatArray,
    dt: float,
    P: FloatArray,
    V: FloatArray,
    A: FloatArray,
    Jk: FloatArray,
) -> None:
    """Fill P, V, A (samples x dofs) at ``times`` (clamped to the path), and Jk with
    (A[k+1] - A[k]) / dt (0 on the last sample).

    ``tables[s, d]``: segment s, dof d: rows (duration, jerk, a0, v0, p0) of its phases,
    zero-length rows in front. Past the last phase (a segment's duration is rounded up to
    whole cycles), the end state carries on at constant acceleration, as in Ruckig's at_time.
    """
    nseg, dofs, phases = tables.shape[0], tables.shape[1], tables.shape[2]
    total = seg_starts[nseg - 1] + seg_durations[nseg - 1]
    for i in range(times.shape[0]):
        t = min(max(times[i], 0.0), total)
        s = 0
        for k in range(nseg):  # the last segment that starts at or before t
            if seg_starts[k] <= t:
                s = k
        local = min(t - seg_starts[s], seg_durations[s])
        for d in range(dofs):
            start = 0.0
            row = 0
            row_start = 0.0
            for ph in range(phases):  # the last phase that starts at or before local
                if start <= local:
                    row = ph
                    row_start = start
                else:
                    break
                start += tables[s, d, ph, 0]
            j = tables[s, d, row, 1]
            a0 = tables[s, d, row, 2]
            v0 = tables[s, d, row, 3]
            p0 = tables[s, d, row, 4]
            h = local - row_start
            if row == phases - 1 and local > start:  # past the last phase: its end state, at constant acceleration
                T = tables[s, d, row, 0]
                p0, v0, a0 = p0 + T * (v0 + T * (a0 / 2 + T * j / 6)), v0 + T * (a0 + T * j / 2), a0 + T * j
                j = 0.0
                h = local - start
            P[i, d] = p0 + h * (v0 + h * (a0 / 2 + h * j / 6))
            V[i, d] = v0 + h * (a0 + h * j / 2)
            A[i, d] = a0 + h * j
    n = times.shape[0]
    for i in range(n):
        for d in range(dofs):
            Jk[i, d] = (A[i + 1, d] - A[i, d]) / dt if i + 1 < n else 0.0


@entry("b1(f8[:, :], f8[:, :], f8[:, :], f8[:, :], f8[:, :], f8[:, :], f8[:, :], f8[:, :], f8[:, :], f8[:], i8[:, :])")
def all_clear(
    P: FloatArray,
    V: FloatArray,
    A: FloatArray,
    Jk: FloatArray,
    coupled: FloatArray,
    angles: FloatArray,
    joints: FloatArray,
    couplings: FloatArray,
    actuators: FloatArray,
    tolerances: FloatArray,
    commands: IntArray,
) -> bool:
    """True when every sample is clearly inside every limit (by MARGIN more than the checks
    ask); ``commands`` gets rint(angle * gain + bias).

    ``coupled`` (samples x coupled limits) and ``angles`` (samples x actuators) are the
    samples' coupled-limit values and actuator angles. The limits, packed (few arguments:
    each costs a compiled call some time): ``joints`` rows lower, upper, vmax, amax, jmax;
    ``couplings`` rows lower, upper; ``actuators`` rows angle lo, angle hi, gain, bias,
    command lo, command hi; ``tolerances`` = (position, rate (relative), actuator angle).
    """
    position_tol, rate_tol, angle_tol = tolerances[0], tolerances[1], tolerances[2]
    n, dofs = P.shape[0], P.shape[1]
    for i in range(n):
        for d in range(dofs):
            p, v, a, jk = P[i, d], V[i, d], A[i, d], Jk[i, d]
            if not (np.isfinite(p) and np.isfinite(v) and np.isfinite(a) and np.isfinite(jk)):
                return False
            if p < joints[0, d] - position_tol + MARGIN or p > joints[1, d] + position_tol - MARGIN:
                return False
            if (
                abs(v) > joints[2, d] * (1 + rate_tol) - MARGIN
                or abs(a) > joints[3, d] * (1 + rate_tol) - MARGIN
                or abs(jk) > joints[4, d] * (1 + rate_tol) - MARGIN
            ):
                return False
        for c in range(coupled.shape[1]):
            x = coupled[i, c]
            if not (x >= couplings[0, c] - position_tol + MARGIN and x <= couplings[1, c] + position_tol - MARGIN):
                return False
        for k in range(angles.shape[1]):
            x = angles[i, k]
            if not (x >= actuators[0, k] - angle_tol + MARGIN and x <= actuators[1, k] + angle_tol - MARGIN):
                return False
            cmd = np.rint(x * actuators[2, k] + actuators[3, k])
            if cmd < actuators[4, k] or cmd > actuators[5, k]:
                return False
            commands[i, k] = np.int64(cmd)
    return True


@entry("i8(Shapes, f8[:], f8[:, :], f8[:], f8, i8, f8[:])")
def clear_walk(
    packed_shapes: Packed,
    T: FloatArray,
    P: FloatArray,
    travel: FloatArray,
    contact: float,
    bisections: int,
    out: FloatArray,
) -> int:
    """:func:`planning.clearance.check_clear`'s walk along the polyline through the samples ``P``
    (rows, at times ``T`` [s]) in one call, every pair compiled (``packed_shapes``: the
    :class:`~armd.solvers.collide.Shapes` packed): the row of the shapes' ``pairs`` first found
    nearer than ``contact`` [m] (narrowed down by ``bisections``), or -1: clear. ``out``
    (n + 3,): the time [s] of the contact, the number of checks made, 1 if it was found at the
    start (else 0), and the configuration there."""
    shapes = shapes_of(packed_shapes)
    m, n = P.shape[0], P.shape[1]
    s = np.zeros(m)  # the travel bound [m] from the first sample to each
    for k in range(1, m):
        step = 0.0
        for j in range(n):
            step += abs(P[k, j] - P[k - 1, j]) * travel[j]
        s[k] = s[k - 1] + step
    end = s[m - 1]
    Q = np.empty((1, n))
    index = np.empty(1, dtype=np.int64)
    distance = np.empty(1)
    at, last_clear, checks = 0.0, -1.0, 0
    while True:
        t = _point(s, T, P, at, Q)
        check(shapes, Q, NEAREST, index, distance)
        checks += 1
        d, pair = distance[0], index[0]
        if d < contact and pair >= 0:
            if last_clear >= 0.0:  # somewhere after the last clear check: narrow it down
                lo, hi = last_clear, at
                for _ in range(bisections):
                    mid = 0.5 * (lo + hi)
                    _point(s, T, P, mid, Q)
                    check(shapes, Q, NEAREST, index, distance)
                    checks += 1
                    if distance[0] < contact and index[0] >= 0:
                        hi, pair = mid, index[0]
                    else:
                        lo = mid
                t = _point(s, T, P, hi, Q)
            out[0], out[1], out[2] = t, checks, 1.0 if at == 0.0 else 0.0
            for j in range(n):
                out[3 + j] = Q[0, j]
            return pair
        if at + d >= end:
            out[0], out[1], out[2] = T[m - 1], checks, 0.0
            return -1
        last_clear = at
        at = min(at + max(d, 2.0 * contact), end)


@jit
def _point(s: FloatArray, T: FloatArray, P: FloatArray, at: float, Q: FloatArray) -> float:
    """The configuration a travel ``at`` [m] along the polyline (into ``Q[0]``) and its time [s]
    (as :func:`planning.clearance.check_clear`'s ``point``)."""
    m, n = P.shape[0], P.shape[1]
    k = 0  # the last sample whose travel is at or before ``at`` (searchsorted, right, less one)
    while k + 1 < m and s[k + 1] <= at:
        k += 1
    k = min(k, max(m - 2, 0))
    if m == 1 or s[k + 1] <= s[k]:
        for j in range(n):
            Q[0, j] = P[k, j]
        return T[k]
    f = min(max((at - s[k]) / (s[k + 1] - s[k]), 0.0), 1.0)
    for j in range(n):
        Q[0, j] = P[k, j] + f * (P[k + 1, j] - P[k, j])
    return T[k] + f * (T[k + 1] - T[k])


@entry("void(f8[:, :, :, :], f8[:], f8[:])")
def extrema(tables: FloatArray, lo: FloatArray, hi: FloatArray) -> None:
    """Each dof's lowest and highest position over the segments' phases (``tables`` as
    :func:`evaluate` takes them) into ``lo`` and ``hi``: each phase's ends, and where its
    velocity (a quadratic) is zero inside it. (Ruckig's own ``position_extrema`` of a
    velocity-interface segment reads 0.0 for a joint that never goes there.)"""
    dofs = tables.shape[1]
    for d in range(dofs):
        lo[d], hi[d] = math.inf, -math.inf
    for s in range(tables.shape[0]):
        for d in range(dofs):
            for ph in range(tables.shape[2]):
                T, j, a0, v0, p0 = (
                    tables[s, d, ph, 0],
                    tables[s, d, ph, 1],
                    tables[s, d, ph, 2],
                    tables[s, d, ph, 3],
                    tables[s, d, ph, 4],
                )
                if T <= 0.0 and ph < tables.shape[2] - 1:
                    continue  # (a zero-length phase: padding in front, or where the next one starts)
                _extend(d, p0, lo, hi)
                _extend(d, p0 + T * (v0 + T * (a0 / 2 + T * j / 6)), lo, hi)
                # v(h) = v0 + a0 h + j h^2 / 2 = 0 for h in (0, T)
                if j != 0.0:
                    disc = a0 * a0 - 2.0 * j * v0
                    if disc >= 0.0:
                        r = math.sqrt(disc)
                        for h in ((-a0 + r) / j, (-a0 - r) / j):
                            if 0.0 < h < T:
                                _extend(d, p0 + h * (v0 + h * (a0 / 2 + h * j / 6)), lo, hi)
                elif a0 != 0.0:
                    h = -v0 / a0
                    if 0.0 < h < T:
                        _extend(d, p0 + h * (v0 + h * a0 / 2), lo, hi)


@jit
def _extend(d: int, p: float, lo: FloatArray, hi: FloatArray) -> None:
    lo[d] = min(lo[d], p)
    hi[d] = max(hi[d], p)


@entry("void(f8[:, :, :, :], f8[:], f8[:], i8, f8, f8[:, :], f8[:, :], f8[:, :], f8[:, :], i8)")
def evaluate_part(
    tables: FloatArray,
    seg_starts: FloatArray,
    seg_durations: FloatArray,
    n: int,
    dt: float,
    reference: FloatArray,
    P: FloatArray,
    V: FloatArray,
    A: FloatArray,
    row: int,
) -> None:
    """:func:`evaluate` at the times ``k * dt`` for k < ``n``, into rows ``row`` on of P, V, A,
    plus a reference motion ``reference`` (rows: position, velocity, acceleration at time 0,
    carried on at that acceleration; zeros: none). A tracking cycle's parts, one call each."""
    times = np.empty(n)
    for k in range(n):
        times[k] = k * dt
    dofs = tables.shape[1]
    p, v, a, jk = np.empty((n, dofs)), np.empty((n, dofs)), np.empty((n, dofs)), np.empty((n, dofs))
    evaluate(tables, seg_starts, seg_durations, times, dt, p, v, a, jk)
    for k in range(n):
        t = times[k]
        for d in range(dofs):
            r0, r1, r2 = reference[0, d], reference[1, d], reference[2, d]
            P[row + k, d] = p[k, d] + r0 + r1 * t + r2 * (t * t / 2)  # (NumPy's order: the same sums)
            V[row + k, d] = v[k, d] + r1 + r2 * t
            A[row + k, d] = a[k, d] + r2


@entry("b1(f8[:, :, :, :], f8[:], f8[:], f8)")
def inside(tables: FloatArray, lower: FloatArray, upper: FloatArray, tol: float) -> bool:
    """Whether every dof's positions over the segments (:func:`extrema`) stay within
    [``lower``, ``upper``] to ``tol``."""
    lo, hi = np.empty(tables.shape[1]), np.empty(tables.shape[1])
    extrema(tables, lo, hi)
    for d in range(tables.shape[1]):  # noqa: SIM110 (a loop: compiled code, no generators)
        if not (lo[d] >= lower[d] - tol and hi[d] <= upper[d] + tol):
            return False
    return True


@entry("b1(f8[:], f8[:, :], i8, f8[:, :])")
def fit_motion(x: FloatArray, Q: FloatArray, degree: int, out: FloatArray) -> bool:
    """The least-squares polynomial of ``degree`` (1 or 2) through the points (``x[i]``,
    ``Q[i]``) (each column on its own), by its normal equations: its value, first and second
    derivative at x = 0 into ``out`` (3, columns) (a line's second: 0). A tracking stream's goal
    motion from its latest goals (:mod:`service.tracking`). False if the equations are singular
    (fewer distinct x than coefficients)."""
    k = degree + 1
    A = np.zeros((3, 3))
    B = np.zeros((3, Q.shape[1]))
    for i in range(x.shape[0]):
        powers = (1.0, x[i], x[i] * x[i])
        for r in range(k):
            for c in range(k):
                A[r, c] += powers[r] * powers[c]
            for j in range(Q.shape[1]):
                B[r, j] += powers[r] * Q[i, j]
    for col in range(k):  # Gaussian elimination with partial pivoting on the k x k system
        pivot = col
        for r in range(col + 1, k):
            if abs(A[r, col]) > abs(A[pivot, col]):
                pivot = r
        if A[pivot, col] == 0.0:
            return False
        if pivot != col:
            for c in range(3):
                A[col, c], A[pivot, c] = A[pivot, c], A[col, c]
            for j in range(Q.shape[1]):
                B[col, j], B[pivot, j] = B[pivot, j], B[col, j]
        for r in range(col + 1, k):
            f = A[r, col] / A[col, col]
            for c in range(col, k):
                A[r, c] -= f * A[col, c]
            for j in range(Q.shape[1]):
                B[r, j] -= f * B[col, j]
    for j in range(Q.shape[1]):
        coef = np.zeros(3)
        for r in range(k - 1, -1, -1):
            s = B[r, j]
            for c in range(r + 1, k):
                s -= A[r, c] * coef[c]
            coef[r] = s / A[r, r]
        out[0, j], out[1, j], out[2, j] = coef[0], coef[1], 2.0 * coef[2]
    return True
