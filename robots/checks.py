"""A user's arm folder, checked before anything of it is built.

Pinocchio and urdfdom trust their input: a chain 10,000 joints deep overflows urdfdom's stack (a
segfault, no error to catch), a URDF names any file as a mesh (``/dev/zero``, ``/etc/passwd``,
``../../x``) and assimp reads it, an STL's header may claim 10^9 triangles, and limits of 1e308
break every sum the planner takes. So the loader (:mod:`robots.catalogue`) reads an arm's files
only through this module, which caps what it reads and refuses, with a :class:`RobotFileError`
naming the file, the element and what is wrong:

- files (``robot.toml``, the URDF, the meshes) only from inside the arm's folder: no absolute path
  outside it, no ``..``, no symbolic link out of it, no device, pipe or folder; each one under its
  size cap;
- the URDF as XML first (expat, no ``<!DOCTYPE>``, so no entities), then its joints (at most
  :data:`MAX_JOINTS`), its tree (one root, no cycle, at most :data:`MAX_DEPTH` joints deep) and
  every number Pinocchio reads from it (finite, within a small arm's magnitudes); only then
  Pinocchio;
- each mesh: one of the formats below, under :data:`MAX_MESH_BYTES`, a binary STL's triangle count
  as its size says and at most :data:`MAX_TRIANGLES`. A mesh that cannot be used refuses the arm,
  naming every one, unless robot.toml stands in for its link or skips it, or says ``[collision]
  meshes_optional = true`` (then that mesh is left out and said, and everything else is checked:
  :mod:`robots.stand_ins`). A mesh outside the folder, or not a regular file, refuses the arm
  whatever robot.toml says: it is never opened;
- the limits, as robot.toml and the URDF give them together (:func:`check_limits`).

Units: positions [rad] (or [m] for a prismatic joint), lengths [m], rates per second.
"""

from __future__ import annotations

import math
import os
import stat
import xml.etree.ElementTree as ET
from pathlib import Path, PurePosixPath
from typing import NamedTuple
from xml.parsers import expat

from armd.errors import FileProblem, RobotFileError

from .limits import JointLimits
from .stand_ins import CollisionEdits

# What a small arm's folder holds, with room to spare; each cap is what a bigger file or number
# would cost or break:
MAX_TOML_BYTES = 1 << 20  # robot.toml: the catalogue's are under 10 kB; read whole, then parsed
MAX_URDF_BYTES = 4 << 20  # the URDF: a vendor's is under 100 kB; read whole, parsed twice (here, then Pinocchio)
MAX_XML_ELEMENTS = 20_000  # XML elements in the URDF: an arm's is a few hundred
MAX_XML_DEPTH = 16  # nesting of XML elements: URDF's is 5 (robot, link, collision, geometry, mesh)
MAX_JOINTS = 128  # <joint> elements, fixed ones included: Pinocchio's model, armd's loops are per joint
MAX_DEPTH = 64  # joints from the URDF's root to its deepest link: urdfdom recurses along the chain
MAX_POSITION = 100.0  # [rad] (or [m]) a joint limit or offset: the largest joint value the protocol takes
MAX_LENGTH = 100.0  # [m] an origin's offset, a shape's size: no small arm is a hundred metres across
MAX_FACTOR = 1e3  # an axis component, a mimic multiplier, a mesh scale, a coupled limit's coefficient
MAX_VELOCITY = 1e3  # [rad/s] (or [m/s]) a velocity limit: 10,000 rpm
MAX_ACCELERATION = 1e5  # [rad/s^2] an acceleration limit
MAX_JERK = 1e7  # [rad/s^3] a jerk limit
MAX_MESH_BYTES = 16 << 20  # one mesh file: a vendor's arm link is under 2 MB
MAX_MESHES_BYTES = 64 << 20  # every mesh of one arm together
MAX_TRIANGLES = 250_000  # one mesh's triangles: coal builds a bounding-volume tree over them at load
MESH_FORMATS = (".stl", ".dae", ".obj")  # what vendors' URDFs use; assimp reads many more, none needed
_STL_HEADER = 84  # [bytes] a binary STL: 80 bytes of header, then the triangle count (uint32)
_STL_TRIANGLE = 50  # [bytes] a binary STL's triangle: normal, 3 vertices (float32 x 12), 2 bytes


class CheckedUrdf(NamedTuple):
    """An arm's URDF, checked: ``text`` as Pinocchio is to read it (each usable mesh named by its
    checked path inside the folder, robot.toml's stand-ins and skips applied); ``unusable``: the
    meshes that cannot be used and why (only with ``meshes_optional``, else they refuse the arm);
    ``links``: what robot.toml changed of a link's collision shapes, or why they were left out."""

    text: str
    unusable: tuple[str, ...]
    links: dict[str, str]


# -- files --------------------------------------------------------------------------------------


def _inside(folder: Path, name: str) -> Path:
    """The file ``name`` (a path relative to the arm's folder, ``package://`` (the folder is the
    package's root) or ``file://``) as a real path inside ``folder``; raises :class:`FileProblem`
    (forbidden) for another scheme, a ``..``, or a path or link that leaves the folder."""
    text = name.strip()
    if not text:
        raise FileProblem("names no file", forbidden=False)
    for scheme in ("package://", "file://"):
        if text.startswith(scheme):
            text = text[len(scheme) :]
            break
    else:
        if "://" in text:
            raise FileProblem("must be a path in the arm's folder (package://, file:// or relative)", forbidden=True)
    path = PurePosixPath(text)
    if ".." in path.parts:
        raise FileProblem("must not go up a folder ('..'): an arm's files are in its own folder", forbidden=True)
    root = folder.resolve()
    real = (root / path).resolve()  # (an absolute path replaces root; links resolved)
    if real != root and root not in real.parents:
        raise FileProblem(f"is outside the arm's folder {root} (as {real})", forbidden=True)
    return real


def _open(real: Path, cap: int, what: str) -> int:
    """A descriptor of the regular file ``real``, at most ``cap`` bytes long (the caller closes it)."""
    try:
        fd = os.open(real, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_NOFOLLOW", 0))
    except FileNotFoundError:
        raise FileProblem(f"{real} not found", forbidden=False) from None
    except OSError as e:
        raise FileProblem(f"{real} cannot be opened: {e.strerror}", forbidden=False) from None
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            raise FileProblem(f"{real} is not a regular file (a device, a pipe or a folder)", forbidden=True)
        if st.st_size > cap:
            raise FileProblem(f"{real} is {st.st_size:,} bytes: {what} may be at most {cap:,}", forbidden=False)
    except BaseException:
        os.close(fd)
        raise
    return fd


def _read(fd: int, cap: int) -> bytes:
    chunks, size = [], 0
    while size <= cap:
        chunk = os.read(fd, min(1 << 20, cap + 1 - size))
        if not chunk:
            break
        chunks.append(chunk)
        size += len(chunk)
    return b"".join(chunks)


def _read_file(folder: Path, name: str, cap: int, what: str, file: str, field: str | None) -> tuple[Path, bytes]:
    """The file ``name`` of the arm's ``folder`` (as :func:`_inside` finds it) and its bytes, at
    most ``cap``; a problem raises :class:`RobotFileError` for ``file`` (and ``field``), the
    file that names it."""
    try:
        real = _inside(folder, name)
        fd = _open(real, cap, what)
        try:
            data = _read(fd, cap)
        finally:
            os.close(fd)
        if len(data) > cap:  # (it grew since it was measured)
            raise FileProblem(f"{real} is over {cap:,} bytes: {what} may be at most {cap:,}", forbidden=False)
    except FileProblem as p:
        raise RobotFileError(file, field, f"{name!r}: {p.problem}") from None
    return real, data


def robot_toml(folder: Path) -> bytes:
    """The bytes of the arm's ``robot.toml``, checked (a regular file in the folder, under its cap)."""
    return _read_file(folder, "robot.toml", MAX_TOML_BYTES, "robot.toml", str(folder / "robot.toml"), None)[1]


# -- the URDF -----------------------------------------------------------------------------------


def urdf(folder: Path, name: str, toml_file: str, edits: CollisionEdits) -> CheckedUrdf:
    """The arm's URDF ``name`` (robot.toml's ``[robot] urdf``), checked before Pinocchio reads
    it: its file, its XML, its joints and tree, its numbers and its meshes (the module's rules),
    with robot.toml's ``edits`` of single links' collision shapes (:mod:`robots.stand_ins`)."""
    real, data = _read_file(folder, name, MAX_URDF_BYTES, "a URDF", toml_file, "robot.urdf")
    file = str(real)
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError as e:
        raise RobotFileError(file, None, f"is not UTF-8 text: {e}") from None
    _scan(text, file)
    try:
        root = ET.fromstring(text)
    except ET.ParseError as e:  # (the scan parsed it already: not reached)
        raise RobotFileError(file, None, f"is not valid XML (Pinocchio cannot load it): {e}") from None
    if root.tag != "robot":
        raise RobotFileError(file, None, f"must be a <robot> element, got <{root.tag}>")
    _tree(root, file)
    links = edits.apply(root)  # (before the numbers and the meshes: a stand-in is checked as the URDF's own)
    _numbers(root, file)
    rewritten, unusable, left_out = _meshes(root, folder, file, edits.meshes_optional)
    edited = rewritten or bool(links)
    return CheckedUrdf(ET.tostring(root, encoding="unicode") if edited else text, unusable, {**links, **left_out})


def _scan(text: str, file: str) -> None:
    """One pass of expat over ``text``: well-formed, no ``<!DOCTYPE>`` (no entity can be
    declared, so none expanded), at most :data:`MAX_XML_ELEMENTS` elements nested at most
    :data:`MAX_XML_DEPTH` deep, at most :data:`MAX_JOINTS` joints; stops at the first excess."""
    parser = expat.ParserCreate()
    depth = elements = joints = 0

    def start(tag: str, attrs: object) -> None:
        nonlocal depth, elements, joints
        depth += 1
        elements += 1
        if depth > MAX_XML_DEPTH:
            raise RobotFileError(file, None, f"nests XML elements over {MAX_XML_DEPTH} deep (<{tag}>)")
        if elements > MAX_XML_ELEMENTS:
            raise RobotFileError(file, None, f"has over {MAX_XML_ELEMENTS:,} XML elements: armd reads an arm's URDF")
        if depth == 2 and tag == "joint":
            joints += 1
            if joints > MAX_JOINTS:
                raise RobotFileError(
                    file, None, f"has over {MAX_JOINTS} joints (fixed ones included): armd takes at most {MAX_JOINTS}"
                )

    def end(tag: str) -> None:
        nonlocal depth
        depth -= 1

    def doctype(*_: object) -> None:
        raise RobotFileError(file, None, "has a <!DOCTYPE>: a URDF needs none, and its entities are not expanded")

    parser.StartElementHandler = start
    parser.EndElementHandler = end
    parser.StartDoctypeDeclHandler = doctype
    parser.EntityDeclHandler = doctype
    try:
        parser.Parse(text, True)
    except expat.ExpatError as e:
        raise RobotFileError(file, None, f"is not valid XML (Pinocchio cannot load it): {e}") from None


def _tree(root: ET.Element, file: str) -> None:
    """Every joint joins two links of the URDF; the links make one tree (one root, no link with
    two parents, no cycle) at most :data:`MAX_DEPTH` joints deep."""
    links: set[str] = set()
    for link in root.findall("link"):
        name = link.get("name")
        if not name:
            raise RobotFileError(file, None, "a <link> has no name")
        if name in links:
            raise RobotFileError(file, f"link {name!r}", "is defined twice")
        links.add(name)
    parent_of: dict[str, str] = {}
    joints: set[str] = set()
    for joint in root.findall("joint"):
        jname = joint.get("name")
        if not jname:
            raise RobotFileError(file, None, "a <joint> has no name")
        if jname in joints:
            raise RobotFileError(file, f"joint {jname!r}", "is defined twice")
        joints.add(jname)
        ends: list[str] = []
        for key in ("parent", "child"):
            el = joint.find(key)
            end = el.get("link") if el is not None else None
            if end is None or end not in links:
                raise RobotFileError(file, f"joint {jname!r} <{key}>", f"names no link of the URDF: {end!r}")
            ends.append(end)
        parent, child = ends
        if child in parent_of:
            raise RobotFileError(
                file, f"joint {jname!r} <child>", f"link {child!r} is already a child of another joint"
            )
        parent_of[child] = parent
    roots = sorted(links - set(parent_of))
    if len(roots) != 1:
        raise RobotFileError(
            file,
            None,
            f"has {len(roots)} root links ({', '.join(roots[:5]) or 'every link is a child: a cycle'}): "
            "its links must make one tree",
        )
    depth: dict[str, int] = {r: 0 for r in roots}
    for at in links:
        path: list[str] = []
        seen: set[str] = set()
        while at not in depth:
            if at in seen:
                raise RobotFileError(file, f"link {at!r}", "is its own ancestor: the joints make a cycle")
            seen.add(at)
            path.append(at)
            at = parent_of[at]
        d = depth[at]
        for up in reversed(path):
            d += 1
            depth[up] = d
            if d > MAX_DEPTH:
                raise RobotFileError(
                    file,
                    f"link {up!r}",
                    f"is over {MAX_DEPTH} joints from the root: armd takes chains {MAX_DEPTH} deep",
                )


def _floats(el: ET.Element | None, attr: str, n: int, bound: float, where: str, file: str) -> list[float] | None:
    """``attr`` of ``el``: ``n`` finite numbers, each of magnitude at most ``bound`` (None: absent)."""
    if el is None or el.get(attr) is None:
        return None
    raw = el.get(attr, "")
    try:
        values = [float(v) for v in raw.split()]
    except ValueError:
        values = []
    if len(values) != n or not all(math.isfinite(v) for v in values):
        raise RobotFileError(file, f"{where} {attr}", f"must be {n} finite number{'s' if n > 1 else ''}, got {raw!r}")
    if any(abs(v) > bound for v in values):
        raise RobotFileError(file, f"{where} {attr}", f"{raw!r} is over {bound:g} in magnitude (armd's cap)")
    return values


def _origin(parent: ET.Element, where: str, file: str) -> None:
    origin = parent.find("origin")
    _floats(origin, "xyz", 3, MAX_LENGTH, f"{where} <origin>", file)
    _floats(origin, "rpy", 3, MAX_POSITION, f"{where} <origin>", file)


# a shape's numbers, each (attribute, how many): all positive [m]
_SHAPES = {
    "box": (("size", 3),),
    "cylinder": (("radius", 1), ("length", 1)),
    "sphere": (("radius", 1),),
    "capsule": (("radius", 1), ("length", 1)),
}


def _numbers(root: ET.Element, file: str) -> None:
    """Every number Pinocchio reads from the URDF is finite, and of a small arm's magnitude."""
    for joint in root.findall("joint"):
        where = f"joint {joint.get('name')!r}"
        _origin(joint, where, file)
        axis = _floats(joint.find("axis"), "xyz", 3, MAX_FACTOR, f"{where} <axis>", file)
        if axis is not None and not any(axis):
            raise RobotFileError(file, f"{where} <axis> xyz", "must not be zero")
        limit = joint.find("limit")
        for key in ("lower", "upper"):
            _floats(limit, key, 1, MAX_POSITION, f"{where} <limit>", file)
        velocity = _floats(limit, "velocity", 1, MAX_VELOCITY, f"{where} <limit>", file)
        if velocity is not None and velocity[0] < 0:
            raise RobotFileError(file, f"{where} <limit> velocity", f"must be >= 0, got {velocity[0]:g}")
        _floats(limit, "effort", 1, math.inf, f"{where} <limit>", file)
        mimic = joint.find("mimic")
        _floats(mimic, "multiplier", 1, MAX_FACTOR, f"{where} <mimic>", file)
        _floats(mimic, "offset", 1, MAX_POSITION, f"{where} <mimic>", file)
    for link in root.findall("link"):
        lname = link.get("name")
        for kind in ("visual", "collision"):
            for part in link.findall(kind):
                where = f"link {lname!r} <{kind}>"
                _origin(part, where, file)
                geometry = part.find("geometry")
                for shape in list(geometry) if geometry is not None else []:
                    if shape.tag == "mesh":
                        scale = _floats(shape, "scale", 3, MAX_FACTOR, f"{where} <mesh>", file)
                        if scale is not None and not all(scale):
                            raise RobotFileError(file, f"{where} <mesh> scale", "must not be zero")
                        continue
                    for attr, n in _SHAPES.get(shape.tag, ()):  # (another shape: Pinocchio's to refuse)
                        values = _floats(shape, attr, n, MAX_LENGTH, f"{where} <{shape.tag}>", file)
                        if values is not None and min(values) <= 0:
                            raise RobotFileError(file, f"{where} <{shape.tag}> {attr}", "must be positive")
        inertial = link.find("inertial")
        if inertial is not None:
            _origin(inertial, f"link {lname!r} <inertial>", file)
            _floats(inertial.find("mass"), "value", 1, math.inf, f"link {lname!r} <inertial> <mass>", file)
            inertia = inertial.find("inertia")
            for key in ("ixx", "ixy", "ixz", "iyy", "iyz", "izz"):
                _floats(inertia, key, 1, math.inf, f"link {lname!r} <inertial> <inertia>", file)


def _meshes(root: ET.Element, folder: Path, file: str, optional: bool) -> tuple[bool, tuple[str, ...], dict[str, str]]:
    """Each mesh the URDF names, checked and renamed by its real path in the folder: whether any
    was, the meshes that cannot be used and why, and the links whose collision shapes were left
    out for it (with ``optional``: each such ``<collision>`` element removed, the link's others
    kept). Without ``optional`` a mesh that cannot be used refuses the arm, every one named."""
    unusable: list[str] = []
    left_out: dict[str, str] = {}
    refused: list[tuple[str, str]] = []  # (field, problem) of each mesh that cannot be used
    seen: dict[Path, int] = {}  # a usable mesh: its size [bytes]
    bad: dict[Path, FileProblem] = {}  # a mesh that cannot be used: why (said once)
    rewritten = False
    for link in root.findall("link"):
        lname = str(link.get("name"))
        for kind in ("collision", "visual"):
            for part in link.findall(kind):
                for mesh in part.findall("geometry/mesh"):
                    name = mesh.get("filename", "")
                    field = f"link {lname!r} <{kind}> <mesh filename>"
                    real: Path | None = None
                    try:
                        real = _inside(folder, name)
                        if real in bad:
                            raise bad[real]
                        if real not in seen:
                            seen[real] = _mesh(real)
                            if sum(seen.values()) > MAX_MESHES_BYTES:
                                raise FileProblem(
                                    f"the arm's meshes together are over {MAX_MESHES_BYTES:,} bytes", forbidden=False
                                )
                    except FileProblem as p:
                        if p.forbidden:  # (never opened, whatever robot.toml says)
                            raise RobotFileError(file, field, f"{name!r}: {p.problem}") from None
                        problem = f"{name!r}: {p.problem}"
                        if real is None or real not in bad:
                            unusable.append(f"{file}: {field}: {problem}")
                            refused.append((field, problem))
                        if real is not None:
                            bad[real] = p
                        if optional and kind == "collision":
                            link.remove(part)
                            rewritten = True
                            left_out[lname] = f"not checked: {problem} ([collision] meshes_optional)"
                        break
                    mesh.set("filename", str(real))
                    rewritten = True
    if refused and not optional:
        more = (
            f" (and {len(refused) - 1} more: {'; '.join(f'{f}: {p}' for f, p in refused[1:])})"
            if len(refused) > 1
            else ""
        )
        raise RobotFileError(
            file,
            refused[0][0],
            f"{refused[0][1]}{more} (to serve the arm, stand in for the link with a primitive or skip it in "
            "robot.toml's [collision], or set [collision] meshes_optional = true to leave such meshes out: "
            "docs/robot-format.md)",
        )
    return rewritten, tuple(unusable), left_out


def _mesh(real: Path) -> int:
    """The size [bytes] of the mesh file ``real``, once it is known to be usable."""
    if real.suffix.lower() not in MESH_FORMATS:
        raise FileProblem(f"is not a mesh format armd reads ({', '.join(MESH_FORMATS)})", forbidden=False)
    fd = _open(real, MAX_MESH_BYTES, "a mesh")
    try:
        size = os.fstat(fd).st_size
        if size == 0:
            raise FileProblem(f"{real} is empty", forbidden=False)
        if real.suffix.lower() == ".stl":
            _stl(fd, size, real)
    finally:
        os.close(fd)
    return size


def _stl(fd: int, size: int, real: Path) -> None:
    """A binary STL's triangle count is its size's, and at most :data:`MAX_TRIANGLES`; an ASCII
    one (``solid`` ...) has at most :data:`MAX_TRIANGLES` facets."""
    head = os.read(fd, _STL_HEADER)
    count = int.from_bytes(head[80:84], "little") if len(head) == _STL_HEADER else -1
    if count >= 0 and _STL_HEADER + _STL_TRIANGLE * count == size:
        if count > MAX_TRIANGLES:
            raise FileProblem(
                f"{real} has {count:,} triangles: a mesh may have at most {MAX_TRIANGLES:,}", forbidden=False
            )
        return
    if head.lstrip().startswith(b"solid"):
        facets = (head + _read(fd, MAX_MESH_BYTES)).count(b"facet normal")
        if facets > MAX_TRIANGLES:
            raise FileProblem(
                f"{real} has {facets:,} facets: a mesh may have at most {MAX_TRIANGLES:,}", forbidden=False
            )
        return
    claimed = f"claims {count:,} triangles ({_STL_HEADER + _STL_TRIANGLE * count:,} bytes)" if count >= 0 else "is"
    raise FileProblem(f"{real} is not an STL: its header {claimed}, the file has {size:,} bytes", forbidden=False)


# -- the limits ---------------------------------------------------------------------------------


def check_limits(limits: JointLimits, file: str) -> None:
    """The arm's limits, from the URDF and robot.toml together: finite, ``lower < upper`` within
    +-:data:`MAX_POSITION`, each rate positive and under its cap; a coupled limit's coefficients
    under :data:`MAX_FACTOR` and its finite bounds within what the joints' could reach."""
    rates = (
        ("velocity", limits.velocity, MAX_VELOCITY, "rad/s"),
        ("acceleration", limits.acceleration, MAX_ACCELERATION, "rad/s^2"),
        ("jerk", limits.jerk, MAX_JERK, "rad/s^3"),
    )
    for i, name in enumerate(limits.names):
        lo, hi = float(limits.lower[i]), float(limits.upper[i])
        if not (math.isfinite(lo) and math.isfinite(hi) and -MAX_POSITION <= lo < hi <= MAX_POSITION):
            raise RobotFileError(
                file,
                f"joints.{name}",
                f"position limits must be finite, lower < upper, within +-{MAX_POSITION:g} rad (or m); got "
                f"[{lo:g}, {hi:g}] (from the URDF's <limit> or this table)",
            )
        for key, values, cap, unit in rates:
            v = float(values[i])
            if not (math.isfinite(v) and 0 < v <= cap):
                raise RobotFileError(
                    file, f"joints.{name}.{key}", f"must be positive and at most {cap:g} {unit}; got {v:g}"
                )
    for c in limits.coupled:
        reach = float(abs(c.coefficients).sum()) * MAX_POSITION
        if not all(math.isfinite(k) and abs(k) <= MAX_FACTOR for k in c.coefficients.tolist()):
            raise RobotFileError(file, f"coupled_limits.{c.name}", f"coefficients must be at most {MAX_FACTOR:g}")
        for key, bound in (("lower", c.lower), ("upper", c.upper)):
            if math.isfinite(bound) and abs(bound) > reach:
                raise RobotFileError(
                    file, f"coupled_limits.{c.name}.{key}", f"{bound:g} is beyond what the joints reach (+-{reach:g})"
                )
