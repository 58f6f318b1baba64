"""armd's one Levenberg-Marquardt iteration, compiled: every step a QP with hard limits.

Seed 004 refines its analytic answer with a Jacobian-transpose iteration. armd instead solves,
at every step, the QP

    min_dq  1/2 |J dq - e|^2 + w^2/2 (j_pitch dq - e_pitch)^2 + mu/2 |dq|^2
    s.t.    max(lower - q, -step) <= dq <= min(upper - q, step)       (box limits, trust region)
            c_lo - C q <= C dq <= c_hi - C q                            (coupled limits)

(:mod:`solvers.activeset`), so that every iterate stays inside every joint limit (hard
constraints, not penalties); a step is taken only if it lowers the cost (else the damping
grows and the QP is solved again), so the error never increases, and the iteration converges
to the target when it is reachable, or to a closest configuration within limits when it is
not. The damping follows Marquardt (relative to diag(J'J)) with Nielsen's gain-ratio update.
A QP that fails (a singular step) is retried with more damping, never raised.

One policy, two models of the arm: the closed-form family's formula (:class:`~.arrays.Family`,
in the family's angles: the closest-point search of an exact family arm) or the URDF's exact
chain (:class:`~.kinematics.Chain`, the URDF's angles: the numerical IK of any arm, and the
refinement of an idealised closed form). :func:`solve_chain` is the numerical IK: the
iteration from the seed and from the atlas configurations nearest the target, the first to
converge wins.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from armd.robots.types import FloatArray

from .activeset import solve_qp
from .arrays import Family, family_at, family_pitch
from .atlas import Atlas, atlas_of, nearest
from .geometric import family_fk, wrap_angle
from .jit import entry, jit
from .kinematics import Chain, chain_jacobian, chain_of, chain_pose_with, chain_work
from .limits import limits_ok
from .packed import Packed

MARGIN = 1e-12  # [rad] kept inside coupled limits, so rounding never leaves them
TRIES = 12  # damping increases per step before the iteration gives up (a constrained optimum)
FIRST_STEPS = 15  # the numerical IK's steps from each start before the best one goes on
DAMPING = 1e-3  # the first step's damping, relative to the largest diagonal of J'J (then Nielsen's rule)
POLISH = 1e-9  # ... from a start already within a micrometre (an idealised closed form's branch)
STEP = 1.0  # [rad] the numerical IK's trust region per step and joint
START_DAMPING = 1e-1  # ... and its first damping (relative, as DAMPING): from a far seed an undamped step
# overshoots and is refused (a QP and an FK each); at 1e-5 the myCobot from random seeds took 1.07-1.10x rtb's
# time, at 1e-1 0.86-0.93x, the answers as near the seed (62% from it, not from the atlas)
STALL = 0.2  # ... and it leaves a start whose cost falls by less than this fraction, twice in a row
FINE = 0.1  # ... and iterates on to this fraction of the tolerance (a margin for the FK check)


@jit
def family_jacobian(f: Family, q: FloatArray, out: FloatArray) -> None:
    """d(tool point)/dq [m/rad] of the family's FK into ``out`` (3, n); zero for other joints."""
    P, J = f.P, f.J
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
def family_cost(
    f: Family, q: FloatArray, target: FloatArray, pitch: float, w2: float, p: FloatArray
) -> tuple[float, float]:
    """(cost, pitch error) of the family at ``q``: squared distance plus ``w2`` pitch error^2;
    the tool point into ``p``."""
    family_fk(f, q, p)
    e0, e1, e2 = target[0] - p[0], target[1] - p[1], target[2] - p[2]
    perr = wrap_angle(pitch - family_pitch(f, q)) if w2 > 0.0 else 0.0
    return e0 * e0 + e1 * e1 + e2 * e2 + w2 * perr * perr, perr


@jit
def _evaluate(
    f: Family,
    ch: Chain,
    on_chain: bool,
    q: FloatArray,
    target: FloatArray,
    pitch: float,
    w2: float,
    p: FloatArray,
    Jac: FloatArray,
    row: FloatArray,
    jacobian: bool,
    work: tuple,
) -> tuple[float, float]:
    """(cost, pitch error) at ``q`` on the model the flag picks; with ``jacobian``, the position
    Jacobian into ``Jac`` and the pitch gradient into ``row``."""
    if not on_chain:
        if jacobian:
            family_jacobian(f, q, Jac)
        return family_cost(f, q, target, pitch, w2, p)
    reached = chain_jacobian(ch, q, p, Jac, row, work) if jacobian else chain_pose_with(ch, q, p, work)
    e0, e1, e2 = target[0] - p[0], target[1] - p[1], target[2] - p[2]
    perr = wrap_angle(pitch - reached) if w2 > 0.0 else 0.0
    return e0 * e0 + e1 * e1 + e2 * e2 + w2 * perr * perr, perr


@jit
def lm_work(ch: Chain, n: int, kc: int) -> tuple:
    """Scratch for :func:`levenberg_marquardt` (n joints, kc coupled limits): one per
    solve, reused by each start's iteration (Numba allocates each array: some 40 ns apiece)."""
    return (
        np.empty(3),
        np.empty((3, n)),
        np.empty(n),
        np.empty(n),
        np.empty(n),
        np.empty(kc),
        np.empty(kc),
        np.empty(n),
        np.empty(n),
        np.empty((n, n)),
        np.empty((n, n)),
        np.empty(n),
        np.empty((n, n)),
        np.empty(n),
        chain_work(ch, n),
    )


@jit
def levenberg_marquardt(
    f: Family,
    ch: Chain,
    on_chain: bool,
    target: FloatArray,
    pitch: float,
    w2: float,
    q: FloatArray,
    max_iter: int,
    step: float,
    tol: float,
    damping: float,
    stall: float,
    scratch: tuple,
) -> tuple[float, float, int]:
    """From ``q`` (within the model's limits), in place: (position error [m], pitch error [rad],
    iterations). ``w2 > 0`` adds the pitch task with that weight^2. Stops at ``tol`` (position
    [m] and pitch [rad]), when no step lowers the cost (a constrained optimum), when the error
    no longer falls by a billionth of itself, or (``stall`` > 0) when two steps in a row each
    lower the cost by less than that fraction of it (creeping toward an optimum pressed
    against a limit: another start does better). ``scratch``: :func:`lm_work`."""
    if on_chain:
        lower, upper, C, clo, chi = ch.lower, ch.upper, ch.C, ch.clo, ch.chi
    else:
        lower, upper, C, clo, chi = f.lower, f.upper, f.C, f.clo, f.chi
    n = q.shape[0]
    kc = C.shape[0]
    p, Jac, row, lb, ub, cl, cu, dq, qn, H, Hd, g, K0, r0, work = scratch
    row[:] = 0.0
    if not on_chain:  # the family's pitch: the sum of its pitch joints
        for k in range(1, 4):
            if f.J[k] >= 0:
                row[f.J[k]] = 1.0
    cost, perr = _evaluate(f, ch, on_chain, q, target, pitch, w2, p, Jac, row, True, work)
    mu = -1.0  # set from the first Jacobian (Marquardt: relative to diag(J'J))
    nu = 2.0
    it = 0
    slow = 0  # consecutive steps that lowered the cost by less than ``stall`` of it
    while it < max_iter:
        err = math.sqrt(max(cost - w2 * perr * perr, 0.0))
        if err <= tol and abs(perr) <= tol:
            break
        it += 1
        e0, e1, e2 = target[0] - p[0], target[1] - p[1], target[2] - p[2]
        hmax = 0.0
        for i in range(n):  # H = J'J (+ w2 r r'), g = -J'e (- w2 perr r): small, by hand
            g[i] = -(Jac[0, i] * e0 + Jac[1, i] * e1 + Jac[2, i] * e2) - w2 * perr * row[i]
            for j in range(i, n):
                v = Jac[0, i] * Jac[0, j] + Jac[1, i] * Jac[1, j] + Jac[2, i] * Jac[2, j] + w2 * row[i] * row[j]
                H[i, j] = v
                H[j, i] = v
            hmax = max(hmax, H[i, i])
        for i in range(n):
            lb[i] = max(lower[i] - q[i], -step)
            ub[i] = min(upper[i] - q[i], step)
        for r in range(kc):
            cq = 0.0
            for i in range(n):
                cq += C[r, i] * q[i]
            cl[r] = min(clo[r] + MARGIN - cq, 0.0)
            cu[r] = max(chi[r] - MARGIN - cq, 0.0)
        if mu < 0.0:
            mu = damping * max(hmax, 1e-12)
        accepted = False
        cost_new = cost
        perr_new = perr
        for _ in range(TRIES):
            Hd[:, :] = H
            for i in range(n):
                Hd[i, i] += mu
            if not solve_qp(Hd, g, lb, ub, C, cl, cu, dq, K0, r0):
                mu *= nu
                nu *= 2.0
                continue
            for i in range(n):
                qn[i] = min(max(q[i] + dq[i], lower[i]), upper[i])
            # (with the Jacobian: an accepted step's is then at hand; H and g keep the current one's)
            cost_new, perr_new = _evaluate(f, ch, on_chain, qn, target, pitch, w2, p, Jac, row, True, work)
            # gain ratio: actual decrease over the decrease the quadratic model predicts
            predicted = 0.0
            for i in range(n):
                hq = 0.0
                for j in range(n):
                    hq += H[i, j] * dq[j]
                predicted -= g[i] * dq[i] + 0.5 * dq[i] * hq
            within = limits_ok(qn, ch, 0.0) if on_chain else limits_ok(qn, f, 0.0)
            if cost_new < cost and within:
                rho = 0.5 * (cost - cost_new) / max(predicted, 1e-300)
                mu *= max(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3)
                nu = 2.0
                accepted = True
                break
            mu *= nu
            nu *= 2.0
        if not accepted:
            _evaluate(f, ch, on_chain, q, target, pitch, w2, p, Jac, row, False, work)
            break
        progress = cost - cost_new
        q[:] = qn
        cost, perr = cost_new, perr_new
        # the cost no longer falls by a billionth of itself (or the step is nothing): a constrained optimum
        biggest = 0.0
        for i in range(n):
            biggest = max(biggest, abs(dq[i]))
        if progress <= 1e-9 * cost + 1e-24 or biggest < 1e-13:
            break
        slow = slow + 1 if progress < stall * (cost + progress) else 0
        if slow >= 2:
            break
    return math.sqrt(max(cost - w2 * perr * perr, 0.0)), abs(perr), it


@jit
def no_chain() -> Chain:
    """An empty chain, for an iteration on the family's formula."""
    e1 = np.zeros(0)
    return Chain(
        np.zeros((0, 4, 4)),
        np.zeros((0, 3)),
        np.zeros(0, dtype=np.int64),
        np.zeros(0, dtype=np.int64),
        e1,
        e1,
        np.eye(4),
        np.zeros(3),
        e1,
        e1,
        np.zeros((0, 0)),
        e1,
        e1,
        -1,
        1.0,
        0.0,
    )


@jit
def no_family() -> Family:
    """An empty family, for an iteration on the exact chain."""
    e1 = np.zeros(0)
    return Family(np.zeros(8), np.full(4, -1, dtype=np.int64), e1, e1, e1, np.zeros((0, 0)), e1, e1, False, False)


@jit
def lm_family(
    f: Family, target: FloatArray, pitch: float, w2: float, q: FloatArray, max_iter: int, step: float, tol: float
) -> tuple[float, float, int]:
    """:func:`levenberg_marquardt` on the family's formula (the family's angles and frame)."""
    ch = no_chain()
    work = lm_work(ch, q.shape[0], f.C.shape[0])
    return levenberg_marquardt(f, ch, False, target, pitch, w2, q, max_iter, step, tol, DAMPING, 0.0, work)


@entry("Tuple((f8, f8, i8))(Family, f8[:], f8, f8, f8[:], i8, f8, f8)")
def refine_family(
    packed_family: Packed,
    target: FloatArray,
    pitch: float,
    w2: float,
    q: FloatArray,
    max_iter: int,
    step: float,
    tol: float,
) -> tuple[float, float, int]:
    """:func:`lm_family`, for Python: the :class:`Family` packed (:mod:`solvers.packed`), as
    every entry point here takes its bundles."""
    return lm_family(family_at(packed_family, 0), target, pitch, w2, q, max_iter, step, tol)


@entry("Tuple((f8, f8, i8))(Chain, f8[:], f8, f8, f8[:], i8, f8, f8)")
def refine_chain(
    packed_chain: Packed,
    target: FloatArray,
    pitch: float,
    w2: float,
    q: FloatArray,
    max_iter: int,
    step: float,
    tol: float,
) -> tuple[float, float, int]:
    """:func:`levenberg_marquardt` on the exact chain (the URDF's angles, ``base``)."""
    ch = chain_of(packed_chain)
    work = lm_work(ch, q.shape[0], ch.C.shape[0])
    return levenberg_marquardt(no_family(), ch, True, target, pitch, w2, q, max_iter, step, tol, DAMPING, 0.0, work)


@jit
def feasible(ch: Chain, q: FloatArray, inside: FloatArray, out: FloatArray) -> bool:
    """``q`` clipped into the box, into ``out``; where that breaks a coupled limit, the farthest
    point toward it from ``inside`` (a configuration within every limit) that keeps them all.
    False if ``inside`` itself is not within the limits."""
    n = q.shape[0]
    for i in range(n):
        out[i] = min(max(q[i], ch.lower[i]), ch.upper[i])
    if limits_ok(out, ch, 0.0):
        return True
    if not limits_ok(inside, ch, 0.0):
        return False
    toward = out.copy()
    lo, hi = 0.0, 1.0
    for _ in range(50):
        mid = 0.5 * (lo + hi)
        for i in range(n):
            out[i] = inside[i] + mid * (toward[i] - inside[i])
        if limits_ok(out, ch, 0.0):
            lo = mid
        else:
            hi = mid
    for i in range(n):
        out[i] = inside[i] + lo * (toward[i] - inside[i])
    return True


@entry("Tuple((f8, f8, i8, i8, f8))(Chain, f8[:], f8, f8, f8[:], f8[:], Atlas, i8, f8, f8, f8[:], f8[:])")
def solve_chain(
    packed_chain: Packed,
    target: FloatArray,
    pitch: float,
    w2: float,
    ref: FloatArray,
    inside: FloatArray,
    packed_atlas: Packed,
    n_atlas: int,
    tol: float,
    pitch_tol: float,
    q_out: FloatArray,
    reached: FloatArray,
) -> tuple[float, float, int, int, float]:
    """The numerical IK of any arm: :func:`levenberg_marquardt` on the exact chain from the seed
    ``ref`` (made feasible toward it from ``inside``, a configuration within every limit), then
    from the ``n_atlas`` atlas configurations whose tool points are nearest the target,
    :data:`FIRST_STEPS` steps each, until one reaches ``tol`` [m] (and ``pitch_tol`` [rad] with
    ``w2 > 0``), then on to :data:`FINE` of ``tol``; else the best of them iterated to
    convergence. Into ``q_out`` and its tool point into ``reached``: (position error, pitch
    error, iterations, starts used, tool pitch [rad]). The chain and the atlas packed
    (:mod:`solvers.packed`)."""
    ch, atlas = chain_of(packed_chain), atlas_of(packed_atlas)
    n = ref.shape[0]
    order = np.empty(n_atlas, dtype=np.int64)
    work = lm_work(ch, n, ch.C.shape[0])
    return _solve_chain(
        ch, target, pitch, w2, ref, inside, atlas, tol, pitch_tol, q_out, reached, np.empty(n), order, work
    )


@jit
def _solve_chain(
    ch: Chain,
    target: FloatArray,
    pitch: float,
    w2: float,
    ref: FloatArray,
    inside: FloatArray,
    atlas: Atlas,
    tol: float,
    pitch_tol: float,
    q_out: FloatArray,
    reached: FloatArray,
    q: FloatArray,
    order: NDArray[np.int64],
    work: tuple,
) -> tuple[float, float, int, int, float]:
    """:func:`solve_chain` with its scratch given (``q`` (n,), ``order`` (n_atlas,), ``work``:
    :func:`lm_work`), so that a batch makes it once."""
    f = no_family()
    n_atlas = order.shape[0]
    fine = max(tol * FINE, 1e-12)  # [m] where the iteration stops, inside the tolerance
    order[:] = -1  # the n_atlas nearest atlas points (after the seed)
    best, best_err, best_perr = 1e300, math.inf, math.inf
    iters = 0
    used = 0
    for s in range(n_atlas + 1):  # a few steps from each start: a reachable target is met in them
        if s == 0:
            if not feasible(ch, ref, inside, q):
                continue
        else:
            if s == 1:  # the seed did not do: the atlas
                nearest(atlas, target, order)
            if order[s - 1] < 0:
                continue
            q[:] = atlas.q[order[s - 1]]
        used += 1
        err, perr, it = levenberg_marquardt(
            f, ch, True, target, pitch, w2, q, FIRST_STEPS, STEP, fine, START_DAMPING, STALL, work
        )
        iters += it
        score = err * err + w2 * perr * perr
        if score < best:
            best, best_err, best_perr = score, err, perr
            q_out[:] = q
        if err <= tol and (w2 == 0.0 or perr <= pitch_tol):  # met: a few more steps take it to ``fine``
            if err > fine:
                best_err, best_perr, it = levenberg_marquardt(
                    f, ch, True, target, pitch, w2, q_out, 10, STEP, fine, DAMPING, 0.0, work
                )
                iters += it
            return best_err, best_perr, iters, used, chain_pose_with(ch, q_out, reached, work[-1])
    if best < 1e300:  # none met it: the best start's iteration to convergence
        best_err, best_perr, it = levenberg_marquardt(
            f, ch, True, target, pitch, w2, q_out, 200, STEP, 1e-12, DAMPING, 0.0, work
        )
        iters += it
    return best_err, best_perr, iters, used, chain_pose_with(ch, q_out, reached, work[-1])


@entry("void(Chain, f8[:, :], f8[:], f8, f8[:, :], f8[:], Atlas, i8, f8, f8, f8[:, :], f8[:, :], f8[:], f8[:], f8[:])")
def solve_chains(
    packed_chain: Packed,
    targets: FloatArray,
    pitches: FloatArray,
    w2: float,
    refs: FloatArray,
    inside: FloatArray,
    packed_atlas: Packed,
    n_atlas: int,
    tol: float,
    pitch_tol: float,
    q_out: FloatArray,
    reached_out: FloatArray,
    err_out: FloatArray,
    perr_out: FloatArray,
    pitch_out: FloatArray,
) -> None:
    """:func:`solve_chain` for each row of ``targets`` (m, 3) [m], at tool pitch ``pitches`` row
    [rad] (with ``w2 > 0``) from seed ``refs`` row (m, n): the batch IK of an arm outside the
    closed-form family. Each row's answer into ``q_out``, its tool point, position error [m],
    pitch error [rad] and tool pitch [rad] (not wrapped) into the others; the same answers as
    :func:`solve_chain` row by row, its scratch made once."""
    ch, atlas = chain_of(packed_chain), atlas_of(packed_atlas)
    n = refs.shape[1]
    q = np.empty(n)
    order = np.empty(n_atlas, dtype=np.int64)
    work = lm_work(ch, n, ch.C.shape[0])
    for i in range(targets.shape[0]):
        err, perr, _, _, reached_pitch = _solve_chain(
            ch,
            targets[i],
            pitches[i],
            w2,
            refs[i],
            inside,
            atlas,
            tol,
            pitch_tol,
            q_out[i],
            reached_out[i],
            q,
            order,
            work,
        )
        err_out[i], perr_out[i], pitch_out[i] = err, perr, reached_pitch


@entry("void(Chain, f8[:, :], i8, f8[:], f8, f8, f8, f8, f8[:], b1[:], i8[:])")
def refine_branches(
    packed_chain: Packed,
    qs: FloatArray,
    m: int,
    target: FloatArray,
    pitch: float,
    w2: float,
    tol: float,
    pitch_tol: float,
    errs: FloatArray,
    kept: NDArray[np.bool_],
    iterations: NDArray[np.int64],
) -> None:
    """The first ``m`` rows of ``qs`` (an idealised closed form's branches, within limits)
    checked on the exact chain and, where they miss by more than ``tol``, iterated there in
    place: each row's exact error into ``errs``, whether it now reaches the target (and the
    pitch ``pitch`` with ``w2 > 0``) into ``kept``, the iterations into ``iterations[0]``."""
    ch = chain_of(packed_chain)
    f = no_family()
    p = np.empty(3)
    work = lm_work(ch, qs.shape[1], ch.C.shape[0])
    iterations[0] = 0
    for r in range(m):
        q = qs[r]
        reached = chain_pose_with(ch, q, p, work[-1])
        err = math.sqrt((p[0] - target[0]) ** 2 + (p[1] - target[1]) ** 2 + (p[2] - target[2]) ** 2)
        perr = abs(wrap_angle(pitch - reached)) if w2 > 0.0 else 0.0
        if err > tol or perr > pitch_tol:
            err, perr, it = levenberg_marquardt(f, ch, True, target, pitch, w2, q, 100, 0.4, 1e-12, POLISH, 0.0, work)
            iterations[0] += it
        errs[r] = err
        kept[r] = err <= tol and perr <= pitch_tol
