"""An arm's collision shapes and its world: the URDF's ``<collision>`` elements (simple shapes:
boxes, cylinders, capsules, spheres) in Pinocchio's geometry model, the ground plane below the
arm, and the pairs that are checked, with coal (which Pinocchio ships).

Checked pairs: every two shapes on links that move apart, except

- neighbours: the shapes of two links joined by one joint, counting a link without shapes as
  part of the joint between its neighbours (a turret between the yaw and the shoulder joints:
  the base and the upper arm touch at the pivot by design);
- two shapes fixed to the base (neither ever moves);
- the pairs ``robot.toml`` allows (``[collision] allowed``: link names, as an SRDF's disabled
  pairs), for parts that touch by design though not neighbours.

The ground (``[world] ground``: the height [m] of the floor in the base frame; the plane z = 0
by default; ``false``: none) and the obstacles (:class:`Obstacle`: boxes, spheres, cylinders
fixed in the base frame) are checked against every shape that moves.
"""

from __future__ import annotations

import functools
import itertools
import math
import threading
import warnings
from collections.abc import Iterable
from typing import NamedTuple

import coal
import numpy as np
import pinocchio as pin
from numpy.typing import NDArray

from .types import FloatArray

GROUND = "ground"  # the name the ground plane goes by in a colliding pair


class Obstacle(NamedTuple):
    """A shape fixed in the base frame: ``kind`` ``"box"`` (``size``: full x, y, z extents
    [m]), ``"sphere"`` (``size``: [radius]) or ``"cylinder"`` (``size``: [radius, length],
    along its own z); centred at ``position`` [m], turned by ``rpy`` [rad] (roll, pitch, yaw
    about x, y, z)."""

    name: str
    kind: str
    size: tuple[float, ...]
    position: tuple[float, float, float]
    rpy: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def shape(self) -> object:
        if self.kind == "box":
            return coal.Box(*self.size)
        if self.kind == "sphere":
            return coal.Sphere(self.size[0])
        if self.kind == "cylinder":
            return coal.Cylinder(self.size[0], self.size[1])
        raise ValueError(f"an obstacle is a box, a sphere or a cylinder, not {self.kind!r}")

    def placement(self) -> pin.SE3:
        return pin.SE3(pin.rpy.rpyToMatrix(*self.rpy), np.array(self.position, dtype=float))


SIZES = {"box": 3, "sphere": 1, "cylinder": 2}  # how many numbers each kind's size takes


class Contact(NamedTuple):
    """Two things in collision: link names (or :data:`GROUND`)."""

    first: str
    second: str

    def __str__(self) -> str:
        return f"{self.first} and {self.second}"


class CollisionModel:
    """The shapes of one arm (``model``, built from ``urdf_text``) and its ground, ready to be
    checked at any joint vector. Thread-safe (each thread its own scratch)."""

    def __init__(
        self,
        model: pin.Model,
        urdf_text: str,
        ground: float | None = 0.0,
        allowed: Iterable[tuple[str, str]] = (),
        obstacles: Iterable[Obstacle] = (),
        package_dirs: Iterable[str] = (),
    ) -> None:
        self.model = model
        self.package_dirs = tuple(package_dirs)
        self.urdf_text = urdf_text
        self.ground = ground
        self.allowed = tuple(allowed)
        self.obstacles = tuple(obstacles)
        geom = pin.buildGeomFromUrdfString(
            model, urdf_text, pin.GeometryType.COLLISION, package_dirs=list(package_dirs)
        )
        self.links = [model.frames[g.parentFrame].name for g in geom.geometryObjects]
        joints = [int(g.parentJoint) for g in geom.geometryObjects]
        world: list[tuple[str, pin.SE3, object]] = []
        if ground is not None:
            world.append((GROUND, pin.SE3(np.eye(3), np.array([0.0, 0.0, ground])), coal.Halfspace(0, 0, 1, 0)))
        world += [(o.name, o.placement(), o.shape()) for o in self.obstacles]
        for name, placement, shape in world:
            geom.addGeometryObject(pin.GeometryObject(name, 0, 0, placement, shape))
            self.links.append(name)
            joints.append(-1)  # (the world's, not the base's: checked against everything that moves)
        shaped = {j for j in joints if j >= 0}
        allow = {frozenset(p) for p in self.allowed}
        self.pairs: list[Contact] = []
        for a, b in itertools.combinations(range(len(self.links)), 2):
            ja, jb = joints[a], joints[b]
            if min(ja, jb) < 0:  # the world: against what moves (the base stands on the floor)
                if max(ja, jb) <= 0:
                    continue
            elif ja == jb or self._neighbours(ja, jb, shaped):  # (ja == jb == 0: both fixed to the base)
                continue
            if frozenset((self.links[a], self.links[b])) in allow:
                continue
            geom.addCollisionPair(pin.CollisionPair(a, b))
            self.pairs.append(Contact(self.links[a], self.links[b]))
        self.geometry = geom
        self._local = threading.local()
        self.derived: dict[
            str, object
        ] = {}  # what other layers build from this world and keep with it (as Robot.derived)

    def describe(self) -> dict[str, object]:
        """A JSON-ready summary (the protocol's ``info``): the floor's height [m] (None: none),
        the obstacles, and the pairs checked."""
        return {
            "ground": self.ground,
            "obstacles": [
                {
                    "name": o.name,
                    "shape": o.kind,
                    "size": list(o.size),
                    "position": list(o.position),
                    "rpy": list(o.rpy),
                }
                for o in self.obstacles
            ],
            "pairs": [[p.first, p.second] for p in self.pairs],
        }

    def with_obstacles(self, obstacles: Iterable[Obstacle]) -> CollisionModel:
        """The same arm and floor among ``obstacles`` instead (built anew: ~0.3 ms)."""
        return CollisionModel(self.model, self.urdf_text, self.ground, self.allowed, obstacles, self.package_dirs)

    def _neighbours(self, ja: int, jb: int, shaped: set[int]) -> bool:
        """Whether the links of joints ``ja`` and ``jb`` meet at one joint, links without shapes
        counting as part of the joints around them."""
        for lo, hi in ((ja, jb), (jb, ja)):
            j = int(self.model.parents[hi])
            while True:
                if j == lo:
                    return True
                if j in shaped or j == 0:
                    break
                j = int(self.model.parents[j])
        return False

    def _scratch(self) -> tuple[pin.Data, pin.GeometryData]:
        scratch = getattr(self._local, "scratch", None)
        if scratch is None:
            gdata = pin.GeometryData(self.geometry)
            with warnings.catch_warnings():  # (the flag is deprecated, but still read, and on by default)
                warnings.simplefilter("ignore", DeprecationWarning)
                for request in gdata.collisionRequests:
                    # GJK from the last call's guess: after other calls, a pair whose boxes overlap
                    # was said clear (coal 3.0.2, 2,994 of 3,000 times in a test); every call from
                    # the default guess instead (tests/test_collision.py)
                    request.enable_cached_gjk_guess = False
                    request.gjk_initial_guess = coal.GJKInitialGuess.DefaultGuess
                for drequest in gdata.distanceRequests:
                    drequest.enable_cached_gjk_guess = False
                    drequest.gjk_initial_guess = coal.GJKInitialGuess.DefaultGuess
            scratch = (self.model.createData(), gdata)
            self._local.scratch = scratch
        return scratch

    def clearance(self, q: FloatArray) -> tuple[float, Contact | None]:
        """The smallest distance [m] between the shapes of a checked pair at ``q`` [rad] and that
        pair (0 or less: in contact); (inf, None) when no pair is checked."""
        if not self.pairs:
            return math.inf, None
        data, gdata = self._scratch()
        k = int(pin.computeDistances(self.model, data, self.geometry, gdata, np.asarray(q, dtype=float)))
        return float(gdata.distanceResults[k].min_distance), self.pairs[k]

    @functools.cached_property
    def travel(self) -> FloatArray:
        """How far [m] any point of any moving shape may go per radian of each joint (per metre of
        a prismatic one), at most: a straight move of the joints by ``dq`` moves no point of the
        arm farther than ``abs(dq) @ travel``. From the URDF's geometry: the distance from each
        joint's origin to the farthest point of every shape it carries (its own link's and every
        link beyond it), bounded along the chain by the joints' offsets (triangle inequality),
        summed over the joints a coordinate drives (a mimic joint by its scaling)."""
        model, geom = self.model, self.geometry
        reach = np.zeros(model.njoints)  # joint -> farthest carried point from its origin [m]
        extra = np.zeros(model.njoints)  # a prismatic joint's own stroke, added above it
        for j in range(1, model.njoints):
            if "Prismatic" in model.joints[j].shortname():
                k = model.joints[j].idx_q
                extra[j] = float(max(abs(model.lowerPositionLimit[k]), abs(model.upperPositionLimit[k])))
        for g in geom.geometryObjects:
            j = int(g.parentJoint)
            if j <= 0:
                continue
            g.geometry.computeLocalAABB()
            centre = g.placement.act(np.asarray(g.geometry.aabb_center, dtype=float))
            r = float(np.linalg.norm(centre)) + float(g.geometry.aabb_radius)
            while j > 0:  # up the chain: each parent's origin is farther by the child's offset
                reach[j] = max(reach[j], r)
                r += extra[j] + float(np.linalg.norm(model.jointPlacements[j].translation))
                j = int(model.parents[j])
        out = np.zeros(model.nq)
        for j in range(1, model.njoints):
            joint = model.joints[j]
            scale = abs(float(joint.extract().scaling)) if "Mimic" in joint.shortname() else 1.0
            per = 1.0 if "Prismatic" in joint.shortname() else reach[j]
            for k in range(joint.idx_q, joint.idx_q + max(joint.nq, 1)):
                if k < model.nq:
                    out[k] += scale * per
        return out

    def first_contact(self, q: FloatArray) -> Contact | None:
        """The first pair in collision at ``q`` [rad], or None: the arm is clear of itself and
        the ground."""
        data, gdata = self._scratch()
        if not pin.computeCollisions(self.model, data, self.geometry, gdata, np.asarray(q, dtype=float), True):
            return None
        for k, result in enumerate(gdata.collisionResults):
            if result.isCollision():
                return self.pairs[k]
        return None  # (not reached: computeCollisions said there was one)

    def colliding(self, Q: FloatArray) -> NDArray[np.bool_]:
        """Whether each row of ``Q`` (m, n) [rad] has a pair in collision."""
        return np.array([self.first_contact(q) is not None for q in np.asarray(Q, dtype=float)], dtype=bool)

    def contacts(self, q: FloatArray) -> list[Contact]:
        """Every pair in collision at ``q`` [rad]."""
        data, gdata = self._scratch()
        pin.computeCollisions(self.model, data, self.geometry, gdata, np.asarray(q, dtype=float), False)
        return [self.pairs[k] for k, r in enumerate(gdata.collisionResults) if r.isCollision()]
