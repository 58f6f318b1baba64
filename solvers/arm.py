"""The solver's state for one arm, built once and kept by the arm (:meth:`Robot.derived`).

:func:`arm_state` gives, for a :class:`~armd.robots.Robot`, the compiled code's arrays
(:class:`~armd.solvers.arrays.Arm`, where the arm is of the closed-form family), the exact
model's chain (:class:`~armd.solvers.kinematics.Chain`), the atlas (in-limit configurations
spread over joint space with their tool points: starts for the closest-point search and the
numerical IK) and per-thread scratch buffers. Each bundle is kept twice over the same memory:
packed (:mod:`solvers.packed`: what the compiled entry points take) and as its named tuple of
views of the packed arrays (what Python reads).
"""

from __future__ import annotations

import threading
from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from armd.robots import Robot
from armd.robots.angles import wrap
from armd.robots.geometry import Geometry
from armd.robots.types import FloatArray

from .arrays import Arm, Family
from .atlas import Atlas, make_atlas
from .geometric import arm_pose
from .kinematics import Chain
from .kinematics import pose as chain_pose
from .packed import Packed, pack, unpacked

ATLAS_SIZE = 4096


class Buffers(threading.local):
    """Scratch arrays for the compiled stage, one set per thread."""

    def __init__(self, n: int) -> None:
        self.qs = np.zeros((4, n))
        self.ids = np.zeros(4, dtype=np.int64)
        self.hits = np.zeros(4, dtype=np.int64)  # (each branch's first pair in contact, -1: clear)
        self.errs = np.zeros(4)
        self.work = np.zeros((4, 5))
        self.reached = np.zeros(3)
        self.point = np.zeros(3)
        # the closed form's out-arguments in its calls' order (solve_point's: the first five),
        # read from the thread's set at once (each attribute of a threading.local is a lookup)
        self.out = (self.qs, self.ids, self.errs, self.work, self.reached, self.hits)


@dataclass
class ArmState:
    """Per-robot solver state (see the module's doc)."""

    robot: Robot
    arrays: Arm | None  # the compiled code's arrays (views of packed_arm); None outside the family
    chain: Chain  # the exact model, compiled (views of packed_chain)
    weights: FloatArray  # 1 / vmax [s/rad]: joint distance ~ time to get there
    exact: bool  # the family's formula is the URDF's FK (to 1e-12 m): branch errors by formula
    atlas: Atlas  # in-limit configurations and their tool points, on a grid (views of packed_atlas)
    reach: float  # [m] the farthest atlas tool point from the base origin: beyond, a target is taken as far
    rolls_tool: bool  # the wrist roll moves the tool point (the closed form holds it at the seed's)
    buffers: Buffers
    packed_arm: Packed | None  # the bundles as the entry points take them (solvers.packed)
    packed_family: Packed | None  # (the arm's family on its own: closest_box, refine_family)
    packed_chain: Packed
    packed_atlas: Packed

    @property
    def family(self) -> Family | None:
        return None if self.arrays is None else self.arrays.family

    def tool_pose(self, q: FloatArray) -> tuple[FloatArray, float]:
        """Tool point [m] and pitch [rad] at ``q`` on the exact model: the family's formula where
        it is the URDF's FK (checked against Pinocchio when the arm was first seen), else the
        URDF's chain (compiled)."""
        reached = np.empty(3)
        if self.packed_arm is None or not self.exact:
            return reached, wrap(chain_pose(self.packed_chain, q, reached))
        return reached, wrap(arm_pose(self.packed_arm, q, reached))


_lock = threading.Lock()


def arm_state(robot: Robot) -> ArmState:
    """``robot``'s solver state, made on first use (thread-safe) and kept by the robot."""
    state = robot.derived.get("solver")
    if state is None:
        with _lock:
            state = robot.derived.get("solver")
            if state is None:
                state = _build(robot)
                robot.derived["solver"] = state
    assert isinstance(state, ArmState)
    return state


def _c(a: FloatArray) -> FloatArray:
    return np.ascontiguousarray(a, dtype=np.float64)


def family_arrays(robot: Robot, g: Geometry) -> Arm:
    """The compiled code's arrays for ``robot`` of geometry ``g`` (:mod:`solvers.arrays`)."""
    lim = robot.limits
    n = robot.nq
    sign = np.ones(n)
    zero = np.zeros(n)
    for k, j in enumerate(g.joints):
        sign[j], zero[j] = g.sign[k], g.zero[k]
    # the box in the family's angles (a joint whose sign is -1 has its ends swapped)
    a, b = sign * lim.lower + zero, sign * lim.upper + zero
    C = np.array([c.coefficients for c in lim.coupled]).reshape(len(lim.coupled), n)
    # C q = C S (theta - zero): the rows in the family's angles, their bounds moved by C S zero
    Cf = C * sign
    shift = Cf @ zero if len(C) else np.zeros(0)
    clo = np.array([c.lower for c in lim.coupled]) + shift
    chi = np.array([c.upper for c in lim.coupled]) + shift
    J = np.array([g.yaw, g.shoulder, g.elbow, -1 if g.wrist is None else g.wrist], dtype=np.int64)
    pitch_joints = [int(j) for j in J[1:] if j >= 0]
    exact_pitch_search = not np.any(C[:, pitch_joints]) if len(C) else True
    P = np.array(
        [g.pivot[0], g.pivot[1], g.pivot[2], g.upper_arm, g.forearm, g.hand, g.tool_offset[0], g.tool_offset[1]]
    )
    family = Family(
        _c(P),
        np.ascontiguousarray(J),
        _c(np.minimum(a, b)),
        _c(np.maximum(a, b)),
        _c(1.0 / lim.velocity),
        _c(Cf),
        _c(clo),
        _c(chi),
        bool(exact_pitch_search),
        bool(g.level),
    )
    model = np.zeros((4, 3))
    roll = -1
    if g.roll is not None and g.roll_model is not None:
        roll = g.roll
        model = np.array([g.roll_model.point, g.roll_model.axis, g.roll_model.tool, g.roll_model.tool_axis])
    return Arm(
        family,
        _c(sign),
        _c(zero),
        _c(lim.lower),
        _c(lim.upper),
        _c(np.array(g.base)),
        float(g.pitch_offset),
        int(roll),
        _c(model),
    )


def exact_chain(robot: Robot) -> Chain:
    """The compiled code's exact model of ``robot`` (:mod:`solvers.kinematics`): the joints from
    the base frame to the tool frame as Pinocchio's model has them, and the arm's limits."""
    model = robot.model
    joints = []
    j = int(model.frames[robot.tool_frame_id].parentJoint)
    while j > 0:
        joints.append(j)
        j = int(model.parents[j])
    joints.reverse()
    data = model.createData()
    pin.forwardKinematics(model, data, np.zeros(model.nq))
    k = len(joints)
    placement, axis = np.zeros((k, 4, 4)), np.zeros((k, 3))
    prismatic, coordinate = np.zeros(k, dtype=np.int64), np.zeros(k, dtype=np.int64)
    scale, offset = np.ones(k), np.zeros(k)
    for r, j in enumerate(joints):
        jm = model.joints[j]
        S = np.array(data.joints[j].S).reshape(6)  # the joint's motion in its frame (a mimic's: scaled)
        if jm.shortname() == "JointModelMimic":
            mimic = jm.extract()
            scale[r], offset[r] = float(mimic.scaling), float(mimic.offset)
        placement[r] = model.jointPlacements[j].homogeneous
        moving = S[:3] if np.linalg.norm(S[3:]) < 1e-12 else S[3:]
        prismatic[r] = int(np.linalg.norm(S[3:]) < 1e-12)
        axis[r] = moving / (scale[r] if scale[r] != 0.0 else 1.0)
        axis[r] /= np.linalg.norm(axis[r])
        coordinate[r] = jm.idx_q
    lim = robot.limits
    C = np.array([c.coefficients for c in lim.coupled]).reshape(len(lim.coupled), robot.nq)
    g = robot.geometry
    return Chain(
        _c(placement),
        _c(axis),
        prismatic,
        coordinate,
        _c(scale),
        _c(offset),
        _c(model.frames[robot.tool_frame_id].placement.homogeneous),
        _c(robot.tool_axis),
        _c(lim.lower),
        _c(lim.upper),
        _c(C),
        _c(np.array([c.lower for c in lim.coupled])),
        _c(np.array([c.upper for c in lim.coupled])),
        -1 if g is None else int(g.yaw),
        1.0 if g is None else float(g.sign[0]),
        0.0 if g is None else float(g.zero[0]),
    )


def _atlas(robot: Robot, n: int = ATLAS_SIZE) -> FloatArray:
    """Fixed quasi-random configurations within every limit."""
    rng = np.random.default_rng(20261121)
    qs = rng.uniform(robot.limits.lower, robot.limits.upper, size=(4 * n, robot.nq))
    return np.ascontiguousarray(qs[robot.limits.contains_batch(qs, tol=0.0)][:n])


def _build(robot: Robot) -> ArmState:
    g = robot.geometry
    packed_arm = pack(family_arrays(robot, g)) if g is not None else None
    arrays = None if packed_arm is None else unpacked(packed_arm)
    exact = False
    if packed_arm is not None:
        rng = np.random.default_rng(0)
        qs = rng.uniform(robot.limits.lower, robot.limits.upper, size=(64, robot.nq))
        out = np.empty(3)
        worst = 0.0
        for q in qs:
            arm_pose(packed_arm, np.ascontiguousarray(q), out)
            worst = max(worst, float(np.max(np.abs(out - robot.fk(q)))))
        exact = worst < 1e-12
    atlas_q = _atlas(robot)
    packed_atlas = pack(make_atlas(atlas_q, np.array([robot.fk(q) for q in atlas_q])))
    atlas = unpacked(packed_atlas)
    packed_chain = pack(exact_chain(robot))
    roll_model = None if g is None else g.roll_model
    return ArmState(
        robot=robot,
        arrays=arrays,
        chain=unpacked(packed_chain),
        weights=1.0 / robot.limits.velocity,
        exact=exact,
        atlas=atlas,
        reach=float(np.max(np.linalg.norm(atlas.p, axis=1))),
        rolls_tool=g is not None and g.roll is not None and roll_model is not None and roll_model.reach > 1e-9,
        buffers=Buffers(robot.nq),
        packed_arm=packed_arm,
        packed_family=None if arrays is None else pack(arrays.family),
        packed_chain=packed_chain,
        packed_atlas=packed_atlas,
    )
