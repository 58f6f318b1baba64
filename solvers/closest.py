"""The closest configuration within limits to a target, on the family's exact model, compiled.

For an arm whose ``[geometry]`` reproduces its URDF (checked against Pinocchio when the
solver first sees the arm), the family's FK formula *is* the exact model, with an analytic
Jacobian. This module runs the same Levenberg-Marquardt iteration as :mod:`solvers.qp`
(each step a QP with the box and coupled limits as hard constraints, solved by
:mod:`solvers.activeset`; a step is taken only if it lowers the cost) entirely in compiled
code, from several starts, and keeps the best: an unreachable target is answered in tens
of microseconds instead of milliseconds.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from .activeset import solve_qp
from .geometric import family_fk, wrap_angle, wrap_into
from .jit import jit
from .limits import limits_ok

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

MARGIN = 1e-12  # [rad] kept inside coupled limits, so rounding never leaves them


@jit
def family_jacobian(P: FloatArray, J: IntArray, q: FloatArray, out: FloatArray) -> None:
    """d(tool point)/dq [m/rad] of the family's FK into ``out`` (3, n); zero for other joints."""
    py, l1, l2, l3 = P[1], P[3], P[4], P[5]
    out[:] = 0.0
    yaw = q[J[0]]
    p1 = q[J[1]]
    p2 = p1 + q[J[2]]
    c0, s0 = math.cos(yaw), math.sin(yaw)
    du = np.zeros(3)
    dz = np.zeros(3)
    s1, c1, s2, c2 = math.sin(p1), math.cos(p1), math.sin(p2), math.cos(p2)
    s3 = c3 = 0.0
    if J[3] >= 0:
        p3 = p2 + q[J[3]]
        s3, c3 = l3 * math.sin(p3), l3 * math.cos(p3)
    du[0] = -(l1 * s1 + l2 * s2 + s3)
    dz[0] = l1 * c1 + l2 * c2 + c3
    du[1] = -(l2 * s2 + s3)
    dz[1] = l2 * c2 + c3
    du[2] = -s3
    dz[2] = c3
    u = P[0] + l1 * c1 + l2 * c2 + c3 + P[6]
    out[0, J[0]] = -s0 * u - c0 * py
    out[1, J[0]] = c0 * u - s0 * py
    for k in range(3):
        j = J[k + 1]
        if j < 0:
            continue
        out[0, j] = c0 * du[k]
        out[1, j] = s0 * du[k]
        out[2, j] = dz[k]


@jit
def _cost(P: FloatArray, J: IntArray, q: FloatArray, target: FloatArray, pitch: float, w2: float,
          p: FloatArray) -> tuple[float, float]:
    family_fk(P, J, q, p)
    e0, e1, e2 = target[0] - p[0], target[1] - p[1], target[2] - p[2]
    perr = 0.0
    if w2 > 0.0:
        s = 0.0
        for k in range(1, 4):
            if J[k] >= 0:
                s += q[J[k]]
        perr = wrap_angle(pitch - s)
    return e0 * e0 + e1 * e1 + e2 * e2 + w2 * perr * perr, perr


@jit
def refine_family(P: FloatArray, J: IntArray, lower: FloatArray, upper: FloatArray, C: FloatArray,
                  clo: FloatArray, chi: FloatArray, target: FloatArray, pitch: float, w2: float,
                  q: FloatArray, max_iter: int, step: float, tol: float) -> tuple[float, float, int]:
    """Levenberg-Marquardt from ``q`` (within limits), in place: (position error [m], pitch error
    [rad], iterations). ``w2 > 0`` adds the pitch task (sum of pitch joints) with that weight^2."""
    n = q.shape[0]
    p = np.empty(3)
    Jac = np.empty((3, n))
    row = np.zeros(n)
    for k in range(1, 4):
        if J[k] >= 0:
            row[J[k]] = 1.0
    lb = np.empty(n)
    ub = np.empty(n)
    kc = C.shape[0]
    cl = np.empty(kc)
    cu = np.empty(kc)
    dq = np.empty(n)
    qn = np.empty(n)
    cost, perr = _cost(P, J, q, target, pitch, w2, p)
    mu = -1.0  # set from the first Jacobian (Marquardt: relative to diag(J'J))
    nu = 2.0
    it = 0
    while it < max_iter:
        err = math.sqrt(max(cost - w2 * perr * perr, 0.0))
        if err <= tol and abs(perr) <= tol:
            break
        it += 1
        family_jacobian(P, J, q, Jac)
        e = target - p
        H = Jac.T @ Jac
        g = -(Jac.T @ e)
        if w2 > 0.0:
            H += w2 * np.outer(row, row)
            g -= w2 * perr * row
        for i in range(n):
            lb[i] = max(lower[i] - q[i], -step)
            ub[i] = min(upper[i] - q[i], step)
        for r in range(kc):
            cq = C[r] @ q
            cl[r] = min(clo[r] + MARGIN - cq, 0.0)
            cu[r] = max(chi[r] - MARGIN - cq, 0.0)
        if mu < 0.0:
            mu = 1e-3 * max(np.max(np.diag(H)), 1e-12)
        accepted = False
        cost_new = cost
        perr_new = perr
        for _ in range(12):
            Hd = H.copy()
            for i in range(n):
                Hd[i, i] += mu
            if not solve_qp(Hd, g, lb, ub, C, cl, cu, dq):
                mu *= nu
                nu *= 2.0
                continue
            for i in range(n):
                qn[i] = min(max(q[i] + dq[i], lower[i]), upper[i])
            cost_new, perr_new = _cost(P, J, qn, target, pitch, w2, p)
            # gain ratio: actual decrease over the decrease the quadratic model predicts
            predicted = float(-(g @ dq) - 0.5 * (dq @ (H @ dq)))
            if cost_new < cost and limits_ok(qn, lower, upper, C, clo, chi, 0.0):
                rho = 0.5 * (cost - cost_new) / max(predicted, 1e-300)
                mu *= max(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3)
                nu = 2.0
                accepted = True
                break
            mu *= nu
            nu *= 2.0
        if not accepted:
            _cost(P, J, q, target, pitch, w2, p)
            break
        progress = cost - cost_new
        q[:] = qn
        cost, perr = cost_new, perr_new
        # the error no longer moves by 1e-11 m (or the step is nothing): a constrained optimum
        if progress <= 2e-11 * math.sqrt(cost) + 1e-24 or np.max(np.abs(dq)) < 1e-13:
            break
    return math.sqrt(max(cost - w2 * perr * perr, 0.0)), abs(perr), it


@jit
def stretched_optimum(P: FloatArray, J: IntArray, lower: FloatArray, upper: FloatArray, C: FloatArray,
                      clo: FloatArray, chi: FloatArray, target: FloatArray, ref: FloatArray,
                      q_out: FloatArray) -> float:
    """The closest configuration in closed form, where it provably is one: (error [m]), or -1.

    With no lateral pivot offset, the family's reachable set (any tool pitch, limits aside)
    is a solid of revolution about the base's z axis whose profile is the shoulder's disc of
    radius l1 + l2 (+ l3, the hand continuing the line) on either side of the axis. A target
    outside both discs is nearest the arm stretched straight at it from the nearer disc's
    centre: that is the unconstrained optimum, so when it lies within every limit it is the
    constrained one too. Anything else (a lateral offset, a target inside a disc, a
    stretched arm outside a limit) returns -1 and is left to the iteration.
    """
    px, py, pz, l1, l2, l3, ox, oz = P[0], P[1], P[2], P[3], P[4], P[5], P[6], P[7]
    if py != 0.0:
        return -1.0
    reach = l1 + l2 + (l3 if J[3] >= 0 else 0.0)
    x, y, z = target[0], target[1], target[2]
    h = math.sqrt(x * x + y * y)
    b = z - pz - oz
    a_front = h - px - ox
    a_flip = -h - px - ox
    d_front = math.sqrt(a_front * a_front + b * b)
    d_flip = math.sqrt(a_flip * a_flip + b * b)
    if d_front <= reach or d_flip <= reach:
        return -1.0
    n = ref.shape[0]
    for i in range(n):
        q_out[i] = min(max(ref[i], lower[i]), upper[i])
    yaw_j = J[0]
    if h > 0.0:
        bearing = math.atan2(y, x)
        yaw = bearing if d_front <= d_flip else bearing - math.pi
    else:  # on the yaw axis: every yaw is as near; keep the seed's
        yaw = q_out[yaw_j]
    a = a_front if d_front <= d_flip else a_flip
    ok, q_out[yaw_j] = wrap_into(yaw, lower[yaw_j], upper[yaw_j], ref[yaw_j], 0.0)
    if not ok:
        return -1.0
    ok, q_out[J[1]] = wrap_into(math.atan2(b, a), lower[J[1]], upper[J[1]], ref[J[1]], 0.0)
    if not ok:
        return -1.0
    for k in range(2, 4):  # elbow and wrist straight
        j = J[k]
        if j >= 0:
            ok, q_out[j] = wrap_into(0.0, lower[j], upper[j], ref[j], 0.0)
            if not ok:
                return -1.0
    if not limits_ok(q_out, lower, upper, C, clo, chi, 0.0):
        return -1.0
    p = np.empty(3)
    family_fk(P, J, q_out, p)
    return math.sqrt((p[0] - x) ** 2 + (p[1] - y) ** 2 + (p[2] - z) ** 2)


@jit
def closest_family(P: FloatArray, J: IntArray, lower: FloatArray, upper: FloatArray, C: FloatArray,
                   clo: FloatArray, chi: FloatArray, target: FloatArray, pitch: float, w2: float,
                   ref: FloatArray, atlas_q: FloatArray, atlas_p: FloatArray, n_atlas: int,
                   q_out: FloatArray) -> tuple[float, float, int]:
    """The stretched arm where it is provably the answer (:func:`stretched_optimum`, free
    pitch only); else the best of :func:`refine_family` from ``ref`` (if within limits) and
    the ``n_atlas`` atlas configurations whose tool points are nearest the target:
    (error, pitch error, iterations)."""
    if w2 == 0.0:
        err = stretched_optimum(P, J, lower, upper, C, clo, chi, target, ref, q_out)
        if err >= 0.0:
            return err, 0.0, 0
    n = ref.shape[0]
    order = np.full(n_atlas, -1, dtype=np.int64)  # the n_atlas nearest atlas points, by a linear scan
    dist = np.full(n_atlas, np.inf)
    for i in range(atlas_p.shape[0]):
        d = (atlas_p[i, 0] - target[0]) ** 2 + (atlas_p[i, 1] - target[1]) ** 2 + (atlas_p[i, 2] - target[2]) ** 2
        if d < dist[n_atlas - 1]:
            k = n_atlas - 1
            while k > 0 and dist[k - 1] > d:
                dist[k] = dist[k - 1]
                order[k] = order[k - 1]
                k -= 1
            dist[k] = d
            order[k] = i
    # the starts' costs; a few steps from the promising ones; the best one to convergence
    starts = np.empty((n_atlas + 1, n))
    costs = np.full(n_atlas + 1, np.inf)
    p = np.empty(3)
    for s in range(n_atlas + 1):
        if s == 0:
            for i in range(n):
                starts[s, i] = min(max(ref[i], lower[i]), upper[i])
            if not limits_ok(starts[s], lower, upper, C, clo, chi, 0.0):
                continue
        elif order[s - 1] >= 0:
            starts[s] = atlas_q[order[s - 1]]
        else:
            continue
        costs[s], _ = _cost(P, J, starts[s], target, pitch, w2, p)
    floor = np.min(costs)
    best = 1e300
    iters = 0
    q = np.empty(n)
    for s in range(n_atlas + 1):
        if not costs[s] <= 4.0 * floor + 1e-6:  # far worse than the best start: skip it
            continue
        q[:] = starts[s]
        err, perr, it = refine_family(P, J, lower, upper, C, clo, chi, target, pitch, w2, q, 4, 0.4, 1e-12)
        iters += it
        score = err * err + w2 * perr * perr
        if score < best - 1e-18:
            best = score
            q_out[:] = q
    err, perr, it = refine_family(P, J, lower, upper, C, clo, chi, target, pitch, w2, q_out, 200, 0.4, 1e-12)
    return err, perr, iters + it
