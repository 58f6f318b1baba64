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
by default; ``false``: none) is checked against every shape that moves.
"""

from __future__ import annotations

import itertools
import threading
from collections.abc import Iterable
from typing import NamedTuple

import coal
import numpy as np
import pinocchio as pin

from .types import FloatArray

GROUND = "ground"  # the name the ground plane goes by in a colliding pair


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
    ) -> None:
        self.model = model
        self.ground = ground
        geom = pin.buildGeomFromUrdfString(model, urdf_text, pin.GeometryType.COLLISION)
        self.links = [model.frames[g.parentFrame].name for g in geom.geometryObjects]
        joints = [int(g.parentJoint) for g in geom.geometryObjects]
        if ground is not None:
            plane = pin.GeometryObject(
                GROUND, 0, 0, pin.SE3(np.eye(3), np.array([0.0, 0.0, ground])), coal.Halfspace(0, 0, 1, 0)
            )
            geom.addGeometryObject(plane)
            self.links.append(GROUND)
            joints.append(-1)  # (the world's, not the base's: checked against everything that moves)
        shaped = {j for j in joints if j >= 0}
        allow = {frozenset(p) for p in allowed}
        self.pairs: list[Contact] = []
        for a, b in itertools.combinations(range(len(self.links)), 2):
            ja, jb = joints[a], joints[b]
            if GROUND in (self.links[a], self.links[b]):
                if max(ja, jb) == 0:  # the ground and the base: the base stands on it
                    continue
            elif ja == jb or self._neighbours(ja, jb, shaped):  # (ja == jb == 0: both fixed to the base)
                continue
            if frozenset((self.links[a], self.links[b])) in allow:
                continue
            geom.addCollisionPair(pin.CollisionPair(a, b))
            self.pairs.append(Contact(self.links[a], self.links[b]))
        self.geometry = geom
        self._local = threading.local()

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
            scratch = (self.model.createData(), pin.GeometryData(self.geometry))
            self._local.scratch = scratch
        return scratch

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

    def contacts(self, q: FloatArray) -> list[Contact]:
        """Every pair in collision at ``q`` [rad]."""
        data, gdata = self._scratch()
        pin.computeCollisions(self.model, data, self.geometry, gdata, np.asarray(q, dtype=float), False)
        return [self.pairs[k] for k, r in enumerate(gdata.collisionResults) if r.isCollision()]
