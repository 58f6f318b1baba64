"""The closest configuration within limits to a target, on the family's exact model, compiled.

For an arm whose closed form reproduces its URDF (checked against Pinocchio when the solver
first sees the arm), the family's FK formula *is* the exact model, with an analytic Jacobian.
This module runs armd's Levenberg-Marquardt iteration (:mod:`solvers.lm`: each step a QP with
the box and coupled limits as hard constraints; a step is taken only if it lowers the cost) on
it from several starts, and keeps the best: an unreachable target is answered in tens of
microseconds. Where the optimum's stationary points can all be
enumerated (:func:`enumerated_closest`, :func:`closest_level`: every catalogue arm), the iteration is
not needed at all: the enumeration is exact, where the iteration can stop in a local minimum.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from armd.robots.types import FloatArray

from .analytic import NONE, solve_one
from .arrays import Family, arm_of, family_at, from_family, to_family, view
from .atlas import atlas_of, nearest
from .geometric import TWO_PI, family_fk, two_link, wrap_angle, wrap_into
from .jit import entry, jit
from .limits import limits_ok
from .lm import MARGIN, family_cost, lm_family
from .packed import Packed

IntArray = NDArray[np.int64]

SLACK = 1e-9  # relative (and [m^2] absolute) slack of enumerated_closest's bounds: a skip is never a rounding's doing
FREE_PREFS = np.array([0.0, -math.pi / 2])  # the free-pitch preference (solvers.ik.FREE_PITCHES)
ALPHA_STEP = math.pi / 32  # [rad] sampling of the target's bearing in the arm frame (closest_level)


# -- a level arm: lateral pivot offset, coupled limits on the planar joints ----------------------


@jit
def _planar_rows(f: Family, rows: FloatArray) -> int:
    """The limits on the shoulder and elbow angles (t1, t2) as rows ``lo <= a1 t1 + a2 t2 <= hi``
    into ``rows`` (k, 4), (a1, a2) one of (1, 0), (0, 1), (1, 1): the box, then the coupled limits
    (MARGIN inside, as the iteration keeps them, so rounding never leaves them).

    These are the directions along which the tool moves on a circle (one angle held, or the
    forearm's absolute angle t1 + t2 held), so every edge of the polygon they make has a closed
    form. Returns the number of rows, or -1 for a limit of another kind (a coupled limit touching
    the yaw or another joint, or mixing t1 and t2 otherwise; a joint without finite limits).
    """
    lower, upper, C, clo, chi = f.lower, f.upper, f.C, f.clo, f.chi
    j1, j2 = f.J[1], f.J[2]
    if not (
        math.isfinite(lower[j1]) and math.isfinite(upper[j1]) and math.isfinite(lower[j2]) and math.isfinite(upper[j2])
    ):
        return -1
    rows[0, 0], rows[0, 1], rows[0, 2], rows[0, 3] = 1.0, 0.0, lower[j1], upper[j1]
    rows[1, 0], rows[1, 1], rows[1, 2], rows[1, 3] = 0.0, 1.0, lower[j2], upper[j2]
    k = 2
    for r in range(C.shape[0]):
        for i in range(C.shape[1]):
            if i != j1 and i != j2 and C[r, i] != 0.0:
                return -1
        c1, c2 = C[r, j1], C[r, j2]
        if c1 == 0.0 and c2 == 0.0:  # a row of zeros: it holds everywhere or nowhere
            if clo[r] > 0.0 or chi[r] < 0.0:
                return -1
            continue
        if c1 != 0.0 and c2 != 0.0 and c1 != c2:
            return -1
        scale = c1 if c1 != 0.0 else c2
        lo, hi = (clo[r] + MARGIN) / scale, (chi[r] - MARGIN) / scale
        if scale < 0.0:
            lo, hi = hi, lo
        rows[k, 0] = 1.0 if c1 != 0.0 else 0.0
        rows[k, 1] = 1.0 if c2 != 0.0 else 0.0
        rows[k, 2], rows[k, 3] = lo, hi
        k += 1
    return k


@jit
def _inside(rows: FloatArray, nr: int, t1: float, t2: float) -> bool:
    """(t1, t2) satisfies every row."""
    for m in range(nr):
        v = rows[m, 0] * t1 + rows[m, 1] * t2
        if v < rows[m, 2] or v > rows[m, 3]:
            return False
    return True


@jit
def _segment(rows: FloatArray, nr: int, p1: float, p2: float, d1: float, d2: float) -> tuple[float, float]:
    """The interval of s where (p1, p2) + s (d1, d2) satisfies every row (lo > hi: empty)."""
    lo, hi = -math.inf, math.inf
    for m in range(nr):
        ap = rows[m, 0] * p1 + rows[m, 1] * p2
        ad = rows[m, 0] * d1 + rows[m, 1] * d2
        if ad == 0.0:  # parallel to the row (its own line among them: ap is exactly a bound)
            if ap < rows[m, 2] or ap > rows[m, 3]:
                return 1.0, 0.0
        else:
            s1, s2 = (rows[m, 2] - ap) / ad, (rows[m, 3] - ap) / ad
            lo = max(lo, min(s1, s2))
            hi = min(hi, max(s1, s2))
    return lo, hi


@jit
def _add_edge(
    P: FloatArray, rows: FloatArray, nr: int, p1: float, p2: float, d1: float, d2: float, edges: FloatArray, k: int
) -> int:
    """The part of the line (t1, t2) = (p1, p2) + s (d1, d2) within every row as row ``k`` of ``edges``:
    [p1, p2, d1, d2, s_lo, s_hi, centre u, centre z, radius, angle at s = 0] of the circle the tool
    moves on (its angle on the circle is the last column + s). Returns k + 1, or k if the line
    misses the polygon."""
    slo, shi = _segment(rows, nr, p1, p2, d1, d2)
    if slo > shi:
        return k
    cu, cz, l1, l2 = P[0] + P[6], P[2] + P[7], P[3], P[4]  # the level tool offset moves the shoulder
    if d1 == 0.0:  # t1 held: the forearm turns about the elbow
        ccu, ccz, rho, th0 = cu + l1 * math.cos(p1), cz + l1 * math.sin(p1), l2, p1 + p2
    elif d2 == 0.0:  # t2 held: the rigid arm turns about the shoulder
        wu, wz = l1 + l2 * math.cos(p2), l2 * math.sin(p2)
        ccu, ccz, rho, th0 = cu, cz, math.hypot(wu, wz), p1 + math.atan2(wz, wu)
    else:  # t1 + t2 held: the upper arm turns, the forearm keeps its absolute angle
        ccu, ccz, rho, th0 = cu + l2 * math.cos(p1 + p2), cz + l2 * math.sin(p1 + p2), l1, p1
    e = edges[k]
    e[0], e[1], e[2], e[3], e[4], e[5] = p1, p2, d1, d2, slo, shi
    e[6], e[7], e[8], e[9] = ccu, ccz, rho, th0
    return k + 1


@jit
def _polygon_edges(P: FloatArray, rows: FloatArray, nr: int, edges: FloatArray) -> int:
    """Every edge of the polygon the rows make in (t1, t2), each row's two lines clipped by all
    rows; then the lines of a straight or folded elbow (t2 = k pi) across it, where the planar
    Jacobian is singular (the only other place the planar optimum can sit inside the polygon).
    Returns the count."""
    k = 0
    for r in range(nr):
        for side in range(2):
            b = rows[r, 2 + side]
            if rows[r, 1] == 0.0:
                k = _add_edge(P, rows, nr, b, 0.0, 0.0, 1.0, edges, k)
            elif rows[r, 0] == 0.0:
                k = _add_edge(P, rows, nr, 0.0, b, 1.0, 0.0, edges, k)
            else:
                k = _add_edge(P, rows, nr, 0.0, b, 1.0, -1.0, edges, k)
            if rows[r, 2] == rows[r, 3]:
                break  # one line
    for m in range(math.ceil(rows[1, 2] / math.pi), math.floor(rows[1, 3] / math.pi) + 1):
        k = _add_edge(P, rows, nr, 0.0, m * math.pi, 1.0, 0.0, edges, k)
    return k


@jit
def _best_yaw(u: float, py: float, ctx: FloatArray) -> float:
    """The yaw within limits that brings the tool's horizontal part (u, py in the yaw frame)
    nearest the target's: toward its bearing, else the limit nearer by angle (the cost,
    -cos of the angle between them, has no other minimum on an interval)."""
    h, bearing, ylo, yhi, yref = ctx[3], ctx[4], ctx[5], ctx[6], ctx[7]
    if h == 0.0 or (u == 0.0 and py == 0.0):
        return yref  # every yaw is as near: keep the seed's
    aim = bearing - math.atan2(py, u)
    ok, v = wrap_into(aim, ylo, yhi, yref, 0.0)
    if ok:
        return v
    return ylo if abs(wrap_angle(ylo - aim)) <= abs(wrap_angle(yhi - aim)) else yhi


@jit
def _offer(P: FloatArray, ctx: FloatArray, t1: float, t2: float, best: FloatArray) -> None:
    """Keep the pose (t1, t2) with its best yaw in ``best`` = [squared error, yaw, t1, t2] if it
    is nearer the target."""
    u = P[0] + P[6] + P[3] * math.cos(t1) + P[4] * math.cos(t1 + t2)
    zz = P[2] + P[7] + P[3] * math.sin(t1) + P[4] * math.sin(t1 + t2)
    yaw = _best_yaw(u, P[1], ctx)
    c, s = math.cos(yaw), math.sin(yaw)
    d2 = (c * u - s * P[1] - ctx[0]) ** 2 + (s * u + c * P[1] - ctx[1]) ** 2 + (zz - ctx[2]) ** 2
    if d2 < best[0] - 1e-30:
        best[0], best[1], best[2], best[3] = d2, yaw, t1, t2


@jit
def _offer_on_edge(P: FloatArray, rows: FloatArray, e: FloatArray, s: float, ctx: FloatArray, best: FloatArray) -> None:
    """:func:`_offer` the point ``s`` of edge ``e``, its box coordinates clamped (exact at the box's lines)."""
    t1 = min(max(e[0] + s * e[2], rows[0, 2]), rows[0, 3])
    t2 = min(max(e[1] + s * e[3], rows[1, 2]), rows[1, 3])
    _offer(P, ctx, t1, t2, best)


@jit
def _nearest_on_edge(e: FloatArray, a: float, zt: float) -> float:
    """The point s of edge ``e`` nearest (a, zt) in the arm's plane if it is the circle's
    nearest point (the only minimum of the distance inside an arc), else NaN (then an end is
    nearest: a vertex). Any point where (a, zt) is the circle's centre; NaN for a circle of
    radius 0 (the edge is one point)."""
    if e[8] <= 0.0:
        return math.nan
    du, dz = a - e[6], zt - e[7]
    if du == 0.0 and dz == 0.0:
        return e[4]
    s = math.atan2(dz, du) - e[9] - e[4]
    s = e[4] + (s - TWO_PI * math.floor(s / TWO_PI))
    return s if s <= e[5] else math.nan


@jit
def _reach(P: FloatArray, rows: FloatArray, nr: int, a: float, zt: float, ctx: FloatArray, best: FloatArray) -> None:
    """Offer every pose that puts the tool exactly on (a, zt) in the arm's plane (both elbows,
    every turn of each angle within its box) within every row."""
    sol = np.empty((2, 2))
    m = two_link(P[3], P[4], a - P[0] - P[6], zt - P[2] - P[7], sol)
    for i in range(m):
        v1, v2 = sol[i, 0], sol[i, 1]
        for k1 in range(math.ceil((rows[0, 2] - v1) / TWO_PI), math.floor((rows[0, 3] - v1) / TWO_PI) + 1):
            for k2 in range(math.ceil((rows[1, 2] - v2) / TWO_PI), math.floor((rows[1, 3] - v2) / TWO_PI) + 1):
                t1, t2 = v1 + k1 * TWO_PI, v2 + k2 * TWO_PI
                if _inside(rows, nr, t1, t2):
                    _offer(P, ctx, t1, t2, best)


@jit
def _planar(
    P: FloatArray, rows: FloatArray, nr: int, edges: FloatArray, ne: int, a: float, ctx: FloatArray, best: FloatArray
) -> None:
    """Offer the stationary points of the planar problem for the target (a, z) in the arm's plane
    (the yaw held): each edge's nearest point, and an exact reach. (The vertices are offered once.)"""
    for k in range(ne):
        s = _nearest_on_edge(edges[k], a, ctx[2])
        if s == s:
            _offer_on_edge(P, rows, edges[k], s, ctx, best)
    _reach(P, rows, nr, a, ctx[2], ctx, best)


@jit
def _slope(ccu: float, Z: float, rho: float, py: float, A: float, B: float) -> tuple[float, float]:
    """Half the first and second derivatives in alpha of f = (B - py)^2 + (d - rho)^2, with
    (A, B) = h (cos alpha, sin alpha) and d = |(A - ccu, Z)|: the squared error of an edge's
    nearest circle point when the target's bearing in the yaw frame is alpha."""
    dx = A - ccu
    d = math.sqrt(dx * dx + Z * Z)
    g = (B - py) * A
    gp = A * A - (B - py) * B
    if d > 0.0:  # (at d = 0, a maximum of f, its kink: the nearest point is anywhere)
        d1 = -dx * B / d
        d2 = (B * B - dx * A) / d - d1 * d1 / d
        g += (d - rho) * d1
        gp += d1 * d1 + (d - rho) * d2
    return g, gp


@jit
def _minimum_between(ccu: float, Z: float, rho: float, py: float, h: float, lo: float, hi: float) -> float:
    """The zero of :func:`_slope` in [lo, hi], where it goes from <= 0 to > 0 (a local minimum
    of f): Newton's method, kept in the bracket by bisection, to 1e-13 rad."""
    x = 0.5 * (lo + hi)
    for _ in range(80):
        g, gp = _slope(ccu, Z, rho, py, h * math.cos(x), h * math.sin(x))
        if g <= 0.0:
            lo = x
        else:
            hi = x
        xn = x - g / gp if gp > 0.0 else 0.5 * (lo + hi)
        if not lo < xn < hi:
            xn = 0.5 * (lo + hi)
        if abs(xn - x) < 1e-13 or hi - lo < 1e-13:
            return xn
        x = xn
    return x


@jit
def _edge_minima(
    P: FloatArray,
    rows: FloatArray,
    e: FloatArray,
    ctx: FloatArray,
    alphas: FloatArray,
    A: FloatArray,
    B: FloatArray,
    best: FloatArray,
) -> None:
    """Offer the edge's stationary points with the yaw free, one per local minimum over the
    target's bearing alpha (yaw = bearing - alpha) of the squared error of the edge's nearest
    circle point: the slope is sampled on ``alphas`` (the yaw's range), each sign change from
    - to + is refined. A smooth function of alpha, varying on the scale of a radian (the same
    stationary points taken over the edge's own angle have features as narrow as py / radius,
    where the arm passes the yaw axis). Minima whose nearest point falls off the arc are the
    vertices'."""
    py, z, h = P[1], ctx[2], ctx[3]
    ccu, Z, rho = e[6], ctx[2] - e[7], e[8]
    if rho <= 0.0:
        return
    g0, _ = _slope(ccu, Z, rho, py, A[0], B[0])
    for i in range(1, alphas.shape[0]):
        g1, _ = _slope(ccu, Z, rho, py, A[i], B[i])
        if g0 <= 0.0 < g1:
            alpha = _minimum_between(ccu, Z, rho, py, h, alphas[i - 1], alphas[i])
            s = _nearest_on_edge(e, h * math.cos(alpha), z)
            if s == s:
                _offer_on_edge(P, rows, e, s, ctx, best)
        g0 = g1


@jit
def closest_level(f: Family, target: FloatArray, ref: FloatArray, q_out: FloatArray) -> float:
    """The closest configuration within every limit for an arm without a wrist, with a lateral
    pivot offset py and coupled limits on the shoulder and elbow (desk4), by enumerating every
    stationary point: (error [m]), or -1 where this does not apply.

    In the yaw frame the tool is (u, py, zz), (u, zz) a planar two-link of the shoulder angle
    t1 and elbow t2; the target is h (cos alpha, sin alpha) horizontally at height z, alpha =
    bearing - yaw. So the squared error is (h sin alpha - py)^2 plus the planar one to (h cos
    alpha, z). The limits on (t1, t2) make a convex polygon whose edges move the tool on circles
    (:func:`_planar_rows`). The optimum is at a vertex (with its best yaw, closed form), or on an
    edge at its circle's point nearest the planar target, or inside at an exact planar reach or
    a straight or folded elbow (the Jacobian singular: more circles). The yaw is at a limit
    (one alpha: each edge's nearest point is closed form) or free, where alpha is stationary:
    for an exact reach, h cos alpha = 0 (or the lateral error 0: a reachable target); on an edge
    the error is a smooth function of alpha whose minima are found by sampling and Newton
    (:func:`_edge_minima`). Every candidate is evaluated with its best yaw; the nearest is the
    optimum. Returns -1 for limits of another kind (:func:`_planar_rows`) or an empty polygon.
    """
    P, J, lower, upper = f.P, f.J, f.lower, f.upper
    rows = np.empty((2 + f.C.shape[0], 4))
    nr = _planar_rows(f, rows)
    if nr < 0:
        return -1.0
    n_straight = max(0, math.floor(rows[1, 3] / math.pi) - math.ceil(rows[1, 2] / math.pi) + 1)
    edges = np.empty((2 * nr + n_straight, 10))
    ne = _polygon_edges(P, rows, nr, edges)
    if ne == 0:
        return -1.0
    x, y, z = target[0], target[1], target[2]
    h = math.sqrt(x * x + y * y)
    yj = J[0]
    ylo, yhi = lower[yj], upper[yj]
    bearing = math.atan2(y, x) if h > 0.0 else 0.0
    ctx = np.array([x, y, z, h, bearing, ylo, yhi, min(max(ref[yj], ylo), yhi)])
    best = np.array([math.inf, 0.0, 0.0, 0.0])
    for k in range(ne):  # the vertices (and the ends of the straight or folded elbow's lines)
        _offer_on_edge(P, rows, edges[k], edges[k, 4], ctx, best)
        _offer_on_edge(P, rows, edges[k], edges[k, 5], ctx, best)
    if h == 0.0:  # on the yaw axis every yaw is as near: the planar problem for (0, z)
        _planar(P, rows, nr, edges, ne, 0.0, ctx, best)
    else:
        limited = yhi - ylo < TWO_PI
        a0, a1 = (bearing - yhi, bearing - ylo) if limited else (bearing - math.pi, bearing + math.pi)
        n = max(8, math.ceil((a1 - a0) / ALPHA_STEP)) + 1
        alphas = np.linspace(a0, a1, n)
        A = h * np.cos(alphas)
        B = h * np.sin(alphas)
        if limited:  # the yaw at either limit
            _planar(P, rows, nr, edges, ne, A[0], ctx, best)
            _planar(P, rows, nr, edges, ne, A[n - 1], ctx, best)
        _reach(P, rows, nr, 0.0, z, ctx, best)  # the yaw free, an exact planar reach: h cos alpha = 0
        if h >= abs(P[1]):  # ... or no lateral error (a target within reach)
            w = math.sqrt(h * h - P[1] * P[1])
            _reach(P, rows, nr, w, z, ctx, best)
            _reach(P, rows, nr, -w, z, ctx, best)
        for k in range(ne):
            _edge_minima(P, rows, edges[k], ctx, alphas, A, B, best)
    if not best[0] < math.inf:
        return -1.0
    for i in range(ref.shape[0]):
        q_out[i] = min(max(ref[i], lower[i]), upper[i])
    q_out[yj], q_out[J[1]], q_out[J[2]] = best[1], best[2], best[3]
    if not limits_ok(q_out, f, 0.0):
        return -1.0
    p = np.empty(3)
    family_fk(f, q_out, p)
    return math.sqrt((p[0] - x) ** 2 + (p[1] - y) ** 2 + (p[2] - z) ** 2)


@entry("f8(Family, f8[:], f8[:], f8[:], b1)")
def closest_box(packed_family: Packed, target: FloatArray, ref: FloatArray, q_out: FloatArray, prune: bool) -> float:
    """:func:`enumerated_closest`, for Python: the :class:`Family` packed (:mod:`solvers.packed`)."""
    return enumerated_closest(family_at(packed_family, 0), target, ref, q_out, prune)


@jit
def enumerated_closest(f: Family, target: FloatArray, ref: FloatArray, q_out: FloatArray, prune: bool) -> float:
    """The closest configuration within the box limits, any tool pitch, by enumerating every
    stationary point: (error [m]), or -1 where this does not apply. ``prune`` False visits every
    candidate (the tests hold the pruned search to it).

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
    can. The best candidate within limits is the optimum. An arm without a wrist that has a
    lateral pivot offset or coupled limits goes to :func:`closest_level`. Returns -1 (the
    iteration answers) for a wrist arm with a lateral pivot offset, a degenerate chain, a
    coupled limit the best one breaks, or a projection the closed form cannot decide. The
    family's angles and frame throughout.
    """
    P, J, lower, upper = f.P, f.J, f.lower, f.upper
    px, py, pz, l1, l2, l3, ox, oz = P[0], P[1], P[2], P[3], P[4], P[5], P[6], P[7]
    if J[3] < 0 and (py != 0.0 or f.C.shape[0] > 0):
        return closest_level(f, target, ref, q_out)
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
    options = 4**nj
    reach = l1 + l2 + (l3 if nj == 3 else 0.0)
    # A lower bound on the error at each yaw: the target's distance from the arm's plane, and
    # its distance in the plane from the shoulder pivot less the whole reach. A yaw (and, below,
    # a face) that cannot beat the best candidate so far is skipped; a candidate that meets its
    # yaw's bound ends that yaw's search (the stretched arm aimed at a target beyond reach).
    # SLACK keeps every skip on the safe side of rounding; a stop allows 1e-12 relative.
    bounds = np.empty(2)
    tus = np.zeros(2)  # the target projected on the arm's plane at each yaw
    laterals = np.zeros(2)  # and its distance from that plane
    for yi in range(n_yaws):
        if h > 0.0:
            tus[yi] = h * math.cos(bearing - yaws[yi])
            laterals[yi] = h * abs(math.sin(bearing - yaws[yi]))
        beyond = max(math.sqrt((tus[yi] - cu) ** 2 + (z - cz) ** 2) - reach, 0.0)
        bounds[yi] = laterals[yi] * laterals[yi] + beyond * beyond
    if prune and n_yaws == 2 and bounds[1] < bounds[0]:  # the more promising yaw first
        yaws[::-1] = yaws.copy()
        bounds[::-1] = bounds.copy()
        tus[::-1] = tus.copy()
        laterals[::-1] = laterals.copy()
    for yi in range(n_yaws):
        if prune and bounds[yi] > best * (1.0 + SLACK) + SLACK:
            continue  # nothing at this yaw is nearer than the best so far
        psi, tu, lateral = yaws[yi], tus[yi], laterals[yi]
        if lateral > 1e-12 and (tu - cu) ** 2 + (z - cz) ** 2 <= reach * reach:
            # the yaw is held at a limit and the target's projection on the arm's plane may be
            # reached exactly (a case the collinearity does not cover): ask the closed form
            if not f.exact_pitch_search:
                return -1.0  # (it is complete only where no coupled limit touches a pitch joint)
            code, m, _ = solve_one(f, ref, tu * math.cos(psi), tu * math.sin(psi), z, FREE_PREFS, qs, ids, errs, work)
            if code != NONE and lateral * lateral < best - 1e-30:
                best = lateral * lateral
                q_out[:] = qs[0]
            if code != NONE:
                continue  # nothing at this yaw is nearer than the projection itself
        for code in range(options):
            if prune and best <= bounds[yi] * (1.0 + 1e-12) + 1e-24:
                break  # the best so far meets this yaw's bound: no face here does better
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
                if prune and first > 0:  # the joints before the first free one are fixed: the rest reach so far
                    rest = 0.0
                    for k in range(first, nj):
                        rest += links[k]
                    short = max(math.sqrt(du * du + dz * dz) - rest, 0.0)
                    if short * short + lateral * lateral > best * (1.0 + SLACK) + SLACK:
                        continue
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
    if best >= 1e300 or not limits_ok(q_out, f, 0.0):
        return -1.0
    family_fk(f, q_out, p)
    return math.sqrt((p[0] - x) ** 2 + (p[1] - y) ** 2 + (p[2] - z) ** 2)


@jit
def _aim_yaw(f: Family, target: FloatArray, theta: FloatArray) -> None:
    """The yaw within limits that brings the tool's horizontal part nearest the target's, for
    the pose ``theta`` (in place): toward its bearing, the tool's lateral offset allowed for."""
    p = np.empty(3)
    yj = f.J[0]
    keep = theta[yj]
    theta[yj] = 0.0
    family_fk(f, theta, p)
    theta[yj] = keep
    h = math.hypot(target[0], target[1])
    if h == 0.0 or (p[0] == 0.0 and p[1] == 0.0):
        return
    aim = math.atan2(target[1], target[0]) - math.atan2(p[1], p[0])
    ok, v = wrap_into(aim, f.lower[yj], f.upper[yj], keep, 0.0)
    if not ok:
        v = f.lower[yj] if abs(wrap_angle(f.lower[yj] - aim)) <= abs(wrap_angle(f.upper[yj] - aim)) else f.upper[yj]
    theta[yj] = v


@entry("Tuple((f8, f8, i8))(Arm, f8[:], f8, f8, f8[:], Atlas, i8, f8[:])")
def closest_family(
    packed_arm: Packed,
    target: FloatArray,
    pitch: float,
    w2: float,
    ref: FloatArray,
    packed_atlas: Packed,
    n_atlas: int,
    q_out: FloatArray,
) -> tuple[float, float, int]:
    """The closest configuration within limits to ``target`` (``base``), with tool pitch
    ``pitch`` weighed by ``w2`` (0: any pitch), into ``q_out`` (the URDF's angles): the
    enumerated optimum where it applies (:func:`enumerated_closest`, free pitch only); else the
    best of :func:`~solvers.lm.lm_family` from ``ref`` (if within limits) and the ``n_atlas``
    atlas configurations (the URDF's angles; tool points in ``base``) whose tool points are
    nearest the target, their joints outside the family kept at ``ref``'s: (error, pitch error,
    iterations). The arm and the atlas packed (:mod:`solvers.packed`)."""
    arm, atlas = arm_of(packed_arm), atlas_of(packed_atlas)
    f, zero, offset = view(arm, ref)
    n = ref.shape[0]
    ref_f = np.empty(n)
    to_family(arm, zero, ref, ref_f)
    goal = np.empty(3)
    goal[0], goal[1], goal[2] = target[0] - arm.base[0], target[1] - arm.base[1], target[2]
    theta = np.empty(n)
    if w2 == 0.0:
        if f.J[3] >= 0 and f.P[1] != 0.0:
            # a wrist arm whose tool is off the yaw's plane (the SO-101's, by 0.4 mm): the
            # enumeration without the offset is within O(offset^2) of the optimum; the
            # iteration takes it the rest of the way
            P0 = f.P.copy()
            P0[1] = 0.0
            flat = Family(P0, f.J, f.lower, f.upper, f.weights, f.C, f.clo, f.chi, f.exact_pitch_search, f.level)
            if enumerated_closest(flat, goal, ref_f, theta, True) >= 0.0:
                _aim_yaw(f, goal, theta)
                err, _, it = lm_family(f, goal, 0.0, 0.0, theta, 5, 0.4, 1e-12)
                from_family(arm, zero, theta, q_out)
                return err, 0.0, it
        else:
            err = enumerated_closest(f, goal, ref_f, theta, True)
            if err >= 0.0:
                from_family(arm, zero, theta, q_out)
                return err, 0.0, 0
    goal_pitch = pitch - offset
    order = np.full(n_atlas, -1, dtype=np.int64)  # the n_atlas nearest atlas points
    nearest(atlas, target, order)
    # the starts' costs; a few steps from the promising ones; the best one to convergence
    family = np.zeros(n, dtype=np.bool_)
    for k in range(4):
        if f.J[k] >= 0:
            family[f.J[k]] = True
    starts = np.empty((n_atlas + 1, n))
    costs = np.full(n_atlas + 1, np.inf)
    p = np.empty(3)
    for s in range(n_atlas + 1):
        if s == 0:
            for i in range(n):
                starts[s, i] = min(max(ref_f[i], f.lower[i]), f.upper[i])
            if not limits_ok(starts[s], f, 0.0):
                continue
        elif order[s - 1] >= 0:
            to_family(arm, zero, atlas.q[order[s - 1]], starts[s])
            for i in range(n):
                if not family[i]:
                    starts[s, i] = ref_f[i]
            if not limits_ok(starts[s], f, 0.0):
                continue
        else:
            continue
        costs[s], _ = family_cost(f, starts[s], goal, goal_pitch, w2, p)
    floor = np.min(costs)
    best = 1e300
    iters = 0
    q = np.empty(n)
    for s in range(n_atlas + 1):
        if not costs[s] <= 4.0 * floor + 1e-6:  # far worse than the best start: skip it
            continue
        q[:] = starts[s]
        err, perr, it = lm_family(f, goal, goal_pitch, w2, q, 4, 0.4, 1e-12)
        iters += it
        score = err * err + w2 * perr * perr
        if score < best - 1e-18:
            best = score
            theta[:] = q
    err, perr, it = lm_family(f, goal, goal_pitch, w2, theta, 200, 0.4, 1e-12)
    from_family(arm, zero, theta, q_out)
    return err, perr, iters + it
