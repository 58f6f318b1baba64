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
from .analytic import NONE, solve_one
from .geometric import family_fk, wrap_angle, wrap_into
from .jit import jit
from .limits import limits_ok

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

MARGIN = 1e-12  # [rad] kept inside coupled limits, so rounding never leaves them
FREE_PREFS = np.array([0.0, -math.pi / 2])  # the free-pitch preference (solvers.ik.FREE_PITCHES)


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
def closest_box(P: FloatArray, J: IntArray, lower: FloatArray, upper: FloatArray, C: FloatArray,
                clo: FloatArray, chi: FloatArray, weights: FloatArray, exact_pitch_search: bool, target: FloatArray,
                ref: FloatArray, q_out: FloatArray) -> float:
    """The closest configuration within the box limits, any tool pitch, by enumerating every
    stationary point: (error [m]), or -1 where this does not apply.

    With no lateral pivot offset, the best yaw for a given arm pose is the yaw within limits
    nearest the target's bearing (tool in front of the axis) or its opposite (behind), so the
    optimum uses one of those two. For the planar chain (shoulder, elbow, wrist angles, each in
    a box), the optimum lies in the relative interior of one face of the box (each joint free,
    or at its lower or upper bound), where every free joint is stationary: its origin, the
    tool point and the target are collinear. All free joints' origins and the tool point then
    lie on the line from the first free joint's origin to the target, each free joint turning
    the rigid chain after it onto that line, pointing along it or back. Every face and both
    directions per free joint, for both yaws: 2 x 4^3 candidates at most, each in closed
    form. Where the yaw is held at a limit, the tool may sit exactly on the target's
    projection on the arm's plane (a case the collinearity does not cover): the closed form
    (complete for free pitch where no coupled limit touches a pitch joint) says whether it
    can. The best candidate within limits is the optimum. Returns -1 (the iteration answers)
    for a lateral pivot offset, a degenerate chain, a coupled limit the best one breaks, or a
    projection the closed form cannot decide.
    """
    px, py, pz, l1, l2, l3, ox, oz = P[0], P[1], P[2], P[3], P[4], P[5], P[6], P[7]
    if py != 0.0:
        return -1.0
    nj = 3 if J[3] >= 0 else 2
    links = np.array([l1, l2, l3])
    x, y, z = target[0], target[1], target[2]
    h = math.sqrt(x * x + y * y)
    n = ref.shape[0]
    q = np.empty(n)
    for i in range(n):
        q[i] = min(max(ref[i], lower[i]), upper[i])
    yaw_j = J[0]
    yaws = np.empty(2)
    n_yaws = 1
    bearing = 0.0
    if h > 0.0:
        bearing = math.atan2(y, x)
        for side in range(2):
            aim = bearing + side * math.pi
            ok, v = wrap_into(aim, lower[yaw_j], upper[yaw_j], aim, 0.0)
            if not ok:  # the aim is outside the yaw range: the nearer end, by angle
                dlo = abs(wrap_angle(lower[yaw_j] - aim))
                dhi = abs(wrap_angle(upper[yaw_j] - aim))
                v = lower[yaw_j] if dlo <= dhi else upper[yaw_j]
            yaws[side] = v
        n_yaws = 2
    else:  # on the yaw axis every yaw is as near: keep the seed's
        yaws[0] = q[yaw_j]
    cu, cz = px + ox, pz + oz
    best = 1e300
    p = np.empty(3)
    theta = np.empty(3)
    opt = np.empty(3, dtype=np.int64)
    qs = np.empty((4, n))
    ids = np.empty(4, dtype=np.int64)
    errs = np.empty(4)
    work = np.empty((4, 5))
    options = 4 ** nj
    reach = l1 + l2 + (l3 if nj == 3 else 0.0)
    for yi in range(n_yaws):
        psi = yaws[yi]
        tu = h * math.cos(bearing - psi) if h > 0.0 else 0.0  # the target projected on the arm's plane
        lateral = h * abs(math.sin(bearing - psi)) if h > 0.0 else 0.0
        if lateral > 1e-12 and (tu - cu) ** 2 + (z - cz) ** 2 <= reach * reach:
            # the yaw is held at a limit and the target's projection on the arm's plane may be
            # reached exactly (a case the collinearity does not cover): ask the closed form
            if not exact_pitch_search:
                return -1.0  # (it is complete only where no coupled limit touches a pitch joint)
            code, m, _ = solve_one(P, J, lower, upper, weights, C, clo, chi, exact_pitch_search, ref,
                                   tu * math.cos(psi), tu * math.sin(psi), z, FREE_PREFS, qs, ids, errs, work)
            if code != NONE and lateral * lateral < best - 1e-30:
                best = lateral * lateral
                q_out[:] = qs[0]
            if code != NONE:
                continue  # nothing at this yaw is nearer than the projection itself
        for code in range(options):
            # joint k: option 0/1 free (pointing along the line / back), 2 at its lower, 3 at its upper bound
            c = code
            for k in range(nj):
                opt[k] = c % 4
                c //= 4
            first = -1
            phi = 0.0
            ou, oz_ = cu, cz
            for k in range(nj):
                o = opt[k]
                if o >= 2:
                    j = J[k + 1]
                    theta[k] = lower[j] if o == 2 else upper[j]
                    if first < 0:
                        phi += theta[k]
                        ou += links[k] * math.cos(phi)
                        oz_ += links[k] * math.sin(phi)
                elif first < 0:
                    first = k
            if first >= 0:
                du, dz = tu - ou, z - oz_
                if du * du + dz * dz < 1e-24:
                    return -1.0
                alpha = math.atan2(dz, du)
                feasible = True
                prev = phi  # absolute angle of the link before joint `first`
                k = first
                while k < nj:
                    o = opt[k]
                    j = J[k + 1]
                    if o >= 2:
                        prev += theta[k]
                        k += 1
                        continue
                    # the rigid chain from joint k to the next free joint (or the tool), with phi_k = 0
                    wu, wz, g = 0.0, 0.0, 0.0
                    m = k
                    while True:
                        wu += links[m] * math.cos(g)
                        wz += links[m] * math.sin(g)
                        m += 1
                        if m >= nj or opt[m] < 2:
                            break
                        g += theta[m]
                    if wu * wu + wz * wz < 1e-24:
                        return -1.0
                    phik = alpha + o * math.pi - math.atan2(wz, wu)
                    ok, v = wrap_into(phik - prev, lower[j], upper[j], q[j], 0.0)
                    if not ok:
                        feasible = False
                        break
                    theta[k] = v
                    prev += v
                    k += 1
                if not feasible:
                    continue
            eu, ez, a = cu, cz, 0.0
            for k in range(nj):
                a += theta[k]
                eu += links[k] * math.cos(a)
                ez += links[k] * math.sin(a)
            d2 = (eu - tu) ** 2 + (ez - z) ** 2 + lateral * lateral
            if d2 < best - 1e-30:
                best = d2
                q[yaw_j] = psi
                for k in range(nj):
                    q[J[k + 1]] = theta[k]
                q_out[:] = q
    if best >= 1e300 or not limits_ok(q_out, lower, upper, C, clo, chi, 0.0):
        return -1.0
    family_fk(P, J, q_out, p)
    return math.sqrt((p[0] - x) ** 2 + (p[1] - y) ** 2 + (p[2] - z) ** 2)


@jit
def closest_family(P: FloatArray, J: IntArray, lower: FloatArray, upper: FloatArray, C: FloatArray,
                   clo: FloatArray, chi: FloatArray, weights: FloatArray, exact_pitch_search: bool,
                   target: FloatArray, pitch: float, w2: float, ref: FloatArray, atlas_q: FloatArray,
                   atlas_p: FloatArray, n_atlas: int, q_out: FloatArray) -> tuple[float, float, int]:
    """The enumerated optimum where it applies (:func:`closest_box`, free pitch only); else
    the best of :func:`refine_family` from ``ref`` (if within limits) and
    the ``n_atlas`` atlas configurations whose tool points are nearest the target:
    (error, pitch error, iterations)."""
    if w2 == 0.0:
        err = closest_box(P, J, lower, upper, C, clo, chi, weights, exact_pitch_search, target, ref, q_out)
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
