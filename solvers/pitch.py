"""Reachable tool pitches of a wrist arm: the reachable pitch nearest a preferred one.

For a fixed target, the set of pitches ``phi`` a wrist arm reaches it with (within joint
limits) is a union of intervals. Its boundary points are pitches where a joint sits on a
limit, or where the elbow is straight or folded (``elbow = 0`` or ``pi``: the reach folds).
Each case fixes one joint and leaves a planar two-link problem, solved in closed form:

* wrist fixed at ``W``: forearm and hand form one rigid link ``L2 + L3 e^{iW}``;
* elbow fixed at ``E``: upper arm and forearm form one rigid link ``L1 + L2 e^{iE}``;
* shoulder fixed at ``S``: the elbow point is fixed, forearm and hand solve the rest.

The reachable pitch nearest a preferred one (not itself reachable) is one of these
candidates (:func:`boundary_pitch`): exact, and no search. When coupled limits involve the
pitch joints, their boundaries are not among the candidates, and :func:`grid_pitch` scans
a 1-degree grid and bisects instead (~1e-7 rad).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from armd.robots.types import FloatArray

from .arrays import Family
from .family import configs_at
from .geometric import TWO_PI, two_link, wrap_angle, wrap_into
from .jit import jit
from .limits import limits_ok

IntArray = NDArray[np.int64]

BOUNDARY_TOL = 1e-9  # [rad] slack for the joint that sits on its limit (then clamped onto it)


@jit
def _pref_key(phi: float, prefs: FloatArray) -> float:
    """Distance [rad] to the nearest preferred pitch, plus a tiny rank term: earlier wins ties."""
    best = 1e300
    for k in range(prefs.shape[0]):
        d = abs(wrap_angle(phi - prefs[k])) + 1e-12 * k
        best = min(best, d)
    return best


@jit
def boundary_pitch(f: Family, ref: FloatArray, x: float, y: float, z: float, prefs: FloatArray) -> tuple[bool, float]:
    """The reachable pitch [rad] nearest the preferred ones, among the boundary pitches."""
    P, lower, upper = f.P, f.lower, f.upper
    ys, sh, el, wr = f.J[0], f.J[1], f.J[2], f.J[3]
    px, py, pz, l1, l2, l3, ox, oz = P[0], P[1], P[2], P[3], P[4], P[5], P[6], P[7]
    h2 = x * x + y * y - py * py
    if h2 < -1e-12:
        return False, 0.0
    h = math.sqrt(max(h2, 0.0))
    bearing = math.atan2(y, x)
    b = z - pz - oz
    tl = np.empty((2, 2))
    sols = np.empty((24, 3))
    q = ref.copy()
    fixed_el = np.empty(5)
    n_el = 0
    for e in (lower[el], upper[el], 0.0, math.pi, -math.pi):
        if n_el < 2 or lower[el] <= e <= upper[el]:
            fixed_el[n_el] = e
            n_el += 1
    found = False
    best_phi = 0.0
    best_key = 1e300
    for side in range(2):
        u = h if side == 0 else -h
        if side == 1 and h == 0.0:
            break
        ok, yaw = wrap_into(bearing - math.atan2(py, u), lower[ys], upper[ys], ref[ys], 1e-12)
        if not ok:
            continue
        a = u - px - ox
        ns = 0
        for w in (lower[wr], upper[wr]):
            vx, vy = l2 + l3 * math.cos(w), l3 * math.sin(w)
            delta = math.atan2(vy, vx)
            for r in range(two_link(l1, math.hypot(vx, vy), a, b, tl)):
                sols[ns, 0], sols[ns, 1], sols[ns, 2] = tl[r, 0], tl[r, 1] - delta, w
                ns += 1
        for i in range(n_el):
            e = fixed_el[i]
            vx, vy = l1 + l2 * math.cos(e), l2 * math.sin(e)
            eps = math.atan2(vy, vx)
            for r in range(two_link(math.hypot(vx, vy), l3, a, b, tl)):
                q1 = tl[r, 0] - eps
                sols[ns, 0], sols[ns, 1], sols[ns, 2] = q1, e, tl[r, 0] + tl[r, 1] - q1 - e
                ns += 1
        for s in (lower[sh], upper[sh]):
            for r in range(two_link(l2, l3, a - l1 * math.cos(s), b - l1 * math.sin(s), tl)):
                sols[ns, 0], sols[ns, 1], sols[ns, 2] = s, tl[r, 0] - s, tl[r, 1]
                ns += 1
        for i in range(ns):
            ok1, w1 = wrap_into(sols[i, 0], lower[sh], upper[sh], ref[sh], BOUNDARY_TOL)
            ok2, w2 = wrap_into(sols[i, 1], lower[el], upper[el], ref[el], BOUNDARY_TOL)
            ok3, w3 = wrap_into(sols[i, 2], lower[wr], upper[wr], ref[wr], BOUNDARY_TOL)
            if not (ok1 and ok2 and ok3):
                continue
            q[ys], q[sh], q[el], q[wr] = yaw, w1, w2, w3
            if not limits_ok(q, f, 0.0):
                continue
            phi = wrap_angle(w1 + w2 + w3)
            key = _pref_key(phi, prefs)
            if key < best_key:
                best_key, best_phi, found = key, phi, True
    return found, best_phi


@jit
def grid_pitch(f: Family, ref: FloatArray, x: float, y: float, z: float, prefs: FloatArray) -> tuple[bool, float]:
    """The reachable pitch [rad] nearest the preferred ones: 1-degree grid, then bisection."""
    n = ref.shape[0]
    qs = np.empty((4, n))
    ids = np.empty(4, dtype=np.int64)
    work = np.empty((4, 5))
    found = False
    good = 0.0
    best_key = 1e300
    for i in range(361):
        phi = -math.pi + i * (TWO_PI / 360.0)
        if configs_at(f, ref, x, y, z, phi, 0.0, qs, ids, work) > 0:
            key = _pref_key(phi, prefs)
            if key < best_key:
                best_key, good, found = key, phi, True
    if not found:
        return False, 0.0
    target = prefs[0]
    for k in range(prefs.shape[0]):
        if abs(abs(wrap_angle(good - prefs[k])) + 1e-12 * k - best_key) < 1e-9:
            target = prefs[k]
            break
    delta = wrap_angle(target - good)
    lo, hi = 0.0, 1.0
    for _ in range(30):
        mid = 0.5 * (lo + hi)
        if configs_at(f, ref, x, y, z, good + mid * delta, 0.0, qs, ids, work) > 0:
            lo = mid
        else:
            hi = mid
    return True, wrap_angle(good + lo * delta)
