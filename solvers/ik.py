"""``solve_ik``: closed-form geometric seed -> QP refinement with hard limits -> FK check.

The pipeline, for an arm of the closed-form family (all four catalogue arms):

1. The target point and the tool pitch the approach asks for (:mod:`solvers.target`).
2. Every branch of the closed form (:mod:`solvers.geometric`), joint values wrapped into
   the limits; branches outside any limit (box or coupled) are dropped.
3. Each remaining branch is checked by FK on the exact Pinocchio model. Where the
   ``[geometry]`` parameters are an idealisation of the URDF (as seed 004's planar model is),
   the QP refinement (:mod:`solvers.qp`) takes the branch the rest of the way, inside the limits.
4. Among the valid branches, the nearest to the seed (or to the neutral pose when there is
   no seed) wins, by joint distance weighted by 1 / vmax (about the time to get there); ties
   go to the first in the fixed order front/up, front/down, flipped/up, flipped/down, so
   the same input always gives the same output.

Pitch: with ``approach`` ``"free"`` (or None) on an arm with a wrist, armd prefers a level
tool (``parallel``), then a tool pointing down (``perpendicular``), then the reachable
pitch nearest to either of them (seed 001's reachable areas A and B). With a pitch asked
for and not reachable at that target, the answer uses the nearest reachable pitch and says
``approximate``.

Unreachable targets get the closest configuration within limits (QP from the arm
stretched toward the target, and from the seed), ``status = "unreachable"``, the reached
point and the remaining error. An arm outside the family gets the QP from several starts.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from robots import BadRequest, Robot

from .geometric import TWO_PI, FamilyParams, branches, branches_batch, wrap_into, wrap_into_batch
from .pitch import boundary_configs
from .qp import QPRefiner
from .result import APPROXIMATE, OK, UNREACHABLE, Branch, IKResult
from .target import PARALLEL, PERPENDICULAR, approach_pitch, target_point

FloatArray = NDArray[np.float64]

DEFAULT_TOLERANCE = 1e-9  # [m]: an answer is "ok" when its tool point is this close to the target
PITCH_TOLERANCE = 1e-9  # [rad]
_PITCH_GRID = np.linspace(-math.pi, math.pi, 361)  # 1-degree grid for the reachable-pitch search
_BISECTIONS = 24
_ATLAS_STARTS = 3


@dataclass
class _Arm:
    """Per-robot solver state, built once: family parameters, limits as floats, the QP."""

    robot: Robot
    fp: FamilyParams | None
    qp: QPRefiner
    lower: list[float]
    upper: list[float]
    weights: list[float]
    coupled: list[tuple[list[tuple[int, float]], float, float]]
    exact: bool  # [geometry] reproduces the URDF's FK to 1e-12 m: branch errors by formula
    atlas_q: FloatArray  # in-limit configurations spread over the workspace (QP starts) [rad]
    atlas_p: FloatArray  # their tool points [m]

    def inside(self, q: list[float], tol: float = 0.0) -> bool:
        """Every box limit holds to ``tol`` and every coupled limit exactly (plain floats: the hot path)."""
        lower, upper = self.lower, self.upper
        for i, v in enumerate(q):
            if v < lower[i] - tol or v > upper[i] + tol:
                return False
        for terms, lo, hi in self.coupled:  # exact: a box slack is clamped away, a coupled one would not be
            v = sum(c * q[i] for i, c in terms)
            if v < lo or v > hi:
                return False
        return True

    def distance(self, q: list[float], ref: list[float]) -> float:
        """Joint distance weighted by 1 / vmax [s]: about the time to move from ``ref`` to ``q``."""
        return sum(abs(a - b) * w for a, b, w in zip(q, ref, self.weights, strict=True))


_cache: dict[int, _Arm] = {}
_cache_lock = threading.Lock()


def _arm(robot: Robot) -> _Arm:
    arm = _cache.get(id(robot))
    if arm is None or arm.robot is not robot:
        with _cache_lock:
            fp = FamilyParams.of(robot) if robot.geometry is not None else None
            coupled = [([(i, float(c)) for i, c in enumerate(cl.coefficients) if c], cl.lower, cl.upper)
                       for cl in robot.limits.coupled]
            exact = False
            if robot.geometry is not None:
                rng = np.random.default_rng(0)
                qs = rng.uniform(robot.limits.lower, robot.limits.upper, size=(64, robot.nq))
                exact = max(float(np.max(np.abs(robot.geometry.fk(q) - robot.fk(q)))) for q in qs) < 1e-12
            atlas_q = _atlas(robot)
            atlas_p = np.array([robot.fk(q) for q in atlas_q])
            arm = _Arm(robot, fp, QPRefiner(robot), robot.limits.lower.tolist(), robot.limits.upper.tolist(),
                       (1.0 / robot.limits.velocity).tolist(), coupled, exact, atlas_q, atlas_p)
            _cache[id(robot)] = arm
    return arm


def _atlas(robot: Robot, n: int = 4096) -> FloatArray:
    """Fixed quasi-random configurations within every limit: starts for the closest-point QP."""
    rng = np.random.default_rng(20261121)
    qs = rng.uniform(robot.limits.lower, robot.limits.upper, size=(4 * n, robot.nq))
    return qs[robot.limits.contains_batch(qs, tol=0.0)][:n]


def solve_ik(
    robot: Robot,
    target: object,
    *,
    approach: object = None,
    seed: Sequence[float] | FloatArray | None = None,
    tolerance: float = DEFAULT_TOLERANCE,
    quantise: bool = False,
) -> IKResult:
    """Joint vector that puts ``robot``'s tool point on ``target``, within every limit.

    Args:
        robot: an arm from :func:`robots.load`.
        target: [x, y, z] [m] in ``base``, or a :class:`~solvers.target.SensorReading`.
        approach: ``"parallel"``, ``"perpendicular"``, a pitch [rad] in [-pi, pi], or
            ``"free"``/None.
        seed: the current joint vector [rad]; the answer is the valid branch nearest to it.
        tolerance: position error [m] under which the answer is ``ok``.
        quantise: answer in whole actuator steps (stepper micro-steps), reporting the
            error quantisation leaves (status ``approximate`` when it exceeds ``tolerance``).

    Raises:
        BadRequest: malformed target, approach, seed or tolerance (nothing is solved).
    """
    arm = _arm(robot)
    ref = robot.neutral if seed is None else robot.joint_vector(seed, "seed")
    point = target_point(robot, target, ref)
    pitch = approach_pitch(robot, approach)
    if not (isinstance(tolerance, (int, float)) and math.isfinite(tolerance) and tolerance > 0):
        raise BadRequest(f"tolerance must be a positive number [m], got {tolerance!r}", field="tolerance")
    if arm.fp is None:
        result = _solve_numerical(arm, point, ref, tolerance)
    else:
        result = _solve_family(arm, point, pitch, ref, tolerance)
    if quantise:
        result = _quantise(arm, result, tolerance)
    return result


# -- the closed-form family ------------------------------------------------------------


def _dist(a: FloatArray, b: FloatArray) -> float:
    """Euclidean distance [m] of two 3-vectors (math.dist: no NumPy call overhead)."""
    return math.dist(a.tolist(), b.tolist())


def _configs(arm: _Arm, x: float, y: float, z: float, phi: float | None, ref: list[float],
             tol: float = 0.0) -> list[tuple[str, list[float]]]:
    """Closed-form branches wrapped into the box and within every limit, as plain lists."""
    fp = arm.fp
    assert fp is not None
    lower, upper = arm.lower, arm.upper
    idx = (fp.yaw, fp.shoulder, fp.elbow, fp.wrist)
    out = []
    for name, *values in branches(fp, x, y, z, phi):
        q = list(ref)
        for j, v in zip(idx, values, strict=True):
            if j is None:
                continue
            w = wrap_into(v, lower[j], upper[j], ref[j], tol if tol else 1e-12)
            if w is None:
                break
            q[j] = w
        else:
            if arm.inside(q, tol):
                out.append((name, q))
    return out


def _verified(arm: _Arm, configs: list[tuple[str, list[float]]], point: FloatArray, phi: float | None,
              ref: list[float], tolerance: float) -> tuple[list[Branch], int]:
    """The configurations, nearest ``ref`` first, checked by FK on the exact model.

    The chosen (first) one is always checked by Pinocchio FK; with an exact ``[geometry]`` the
    others are checked by the family's formula, otherwise by Pinocchio too, and any that
    misses is refined by the QP (inside the limits) or dropped.
    """
    robot = arm.robot
    ranked = sorted(configs, key=lambda c: arm.distance(c[1], ref))
    out: list[Branch] = []
    iterations = 0
    for k, (name, ql) in enumerate(ranked):
        q = np.array(ql)
        if k > 0 and arm.exact:
            assert robot.geometry is not None
            err = _dist(robot.geometry.fk(q), point)
        else:
            err = _dist(robot.fk(q), point)
        if err > tolerance:
            refined = arm.qp.solve(point, q, pitch=phi)
            iterations += refined.iterations
            if refined.position_error > tolerance or refined.pitch_error > PITCH_TOLERANCE:
                continue
            q, err = refined.q, refined.position_error
        out.append(Branch(name, q, err))
    return out, iterations


def _result(arm: _Arm, status: str, chosen: Branch, others: list[Branch], point: FloatArray,
            asked_pitch: float | None, iterations: int, reason: str | None) -> IKResult:
    robot = arm.robot
    pose = robot.pose(chosen.q)
    pitch_error = None if asked_pitch is None else math.remainder(pose.pitch - asked_pitch, TWO_PI)
    err = _dist(pose.position, point)
    return IKResult(
        status=status, q=chosen.q, position_error=err, reached=pose.position, target=point,
        pitch=pose.pitch, pitch_error=pitch_error, branch=chosen.name, branches=tuple(others),
        iterations=iterations, reason=reason,
    )


def _solve_family(arm: _Arm, point: FloatArray, pitch: float | None, ref_a: FloatArray,
                  tolerance: float) -> IKResult:
    fp = arm.fp
    assert fp is not None
    ref = ref_a.tolist()
    x, y, z = point.tolist()
    iterations = 0
    if fp.wrist is None:
        found, iterations = _verified(arm, _configs(arm, x, y, z, None, ref), point, None, ref, tolerance)
        if found:
            return _result(arm, OK, found[0], found[1:], point, None, iterations, None)
        return _closest(arm, point, None, ref_a, tolerance, iterations)
    preferred = [pitch] if pitch is not None else [PARALLEL, PERPENDICULAR]
    for phi in preferred:
        configs = _configs(arm, x, y, z, phi, ref)
        if configs:
            found, its = _verified(arm, configs, point, phi, ref, tolerance)
            iterations += its
            if found:
                return _result(arm, OK, found[0], found[1:], point, pitch, iterations, None)
    nearest = _nearest_reachable_pitch(arm, x, y, z, preferred, ref)
    if nearest is not None:
        configs = _configs(arm, x, y, z, nearest, ref, tol=1e-9)
        found, its = _verified(arm, configs, point, nearest, ref, tolerance)
        iterations += its
        if found:
            if pitch is None:
                return _result(arm, OK, found[0], found[1:], point, None, iterations, None)
            reason = (f"pitch {pitch:.4f} rad is not reachable at this target within the joint limits; "
                      f"the nearest reachable pitch is {nearest:.4f} rad")
            return _result(arm, APPROXIMATE, found[0], found[1:], point, pitch, iterations, reason)
    return _closest(arm, point, pitch, ref_a, tolerance, iterations)


def _pitch_distance(phi: float, preferred: list[float]) -> tuple[float, int]:
    """(wrapped distance to the nearest preferred pitch, its rank): the search's sort key."""
    return min((abs(math.remainder(phi - p, TWO_PI)), k) for k, p in enumerate(preferred))


def _nearest_reachable_pitch(arm: _Arm, x: float, y: float, z: float, preferred: list[float],
                             ref: list[float]) -> float | None:
    """The reachable pitch [rad] nearest any preferred pitch (earlier preferred wins ties), or None.

    Exact for arms whose coupled limits do not involve the pitch joints (every catalogue
    arm): the answer is a boundary pitch of the reachable set (:mod:`solvers.pitch`).
    Otherwise a 1-degree grid and bisection find it to ~1e-7 rad.
    """
    fp = arm.fp
    assert fp is not None and fp.wrist is not None
    pitch_joints = {fp.shoulder, fp.elbow, fp.wrist}
    if not any(i in pitch_joints for terms, _, _ in arm.coupled for i, _ in terms):
        cands = boundary_configs(fp, x, y, z, arm.lower, arm.upper, ref)
        cands.sort(key=lambda c: _pitch_distance(c[0], preferred))
        for phi, _name, q in cands:
            if arm.inside(q, 1e-9):
                return phi
        return None
    return _grid_pitch(arm, np.array([x, y, z]), preferred, np.array(ref))


def _reachable_pitches(arm: _Arm, point: FloatArray, phis: FloatArray) -> NDArray[np.bool_]:
    """For each pitch [rad], whether some branch reaches ``point`` within the limits (closed form)."""
    fp = arm.fp
    assert fp is not None and fp.wrist is not None
    m = len(phis)
    pts = np.broadcast_to(point, (m, 3))
    feasible = np.zeros(m, dtype=bool)
    lim = arm.robot.limits
    idx = [fp.yaw, fp.shoulder, fp.elbow, fp.wrist]
    for arr in branches_batch(fp, pts, phis).values():
        q = np.broadcast_to(arm.robot.neutral, (m, fp.n)).copy()
        for col, j in enumerate(idx):
            q[:, j] = wrap_into_batch(arr[:, col], lim.lower[j], lim.upper[j], 0.0)
        ok = ~np.any(np.isnan(q), axis=1)
        ok[ok] = lim.contains_batch(q[ok], tol=0.0)
        feasible |= ok
    return feasible


def _grid_pitch(arm: _Arm, point: FloatArray, preferred: list[float], ref: FloatArray) -> float | None:
    feasible = _reachable_pitches(arm, point, _PITCH_GRID)
    if not feasible.any():
        return None
    grid = _PITCH_GRID[feasible]
    good = min(grid.tolist(), key=lambda g: _pitch_distance(g, preferred))
    pref = preferred[_pitch_distance(good, preferred)[1]]
    delta = math.remainder(pref - good, TWO_PI)
    x, y, z = point.tolist()
    refl = ref.tolist()
    lo, hi = 0.0, 1.0
    for _ in range(_BISECTIONS):
        mid = 0.5 * (lo + hi)
        if _configs(arm, x, y, z, good + mid * delta, refl):
            lo = mid
        else:
            hi = mid
    return math.remainder(good + lo * delta, TWO_PI)


def _stretched_start(arm: _Arm, point: FloatArray, pitch: float | None, ref: FloatArray) -> FloatArray | None:
    """The arm pointed at ``point`` with the target pulled into its reach: a QP start."""
    fp = arm.fp
    assert fp is not None
    x, y, z = (float(v) for v in point)
    h = math.sqrt(max(x * x + y * y - fp.py * fp.py, 0.0))
    a = h - fp.px - fp.ox
    b = z - fp.pz - fp.oz
    reach_hi = fp.l1 + fp.l2 + (fp.l3 if pitch is None else 0.0)
    reach_lo = abs(fp.l1 - fp.l2)
    if fp.wrist is not None and pitch is not None:
        a -= fp.l3 * math.cos(pitch)
        b -= fp.l3 * math.sin(pitch)
    d = math.hypot(a, b)
    scale = min(max(d, reach_lo * 1.000001 + 1e-9), reach_hi * 0.999999) / max(d, 1e-300)
    a, b = a * scale, b * scale
    phi = pitch
    if fp.wrist is not None and pitch is None:  # free pitch: the hand continues the line to the target
        phi = math.atan2(b, a)
        dd = math.hypot(a, b)
        inner = max(dd - fp.l3, reach_lo * 1.000001 + 1e-9)
        a, b = a * inner / max(dd, 1e-300), b * inner / max(dd, 1e-300)
        a += fp.l3 * math.cos(phi)
        b += fp.l3 * math.sin(phi)
    elif fp.wrist is not None and phi is not None:
        a += fp.l3 * math.cos(phi)
        b += fp.l3 * math.sin(phi)
    u = a + fp.px + fp.ox
    zz = b + fp.pz + fp.oz
    bearing = math.atan2(y, x) if (x or y) else 0.0
    # the pulled-in point, rebuilt in 3-D along the target's bearing
    yaw = bearing - math.atan2(fp.py, u) if u else bearing
    c, s = math.cos(yaw), math.sin(yaw)
    pulled = (c * u - s * fp.py, s * u + c * fp.py, zz)
    cands = branches(fp, *pulled, phi)
    if not cands:
        return None
    best = None
    for _name, *values in cands:
        q = ref.copy()
        for j, v in zip((fp.yaw, fp.shoulder, fp.elbow, fp.wrist), values, strict=True):
            if j is not None:
                q[j] = v - TWO_PI * round((v - ref[j]) / TWO_PI)
        q = arm.qp.project(q)
        dist = float(np.linalg.norm(arm.robot.fk(q) - point))
        if best is None or dist < best[0]:
            best = (dist, q)
    return None if best is None else best[1]


def _closest(arm: _Arm, point: FloatArray, pitch: float | None, ref: FloatArray, tolerance: float,
             iterations: int) -> IKResult:
    """The configuration within limits whose tool point is nearest ``point``."""
    starts = []
    if arm.fp is not None:
        s = _stretched_start(arm, point, pitch, ref)
        if s is not None:
            starts.append(s)
    starts.append(ref)
    # the atlas configurations nearest the target, from different regions of joint space
    d = np.linalg.norm(arm.atlas_p - point, axis=1)
    for k in np.argsort(d)[:_ATLAS_STARTS]:
        starts.append(arm.atlas_q[k])
    best = None
    for q0 in starts:
        refined = arm.qp.solve(point, q0, pitch=pitch)
        iterations += refined.iterations
        if best is None or refined.position_error < best.position_error - 1e-12:
            best = refined
    assert best is not None
    chosen = Branch("numerical", best.q, best.position_error)
    if best.position_error <= tolerance:
        if pitch is not None and best.pitch_error > PITCH_TOLERANCE:
            return _result(arm, APPROXIMATE, chosen, [], point, pitch, iterations,
                           "the asked pitch is not reachable at this target within the joint limits")
        return _result(arm, OK, chosen, [], point, pitch, iterations, None)
    reason = (f"the target is out of reach within the joint limits: the closest the tool gets is "
              f"{best.position_error:.6g} m away")
    return _result(arm, UNREACHABLE, chosen, [], point, pitch, iterations, reason)


# -- arms outside the family -------------------------------------------------------------


def _solve_numerical(arm: _Arm, point: FloatArray, ref: FloatArray, tolerance: float) -> IKResult:
    """QP from the seed, the neutral pose and fixed quasi-random starts; the best wins."""
    robot = arm.robot
    rng = np.random.default_rng(12345)
    starts = [ref, robot.neutral, *list(rng.uniform(robot.limits.lower, robot.limits.upper, size=(6, robot.nq)))]
    best = None
    iterations = 0
    for q0 in starts:
        refined = arm.qp.solve(point, q0)
        iterations += refined.iterations
        if best is None or refined.position_error < best.position_error:
            best = refined
        if best.position_error <= tolerance:
            break
    assert best is not None
    chosen = Branch("numerical", best.q, best.position_error)
    if best.position_error <= tolerance:
        return _result(arm, OK, chosen, [], point, None, iterations, None)
    reason = (f"no start reached the target within the joint limits: the closest the tool gets is "
              f"{best.position_error:.6g} m away")
    return _result(arm, UNREACHABLE, chosen, [], point, None, iterations, reason)


# -- whole actuator steps ----------------------------------------------------------------------


def _quantise(arm: _Arm, result: IKResult, tolerance: float) -> IKResult:
    """The answer moved to whole actuator commands: the best of the neighbouring step counts."""
    robot = arm.robot
    amap = robot.actuators
    if not np.allclose(np.abs(amap.M).sum(axis=1), 1.0) or not np.all(np.count_nonzero(amap.M, axis=1) == 1):
        raise BadRequest(f"quantise needs one joint per actuator; {robot.name}'s actuator map couples joints",
                         field="quantise")
    first = [int(np.flatnonzero(amap.M[:, j])[0]) for j in range(robot.nq)]
    grids = []
    for j, k in enumerate(first):
        act = amap.actuators[k]
        raw = float(act.to_command(np.array(amap.M[k, j] * result.q[j] + amap.b[k])))
        options = sorted({math.floor(raw), math.ceil(raw)})
        grids.append([(float(act.to_angle(np.array(c))) - amap.b[k]) / amap.M[k, j] for c in options])
    best_q, best_err = None, math.inf
    for combo in np.array(np.meshgrid(*grids, indexing="ij")).reshape(robot.nq, -1).T:
        if not robot.limits.contains(combo, tol=0.0):
            continue
        err = float(np.linalg.norm(robot.fk(combo) - result.target))
        if err < best_err:
            best_q, best_err = combo, err
    if best_q is None:
        raise BadRequest("no whole-step configuration next to the answer is within the joint limits",
                         field="quantise")
    amap.commands(best_q)  # every actuator inside its range, or an error
    status, reason = result.status, result.reason
    if status == OK and best_err > tolerance:
        status = APPROXIMATE
        reason = f"quantised to whole actuator steps: {best_err:.3g} m from the target"
    chosen = Branch(result.branch, best_q, best_err)
    asked = None if result.pitch_error is None else result.pitch - result.pitch_error
    return _result(arm, status, chosen, list(result.branches), result.target, asked, result.iterations, reason)
