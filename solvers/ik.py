"""``solve_ik``: closed-form geometric seed -> QP refinement with hard limits -> FK check.

The pipeline, for an arm of the closed-form family (all four catalogue arms):

1. The target point and the tool pitch the approach asks for (:mod:`solvers.target`).
2. Every branch of the closed form (:mod:`solvers.geometric`), joint values wrapped into
   the limits; branches outside any limit (box or coupled) are dropped.
3. Each remaining branch is checked by FK on the exact Pinocchio model. Where the
   ``[geometry]`` parameters are an idealisation of the URDF (as seed 004's planar model is),
   the refinement on the exact chain (:mod:`solvers.lm`: Levenberg-Marquardt, each step a QP
   with hard limits) takes the branch the rest of the way, inside the limits.
4. Among the valid branches, the nearest to the seed (or to the neutral pose when there is
   no seed) wins, by joint distance weighted by 1 / vmax (about the time to get there); ties
   go to the first in the fixed order front/up, front/down, flipped/up, flipped/down, so
   the same input always gives the same output.

Pitch: with ``approach`` ``"free"`` (or None) on an arm with a wrist, armd prefers a level
tool (``parallel``), then a tool pointing down (``perpendicular``), then the reachable
pitch nearest to either of them (seed 001's reachable areas A and B). With a pitch asked
for and not reachable at that target, the answer uses the nearest reachable pitch and says
``approximate``.

Unreachable targets get the closest configuration within limits (:mod:`solvers.closest`:
from the seed and from the atlas configurations nearest the target), ``status =
"unreachable"``, the reached point and the remaining error. An arm outside the family gets
the numerical IK (:func:`solvers.lm.solve_chain`) from the seed, then from the atlas.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Sequence

import numpy as np

from armd.errors import BadRequest
from armd.robots import Robot
from armd.robots.angles import wrap
from armd.robots.types import FloatArray

from .analytic import EXACT, NONE, solve_pitches, solve_point, solve_point_clear
from .arm import ArmState, arm_state
from .clearance import clear, clear_starts, pitches
from .closest import closest_family
from .geometric import BRANCH_NAMES
from .lm import refine_branches, refine_chain, solve_chain
from .result import APPROXIMATE, COLLISION, OK, UNREACHABLE, Branch, IKResult
from .target import PARALLEL, PERPENDICULAR, approach_pitch, target_point
from .world import CompiledWorld, World, compiled

DEFAULT_TOLERANCE = 1e-9  # [m]: an answer is "ok" when its tool point is this close to the target
MAX_TOLERANCE = 0.01  # [m]: a looser "ok" would not be an answer to the question asked
PITCH_TOLERANCE = 1e-9  # [rad]
FREE_PITCHES = np.array([PARALLEL, PERPENDICULAR])  # the free-pitch preference, in order
_ATLAS_STARTS = 3  # closest-point starts from the atlas (after the seed)
_NUMERICAL_STARTS = 8  # numerical IK starts from the atlas (after the seed)
_NEAR = 1e-3  # [m] an idealised closed form's closest point this near: the numerical IK tries too
_NEAR_PITCH = 1e-4  # [rad] an idealised closed form's nearest pitch this near the asked one: it is tried
_PITCH_WEIGHT = 0.1  # [m/rad]: in the closest-point cost, 1 rad of pitch error weighs as 10 cm
_ROLL_STEP = math.pi / 8  # [rad] the tool roll turns tried: every sixteenth of a turn each way, and to each limit
_ROLL_HALVINGS = 2  # ... and halvings of the turn that reaches, toward the seed's roll
_ORIGIN = np.zeros(3)


def solve_ik(
    robot: Robot,
    target: object,
    *,
    approach: object = None,
    seed: Sequence[float] | FloatArray | None = None,
    tolerance: float = DEFAULT_TOLERANCE,
    quantise: bool = False,
    roll: float | None = None,
    collisions: bool = True,
) -> IKResult:
    """Joint vector that puts ``robot``'s tool point on ``target``, within every limit.

    Args:
        robot: an arm from :func:`robots.load`.
        target: [x, y, z] [m] in ``base``, or a :class:`~solvers.target.SensorReading`.
        approach: ``"parallel"``, ``"perpendicular"``, a pitch [rad] in [-pi, pi], or
            ``"free"``/None.
        seed: the current joint vector [rad]; the answer is the valid branch nearest to it. A
            reading of a sensor on the arm (``mount = "frame"``) is converted at it: without
            a seed such a target is refused (the service gives the arm's present state).
        tolerance: position error [m] under which the answer is ``ok``.
        quantise: answer in whole actuator steps (stepper micro-steps), reporting the
            error quantisation leaves (status ``approximate`` when it exceeds ``tolerance``).
        roll: the tool's roll about its axis [rad] (:meth:`Robot.tool_roll`; an arm with a
            wrist roll): held through the solve. Without it the seed's roll is kept, and changed
            only where the target is out of reach with it.
        collisions: False: answer as if the arm had no world (no floor, obstacles or links to
            touch): for a Cartesian line, whose motion is checked whole (planning.clearance).

    Raises:
        BadRequest: malformed target, approach, seed, tolerance or roll (nothing is solved).
    """
    arm = arm_state(robot)
    at = (
        None if seed is None else robot.joint_vector(seed, "seed")
    )  # where the arm is (a frame sensor's reading's pose)
    ref = robot.neutral if at is None else at
    if roll is not None:
        angle = robot.roll_angle(roll, ref)  # (BadRequest on an arm without a wrist roll)
        assert robot.roll_joint is not None
        ref = ref.copy()
        ref[robot.roll_joint.index] = angle
    point = target_point(robot, target, at)  # (a sensor on the arm, with no seed: refused, never the neutral pose)
    pitch = approach_pitch(robot, approach)
    if type(tolerance) is float and 0.0 < tolerance <= MAX_TOLERANCE:
        pass  # the common case (NaN fails the comparison and takes the full check)
    elif isinstance(tolerance, bool) or not (
        isinstance(tolerance, (int, float)) and math.isfinite(tolerance) and 0 < tolerance <= MAX_TOLERANCE
    ):
        raise BadRequest(f"tolerance must be a number in (0, {MAX_TOLERANCE}] m, got {tolerance!r}", field="tolerance")
    world = compiled(robot.collision) if collisions and robot.collision is not None else None
    checked = False  # (the answer and its branches found clear in the closed form's own call)
    if arm.arrays is None:
        result = _solve_numerical(arm, point, pitch, ref, tolerance)
    else:
        result, checked = _solve_family(arm, point, pitch, ref, tolerance, roll is None, world)
    solved = result.q  # (the closed form's exact answer comes with its roll: at this q)
    if world is not None and not (checked and (world.ground is None or float(point[2]) >= world.ground)):
        result = clear(arm, world, result, lambda: _alternatives(arm, world, point, pitch, ref, tolerance))
    if quantise:
        result = _quantise(arm, result, tolerance)
        hit = None if world is None or result.status == COLLISION else world.first_contact(result.q)
        if hit is not None:
            reason = f"quantised to whole actuator steps, the answer collides: {hit}"
            result = result._replace(status=COLLISION, contact=(hit.first, hit.second), reason=reason)
    if robot.roll_joint is not None and (result.roll is None or result.q is not solved):
        result = result._replace(roll=robot.tool_roll(result.q))
    return result


# -- the closed-form family ------------------------------------------------------------


def _dist(a: FloatArray, b: FloatArray) -> float:
    """Euclidean distance [m] of two 3-vectors (math.dist: no NumPy call overhead)."""
    return math.dist(a.tolist(), b.tolist())


def _result(
    arm: ArmState,
    status: str,
    chosen: Branch,
    others: list[Branch],
    point: FloatArray,
    asked_pitch: float | None,
    iterations: int,
    reason: str | None,
    pose: tuple[FloatArray, float] | None = None,
) -> IKResult:
    """The answer, with the tool point and pitch at ``chosen.q`` by FK on the exact model (the
    check; ``pose`` where the caller has it already)."""
    reached, pitch = arm.tool_pose(chosen.q) if pose is None else pose
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
    """Branches of an idealised closed form checked on the exact model and refined by the
    iteration on it (inside the limits, :mod:`solvers.lm`) where they miss; those it cannot
    bring in are dropped."""
    m = len(rows)
    qs = np.array([q for _, q, _ in rows])
    errs, kept, its = np.empty(m), np.empty(m, dtype=bool), np.zeros(1, dtype=np.int64)
    w2 = 0.0 if phi is None else _PITCH_WEIGHT**2
    aim = 0.0 if phi is None else phi
    refine_branches(arm.packed_chain, qs, m, point, aim, w2, tolerance, PITCH_TOLERANCE, errs, kept, its)
    found = [Branch(rows[r][0], qs[r], float(errs[r])) for r in range(m) if kept[r]]
    return found, int(its[0])


def _solve_family(
    arm: ArmState,
    point: FloatArray,
    pitch: float | None,
    ref: FloatArray,
    tolerance: float,
    free_roll: bool = True,
    world: CompiledWorld | None = None,
) -> tuple[IKResult, bool]:
    """The closed form's answer, and whether it and every branch listed were found clear of
    ``world`` in the same compiled call (a world of primitive shapes; else not checked here)."""
    assert arm.packed_arm is not None
    out = arm.buffers.out
    prefs = FREE_PITCHES if pitch is None else np.array([pitch])
    together = world is not None and not world.coal_pairs
    if together:
        assert world is not None
        code, m, phi, pitch_sum = solve_point_clear(arm.packed_arm, world.packed_shapes, ref, point, prefs, *out)
    else:
        code, m, phi, pitch_sum = solve_point(arm.packed_arm, ref, point, prefs, *out[:5])
    if code == NONE and free_roll and arm.rolls_tool and _dist(point, _ORIGIN) <= arm.reach:
        # out of reach with the seed's roll, and the roll moves the tool point: the closed form
        # at other rolls, the least turn first
        turned = _turn_roll(arm, point, prefs, ref)
        if turned is not None:
            ref, (code, m, phi, pitch_sum) = turned
            together = False  # (solve_point's branches: not checked)
    if code == NONE:
        return _closest(arm, point, pitch, ref, tolerance, 0, free_roll), False
    if code == EXACT or pitch is None:
        status, reason = OK, None
    else:
        status = APPROXIMATE
        reason = (
            f"pitch {pitch:.4f} rad is not reachable at this target within the joint limits; "
            f"the nearest reachable pitch is {phi:.4f} rad"
        )
    b_qs, b_ids, b_errs, _, b_reached, b_hits = out
    qs = b_qs.copy()  # (all four rows: cheaper than slicing first; rows m and on are never read)
    ids, errs = b_ids.tolist(), b_errs.tolist()  # (likewise)
    if arm.exact and errs[0] <= tolerance:
        # the formula is the URDF's FK (checked against Pinocchio when the arm was first seen), so
        # ``errs`` are the FK check: no refinement, and the answer is built from the compiled stage,
        # its tool roll with it (what solve_ik would add by _replace, a microsecond more)
        reached_pitch = wrap(pitch_sum)
        others = tuple([Branch(BRANCH_NAMES[ids[r]], qs[r], errs[r]) for r in range(1, m)]) if m > 1 else ()
        checked = together and max(b_hits.tolist()[:m]) < 0
        robot = arm.robot
        return IKResult(  # (positional: the fields' order, status to roll)
            status,
            qs[0],
            errs[0],
            b_reached.copy(),
            point,
            reached_pitch,
            None if pitch is None else wrap(reached_pitch - pitch),
            BRANCH_NAMES[ids[0]],
            others,
            0,
            None if status == OK else reason,
            None if robot.roll_joint is None else robot.tool_roll(qs[0]),
        ), checked
    names = [BRANCH_NAMES[i] for i in ids[:m]]
    # an idealised [geometry], or an exact one whose first branch is off target (never "ok" off
    # target): each branch checked on the exact model and iterated there where it misses, at the
    # asked pitch (a free one was only the closed form's preference: the position alone counts)
    rows = [(names[r], qs[r], errs[r]) for r in range(m)]
    has_wrist = arm.robot.geometry is not None and arm.robot.geometry.has_wrist
    # the idealised form's nearest pitch a hair off the asked one: the URDF may reach the asked one
    retry = not arm.exact and status == APPROXIMATE and pitch is not None and abs(wrap(phi - pitch)) < _NEAR_PITCH
    aim = pitch if retry else phi
    found, iterations = _refined(arm, rows, point, aim if has_wrist and pitch is not None else None, tolerance)
    if found and retry:
        status, reason = OK, None
    if not found and retry:  # it does not: the nearest pitch, as the closed form said
        found, more = _refined(arm, rows, point, phi, tolerance)
        iterations += more
    if not found:
        return _closest(arm, point, pitch, ref, tolerance, iterations, free_roll), False
    return _result(arm, status, found[0], found[1:], point, pitch, iterations, reason), False


def _turn_roll(
    arm: ArmState, point: FloatArray, prefs: FloatArray, ref: FloatArray
) -> tuple[FloatArray, tuple[int, int, float, float]] | None:
    """The seed with its wrist roll turned, as little as it takes, so that the closed form
    reaches ``point``; with the closed form's answer there (in ``arm.buffers``). None if no
    probe does. Probes, the least turn first: every sixteenth of a turn each way from the seed's
    roll (each the joint angle within limits nearest the seed's), and the roll joint's two limits
    (a target reached only near a limit: a Braccio-like roll of [0, pi] whose probes at a
    multiple of 45 degrees all fell outside it); the turn that reaches is halved toward the
    seed's joint angle while it still does."""
    packed_arm, g = arm.packed_arm, arm.robot.geometry
    assert packed_arm is not None and g is not None and g.roll is not None
    b = arm.buffers
    i = g.roll
    lo, hi = float(arm.robot.limits.lower[i]), float(arm.robot.limits.upper[i])
    start = float(ref[i])
    probe = ref.copy()

    def at(angle: float) -> tuple[int, int, float, float]:
        probe[i] = angle
        return solve_point(packed_arm, probe, point, prefs, b.qs, b.ids, b.errs, b.work, b.reached)

    for turn in _roll_turns(start, lo, hi):
        found = at(start + turn)
        if found[0] == NONE:
            continue
        for _ in range(_ROLL_HALVINGS):
            nearer = at(start + 0.5 * turn)
            if nearer[0] == NONE:
                found = at(start + turn)  # (the buffers hold the last probe's answer)
                break
            turn, found = 0.5 * turn, nearer
        return probe, found
    return None


def _roll_turns(start: float, lo: float, hi: float) -> list[float]:
    """The turns [rad] of a roll joint at ``start`` within [``lo``, ``hi``] that :func:`_turn_roll`
    tries, the least first (a turn one way before the same the other)."""
    turns = {round(lo - start, 12), round(hi - start, 12)}
    for k in range(1, 9):
        for sign in (1, -1):
            within = [t for t in (sign * k * _ROLL_STEP + 2 * math.pi * m for m in (-1, 0, 1)) if lo <= start + t <= hi]
            if within:
                turns.add(min(within, key=abs))
    return sorted((t for t in turns if abs(t) > 1e-9), key=lambda t: (abs(t), t < 0))


def _closest(
    arm: ArmState,
    point: FloatArray,
    pitch: float | None,
    ref: FloatArray,
    tolerance: float,
    iterations: int,
    free_roll: bool = True,
) -> IKResult:
    """The configuration within limits whose tool point is nearest ``point``: on the family's
    formula (then, where it is an idealisation of the URDF, iterated on the exact chain from
    there), else the numerical IK's best."""
    if arm.arrays is not None and arm.packed_arm is not None:
        q = np.empty(arm.robot.nq)
        has_wrist = bool(arm.arrays.family.J[3] >= 0)
        w2 = _PITCH_WEIGHT**2 if (pitch is not None and has_wrist) else 0.0
        aim = 0.0 if pitch is None else pitch
        err, perr, its = closest_family(arm.packed_arm, point, aim, w2, ref, arm.packed_atlas, _ATLAS_STARTS, q)
        if not arm.exact:
            err, perr, its2 = refine_chain(arm.packed_chain, point, aim, w2, q, 30, 0.4, 1e-12)
            its += its2
            if tolerance < err <= _NEAR:  # the idealised closed form may say no where the URDF reaches
                q, err, perr, its2 = _numerically_better(arm, point, aim, w2, q, err, perr, tolerance)
                its += its2
        g = arm.robot.geometry
        if free_roll and tolerance < err <= _roll_reach(arm) and g is not None and g.roll is not None:
            # the closed form held the wrist roll at the seed's, and the roll moves the tool by
            # as much as is missing: the numerical IK with the roll free, from here and the atlas
            q, err, perr, its2 = _numerically_better(arm, point, aim, w2, q, err, perr, tolerance)
            its += its2
        return _closest_result(arm, point, pitch, Branch("numerical", q, err), perr, iterations + its, tolerance)
    q = np.empty(arm.robot.nq)
    w2 = 0.0 if pitch is None or not arm.robot.chooses_pitch else _PITCH_WEIGHT**2
    err, perr, its, _ = _chain_solve(
        arm, point, 0.0 if pitch is None else pitch, w2, ref, arm.robot.neutral, _ATLAS_STARTS, tolerance, q
    )
    return _closest_result(arm, point, pitch, Branch("numerical", q, err), perr, iterations + its, tolerance)


def _chain_solve(
    arm: ArmState,
    point: FloatArray,
    pitch: float,
    w2: float,
    ref: FloatArray,
    inside: FloatArray,
    starts: int,
    tolerance: float,
    q_out: FloatArray,
    reached: FloatArray | None = None,
) -> tuple[float, float, int, float]:
    """:func:`solvers.lm.solve_chain` on ``arm``'s chain and atlas (``starts`` of it): (position
    error, pitch error, iterations, tool pitch), the answer into ``q_out`` and its tool point
    into ``reached``."""
    err, perr, its, _, reached_pitch = solve_chain(
        arm.packed_chain,
        point,
        pitch,
        w2,
        ref,
        inside,
        arm.packed_atlas,
        starts,
        tolerance,
        PITCH_TOLERANCE,
        q_out,
        np.empty(3) if reached is None else reached,
    )
    return err, perr, its, reached_pitch


def _numerically_better(
    arm: ArmState,
    point: FloatArray,
    aim: float,
    w2: float,
    q: FloatArray,
    err: float,
    perr: float,
    tolerance: float,
) -> tuple[FloatArray, float, float, int]:
    """The numerical IK on the exact chain from ``q`` (an answer missing by ``err``), then from
    the atlas: its answer where it is nearer, else ``q``'s; with the iterations it took."""
    other = np.empty(arm.robot.nq)
    e2, p2, its, _ = _chain_solve(arm, point, aim, w2, q, q, _NUMERICAL_STARTS, tolerance, other)
    if e2 * e2 + w2 * p2 * p2 < err * err + w2 * perr * perr:
        return other, e2, p2, its
    return q, err, perr, its


def _roll_reach(arm: ArmState) -> float:
    """How far [m] the wrist roll moves the tool point (0: no roll, or one that does not)."""
    g = arm.robot.geometry
    return 0.0 if g is None or g.roll_model is None else g.roll_model.reach


def _closest_result(
    arm: ArmState,
    point: FloatArray,
    pitch: float | None,
    chosen: Branch,
    pitch_error: float,
    iterations: int,
    tolerance: float,
    pose: tuple[FloatArray, float] | None = None,
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
                pose,
            )
        return _result(arm, OK, chosen, [], point, pitch, iterations, None, pose)
    reason = (
        f"the target is out of reach within the joint limits: the closest the tool gets is "
        f"{chosen.position_error:.6g} m away"
    )
    return _result(arm, UNREACHABLE, chosen, [], point, pitch, iterations, reason, pose)


def _alternatives(
    arm: ArmState, world: World, point: FloatArray, pitch: float | None, ref: FloatArray, tolerance: float
) -> Iterator[list[Branch]]:
    """Configurations on ``point`` other than the first answer's branches, in stages preferred
    first, for when they all collide (:func:`solvers.clearance.clear`, a stage checked in one
    call): with a free pitch, the closed form's branches at the other pitches, nearest the
    preferred one first; the branches with the wrist rolled; then the numerical IK from the clear
    atlas configurations nearest the target (other wrist rolls; an arm outside the family)."""
    at: dict[float, list[Branch]] = {}  # each pitch's branches (the rolled stage tries some again)
    if arm.arrays is not None and pitch is None and arm.robot.chooses_pitch:
        yield _at_pitches(arm, point, pitches(float(FREE_PITCHES[0])), ref, tolerance, at)
    yield _rolled(arm, point, pitch, ref, tolerance, at)
    w2 = 0.0 if pitch is None else _PITCH_WEIGHT**2
    found = []
    for start in clear_starts(arm, world, point, _NUMERICAL_STARTS):
        q = np.empty(arm.robot.nq)
        err, perr, _, _ = _chain_solve(arm, point, 0.0 if pitch is None else pitch, w2, start, start, 0, tolerance, q)
        if err <= tolerance and (pitch is None or perr <= PITCH_TOLERANCE):
            found.append(Branch("numerical", q, err))
    yield found


ROLL_STEP = math.pi / 12  # [rad] the other wrist rolls tried when every branch collides
ROLLED_PITCHES = 8  # ... at the preferred pitch and this many nearest it (a free pitch)


def _rolled(
    arm: ArmState,
    point: FloatArray,
    pitch: float | None,
    ref: FloatArray,
    tolerance: float,
    at: dict[float, list[Branch]],
) -> list[Branch]:
    """For an arm whose wrist roll turns the tool about its own axis without moving the tool
    point: the closed form's branches with the roll turned (every ROLL_STEP within its limits,
    nearest the seed's first): the gripper turned may clear what it hit."""
    rj = arm.robot.roll_joint
    if arm.arrays is None or rj is None or arm.rolls_tool:
        return []
    i = rj.index
    lo, hi = float(arm.robot.limits.lower[i]), float(arm.robot.limits.upper[i])
    r0 = float(ref[i])
    rolls = [r0 + sign * k * ROLL_STEP for k in range(1, 13) for sign in (1.0, -1.0)]
    rolls = [r for r in rolls if lo <= r <= hi]
    if pitch is not None:
        tried = [pitch]
    elif arm.robot.chooses_pitch:
        tried = [float(FREE_PITCHES[0]), *pitches(float(FREE_PITCHES[0]))[:ROLLED_PITCHES]]
    else:
        tried = [float(FREE_PITCHES[0])]
    found = _at_pitches(arm, point, tried, ref, tolerance, at)
    if not found:
        return []
    Q = np.tile(np.array([b.q for b in found]), (len(rolls), 1))  # (each roll, each branch)
    Q[:, i] = np.repeat(rolls, len(found))
    return [Branch(b.name, q, b.position_error) for q, b in zip(Q, found * len(rolls), strict=True)]


def _at_pitches(
    arm: ArmState, point: FloatArray, ps: list[float], ref: FloatArray, tolerance: float, at: dict[float, list[Branch]]
) -> list[Branch]:
    """The closed form's branches on ``point`` at each tool pitch of ``ps`` in turn (those not in
    ``at`` yet: for an exact arm in one compiled call, :func:`solvers.analytic.solve_pitches`)."""
    assert arm.packed_arm is not None
    new = [p for p in dict.fromkeys(ps) if p not in at]
    if arm.exact and new:
        k, n = len(new), arm.robot.nq
        qs, ids, errs, counts = (
            np.empty((4 * k, n)),
            np.empty(4 * k, dtype=np.int64),
            np.empty(4 * k),
            np.empty(k, dtype=np.int64),
        )
        solve_pitches(arm.packed_arm, ref, point, np.array(new), qs, ids, errs, counts)
        row = 0
        for p, m in zip(new, counts.tolist(), strict=True):
            at[p] = [
                Branch(BRANCH_NAMES[int(ids[r])], qs[r].copy(), float(errs[r]))
                for r in range(row, row + m)
                if errs[r] <= tolerance
            ]
            row += m
    return [b for p in ps for b in _branches_at(arm, point, p, ref, tolerance, at)]


def _branches_at(
    arm: ArmState, point: FloatArray, p: float, ref: FloatArray, tolerance: float, at: dict[float, list[Branch]]
) -> list[Branch]:
    """The closed form's branches on ``point`` at tool pitch ``p`` (refined by the QP for an arm
    outside the exact family); none where the pitch does not reach it. Kept in ``at``."""
    if p in at:
        return at[p]
    at[p] = found = _solved_at(arm, point, p, ref, tolerance)
    return found


def _solved_at(arm: ArmState, point: FloatArray, p: float, ref: FloatArray, tolerance: float) -> list[Branch]:
    assert arm.packed_arm is not None
    b = arm.buffers
    code, m, _, _ = solve_point(arm.packed_arm, ref, point, np.array([p]), b.qs, b.ids, b.errs, b.work, b.reached)
    if code != EXACT:
        return []
    names = [BRANCH_NAMES[i] for i in b.ids.tolist()[:m]]
    rows = [(names[r], b.qs[r].copy(), float(b.errs[r])) for r in range(m)]
    if arm.exact:
        return [Branch(n, q, e) for n, q, e in rows if e <= tolerance]
    return list(_refined(arm, rows, point, p, tolerance)[0])


# -- arms outside the family -------------------------------------------------------------


def _solve_numerical(
    arm: ArmState, point: FloatArray, pitch: float | None, ref: FloatArray, tolerance: float
) -> IKResult:
    """The iteration on the exact chain (:func:`solvers.lm.solve_chain`) from the seed, then from
    the atlas configurations nearest the target, until one reaches it (with the asked pitch);
    else the best."""
    q = np.empty(arm.robot.nq)
    reached = np.empty(3)
    w2 = 0.0 if pitch is None else _PITCH_WEIGHT**2
    err, perr, iterations, reached_pitch = _chain_solve(
        arm,
        point,
        0.0 if pitch is None else pitch,
        w2,
        ref,
        arm.robot.neutral,
        _NUMERICAL_STARTS,
        tolerance,
        q,
        reached,
    )
    if pitch is None and err <= tolerance:  # the common case, answered without another FK
        return IKResult(OK, q, err, reached, point, wrap(reached_pitch), None, "numerical", (), iterations, None)
    pose: tuple[FloatArray, float] | None = (reached, wrap(reached_pitch))
    if pitch is not None and err > tolerance:
        # not met with the pitch: the target may still be reached at another (then "approximate")
        free = np.empty(arm.robot.nq)
        e2, _, more, _ = _chain_solve(arm, point, 0.0, 0.0, q, arm.robot.neutral, _NUMERICAL_STARTS, tolerance, free)
        iterations += more
        if e2 <= tolerance or e2 < err:
            q, err, pose = free, e2, None
            perr = abs(wrap(arm.robot.tool_pitch(q) - pitch))
    return _closest_result(arm, point, pitch, Branch("numerical", q, err), perr, iterations, tolerance, pose)


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
