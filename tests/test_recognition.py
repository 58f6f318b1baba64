"""armd finds the closed-form family in a URDF's chain (robots/chain.py): the catalogue's arms
without their [geometry], the same arms' URDFs rewritten the ways vendors write them (other
zeros, axes turning the other way, the pan about -z and off the base origin, lateral offsets,
a base turned), the SO-101 as its vendor publishes it; and it says why an arm is not of the
family, naming the joint. Every found arm is solved exactly, in the URDF's own joint angles."""

from __future__ import annotations

import math
import shutil
import xml.etree.ElementTree as ET
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from armd import robots
from armd.robots.geometry import Geometry
from armd.solvers import solve_ik

Edit = Callable[[ET.Element], None]
DROPPED = ("[geometry]", "[controller]", "[servo]", "[[actuators]]", "[actuators.linkage]", "[gripper]", "[[sensors]]")


def _without_geometry(toml: str) -> str:
    return _without(toml, ("[geometry]",))


def _bare(toml: str) -> str:
    """robot.toml without [geometry] and what drives hardware (a rewritten URDF's angles are
    not the servos' any more)."""
    return _without(toml, DROPPED)


def _without(toml: str, tables: tuple[str, ...]) -> str:
    out, skip = [], False
    for line in toml.splitlines():
        if line.startswith("["):
            skip = line.strip() in tables
        if not skip:
            out.append(line)
    return "\n".join(out) + "\n"


def _copy(tmp_path: Path, name: str, *edits: Edit, toml: Callable[[str], str] = _without_geometry) -> Path:
    """The catalogue arm ``name`` in ``tmp_path``, [geometry] removed, its URDF edited (and the
    neutral pose with it: each edit maps the joint values it changes, ``edit.maps``)."""
    folder = tmp_path / name
    shutil.copytree(robots.CATALOGUE_DIR / name, folder)
    text = toml((folder / "robot.toml").read_text())
    maps = [m for e in edits for m in getattr(e, "maps", ())]
    if maps:
        arm = robots.load(name)
        neutral = arm.neutral.copy()
        for joint, scale, shift in maps:
            i = arm.joint_names.index(joint)
            neutral[i] = scale * neutral[i] + shift
        lines = [ln for ln in text.splitlines() if not ln.startswith("neutral")]
        at = lines.index("[robot]") + 1
        lines.insert(at, f"neutral = {[float(v) for v in neutral]}")
        text = "\n".join(lines) + "\n"
    (folder / "robot.toml").write_text(text)
    root = ET.parse(folder / "robot.urdf").getroot()
    for edit in edits:
        edit(root)
    (folder / "robot.urdf").write_text(ET.tostring(root, encoding="unicode"))
    return folder


def _joint(root: ET.Element, name: str) -> ET.Element:
    for joint in root.iter("joint"):
        if joint.get("name") == name:
            return joint
    raise KeyError(name)


def _origin(joint: ET.Element) -> ET.Element:
    origin = joint.find("origin")
    if origin is None:
        origin = ET.SubElement(joint, "origin", {"xyz": "0 0 0", "rpy": "0 0 0"})
    return origin


def _vec(text: str | None) -> np.ndarray:
    return np.array([float(v) for v in (text or "0 0 0").split()])


def _set(el: ET.Element, key: str, v: np.ndarray) -> None:
    el.set(key, " ".join(repr(float(x)) for x in v))


def _mapping(edit: Edit, joint: str, scale: float, shift: float) -> Edit:
    edit.maps = [(joint, scale, shift)]  # type: ignore[attr-defined]
    return edit


def flip_axis(name: str) -> Edit:
    """The joint turns the other way: its axis negated, its limits mirrored."""

    def edit(root: ET.Element) -> None:
        joint = _joint(root, name)
        axis = joint.find("axis")
        assert axis is not None
        _set(axis, "xyz", -_vec(axis.get("xyz")))
        limit = joint.find("limit")
        assert limit is not None
        lo, hi = float(limit.get("lower", "0")), float(limit.get("upper", "0"))
        limit.set("lower", repr(-hi))
        limit.set("upper", repr(-lo))

    return _mapping(edit, name, -1.0, 0.0)


def shift_zero(name: str, offset: float) -> Edit:
    """The joint's zero moved by ``offset`` [rad]: its frame turned about its axis, so that the
    URDF's angle for a pose is ``offset`` less; its limits moved with it."""

    def edit(root: ET.Element) -> None:
        import pinocchio as pin

        joint = _joint(root, name)
        origin = _origin(joint)
        axis_el = joint.find("axis")
        axis = _vec(axis_el.get("xyz") if axis_el is not None else "1 0 0")
        R = pin.rpy.rpyToMatrix(*_vec(origin.get("rpy"))) @ pin.AngleAxis(offset, axis / np.linalg.norm(axis)).matrix()
        _set(origin, "rpy", pin.rpy.matrixToRpy(R))
        limit = joint.find("limit")
        assert limit is not None
        limit.set("lower", repr(float(limit.get("lower", "0")) - offset))
        limit.set("upper", repr(float(limit.get("upper", "0")) - offset))

    return _mapping(edit, name, 1.0, -offset)


def move_origin(name: str, dxyz: tuple[float, float, float], drpy: tuple[float, float, float] = (0, 0, 0)) -> Edit:
    """The joint's origin moved (a lateral offset, the yaw off the base origin, the base turned)."""

    def edit(root: ET.Element) -> None:
        origin = _origin(_joint(root, name))
        _set(origin, "xyz", _vec(origin.get("xyz")) + np.array(dxyz))
        _set(origin, "rpy", _vec(origin.get("rpy")) + np.array(drpy))

    return edit


def pan_about_minus_z(name: str) -> Edit:
    """The first joint's frame upside down (rpy roll pi): it turns about -z, its child's frame
    turned back, so the arm is unchanged at every pose and only the pan's sense differs."""

    def edit(root: ET.Element) -> None:
        import pinocchio as pin

        joint = _joint(root, name)
        origin = _origin(joint)
        flip = pin.rpy.rpyToMatrix(math.pi, 0.0, 0.0)
        _set(origin, "rpy", pin.rpy.matrixToRpy(pin.rpy.rpyToMatrix(*_vec(origin.get("rpy"))) @ flip))
        link = joint.find("child")
        assert link is not None
        for child in root.iter("joint"):
            parent = child.find("parent")
            if parent is not None and parent.get("link") == link.get("link"):
                o = _origin(child)
                _set(o, "xyz", flip.T @ _vec(o.get("xyz")))
                _set(o, "rpy", pin.rpy.matrixToRpy(flip.T @ pin.rpy.rpyToMatrix(*_vec(o.get("rpy")))))
        limit = joint.find("limit")
        assert limit is not None
        lo, hi = float(limit.get("lower", "0")), float(limit.get("upper", "0"))
        limit.set("lower", repr(-hi))
        limit.set("upper", repr(-lo))

    return _mapping(edit, name, -1.0, 0.0)


def _clear(arm: robots.Robot, q: np.ndarray) -> bool:
    """Whether ``q`` is clear of ``arm``'s world, its tool above the floor: a truth IK answers ``ok``."""
    world = arm.collision
    if world is None:
        return True
    return world.first_contact(q) is None and (world.ground is None or arm.fk(q)[2] >= world.ground)


def _exactly_solved(arm: robots.Robot, n: int = 400, seed: int = 3, tol: float = 1e-9) -> None:
    """Targets made by FK from random in-limit configurations (the roll, if any, the seed's):
    every one ``ok`` within ``tol``, within every limit, Pinocchio's FK agreeing; and with an
    approach equal to the making configuration's pitch on a wrist arm."""
    assert arm.geometry is not None
    rng = np.random.default_rng(seed)
    done = 0
    while done < n:
        q = rng.uniform(arm.limits.lower, arm.limits.upper)
        if not arm.limits.contains(q) or not _clear(arm, q):
            continue
        seed_q = arm.neutral.copy()
        if arm.geometry.roll is not None:
            seed_q[arm.geometry.roll] = q[arm.geometry.roll]
        target = arm.fk(q)
        r = solve_ik(arm, target, seed=seed_q)
        assert r.status == "ok", (q.tolist(), r.reason)
        assert r.position_error <= tol and arm.limits.contains(r.q, tol=0.0)
        assert float(np.linalg.norm(arm.fk(r.q) - target)) <= tol
        assert r.pitch == pytest.approx(arm.tool_pitch(r.q), abs=1e-9)
        if arm.geometry.has_wrist:
            pitch = arm.tool_pitch(q)
            a = solve_ik(arm, target, seed=seed_q, approach=pitch)
            assert a.status == "ok", (q.tolist(), a.reason)
            assert abs(arm.tool_pitch(a.q) - pitch) <= 1e-9 and a.position_error <= tol
        done += 1


@pytest.mark.parametrize("name", ["gupta3", "insomniac", "sg5ut"])
def test_the_catalogue_arms_are_found_with_their_own_numbers(tmp_path: Path, name: str) -> None:
    found = robots.load_folder(_copy(tmp_path, name))
    given = robots.load(name)
    assert found.solver.startswith("closed form: yaw + ") and "found from the URDF's chain" in found.solver
    g, h = found.geometry, given.geometry
    assert g is not None and h is not None
    for field in ("yaw", "shoulder", "elbow", "wrist", "level"):
        assert getattr(g, field) == getattr(h, field), field
    assert np.allclose(
        [*g.pivot, g.upper_arm, g.forearm, g.hand], [*h.pivot, h.upper_arm, h.forearm, h.hand], atol=1e-12
    )
    assert g.sign == (1.0, 1.0, 1.0, 1.0) and np.allclose(g.zero, 0.0, atol=1e-12) and g.base == pytest.approx((0, 0))
    rng = np.random.default_rng(5)
    for q in rng.uniform(given.limits.lower, given.limits.upper, size=(200, given.nq)):
        a, b = solve_ik(found, given.fk(q)), solve_ik(given, given.fk(q))
        assert a.status == b.status
        assert np.allclose(a.q, b.q, atol=1e-7)


VARIANTS: dict[str, tuple[str, list[Edit]]] = {
    "axes turning the other way": ("sg5ut", [flip_axis("shoulder"), flip_axis("wrist"), flip_axis("base_yaw")]),
    "other zeros": ("sg5ut", [shift_zero("shoulder", 0.7), shift_zero("elbow", -1.1), shift_zero("wrist", 0.4)]),
    "the pan about -z, off the base origin": (
        "insomniac",
        [pan_about_minus_z("base_yaw"), move_origin("base_yaw", (0.0208, -0.0231, 0.0))],
    ),
    "lateral offsets and a turned base": (
        "insomniac",
        [
            move_origin("base_yaw", (0.01, 0.02, 0.0), (0.0, 0.0, 0.6)),
            move_origin("shoulder", (0.0, 0.015, 0.0)),
            move_origin("wrist", (0.0, -0.004, 0.0)),
        ],
    ),
    "all of it": (
        "sg5ut",
        [
            pan_about_minus_z("base_yaw"),
            move_origin("base_yaw", (-0.03, 0.01, 0.0), (0.0, 0.0, -1.2)),
            shift_zero("shoulder", -0.5),
            flip_axis("elbow"),
            shift_zero("wrist", 1.3),
            move_origin("elbow", (0.0, 0.02, 0.0)),
        ],
    ),
}


@pytest.mark.parametrize("variant", sorted(VARIANTS))
def test_a_chain_written_another_way_is_found_and_solved_in_its_own_angles(tmp_path: Path, variant: str) -> None:
    name, edits = VARIANTS[variant]
    arm = robots.load_folder(_copy(tmp_path, name, *edits, toml=_bare))
    g = arm.geometry
    assert g is not None, arm.solver
    assert "found from the URDF's chain" in arm.solver
    if variant == "the pan about -z, off the base origin":
        assert g.sign[0] == -1.0 and g.base == pytest.approx((0.0208, -0.0231), abs=1e-12)
    if variant == "lateral offsets and a turned base":
        assert g.base == pytest.approx((0.01, 0.02), abs=1e-12) and g.pivot[1] == pytest.approx(0.011, abs=1e-12)
    if variant == "axes turning the other way":
        assert g.sign == (-1.0, -1.0, 1.0, -1.0)
    if variant == "other zeros":
        assert g.zero[1:] == pytest.approx((0.7, -1.1, 0.4), abs=1e-12)
    arm.collision = None  # (the edits rewrite the chain, not the shapes on it: the pan's turret is in the floor)
    _exactly_solved(arm)


def test_the_so101_is_found_roll_and_all() -> None:
    arm = robots.load("so101")
    assert arm.solver == "closed form: yaw + 3 pitch + roll (found from the URDF's chain)"
    g = arm.geometry
    assert isinstance(g, Geometry) and g.roll == 4 and g.roll_model is not None
    assert g.sign[0] == -1.0  # the pan turns about -z
    assert math.hypot(*g.base) == pytest.approx(0.031, abs=0.001)  # 31 mm off the base origin
    # the roll moves the tool point (it is 7.9 mm off the roll axis): up to 15.8 mm
    q = arm.neutral.copy()
    points = []
    for roll in np.linspace(arm.limits.lower[4], arm.limits.upper[4], 50):
        q[4] = roll
        points.append(arm.fk(q))
    spread = max(float(np.linalg.norm(a - b)) for a in points for b in points)
    assert 0.015 < spread < 0.016
    _exactly_solved(arm, n=600)


def test_so101_joint_angles_are_the_vendors(tmp_path: Path) -> None:
    """The answer is in the URDF's angles: Pinocchio's FK of it is on the target, and the
    seed's branch comes back exactly (no re-zeroing on the way)."""
    arm = robots.load("so101")
    rng = np.random.default_rng(8)
    for q in rng.uniform(arm.limits.lower, arm.limits.upper, size=(200, 5)):
        if not _clear(arm, q):
            continue
        r = solve_ik(arm, arm.fk(q), seed=q, approach=arm.tool_pitch(q))
        assert r.status == "ok" and np.allclose(r.q, q, atol=1e-9), (q.tolist(), r.q.tolist())


def _tilted(axis: str) -> Edit:
    def edit(root: ET.Element) -> None:
        joint = _joint(root, axis)
        el = joint.find("axis")
        assert el is not None
        _set(el, "xyz", np.array([0.0, -math.cos(0.05), math.sin(0.05)]))

    return edit


def _prismatic(root: ET.Element) -> None:
    joint = _joint(root, "elbow")
    joint.set("type", "prismatic")


@pytest.mark.parametrize(
    ("name", "edits", "why"),
    [
        ("insomniac", [_tilted("wrist")], "joint 'wrist_roll' follows the wrist roll 'wrist'"),
        ("sg5ut", [_tilted("elbow")], "joint 'elbow''s axis is not parallel to 'shoulder''s"),
        ("sg5ut", [_prismatic], "joint 'elbow' is prismatic"),
        ("desk4", [], "joint 'level_major' mimics another (a linkage)"),
    ],
)
def test_an_arm_outside_the_family_is_told_why(tmp_path: Path, name: str, edits: list[Edit], why: str) -> None:
    arm = robots.load_folder(_copy(tmp_path, name, *edits, toml=_bare))
    assert arm.geometry is None
    assert arm.solver.startswith("numerical: ") and why in arm.solver, arm.solver
    assert arm.describe()["solver"] == arm.solver


def test_geometry_in_robot_toml_overrides(tmp_path: Path) -> None:
    arm = robots.load_folder(_copy(tmp_path, "sg5ut", toml=lambda t: t))
    assert arm.solver == "closed form: yaw + 3 pitch (robot.toml [geometry])"


def test_the_so101_as_its_vendor_rounds_it_is_found_nearly_and_solved_exactly() -> None:
    """The vendor's 1.5708 for pi/2 leaves the axes 3.7e-6 rad off parallel: the closed form is
    found to 1.7e-6 m and each answer refined on the exact model, to 1e-9 m."""
    arm = robots.load_folder(Path(__file__).resolve().parent.parent / "examples" / "arms" / "so101-vendor")
    assert "refined on the exact model" in arm.solver and arm.solver.startswith("closed form: yaw + 3 pitch + roll")
    _exactly_solved(arm, n=400)


def test_the_openmanipulator_x_from_its_vendor_urdf_is_found_exactly() -> None:
    """ROBOTIS's URDF as published: the yaw 12 mm off the base origin, joint3 24 mm forward of the
    upper arm's axis (a zero offset of atan(24 / 128) between the vendor's angles and the
    family's), pitch axes +y: the closed form is found with the vendor's joint angles, exact."""
    arm = robots.load_folder(Path(__file__).resolve().parent.parent / "examples" / "arms" / "openmanipulator-x")
    assert arm.solver == "closed form: yaw + 3 pitch (found from the URDF's chain)", arm.solver
    assert np.allclose(arm.fk(arm.neutral), [0.286, 0.0, 0.1875], atol=1e-12)  # the vendor's zero: as its URDF says
    _exactly_solved(arm, n=400)
