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
from collections.abc import Sequence

import numpy as np

from armd.errors import BadRequest
from armd.robots import Robot
from armd.robots.angles import wrap
from armd.robots.types import FloatArray

from .analytic import EXACT, NONE, solve_point
from .arm import ArmState, arm_state
from .closest import closest_family
from .geometric import BRANCH_NAMES, TWO_PI, arm_pose, branches
from .result import APPROXIMATE, OK, UNREACHABLE, Branch, IKResult
from .target import PARALLEL, PERPENDICULAR, approach_pitch, target_point

DEFAULT_TOLERANCE = 1e-9  # [m]: an answer is "ok" when its tool point is this close to the target
MAX_TOLERANCE = 0.01  # [m]: a looser "ok" would not be an answer to the question asked
PITCH_TOLERANCE = 1e-9  # [rad]
FREE_PITCHES = np.array([PARALLEL, PERPENDICULAR])  # the free-pitch preference, in order
_ATLAS_STARTS = 3
_PITCH_WEIGHT = 0.1  # [m/rad]: in the closest-point cost, 1 rad of pitch error weighs as 10 cm


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
    arm = arm_state(robot)
    ref = robot.neutral if seed is None else robot.joint_vector(seed, "seed")
    point = target_point(robot, target, ref)
    pitch = approach_pitch(robot, approach)
    if type(tolerance) is float and 0.0 < tolerance <= MAX_TOLERANCE:
        pass  # the common case (NaN fails the comparison and takes the full check)
    elif isinstance(tolerance, bool) or not (
        isinstance(tolerance, (int, float)) and math.isfinite(tolerance) and 0 < tolerance <= MAX_TOLERANCE
    ):
        raise BadRequest(f"tolerance must be a number in (0, {MAX_TOLERANCE}] m, got {tolerance!r}", field="tolerance")
    if arm.arrays is None:
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


def _pose(arm: ArmState, q: FloatArray) -> tuple[FloatArray, float]:
    """Tool point [m] and pitch [rad] at ``q`` on the exact model: the family's formula where
    it is the URDF's FK (checked against Pinocchio when the arm was first seen), else Pinocchio."""
    if arm.arrays is None or not arm.exact:
        pose = arm.robot.pose(q)
        return pose.position, pose.pitch
    reached = np.empty(3)
    pitch = arm_pose(arm.arrays, q, reached)
    return reached, wrap(pitch)


def _result(
    arm: ArmState,
    status: str,
    chosen: Branch,
    others: list[Branch],
    point: FloatArray,
    asked_pitch: float | None,
    iterations: int,
    reason: str | None,
) -> IKResult:
    """The answer, with the tool point and pitch at ``chosen.q`` by FK on the exact model (the check)."""
    reached, pitch = _pose(arm, chosen.q)
    pitch_error = None if asked_pitch is None else wrap(pitch - asked_pitch)
    return IKResult(
        status=status,
        q=chosen.q,
        position_error=_dist(reached, point),
        reached=reached,
        target=point,
        pitch=pitch,
        pitch_error=pitch_error,
        branch=chosen.name,
        branches=tuple(others),
        iterations=iterations,
        reason=reason,
    )


def _refined(
    arm: ArmState, rows: list[tuple[str, FloatArray, float]], point: FloatArray, phi: float | None, tolerance: float
) -> tuple[list[Branch], int]:
    """Branches of an idealised ``[geometry]`` checked on the exact model and refined by the QP
    (inside the limits) where they miss; those the QP cannot bring in are dropped."""
    found: list[Branch] = []
    iterations = 0
    for name, q, _ in rows:
        err = _dist(arm.robot.fk(q), point)
        if err > tolerance:
            refined = arm.qp.solve(point, q, pitch=phi)
            iterations += refined.iterations
            if refined.position_error > tolerance or refined.pitch_error > PITCH_TOLERANCE:
                continue
            q, err = refined.q, refined.position_error
        found.append(Branch(name, q, err))
    return found, iterations


def _solve_family(arm: ArmState, point: FloatArray, pitch: float | None, ref: FloatArray, tolerance: float) -> IKResult:
    assert arm.arrays is not None
    b = arm.buffers
    prefs = FREE_PITCHES if pitch is None else np.array([pitch])
    code, m, phi, pitch_sum = solve_point(arm.arrays, ref, point, prefs, b.qs, b.ids, b.errs, b.work, b.reached)
    if code == NONE:
        return _closest(arm, point, pitch, ref, tolerance, 0)
    if code == EXACT or pitch is None:
        status, reason = OK, None
    else:
        status = APPROXIMATE
        reason = (
            f"pitch {pitch:.4f} rad is not reachable at this target within the joint limits; "
            f"the nearest reachable pitch is {phi:.4f} rad"
        )
    qs = b.qs.copy()  # (all four rows: cheaper than slicing first; rows m and on are never read)
    names = [BRANCH_NAMES[i] for i in b.ids.tolist()[:m]]
    errs = b.errs.tolist()[:m]
    if arm.exact and errs[0] <= tolerance:
        # the formula is the URDF's FK (checked against Pinocchio when the arm was first seen), so
        # ``errs`` are the FK check: no refinement, and the answer is built from the compiled stage
        reached_pitch = wrap(pitch_sum)
        others = tuple([Branch(names[r], qs[r], errs[r]) for r in range(1, m)]) if m > 1 else ()
        return IKResult(  # (positional: the fields' order, status to reason)
            status,
            qs[0],
            errs[0],
            b.reached.copy(),
            point,
            reached_pitch,
            None if pitch is None else wrap(reached_pitch - pitch),
            names[0],
            others,
            0,
            None if status == OK else reason,
        )
    # an idealised [geometry], or an exact one whose first branch is off target (never "ok" off
    # target): each branch checked on the exact model and refined by the QP where it misses
    rows = [(names[r], qs[r], errs[r]) for r in range(m)]
    has_wrist = arm.robot.geometry is not None and arm.robot.geometry.has_wrist
    found, iterations = _refined(arm, rows, point, phi if has_wrist else None, tolerance)
    if not found:
        return _closest(arm, point, pitch, ref, tolerance, iterations)
    return _result(arm, status, found[0], found[1:], point, pitch, iterations, reason)


def _stretched_start(arm: ArmState, point: FloatArray, pitch: float | None, ref: FloatArray) -> FloatArray | None:
    """The arm pointed at ``point``, with the target pulled into its reach: a closest-point QP start.

    Without limits this is the closest configuration: a target beyond reach is best met by
    the arm stretched toward it (with a free wrist, the hand continuing the same line).
    """
    assert arm.arrays is not None
    f = arm.arrays.family
    has_wrist = bool(f.J[3] >= 0)
    px, py, pz, l1, l2, l3, ox, oz = f.P.tolist()
    x, y, z = point.tolist()
    h = math.sqrt(max(x * x + y * y - py * py, 0.0))
    a, b = h - px - ox, z - pz - oz  # the target in the arm's plane, from the shoulder
    lo = abs(l1 - l2) * 1.000001 + 1e-9
    if has_wrist and pitch is not None:  # the wrist must sit one hand back from the target
        wa, wb = a - l3 * math.cos(pitch), b - l3 * math.sin(pitch)
        d = math.hypot(wa, wb)
        k = min(max(d, lo), (l1 + l2) * 0.999999) / max(d, 1e-300)
        a, b = wa * k + l3 * math.cos(pitch), wb * k + l3 * math.sin(pitch)
        phi = pitch
    else:
        d = math.hypot(a, b)
        phi = math.atan2(b, a)
        reach = l1 + l2 + (l3 if has_wrist else 0.0)
        k = min(max(d, lo + (l3 if has_wrist else 0.0)), reach * 0.999999) / max(d, 1e-300)
        a, b = a * k, b * k
    u = a + px + ox
    yaw = math.atan2(y, x) - math.atan2(py, u)
    c, s = math.cos(yaw), math.sin(yaw)
    work = np.empty((4, 5))
    count = branches(f.P, has_wrist, c * u - s * py, s * u + c * py, b + pz + oz, phi, work)
    sign, zero = arm.arrays.sign, arm.arrays.zero
    best: tuple[float, FloatArray] | None = None
    for r in range(count):
        q = ref.copy()
        for col in range(4):
            j = int(f.J[col])
            if j >= 0:
                v = sign[j] * (float(work[r, col + 1]) - zero[j])  # (the family's angle in the URDF's)
                q[j] = v - TWO_PI * round((v - ref[j]) / TWO_PI)
        q = arm.qp.project(q)
        dist = _dist(arm.robot.fk(q), point)
        if best is None or dist < best[0]:
            best = (dist, q)
    return None if best is None else best[1]


def _closest(
    arm: ArmState, point: FloatArray, pitch: float | None, ref: FloatArray, tolerance: float, iterations: int
) -> IKResult:
    """The configuration within limits whose tool point is nearest ``point``."""
    if arm.arrays is not None and arm.exact:  # the family formula is the exact model: compiled
        q = np.empty(arm.robot.nq)
        has_wrist = bool(arm.arrays.family.J[3] >= 0)
        w2 = _PITCH_WEIGHT**2 if (pitch is not None and has_wrist) else 0.0
        err, perr, its = closest_family(
            arm.arrays, point, 0.0 if pitch is None else pitch, w2, ref, arm.atlas_q, arm.atlas_p, _ATLAS_STARTS, q
        )
        return _closest_result(arm, point, pitch, Branch("numerical", q, err), perr, iterations + its, tolerance)
    starts = []
    if arm.arrays is not None:
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
    return _closest_result(arm, point, pitch, chosen, best.pitch_error, iterations, tolerance)


def _closest_result(
    arm: ArmState,
    point: FloatArray,
    pitch: float | None,
    chosen: Branch,
    pitch_error: float,
    iterations: int,
    tolerance: float,
) -> IKResult:
    if chosen.position_error <= tolerance:
        if pitch is not None and pitch_error > PITCH_TOLERANCE:
            return _result(
                arm,
                APPROXIMATE,
                chosen,
                [],
                point,
                pitch,
                iterations,
                "the asked pitch is not reachable at this target within the joint limits",
            )
        return _result(arm, OK, chosen, [], point, pitch, iterations, None)
    reason = (
        f"the target is out of reach within the joint limits: the closest the tool gets is "
        f"{chosen.position_error:.6g} m away"
    )
    return _result(arm, UNREACHABLE, chosen, [], point, pitch, iterations, reason)


# -- arms outside the family -------------------------------------------------------------


def _solve_numerical(arm: ArmState, point: FloatArray, ref: FloatArray, tolerance: float) -> IKResult:
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
    reason = (
        f"no start reached the target within the joint limits: the closest the tool gets is "
        f"{best.position_error:.6g} m away"
    )
    return _result(arm, UNREACHABLE, chosen, [], point, None, iterations, reason)


# -- whole actuator steps ----------------------------------------------------------------------


def _quantise(arm: ArmState, result: IKResult, tolerance: float) -> IKResult:
    """The answer moved to whole actuator commands: the best of the neighbouring step counts."""
    robot = arm.robot
    amap = robot.actuators
    if not np.allclose(np.abs(amap.M).sum(axis=1), 1.0) or not np.all(np.count_nonzero(amap.M, axis=1) == 1):
        raise BadRequest(
            f"quantise needs one joint per actuator; {robot.name}'s actuator map couples joints", field="quantise"
        )
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
        raise BadRequest("no whole-step configuration next to the answer is within the joint limits", field="quantise")
    amap.commands(best_q)  # every actuator inside its range, or an error
    status, reason = result.status, result.reason
    if status == OK and best_err > tolerance:
        status = APPROXIMATE
        reason = f"quantised to whole actuator steps: {best_err:.3g} m from the target"
    chosen = Branch(result.branch, best_q, best_err)
    asked = None if result.pitch_error is None else result.pitch - result.pitch_error
    return _result(arm, status, chosen, list(result.branches), result.target, asked, result.iterations, reason)
