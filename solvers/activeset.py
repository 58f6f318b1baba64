"""A small dense QP solver, compiled: the steps of the compiled closest-point iteration.

    min_x  1/2 x' H x + g' x   s.t.   lb <= x <= ub,   cl <= C x <= cu

Primal active-set method (Nocedal & Wright, Numerical Optimization, algorithm 16.3) from
the feasible start ``x = 0`` (the caller's current configuration is within limits, so the
step 0 is feasible). ``H`` must be positive definite (the Levenberg-Marquardt damping makes
it so). For the 3-6 variables and at most a few coupled rows of an arm IK step it takes a
handful of iterations of a tiny KKT solve: about a microsecond, compiled.
"""

from __future__ import annotations

import numpy as np

from armd.robots.types import FloatArray

from .jit import jit


@jit
def _row(i: int, n: int, C: FloatArray, a: FloatArray) -> float:
    """Constraint i as ``a . x <= b``: fills ``a`` and returns its sign-free index meaning.

    Rows: 0..n-1 upper bounds, n..2n-1 lower bounds (negated), then coupled upper, coupled
    lower (negated).
    """
    a[:] = 0.0
    k = C.shape[0]
    if i < n:
        a[i] = 1.0
    elif i < 2 * n:
        a[i - n] = -1.0
    elif i < 2 * n + k:
        a[:] = C[i - 2 * n]
    else:
        a[:] = -C[i - 2 * n - k]
    return 0.0


@jit
def _rhs(i: int, n: int, lb: FloatArray, ub: FloatArray, cl: FloatArray, cu: FloatArray) -> float:
    k = cl.shape[0]
    if i < n:
        return ub[i]
    if i < 2 * n:
        return -lb[i - n]
    if i < 2 * n + k:
        return cu[i - 2 * n]
    return -cl[i - 2 * n - k]


@jit
def _gauss(K: FloatArray, r: FloatArray, out: FloatArray, size: int) -> bool:
    """Solve ``K out = r`` in the leading ``size`` rows and columns, in place, by Gaussian
    elimination with partial pivoting (K, r destroyed); False when K is singular (dependent
    active constraints). (A size, not a view: Numba counts a reference for every view.)"""
    for c in range(size):
        piv = c
        big = abs(K[c, c])
        for i in range(c + 1, size):
            if abs(K[i, c]) > big:
                big = abs(K[i, c])
                piv = i
        if big < 1e-13:
            return False
        if piv != c:
            for j in range(size):
                K[c, j], K[piv, j] = K[piv, j], K[c, j]
            r[c], r[piv] = r[piv], r[c]
        for i in range(c + 1, size):
            f = K[i, c] / K[c, c]
            if f != 0.0:
                for j in range(c, size):
                    K[i, j] -= f * K[c, j]
                r[i] -= f * r[c]
    for i in range(size - 1, -1, -1):
        acc = r[i]
        for j in range(i + 1, size):
            acc -= K[i, j] * out[j]
        out[i] = acc / K[i, i]
    return True


@jit
def _inside(x: FloatArray, lb: FloatArray, ub: FloatArray, C: FloatArray, cl: FloatArray, cu: FloatArray) -> bool:
    for i in range(x.shape[0]):
        if x[i] < lb[i] or x[i] > ub[i]:
            return False
    for r in range(C.shape[0]):
        v = 0.0
        for i in range(x.shape[0]):
            v += C[r, i] * x[i]
        if v < cl[r] or v > cu[r]:
            return False
    return True


@jit
def _solve_box(H: FloatArray, g: FloatArray, lb: FloatArray, ub: FloatArray, x: FloatArray) -> bool:
    """:func:`solve_qp` with box bounds only: the same primal active-set method from x = 0, its
    working set the variables held at a bound, each step a solve in the free ones alone."""
    n = H.shape[0]
    at = np.zeros(n, dtype=np.int64)  # 0 free, -1 at its lower bound, +1 at its upper
    x[:] = 0.0
    K = np.empty((n, n))
    r = np.empty(n)
    sol = np.empty(n)
    free = np.empty(n, dtype=np.int64)
    target = np.empty(n)
    for _ in range(4 * n + 20):
        nf = 0
        for i in range(n):
            if at[i] == 0:
                free[nf] = i
                nf += 1
        # the minimiser over the free variables, the others where they are
        for a in range(nf):
            i = free[a]
            acc = -g[i]
            for j in range(n):
                if at[j] != 0:
                    acc -= H[i, j] * x[j]
            r[a] = acc
            for b in range(nf):
                K[a, b] = H[i, free[b]]
        if nf > 0 and not _gauss(K, r, sol, nf):
            return False
        for i in range(n):
            target[i] = x[i]
        for a in range(nf):
            target[free[a]] = sol[a]
        # step toward it, stopping at the first bound in the way
        alpha = 1.0
        block = -1
        for a in range(nf):
            i = free[a]
            d = target[i] - x[i]
            if d > 1e-15 and x[i] + d > ub[i]:
                t = (ub[i] - x[i]) / d
                if t < alpha:
                    alpha, block = max(t, 0.0), i
            elif d < -1e-15 and x[i] + d < lb[i]:
                t = (lb[i] - x[i]) / d
                if t < alpha:
                    alpha, block = max(t, 0.0), i
        for a in range(nf):
            i = free[a]
            step = alpha * (target[i] - x[i])
            x[i] += step
        if block >= 0:
            x[block] = ub[block] if target[block] > x[block] else lb[block]
            at[block] = 1 if abs(x[block] - ub[block]) <= abs(x[block] - lb[block]) else -1
            continue
        # at the minimiser of this working set: release a held variable whose gradient pulls it inside
        worst = -1
        most = 1e-14
        for i in range(n):
            if at[i] == 0:
                continue
            grad = g[i]
            for j in range(n):
                grad += H[i, j] * x[j]
            gain = grad if at[i] == 1 else -grad  # > 0: the cost falls moving off the bound
            if gain > most:
                most = gain
                worst = i
        if worst < 0:
            return True
        at[worst] = 0
    return False


@jit
def solve_qp(
    H: FloatArray,
    g: FloatArray,
    lb: FloatArray,
    ub: FloatArray,
    C: FloatArray,
    cl: FloatArray,
    cu: FloatArray,
    x: FloatArray,
    K0: FloatArray,
    r0: FloatArray,
) -> bool:
    """Solve into ``x`` (n,), starting from x = 0 (which must be feasible). True on success.
    ``K0`` (n, n) and ``r0`` (n,): scratch (the caller's, made once, not per step).

    First the unconstrained minimiser: where it keeps every bound (most steps of an iteration
    that is not pressed against a limit) it is the answer, and no working set is built."""
    n = H.shape[0]
    for i in range(n):
        r0[i] = -g[i]
        for j in range(n):
            K0[i, j] = H[i, j]
    if _gauss(K0, r0, x, n) and _inside(x, lb, ub, C, cl, cu):
        return True
    if C.shape[0] == 0:
        return _solve_box(H, g, lb, ub, x)
    m = 2 * n + 2 * C.shape[0]
    A = np.empty((m, n))
    b = np.empty(m)
    a = np.empty(n)
    for i in range(m):
        _row(i, n, C, a)
        A[i] = a
        b[i] = _rhs(i, n, lb, ub, cl, cu)
    x[:] = 0.0
    active = np.zeros(m, dtype=np.bool_)
    w = np.empty(m, dtype=np.int64)
    K = np.empty((n + m, n + m))
    r = np.empty(n + m)
    sol = np.empty(n + m)
    Hx = np.empty(n)
    newest = -1  # the constraint added last: dropped first if the active rows become dependent
    for _ in range(4 * m + 20):
        nw = 0
        for i in range(m):
            if active[i]:
                w[nw] = i
                nw += 1
        size = n + nw
        for i in range(size):
            for j in range(size):
                K[i, j] = 0.0
        for i in range(n):
            for j in range(n):
                K[i, j] = H[i, j]
        for j in range(nw):
            for i in range(n):
                K[i, n + j] = A[w[j], i]
                K[n + j, i] = A[w[j], i]
        for i in range(n):
            acc = g[i]
            for j in range(n):
                acc += H[i, j] * x[j]
            Hx[i] = acc
            r[i] = -acc
        for j in range(nw):
            r[n + j] = 0.0
        if not _gauss(K, r, sol, size):
            if nw == 0:  # singular with no constraint to drop: H itself is; the caller damps it and retries
                return False
            # dependent active rows: drop the newest one (or, that done, the last in the working set)
            active[newest if newest >= 0 and active[newest] else w[nw - 1]] = False
            newest = -1
            continue
        pmax = 0.0
        for i in range(n):
            pmax = max(pmax, abs(sol[i]))
        if pmax < 1e-14:
            if nw == 0:
                return True
            jmin = 0
            for j in range(1, nw):
                if sol[n + j] < sol[n + jmin]:
                    jmin = j
            if sol[n + jmin] >= -1e-14:
                return True
            active[w[jmin]] = False
            continue
        alpha = 1.0
        block = -1
        for i in range(m):
            if active[i]:
                continue
            ap = 0.0
            ax = 0.0
            for j in range(n):
                ap += A[i, j] * sol[j]
                ax += A[i, j] * x[j]
            if ap > 1e-15:
                t = (b[i] - ax) / ap
                if t < alpha:
                    alpha = max(t, 0.0)
                    block = i
        for j in range(n):
            x[j] += alpha * sol[j]
        if block >= 0:
            active[block] = True
            newest = block
    return False
