"""Reachable tool pitches of a wrist arm: the exact boundary pitches of the reachable set.

For a fixed target, the set of pitches ``phi`` a wrist arm can reach it with (within joint
limits) is a union of intervals. Its boundary points are pitches where a joint sits on a
limit, or where the elbow is straight or folded (``elbow = 0`` or ``pi``: the reach folds).
Each such case fixes one joint and leaves a planar two-link problem, solved in closed form:

* wrist fixed at ``W``: forearm and hand form one rigid link ``L2 + L3 e^{iW}``;
* elbow fixed at ``E``: upper arm and forearm form one rigid link ``L1 + L2 e^{iE}``;
* shoulder fixed at ``S``: the elbow point is fixed, forearm and hand solve the rest.

The reachable pitch nearest a preferred one (not itself reachable) is one of these
candidates, so checking them in order of distance gives it exactly, with no search.
"""

from __future__ import annotations

import math

from .geometric import TWO_PI, FamilyParams, wrap_into

_EPS = 1e-12


def two_link(p: float, q: float, tx: float, ty: float) -> list[tuple[float, float]]:
    """Planar two-link (lengths p, q) reaching (tx, ty): [(absolute angle 1, relative angle 2)]."""
    if p < _EPS or q < _EPS:
        return []
    c = (tx * tx + ty * ty - p * p - q * q) / (2.0 * p * q)
    if c > 1.0:
        if c > 1.0 + _EPS:
            return []
        c = 1.0
    elif c < -1.0:
        if c < -1.0 - _EPS:
            return []
        c = -1.0
    s = math.sqrt(max(0.0, 1.0 - c * c))
    base = math.atan2(ty, tx)
    out = []
    for s2 in (s, -s) if s > 0.0 else (0.0,):
        t2 = math.atan2(s2, c)
        out.append((base - math.atan2(q * s2, p + q * c), t2))
    return out


def boundary_configs(
    fp: FamilyParams,
    x: float,
    y: float,
    z: float,
    lower: list[float],
    upper: list[float],
    ref: list[float],
    tol: float = 1e-9,
) -> list[tuple[float, str, list[float]]]:
    """Every candidate boundary configuration inside the box limits: (pitch, branch, q).

    ``q`` is a full joint vector (joints outside the family copied from ``ref``), each joint
    wrapped into its limits (``tol`` [rad] of slack for the joint that sits on its limit).
    """
    assert fp.wrist is not None
    ys, sh, el, wr = fp.yaw, fp.shoulder, fp.elbow, fp.wrist
    l1, l2, l3 = fp.l1, fp.l2, fp.l3
    out: list[tuple[float, str, list[float]]] = []
    h2 = x * x + y * y - fp.py * fp.py
    if h2 < -_EPS:
        return out
    h = math.sqrt(max(h2, 0.0))
    bearing = math.atan2(y, x)
    b = z - fp.pz - fp.oz
    el_fixed = [lower[el], upper[el]] + [e for e in (0.0, math.pi, -math.pi) if lower[el] <= e <= upper[el]]
    for side, u in (("front", h), ("flipped", -h)):
        if side == "flipped" and h == 0.0:
            break
        yaw = wrap_into(bearing - math.atan2(fp.py, u), lower[ys], upper[ys], ref[ys])
        if yaw is None:
            continue
        a = u - fp.px - fp.ox
        sols: list[tuple[float, float, float]] = []  # (shoulder, elbow, wrist)
        for w in (lower[wr], upper[wr]):
            vx, vy = l2 + l3 * math.cos(w), l3 * math.sin(w)
            delta = math.atan2(vy, vx)
            for t1, t2 in two_link(l1, math.hypot(vx, vy), a, b):
                sols.append((t1, t2 - delta, w))
        for e in el_fixed:
            vx, vy = l1 + l2 * math.cos(e), l2 * math.sin(e)
            eps = math.atan2(vy, vx)
            for t1, t2 in two_link(math.hypot(vx, vy), l3, a, b):
                q1 = t1 - eps
                sols.append((q1, e, t1 + t2 - q1 - e))
        for s in (lower[sh], upper[sh]):
            for t1, t2 in two_link(l2, l3, a - l1 * math.cos(s), b - l1 * math.sin(s)):
                sols.append((s, t1 - s, t2))
        for q1, q2, q3 in sols:
            w1 = wrap_into(q1, lower[sh], upper[sh], ref[sh], tol)
            w2 = wrap_into(q2, lower[el], upper[el], ref[el], tol)
            w3 = wrap_into(q3, lower[wr], upper[wr], ref[wr], tol)
            if w1 is None or w2 is None or w3 is None:
                continue
            q = list(ref)
            q[ys], q[sh], q[el], q[wr] = yaw, w1, w2, w3
            up = (w2 < 0.0) == (a - l3 * math.cos(w1 + w2 + w3) >= 0.0)
            name = f"{side}/elbow_{'up' if up else 'down'}"
            out.append((math.remainder(w1 + w2 + w3, TWO_PI), name, q))
    return out
