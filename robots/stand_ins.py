"""What robot.toml's ``[collision]`` says of single links: the URDF's collision elements edited
before Pinocchio reads them.

- ``skip = ["link", ...]``: those links' collision shapes are not loaded (their meshes need not
  exist): the links are never checked, and ``info`` says so;
- ``[collision.stand_in.LINK]``: the link's collision shapes replaced by one primitive in the
  link's frame: ``box = [x, y, z]``, ``sphere = r`` or ``cylinder = [r, length]`` (along its z)
  [m], placed by ``xyz`` [m] and ``rpy`` [rad] (default 0): for a link whose mesh is missing or
  unusable, or too heavy to check;
- ``meshes_optional = true``: a collision mesh that cannot be used (missing, over its cap, not a
  format armd reads) is left out, said (in the log and in ``info``), and the arm is served with
  everything else checked: its other shapes, the floor and the obstacles. Without it such a mesh
  refuses the arm, naming every one (robots/checks.py).
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections.abc import Mapping
from typing import NamedTuple

from armd.errors import RobotFileError

SHAPES = {"box": 3, "sphere": 1, "cylinder": 2}  # a stand-in's shape: how many sizes [m] it takes


class StandIn(NamedTuple):
    """One primitive standing in for a link's collision shapes, in the link's frame."""

    shape: str  # a key of SHAPES
    size: tuple[float, ...]  # box: x, y, z; sphere: radius; cylinder: radius, length [m]
    xyz: tuple[float, float, float]  # [m]
    rpy: tuple[float, float, float]  # [rad]

    def describe(self) -> str:
        sizes = " x ".join(f"{s:g}" for s in self.size)
        return f"{self.shape} {sizes} m (robot.toml stand_in)"

    def element(self) -> ET.Element:
        """The URDF ``<collision>`` element of this primitive."""
        part = ET.Element("collision")
        ET.SubElement(part, "origin", xyz=" ".join(map(repr, self.xyz)), rpy=" ".join(map(repr, self.rpy)))
        geometry = ET.SubElement(part, "geometry")
        if self.shape == "box":
            ET.SubElement(geometry, "box", size=" ".join(map(repr, self.size)))
        elif self.shape == "sphere":
            ET.SubElement(geometry, "sphere", radius=repr(self.size[0]))
        else:
            ET.SubElement(geometry, "cylinder", radius=repr(self.size[0]), length=repr(self.size[1]))
        return part


class CollisionEdits(NamedTuple):
    """robot.toml's word on single links' collision shapes (see the module's doc)."""

    toml_file: str
    skip: tuple[str, ...] = ()
    stand_in: Mapping[str, StandIn] = {}
    meshes_optional: bool = False

    def apply(self, root: ET.Element) -> dict[str, str]:
        """The URDF ``root`` edited in place: each skipped link's collision elements removed,
        each stood-in link's replaced by its primitive. Returns what each of those links is
        checked as (``info``). A link the URDF lacks is a RobotFileError naming robot.toml's field."""
        links = {link.get("name"): link for link in root.findall("link")}
        said: dict[str, str] = {}
        for field, names in (("collision.skip", self.skip), ("collision.stand_in", tuple(self.stand_in))):
            for name in names:
                if name not in links:
                    raise RobotFileError(
                        self.toml_file,
                        field,
                        f"the URDF has no link {name!r}; links: {', '.join(sorted(map(str, links)))}",
                    )
        for name in self.skip:
            if name in self.stand_in:
                raise RobotFileError(self.toml_file, "collision.skip", f"{name!r} is both skipped and stood in for")
            for part in links[name].findall("collision"):
                links[name].remove(part)
            said[name] = "not checked (robot.toml skip)"
        for name, stand_in in self.stand_in.items():
            for part in links[name].findall("collision"):
                links[name].remove(part)
            links[name].append(stand_in.element())
            said[name] = stand_in.describe()
        return said
