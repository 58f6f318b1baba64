"""An arm's world for the compiled collision stage: :class:`CompiledWorld`, built from its
:class:`~armd.robots.collision.CollisionModel` by :func:`compile_world`.

The builder reads the collision model's Pinocchio geometry model (each geometry object's coal
shape, the joint it hangs on and its placement there; the ground and the obstacles on the base
frame) and its checked pairs, and the joint tree of its Pinocchio model
(:class:`~armd.solvers.tree.Tree`). Primitive shapes (coal's ``Sphere``, ``Capsule``, ``Box``,
``Cylinder``, ``Halfspace``) on revolute or prismatic joints (mimic ones included) go into
:class:`~armd.solvers.collide.Shapes`; anything else stays on coal, and
:attr:`CompiledWorld.unsupported` says which shapes and why (a mesh, a cone, a continuous
joint's link), :attr:`CompiledWorld.on_coal` which pairs.

:class:`CompiledWorld` answers as the collision model does (:meth:`~CompiledWorld.first_contact`,
:meth:`~CompiledWorld.contacts`, :meth:`~CompiledWorld.clearance`), the same pairs in the same
order: the compiled pairs by one compiled call, the pairs on coal through Pinocchio after it,
merged in the model's order. It keeps the shapes packed (:attr:`~CompiledWorld.packed_shapes`:
what the compiled calls take, :mod:`armd.solvers.packed`) and as a :class:`Shapes` of views of the
same arrays (:attr:`~CompiledWorld.shapes`). :func:`compiled` keeps one per collision model: what the solver,
the planner and the tracker check with.
"""

from __future__ import annotations

import logging
import math
import threading
from typing import NamedTuple, Protocol

import coal
import numpy as np
import pinocchio as pin
from numpy.typing import NDArray

from armd.robots.collision import CollisionModel, Contact
from armd.robots.types import FloatArray

from .collide import Shapes, first_collision, first_collisions, min_distance, pair_distances
from .narrowphase import BOX, CAPSULE, CYLINDER, HALFSPACE, SIZE, SPHERE, TOUCH
from .packed import Packed, pack, unpacked
from .tree import FIXED, PRISMATIC, REVOLUTE, Tree

log = logging.getLogger(__name__)

# the joint models whose motion the tree computes (a mimic joint: if its S is one of these kinds')
JOINTS = {
    "JointModelRX",
    "JointModelRY",
    "JointModelRZ",
    "JointModelRevoluteUnaligned",
    "JointModelPX",
    "JointModelPY",
    "JointModelPZ",
    "JointModelPrismaticUnaligned",
    "JointModelMimic",
}


class World(Protocol):
    """What the solver checks an answer against: an arm's world, its floor and its pairs (a
    :class:`~armd.robots.collision.CollisionModel` through coal, or its :class:`CompiledWorld`)."""

    @property
    def ground(self) -> float | None: ...

    def first_contact(self, q: FloatArray) -> Contact | None: ...

    def colliding(self, Q: FloatArray) -> NDArray[np.bool_]: ...

    def contacts(self, q: FloatArray) -> list[Contact]: ...

    def clearance(self, q: FloatArray) -> tuple[float, Contact | None]: ...


class Unsupported(NamedTuple):
    """A shape the compiled stage leaves to coal, and why."""

    name: str  # the geometry object's name (a link's shape: ``<link>_<k>``; the ground, an obstacle: its name)
    reason: str


def _c(a: FloatArray) -> FloatArray:
    return np.ascontiguousarray(a, dtype=np.float64)


def tree_of(model: pin.Model) -> tuple[Tree, dict[int, str]]:
    """``model``'s joint tree (:class:`Tree`: row j, Pinocchio's joint j), and the joints it
    cannot move, with why (a joint below one of them inherits it): their rows are fixed."""
    J = model.njoints
    parent = np.full(J, -1, dtype=np.int64)
    placement = np.zeros((J, 4, 4))
    axis = np.zeros((J, 3))
    axis[:, 2] = 1.0
    kind = np.full(J, FIXED, dtype=np.int64)
    coordinate = np.zeros(J, dtype=np.int64)
    scale, offset = np.ones(J), np.zeros(J)
    placement[0] = np.eye(4)
    data = model.createData()
    pin.forwardKinematics(model, data, pin.neutral(model))
    bad: dict[int, str] = {}
    for j in range(1, J):
        jm = model.joints[j]
        parent[j] = int(model.parents[j])
        placement[j] = model.jointPlacements[j].homogeneous
        if parent[j] in bad:
            bad[j] = bad[int(parent[j])]
            continue
        name = jm.shortname()
        S = np.array(data.joints[j].S).reshape(-1)
        if name not in JOINTS or S.shape != (6,):
            bad[j] = f"joint {model.names[j]!r} is a {name}: the compiled stage moves revolute and prismatic joints"
            continue
        linear, angular = S[:3], S[3:]
        if name == "JointModelMimic":
            mimic = jm.extract()
            scale[j], offset[j] = float(mimic.scaling), float(mimic.offset)
        if np.linalg.norm(angular) > 1e-12 and np.linalg.norm(linear) <= 1e-12:
            kind[j], moving = REVOLUTE, angular
        elif np.linalg.norm(angular) <= 1e-12 and np.linalg.norm(linear) > 1e-12:
            kind[j], moving = PRISMATIC, linear
        else:
            bad[j] = f"joint {model.names[j]!r} moves as neither a revolute nor a prismatic joint"
            continue
        a = moving / (scale[j] if scale[j] != 0.0 else 1.0)  # (a mimic's S is scaled)
        axis[j] = a / np.linalg.norm(a)
        coordinate[j] = jm.idx_q
    tree = Tree(parent, _c(placement), _c(axis), kind, coordinate, _c(scale), _c(offset))
    return tree, bad


def primitive(shape: object) -> tuple[int, FloatArray, int, tuple[float, float]] | str:
    """A coal shape as the compiled stage's kind and size (4,), with a capsule about its origin
    holding it (its axis in the shape's frame, its half-length and radius [m]); or why not."""
    if float(getattr(shape, "getSweptSphereRadius", lambda: 0.0)()) != 0.0:
        return f"a {type(shape).__name__} with a swept-sphere radius"
    size = np.zeros(SIZE)
    if isinstance(shape, coal.Sphere):
        size[0] = shape.radius
        return SPHERE, size, 2, (0.0, float(shape.radius))
    if isinstance(shape, coal.Capsule):
        size[:2] = shape.radius, shape.halfLength
        return CAPSULE, size, 2, (float(shape.halfLength), float(shape.radius))
    if isinstance(shape, coal.Box):
        size[:3] = np.asarray(shape.halfSide, dtype=float)
        k = int(np.argmax(size[:3]))  # along its longest side, as thick as its diagonal across
        i, j = (k + 1) % 3, (k + 2) % 3
        return BOX, size, k, (float(size[k]), float(math.hypot(size[i], size[j])))
    if isinstance(shape, coal.Cylinder):
        size[:2] = shape.radius, shape.halfLength
        return CYLINDER, size, 2, (float(shape.halfLength), float(shape.radius))
    if isinstance(shape, coal.Halfspace):
        n = np.asarray(shape.n, dtype=float)
        norm = float(np.linalg.norm(n))
        size[:3], size[3] = n / norm, float(shape.d) / norm
        return HALFSPACE, size, 2, (math.inf, math.inf)
    kind = type(shape).__name__
    what = "a mesh" if kind.startswith(("BVHModel", "Convex")) else f"a {kind}"
    return f"{what}: the compiled stage takes spheres, capsules, boxes, cylinders and half-spaces"


class CompiledWorld:
    """``world``'s shapes and pairs as the compiled stage checks them (the module's doc)."""

    def __init__(self, world: CollisionModel) -> None:
        self.world = world
        geom = world.geometry
        tree, bad_joints = tree_of(world.model)
        rows: dict[int, int] = {}  # geometry object -> compiled shape
        kinds: list[int] = []
        sizes: list[FloatArray] = []
        joints: list[int] = []
        locals_: list[FloatArray] = []
        axes: list[int] = []
        bounds: list[tuple[float, float]] = []
        unsupported: list[Unsupported] = []
        for k, g in enumerate(geom.geometryObjects):
            j = int(g.parentJoint)
            got = primitive(g.geometry)
            if j in bad_joints:
                unsupported.append(Unsupported(g.name, bad_joints[j]))
                continue
            if isinstance(got, str):
                unsupported.append(Unsupported(g.name, got))
                continue
            rows[k] = len(kinds)
            kinds.append(got[0])
            sizes.append(got[1])
            joints.append(j)
            locals_.append(g.placement.homogeneous)
            axes.append(got[2])
            bounds.append(got[3])
        compiled, pairs = [], []
        coal_pairs = []
        for index, cp in enumerate(geom.collisionPairs):
            a, b = int(cp.first), int(cp.second)
            if a in rows and b in rows and not (kinds[rows[a]] == HALFSPACE and kinds[rows[b]] == HALFSPACE):
                compiled.append(index)
                first, second = rows[a], rows[b]
                if kinds[first] == HALFSPACE:  # (a half-space second: the compiled loop's fast path)
                    first, second = second, first
                pairs.append((first, second))
            else:
                coal_pairs.append(index)
        # what the entry points take (solvers.packed), and the same memory as a Shapes for Python
        self.packed_shapes: Packed = pack(
            Shapes(
                tree,
                np.array(kinds, dtype=np.int64),
                _c(np.array(sizes).reshape(len(kinds), SIZE)),
                np.array(joints, dtype=np.int64),
                _c(np.array(locals_).reshape(len(kinds), 4, 4)),
                np.array(axes, dtype=np.int64),
                _c(np.array(bounds).reshape(len(kinds), 2)),
                np.array(pairs, dtype=np.int64).reshape(len(pairs), 2),
            )
        )
        self.shapes: Shapes = unpacked(self.packed_shapes)
        self.n_compiled = len(pairs)  # the pairs the compiled stage checks
        self.unsupported: tuple[Unsupported, ...] = tuple(unsupported)
        self.compiled_pairs = np.array(compiled, dtype=np.int64)  # each compiled pair's index in world.pairs
        self.coal_pairs: tuple[int, ...] = tuple(coal_pairs)  # the indices in world.pairs left to coal
        self.on_coal: tuple[Contact, ...] = tuple(world.pairs[k] for k in coal_pairs)
        if unsupported:
            log.info(
                "%d of %d pairs stay on coal: %s",
                len(coal_pairs),
                len(world.pairs),
                "; ".join(f"{u.name}: {u.reason}" for u in unsupported),
            )

    @property
    def ground(self) -> float | None:
        """The floor's height [m] (None: none), as the collision model's."""
        return self.world.ground

    @property
    def pairs(self) -> list[Contact]:
        """Every pair checked, in the collision model's order (the compiled ones and coal's)."""
        return self.world.pairs

    def _coal(self, q: FloatArray) -> pin.GeometryData:
        """The collision model's own scratch (its requests' settings) with its shapes placed at
        ``q``: for the pairs on coal."""
        data, gdata = self.world._scratch()
        pin.updateGeometryPlacements(self.world.model, data, self.world.geometry, gdata, q)
        return gdata

    def first_contact(self, q: FloatArray) -> Contact | None:
        """The first pair in collision at ``q`` [rad], or None (as
        :meth:`CollisionModel.first_contact`)."""
        q = np.ascontiguousarray(q, dtype=np.float64)
        p = int(first_collision(self.packed_shapes, q)) if self.n_compiled else -1
        first = int(self.compiled_pairs[p]) if p >= 0 else len(self.world.pairs)
        if self.coal_pairs and self.coal_pairs[0] < first:
            gdata = self._coal(q)
            for k in self.coal_pairs:
                if k >= first:
                    break
                if pin.computeCollision(self.world.geometry, gdata, k):
                    first = k
                    break
        return self.world.pairs[first] if first < len(self.world.pairs) else None

    def colliding(self, Q: FloatArray) -> NDArray[np.bool_]:
        """Whether each row of ``Q`` (m, n) [rad] has a pair in collision: one compiled call
        (the pairs on coal after it, for the rows it found clear)."""
        Q = np.ascontiguousarray(Q, dtype=np.float64)
        out = np.full(len(Q), -1, dtype=np.int64)
        if self.n_compiled and len(Q):
            first_collisions(self.packed_shapes, Q, out)
        hit = out >= 0
        if self.coal_pairs:
            for i in np.flatnonzero(~hit).tolist():
                gdata = self._coal(Q[i])
                hit[i] = any(pin.computeCollision(self.world.geometry, gdata, k) for k in self.coal_pairs)
        return hit

    def contacts(self, q: FloatArray) -> list[Contact]:
        """Every pair in collision at ``q`` [rad] (as :meth:`CollisionModel.contacts`)."""
        q = np.ascontiguousarray(q, dtype=np.float64)
        hit = sorted(int(self.compiled_pairs[p]) for p in np.flatnonzero(self.distances(q) <= TOUCH))
        if self.coal_pairs:
            gdata = self._coal(q)
            hit = sorted(hit + [k for k in self.coal_pairs if pin.computeCollision(self.world.geometry, gdata, k)])
        return [self.world.pairs[k] for k in hit]

    def distances(self, q: FloatArray) -> FloatArray:
        """Each compiled pair's distance [m] at ``q`` (<= TOUCH: in contact), in the order of
        :attr:`compiled_pairs`."""
        out = np.empty(self.n_compiled)
        if self.n_compiled:
            pair_distances(self.packed_shapes, np.ascontiguousarray(q, dtype=np.float64), out)
        return out

    def clearance(self, q: FloatArray) -> tuple[float, Contact | None]:
        """The smallest distance [m] between the shapes of a checked pair at ``q`` and that pair
        (<= TOUCH with a pair in contact: the first in contact among the compiled ones, not the
        deepest as coal's; as :meth:`CollisionModel.clearance` otherwise); (inf, None) when no
        pair is checked."""
        q = np.ascontiguousarray(q, dtype=np.float64)
        d, p = min_distance(self.packed_shapes, q) if self.n_compiled else (math.inf, -1)
        best, which = float(d), (int(self.compiled_pairs[p]) if p >= 0 else -1)
        if self.coal_pairs and best > TOUCH:
            gdata = self._coal(q)
            for k in self.coal_pairs:
                dk = float(pin.computeDistance(self.world.geometry, gdata, k).min_distance)
                if dk < best or (dk == best and k < which):
                    best, which = dk, k
        return best, (self.world.pairs[which] if which >= 0 else None)


def compile_world(world: CollisionModel) -> CompiledWorld:
    """``world`` for the compiled stage (about a millisecond: build it once per world)."""
    return CompiledWorld(world)


_compiling = threading.Lock()


def compiled(world: CollisionModel) -> CompiledWorld:
    """``world``'s :class:`CompiledWorld`, built on first use and kept in ``world.derived`` (as
    the solver's state in ``Robot.derived``; a weak map would keep it for ever, the compiled
    world holding its model; a world with other obstacles is another collision model, compiled
    anew)."""
    got = world.derived.get("compiled")
    if got is None:
        with _compiling:
            got = world.derived.get("compiled")
            if got is None:
                got = world.derived["compiled"] = CompiledWorld(world)
    assert isinstance(got, CompiledWorld)
    return got
