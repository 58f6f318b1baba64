"""``solve_ik_batch``: many targets in one call, the closed-form stage compiled and looped.

The statuses mean what they mean for :func:`solvers.solve_ik` (collisions included: an
answer of the compiled loop that collides, or a target under the floor, takes the
single-target path, which chooses a clear branch or says ``collision``). For an arm whose
``[geometry]`` reproduces its URDF exactly (checked against Pinocchio when the solver first
sees the arm; every catalogue arm), the answers are checked by the family's FK formula in
the compiled loop; otherwise each answer is checked by Pinocchio FK and refined by the QP.
Targets with no closed-form answer within limits (unreachable, or blocked by limits) take
the single-target path: the closest configuration within limits, by the QP.

An arm outside the family gets the numerical IK of every row in compiled calls
(:func:`solvers.lm.solve_chains`), each row answered as :func:`solvers.solve_ik` answers from
that same iteration; only the rows it leaves (a pitch asked for and missed, an answer that
collides, a target under the floor) take the single-target path.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from armd.errors import BadRequest
from armd.robots import Robot
from armd.robots.angles import wrap_array
from armd.robots.types import FloatArray

from .analytic import EXACT, NONE, clear_branches, solve_many
from .arm import ArmState, arm_state
from .clearance import pitches
from .geometric import BRANCH_NAMES
from .ik import (
    _NUMERICAL_STARTS,
    _PITCH_WEIGHT,
    DEFAULT_TOLERANCE,
    FREE_PITCHES,
    MAX_TOLERANCE,
    PITCH_TOLERANCE,
    _closest,
    solve_ik,
)
from .lm import solve_chains
from .result import APPROXIMATE, OK, UNREACHABLE, IKResult
from .target import approach_pitch
from .world import CompiledWorld, compiled


@dataclass(frozen=True)
class BatchIKResult:
    """Answers for m targets, as arrays (row i answers target i).

    Attributes:
        status: (m,) ``"ok"``, ``"approximate"``, ``"unreachable"`` or ``"collision"``.
        q: (m, n) joint vectors [rad], all within limits.
        position_error: (m,) [m].
        reached: (m, 3) tool points [m] at ``q``.
        pitch: (m,) tool pitch [rad] at ``q``.
        branch: (m,) branch names (``"numerical"`` where the QP answered).
        contact: (m,) the colliding pair where the status is ``"collision"``, else None.
    """

    status: NDArray[np.str_]
    q: FloatArray
    position_error: FloatArray
    reached: FloatArray
    pitch: FloatArray
    branch: NDArray[np.str_]
    contact: list[tuple[str, str] | None]

    def __len__(self) -> int:
        return len(self.status)

    def to_dict(self) -> dict[str, Any]:
        return {
            "status": self.status.tolist(),
            "q": self.q.tolist(),
            "position_error": self.position_error.tolist(),
            "reached": self.reached.tolist(),
            "pitch": self.pitch.tolist(),
            "branch": self.branch.tolist(),
            "contact": [None if c is None else list(c) for c in self.contact],
        }


CHUNK = 128  # targets per compiled call (about 0.3 ms): the native build holds the interpreter while it runs


def _solve_many(
    arm: ArmState,
    refs: FloatArray,
    pts: FloatArray,
    prefs: FloatArray,
    q: FloatArray,
    codes: NDArray[np.int64],
    pitch_out: FloatArray,
    ids: NDArray[np.int64],
    err: FloatArray,
    reached: FloatArray,
) -> None:
    """:func:`solve_many` over the rows, :data:`CHUNK` at a time: between chunks the other
    threads run (a move, a stop, an adapter's state), instead of waiting behind 10,000 targets.
    The chunks are views: each call writes into the caller's arrays."""
    assert arm.packed_arm is not None  # (a family arm: the compiled stage's)
    for a in range(0, len(pts), CHUNK):
        b = a + CHUNK
        solve_many(
            arm.packed_arm,
            refs[a:b],
            pts[a:b],
            prefs[a:b],
            q[a:b],
            codes[a:b],
            pitch_out[a:b],
            ids[a:b],
            err[a:b],
            reached[a:b],
        )


def _targets(targets: object) -> FloatArray:
    try:
        pts = np.asarray(targets, dtype=float)
    except (TypeError, ValueError):
        raise BadRequest("targets must be a list of [x, y, z] points in metres", field="targets") from None
    if pts.ndim != 2 or pts.shape[1] != 3 or pts.shape[0] == 0:
        raise BadRequest(
            f"targets must be a non-empty list of [x, y, z] points, got shape {list(pts.shape)}", field="targets"
        )
    if not np.all(np.isfinite(pts)):
        bad = int(np.argmin(np.all(np.isfinite(pts), axis=1)))
        raise BadRequest(f"targets[{bad}] is not finite: {pts[bad].tolist()}", field="targets", index=bad)
    return np.ascontiguousarray(pts)


def solve_ik_batch(
    robot: Robot,
    targets: object,
    *,
    approach: object = None,
    seeds: Sequence[float] | FloatArray | None = None,
    tolerance: float = DEFAULT_TOLERANCE,
    check: Callable[[], None] | None = None,
    collisions: bool = True,
) -> BatchIKResult:
    """IK for every row of ``targets`` (m, 3) [m]; ``seeds`` one joint vector for all, or (m, n);
    ``approach`` one approach for all, or one pitch [rad] per target (a sequence of m numbers).

    ``check`` is called before each target that takes the slow path (about 0.5 ms each for an
    unreachable target, against about 3 us in the compiled loop), and for an arm outside the
    family before each compiled call (:data:`NUMERICAL_CHUNK` targets); whatever it raises
    abandons the batch. The service's per-request deadline uses it. ``collisions``: as
    :func:`solve_ik`'s, for every arm.

    Raises :class:`BadRequest` (and solves nothing) when any input is malformed.
    """
    arm = arm_state(robot)
    pts = _targets(targets)
    m, n = len(pts), robot.nq
    per_target = isinstance(approach, (list, tuple, np.ndarray))
    if per_target:
        pitches = np.asarray(approach, dtype=float) if len(approach) else np.zeros(0)  # type: ignore[arg-type]
        if pitches.shape != (m,):
            raise BadRequest(
                f"approach must be one approach or {m} pitches, got shape {list(pitches.shape)}", field="approach"
            )
        for p in pitches.tolist():
            approach_pitch(robot, p)  # each one valid for this arm
        pitch: float | None = 0.0
    else:
        pitch = approach_pitch(robot, approach)
    if seeds is None:
        refs = np.broadcast_to(robot.neutral, (m, n))
    else:
        s = np.asarray(seeds, dtype=float) if not isinstance(seeds, str) else np.array([np.nan])
        if s.shape == (n,):
            refs = np.broadcast_to(robot.joint_vector(s, "seeds"), (m, n))
        elif s.shape == (m, n) and np.all(np.isfinite(s)):
            refs = s
        else:
            raise BadRequest(
                f"seeds must be one joint vector of {n} values or one per target ({m} x {n}), "
                f"got shape {list(s.shape)}",
                field="seeds",
            )
    refs = np.ascontiguousarray(refs)
    if isinstance(tolerance, bool) or not (
        isinstance(tolerance, (int, float)) and math.isfinite(tolerance) and 0 < tolerance <= MAX_TOLERANCE
    ):
        raise BadRequest(f"tolerance must be a number in (0, {MAX_TOLERANCE}] m, got {tolerance!r}", field="tolerance")

    status = np.full(m, UNREACHABLE, dtype="<U11")
    branch = np.full(m, "numerical", dtype="<U18")
    q = np.empty((m, n))
    err = np.empty(m)
    reached = np.empty((m, 3))
    pitch_out = np.empty(m)
    contact: list[tuple[str, str] | None] = [None] * m
    world = compiled(robot.collision) if collisions and robot.collision is not None else None
    if arm.arrays is None:
        asked = pitches if per_target else np.full(m, 0.0 if pitch is None else pitch)
        free = pitch is None and not per_target
        slow = _numerical(arm, pts, asked, free, refs, tolerance, check, world, status, q, err, reached, pitch_out)
        for i in np.flatnonzero(slow):  # missed (with a pitch), colliding or under the floor
            if check is not None:
                check()
            a_i = float(pitches[i]) if per_target else approach
            r = solve_ik(robot, pts[i], approach=a_i, seed=refs[i], tolerance=tolerance, collisions=collisions)
            _store(int(i), r, status, branch, q, err, reached, pitch_out, contact)
        return BatchIKResult(status, q, err, reached, pitch_out, branch, contact)

    if per_target:
        prefs = np.ascontiguousarray(pitches.reshape(m, 1))
    else:
        shared = FREE_PITCHES if pitch is None else np.array([pitch])
        prefs = np.ascontiguousarray(np.broadcast_to(shared, (m, len(shared))))  # (one compiled layout)
    codes = np.empty(m, dtype=np.int64)
    ids = np.empty(m, dtype=np.int64)
    _solve_many(arm, refs, pts, prefs, q, codes, pitch_out, ids, err, reached)
    solved = codes != NONE
    good = solved & (err <= tolerance) if arm.exact else np.zeros(m, dtype=bool)
    moved = np.zeros(0, dtype=np.int64)
    if world is not None:  # a target under the floor: the single-target path (it says collision)
        good &= ~_under(world, pts)
        hit = np.flatnonzero(good)
        hit = hit[world.colliding(q[hit])]  # (the rows in one compiled call)
        good[hit] = False
        if len(hit) and not world.coal_pairs:  # a colliding answer: the branch solve_ik would choose
            others = FREE_PITCH_GRID if pitch is None and not per_target and robot.chooses_pitch else _NO_PITCHES
            moved = hit[_clear(arm, world, refs, pts, prefs, others, tolerance, hit, q, ids)]
            good[moved] = True
    status[good] = np.where((codes[good] == EXACT) | (pitch is None and not per_target), OK, APPROXIMATE)
    branch[good] = np.array(BRANCH_NAMES)[ids[good]]
    pitch_out[good] = wrap_array(pitch_out[good])  # (the compiled stage's tool pitch, unwrapped)
    for i in moved.tolist():  # (as solvers.clearance's _chosen: the pose by FK)
        reached[i], pitch_out[i] = arm.tool_pose(q[i])
        err[i] = math.dist(reached[i].tolist(), pts[i].tolist())
    for i in np.flatnonzero(~good):  # the slow path: the single-target pipeline (QP, closest point)
        if check is not None:
            check()
        a_i = float(pitches[i]) if per_target else approach
        p_i = float(pitches[i]) if per_target else pitch
        r = (
            solve_ik(robot, pts[i], approach=a_i, seed=refs[i], tolerance=tolerance, collisions=collisions)
            if solved[i] or arm.rolls_tool or world is not None  # (solve_ik turns the roll, checks collisions)
            else _closest(arm, pts[i], p_i, refs[i], tolerance, 0)
        )
        _store(int(i), r, status, branch, q, err, reached, pitch_out, contact)
    return BatchIKResult(status, q, err, reached, pitch_out, branch, contact)


CLEAR_CHUNK = 16  # colliding answers per compiled call (up to about 0.1 ms each: every branch at 24 pitches)
FREE_PITCH_GRID = np.array(pitches(float(FREE_PITCHES[0])))  # solve_ik's other pitches where a free one's collide
_NO_PITCHES = np.zeros(0)


def _clear(
    arm: ArmState,
    world: CompiledWorld,
    refs: FloatArray,
    pts: FloatArray,
    prefs: FloatArray,
    others: FloatArray,
    tolerance: float,
    rows: NDArray[np.int64],
    q: FloatArray,
    ids: NDArray[np.int64],
) -> NDArray[np.bool_]:
    """For the ``rows`` whose closed-form answer collides, the clear branch :func:`solve_ik`
    chooses (:func:`solvers.analytic.clear_branches`: the other branches, then those at the
    pitches ``others``) into ``q`` and ``ids``, :data:`CLEAR_CHUNK` rows a compiled call; which
    of ``rows`` found one (the others take the single-target path: its wrist rolls and
    numerical starts)."""
    assert arm.packed_arm is not None
    for a in range(0, len(rows), CLEAR_CHUNK):
        clear_branches(
            arm.packed_arm, world.packed_shapes, refs, pts, prefs, others, tolerance, rows[a : a + CLEAR_CHUNK], q, ids
        )
    found: NDArray[np.bool_] = ids[rows] >= 0
    return found


NUMERICAL_CHUNK = 8  # targets per compiled call of the numerical batch (about 0.2 ms; 1 ms when out of reach)


def _numerical(
    arm: ArmState,
    pts: FloatArray,
    pitches: FloatArray,
    free: bool,
    refs: FloatArray,
    tolerance: float,
    check: Callable[[], None] | None,
    world: CompiledWorld | None,
    status: NDArray[np.str_],
    q: FloatArray,
    err: FloatArray,
    reached: FloatArray,
    pitch_out: FloatArray,
) -> NDArray[np.bool_]:
    """The batch of an arm outside the closed-form family: the numerical IK
    (:func:`solvers.lm.solve_chains`: from each row's seed, then from the atlas, as
    :func:`solve_ik`'s) over the rows in compiled calls of :data:`NUMERICAL_CHUNK` (``check``
    before each), and each row answered as :func:`solve_ik` answers from that same iteration: a
    row that reaches its target, and with a free pitch one that does not (its closest). Returns
    the rows left to the single-target path, which does more: a pitch asked for and missed
    (tried free next), an answer that collides or a target under the floor (with ``world``)."""
    m = len(pts)
    perr = np.empty(m)
    inside = np.ascontiguousarray(arm.robot.neutral, dtype=float)
    w2 = 0.0 if free else _PITCH_WEIGHT**2
    for a in range(0, m, NUMERICAL_CHUNK):
        if check is not None:
            check()
        b = a + NUMERICAL_CHUNK
        solve_chains(
            arm.packed_chain,
            pts[a:b],
            pitches[a:b],
            w2,
            refs[a:b],
            inside,
            arm.packed_atlas,
            _NUMERICAL_STARTS,
            tolerance,
            PITCH_TOLERANCE,
            q[a:b],
            reached[a:b],
            err[a:b],
            perr[a:b],
            pitch_out[a:b],
        )
    met = err <= tolerance
    answered = met | free
    if world is not None:
        answered[_touching(world, pts, q, answered)] = False
    pitch_out[answered] = wrap_array(pitch_out[answered])
    if free:
        status[answered & met] = OK
        rows = answered & ~met  # (solve_ik measures these from the tool point, as below)
    else:
        status[answered] = np.where(perr[answered] <= PITCH_TOLERANCE, OK, APPROXIMATE)
        rows = answered
    for i in np.flatnonzero(rows).tolist():
        err[i] = math.dist(reached[i].tolist(), pts[i].tolist())
    if free:
        status[rows] = UNREACHABLE
    slow: NDArray[np.bool_] = ~answered
    return slow


def _store(
    i: int,
    r: IKResult,
    status: NDArray[np.str_],
    branch: NDArray[np.str_],
    q: FloatArray,
    err: FloatArray,
    reached: FloatArray,
    pitch: FloatArray,
    contact: list[tuple[str, str] | None],
) -> None:
    contact[i] = r.contact
    status[i], branch[i], q[i], err[i], reached[i], pitch[i] = (
        r.status,
        r.branch,
        r.q,
        r.position_error,
        r.reached,
        r.pitch,
    )


def reachable(
    robot: Robot, targets: object, *, approach: object = None, tolerance: float = DEFAULT_TOLERANCE
) -> NDArray[np.bool_]:
    """Which targets :func:`solve_ik_batch` answers ``ok`` (with ``approach``), for maps of the
    workspace (clear of collisions, above the floor): the same closed-form stage, without the
    closest-point search that an
    unreachable target's answer needs (so a mostly unreachable grid costs what a reachable
    one does). Arms outside the exact closed form take :func:`solve_ik_batch` itself.
    """
    arm = arm_state(robot)
    pts = _targets(targets)
    pitch = approach_pitch(robot, approach)
    if arm.arrays is None or not arm.exact:
        ok: NDArray[np.bool_] = solve_ik_batch(robot, pts, approach=approach, tolerance=tolerance).status == OK
        return ok
    m, n = len(pts), robot.nq
    refs = np.ascontiguousarray(np.broadcast_to(robot.neutral, (m, n)))
    shared = FREE_PITCHES if pitch is None else np.array([pitch])
    prefs = np.ascontiguousarray(np.broadcast_to(shared, (m, len(shared))))
    q, reached = np.empty((m, n)), np.empty((m, 3))
    codes, ids = np.empty(m, dtype=np.int64), np.empty(m, dtype=np.int64)
    pitch_out, err = np.empty(m), np.empty(m)
    _solve_many(arm, refs, pts, prefs, q, codes, pitch_out, ids, err, reached)
    good: NDArray[np.bool_] = (codes != NONE) & (err <= tolerance)
    if pitch is not None:
        good &= codes == EXACT
    world = compiled(robot.collision) if robot.collision is not None else None
    if world is not None:  # clear of the arm itself, the floor and the obstacles (else solve_ik's word)
        under = _under(world, pts)
        for i in _touching(world, pts, q, good):
            good[i] = not under[i] and solve_ik(robot, pts[i], approach=approach, tolerance=tolerance).status == OK
    return good


def _under(world: CompiledWorld, pts: FloatArray) -> NDArray[np.bool_]:
    """Which targets lie under the floor (none without one)."""
    return pts[:, 2] < world.ground if world.ground is not None else np.zeros(len(pts), dtype=bool)


def _touching(world: CompiledWorld, pts: FloatArray, q: FloatArray, rows: NDArray[np.bool_]) -> list[int]:
    """Of the ``rows`` answered, those whose target is under the floor or whose answer ``q[i]``
    touches something: the single-target path's to answer (it looks for a clear branch)."""
    under = _under(world, pts)
    asked = np.flatnonzero(rows & ~under)
    hit = np.zeros(len(pts), dtype=bool)
    hit[asked] = world.colliding(q[asked])  # (the rows in one compiled call)
    return np.flatnonzero(rows & (under | hit)).tolist()
