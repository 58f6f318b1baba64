"""robots.collision: each catalogue arm's collision shapes and its floor, and the pairs checked.
What the checker says is held against an independent computation: points filling each shape,
placed by the arm's FK, tested for lying inside another shape with plain geometry."""

from __future__ import annotations

import logging
from collections.abc import Callable
from pathlib import Path

import coal
import numpy as np
import pinocchio as pin
import pytest
from conftest import clear_configs

from armd import robots, solvers
from armd.errors import RobotFileError
from armd.robots.collision import GROUND, CollisionModel, Contact, Obstacle

ARMS = robots.names()


def _fill(shape: object, n: int = 7) -> np.ndarray:
    """Points filling a box or a cylinder (about its local z), in its own frame."""
    u = np.linspace(-1.0, 1.0, n)
    if isinstance(shape, coal.Box):
        h = np.asarray(shape.halfSide)
        g = np.stack(np.meshgrid(u, u, u, indexing="ij"), -1).reshape(-1, 3)
        return g * h
    if isinstance(shape, coal.Cylinder):
        g = np.stack(np.meshgrid(u, u, u, indexing="ij"), -1).reshape(-1, 3)
        g = g[np.hypot(g[:, 0], g[:, 1]) <= 1.0]
        return g * np.array([shape.radius, shape.radius, shape.halfLength])
    if isinstance(shape, coal.Sphere):
        g = np.stack(np.meshgrid(u, u, u, indexing="ij"), -1).reshape(-1, 3)
        return g[np.linalg.norm(g, axis=1) <= 1.0] * shape.radius
    raise AssertionError(f"no filling for {type(shape).__name__}")


def _inside(shape: object, local: np.ndarray) -> np.ndarray:
    """Which points (in the shape's own frame) lie inside it."""
    if isinstance(shape, coal.Box):
        return np.all(np.abs(local) <= np.asarray(shape.halfSide), axis=1)
    if isinstance(shape, coal.Cylinder):
        return (np.hypot(local[:, 0], local[:, 1]) <= shape.radius) & (np.abs(local[:, 2]) <= shape.halfLength)
    if isinstance(shape, coal.Sphere):
        return np.linalg.norm(local, axis=1) <= shape.radius
    if isinstance(shape, coal.Halfspace):
        return local @ np.asarray(shape.n) <= shape.d
    raise AssertionError(f"no test for {type(shape).__name__}")


def overlapping(arm: robots.Robot, q: np.ndarray) -> set[Contact]:
    """The checked pairs that share a point at ``q``, by filling each shape with points."""
    cm = arm.collision
    assert cm is not None
    data, gdata = cm.model.createData(), pin.GeometryData(cm.geometry)
    pin.updateGeometryPlacements(cm.model, data, cm.geometry, gdata, q)
    objs = cm.geometry.geometryObjects
    index = {name: k for k, name in enumerate(cm.links)}
    found = set()
    for pair in cm.pairs:
        a, b = index[pair.first], index[pair.second]
        if isinstance(objs[a].geometry, coal.Halfspace):
            a, b = b, a
        pts = _fill(objs[a].geometry)
        M, N = gdata.oMg[a], gdata.oMg[b]
        world = pts @ np.asarray(M.rotation).T + np.asarray(M.translation)
        local = (world - np.asarray(N.translation)) @ np.asarray(N.rotation)
        if np.any(_inside(objs[b].geometry, local)):
            found.add(pair)
    return found


@pytest.mark.parametrize("name", ARMS)
def test_every_catalogue_arm_has_shapes_a_floor_and_a_clear_neutral_pose(name: str) -> None:
    arm = robots.load(name)
    cm = arm.collision
    assert cm is not None and cm.ground is not None
    moving = {p.first for p in cm.pairs} | {p.second for p in cm.pairs}
    assert GROUND in moving and len(cm.links) >= 4
    assert cm.first_contact(arm.neutral) is None and not overlapping(arm, arm.neutral)


def among_obstacles(arm: robots.Robot) -> robots.Robot:
    """``arm`` with a box, a sphere and a cylinder around it, clear of its neutral pose."""
    cm = arm.collision
    assert cm is not None
    p = arm.fk(arm.neutral)
    r = max(float(np.hypot(p[0], p[1])), 0.1)
    z = float(p[2])
    for k in (0.8, 1.2, 1.6, 2.4):  # as near as the neutral pose leaves them clear
        obstacles = [
            Obstacle("crate", "box", (0.06, 0.08, 0.05), (0.0, k * r, z), (0.0, 0.0, 0.4)),
            Obstacle("ball", "sphere", (0.04,), (0.0, -k * r, z)),
            Obstacle("post", "cylinder", (0.02, 0.3), (-k * r, 0.0, z), (0.3, 0.0, 0.0)),
        ]
        arm.collision = cm.with_obstacles(obstacles)
        if arm.collision.first_contact(arm.neutral) is None:
            break
    assert arm.collision.first_contact(arm.neutral) is None
    return arm


@pytest.mark.parametrize("among", [False, True], ids=["alone", "among obstacles"])
@pytest.mark.parametrize("name", ARMS)
def test_what_the_checker_says_agrees_with_filled_shapes(name: str, among: bool) -> None:
    """300 random configurations: every pair whose shapes share a point (by the filling) is
    reported, and the first contact is found exactly where some pair is reported."""
    arm = robots.load_folder(robots.CATALOGUE_DIR / name)  # (a copy of its own: obstacles are added)
    if among:
        arm = among_obstacles(arm)
    cm = arm.collision
    assert cm is not None
    rng = np.random.default_rng(sum(name.encode()))
    seen = 0
    struck: set[str] = set()  # obstacles some configuration reaches
    for _ in range(300):
        q = rng.uniform(arm.limits.lower, arm.limits.upper)
        reported = set(cm.contacts(q))
        filled = overlapping(arm, q)
        assert filled <= reported, (q, filled - reported)
        assert (cm.first_contact(q) is None) == (not reported)
        seen += bool(reported)
        struck |= {name for pair in reported for name in pair} & {o.name for o in cm.obstacles}
    assert seen >= 10  # the sample holds collisions: the comparison was not empty
    assert not among or struck  # ... with the obstacles too


@pytest.mark.parametrize("name", ARMS)
def test_an_answer_does_not_depend_on_the_calls_before_it(name: str) -> None:
    """Each configuration's pairs in contact, from the checker that has answered every other
    configuration before it, against Pinocchio's check on data made for that configuration alone.
    (With coal's cached GJK guess on, as Pinocchio leaves it, insomniac's gripper sunk in a crate
    was said clear after nearly any other call.)"""
    arm = among_obstacles(robots.load_folder(robots.CATALOGUE_DIR / name))
    cm = arm.collision
    assert cm is not None
    rng = np.random.default_rng(sum(name.encode()) + 5)
    seen = 0
    for _ in range(400):
        q = rng.uniform(arm.limits.lower, arm.limits.upper)
        alone = pin.GeometryData(cm.geometry)
        pin.computeCollisions(cm.model, cm.model.createData(), cm.geometry, alone, q, False)
        fresh = {cm.pairs[k] for k, r in enumerate(alone.collisionResults) if r.isCollision()}
        assert set(cm.contacts(q)) == fresh, q.tolist()
        assert (cm.first_contact(q) is None) == (not fresh)
        seen += bool(fresh)
    assert seen >= 20


def test_neighbours_are_not_checked_and_the_base_stands_on_the_floor() -> None:
    pairs = {frozenset((p.first, p.second)) for p in robots.load("insomniac").collision.pairs}  # type: ignore[union-attr]
    assert frozenset(("humerus", "forearm")) not in pairs  # one joint apart
    assert frozenset(("forearm", "gripper")) not in pairs  # apart by the hand, which has no shape
    assert frozenset(("base", GROUND)) not in pairs  # the Create stands on the floor
    assert frozenset(("base", "gripper")) in pairs and frozenset(("gripper", GROUND)) in pairs


def test_seed_001_nothing_below_the_floor() -> None:
    """The issue's case: a target 5 cm under the floor is never ``ok`` (it was, with the gripper
    in the floor): ``collision``, the tool and the ground, by single and batch IK alike; nor is any
    point of a grid under the floor of every catalogue arm."""
    arm = robots.load("insomniac")
    for approach in (None, "parallel", "perpendicular"):
        r = solvers.solve_ik(arm, [0.30, 0.0, -0.05], approach=approach)
        assert r.status == "collision" and r.contact == (arm.tool_frame, GROUND), r
        assert "below the ground" in (r.reason or "") and r.to_dict()["contact"] == [arm.tool_frame, GROUND]
    b = solvers.solve_ik_batch(arm, [[0.30, 0.0, -0.05], [0.25, 0.05, 0.12]])
    assert b.status.tolist() == ["collision", "ok"] and b.contact == [(arm.tool_frame, GROUND), None]
    for name in ARMS:
        arm = robots.load(name)
        ground = arm.collision.ground  # type: ignore[union-attr]
        xs = np.linspace(-0.3, 0.3, 7)
        under = np.array([[x, y, ground - d] for x in xs for y in xs for d in (1e-4, 0.02, 0.1)])
        assert not np.any(solvers.solve_ik_batch(arm, under).status == "ok"), name
        assert not np.any(solvers.reachable(arm, under)), name


def _unchecked(name: str) -> robots.Robot:
    """A copy of catalogue arm ``name`` that checks no collisions (the answers before issue 17)."""
    arm = robots.load_folder(robots.CATALOGUE_DIR / name)
    arm.collision = None
    return arm


@pytest.mark.parametrize("name", ARMS)
def test_ik_answers_are_clear_and_a_colliding_branch_gives_way(name: str) -> None:
    """Among three obstacles near the arm, targets from random clear configurations, from random
    seeds: every answer ``ok``, clear of collisions by the filled shapes (the independent
    computation), every branch it lists clear too; and some of them differ from the answer
    without the check, which collides."""
    arm, plain = among_obstacles(robots.load_folder(robots.CATALOGUE_DIR / name)), _unchecked(name)
    cm = arm.collision
    assert cm is not None
    rng = np.random.default_rng(sum(name.encode()) + 17)
    gave_way = 0
    for q in clear_configs(arm, rng, 300):
        target, seed = arm.fk(q), rng.uniform(arm.limits.lower, arm.limits.upper)
        r = solvers.solve_ik(arm, target, seed=seed)
        assert r.status == "ok" and r.position_error <= 1e-9, (q.tolist(), r.reason)
        assert arm.limits.contains(r.q, tol=0.0)
        assert not overlapping(arm, r.q) and cm.first_contact(r.q) is None
        assert all(cm.first_contact(b.q) is None for b in r.branches)
        before = solvers.solve_ik(plain, target, seed=seed)
        if cm.first_contact(before.q) is not None:
            gave_way += 1
            assert not np.allclose(r.q, before.q)
    # (desk4's limits leave one configuration on each target: its answer is the clear truth's)
    assert gave_way >= 3 or name == "desk4", "no answer collided without the check: the test proves nothing"


def _crate_on(arm: robots.Robot, centre: np.ndarray, size: float = 0.08) -> robots.Robot:
    """A copy of ``arm`` with a box of side ``size`` [m] centred on ``centre``."""
    copy = robots.load_folder(robots.CATALOGUE_DIR / arm.name)
    copy.collision = arm.collision.with_obstacles(  # type: ignore[union-attr]
        [Obstacle("crate", "box", (size, size, size), tuple(float(c) for c in centre))]
    )
    return copy


def test_a_target_inside_an_obstacle_is_a_collision_naming_the_pair() -> None:
    """Every configuration that reaches a point inside a crate has the tool in the crate: status
    ``collision``, the pair named, at every approach; single and batch agree."""
    arm = robots.load("insomniac")
    centre = np.array([0.26, 0.0, 0.12])
    boxed = _crate_on(arm, centre)
    assert boxed.collision.first_contact(boxed.neutral) is None  # type: ignore[union-attr]
    assert solvers.solve_ik(arm, centre).status == "ok"  # reachable without the crate
    for approach in (None, "parallel", "perpendicular", -0.6):
        r = solvers.solve_ik(boxed, centre, approach=approach)
        assert r.status == "collision" and r.contact is not None and "crate" in r.contact, (approach, r)
        assert "collides" in (r.reason or "")
    b = solvers.solve_ik_batch(boxed, [centre, [0.2, 0.15, 0.15]])
    assert b.status.tolist()[0] == "collision" and "crate" in (b.contact[0] or ())
    assert b.status.tolist()[1] == "ok"


def test_an_unreachable_target_behind_a_wall_gets_the_closest_clear_configuration() -> None:
    """A target out of reach beyond a wall: the closest configuration within limits pushes the
    arm into the wall; the answer is a clear configuration (by the filled shapes), ``unreachable``,
    saying what was in the way, and farther from the target than the one through the wall."""
    arm = robots.load("insomniac")
    wall = robots.load_folder(robots.CATALOGUE_DIR / "insomniac")
    wall.collision = arm.collision.with_obstacles(  # type: ignore[union-attr]
        [Obstacle("wall", "box", (0.02, 0.6, 0.4), (0.30, 0.0, 0.2))]
    )
    assert wall.collision.first_contact(wall.neutral) is None
    target = [0.8, 0.0, 0.15]
    through = solvers.solve_ik(arm, target)
    assert through.status == "unreachable" and wall.collision.first_contact(through.q) is not None
    r = solvers.solve_ik(wall, target)
    assert r.status == "unreachable" and r.contact is None, r
    assert wall.collision.first_contact(r.q) is None and not overlapping(wall, r.q)
    assert wall.limits.contains(r.q, tol=0.0) and r.position_error > through.position_error
    assert "wall" in (r.reason or "") and "collision-free" in (r.reason or "")


def test_world_and_allowed_pairs_in_robot_toml(arm_copy: Callable[..., Path], caplog: pytest.LogCaptureFixture) -> None:
    toml = (robots.CATALOGUE_DIR / "insomniac" / "robot.toml").read_text()
    ground = next(line for line in toml.splitlines() if line.startswith("ground ="))
    none = robots.load_folder(arm_copy("insomniac", [(ground, "ground = false")], as_name="a"))
    assert none.collision is not None and none.collision.ground is None
    assert all(GROUND not in (p.first, p.second) for p in none.collision.pairs)
    allowed = robots.load_folder(
        arm_copy("insomniac", [(ground, ground + '\n[collision]\nallowed = [["base", "gripper"]]')], as_name="b")
    )
    assert Contact("base", "gripper") not in allowed.collision.pairs  # type: ignore[union-attr]
    with pytest.raises(RobotFileError, match="has no link 'nosuch'"):
        robots.load_folder(
            arm_copy("insomniac", [(ground, ground + '\n[collision]\nallowed = [["base", "nosuch"]]')], as_name="c")
        )
    with caplog.at_level(logging.WARNING, logger="armd.robots.catalogue"):
        high = robots.load_folder(arm_copy("insomniac", [(ground, "ground = 0.5")], as_name="d"))
    assert high.collision is not None and high.collision.first_contact(high.neutral) is not None
    assert any("neutral pose is in collision" in r.getMessage() and "ground" in r.getMessage() for r in caplog.records)


def test_a_collision_model_without_shapes_checks_nothing_but_is_clear() -> None:
    arm = robots.load("insomniac")
    bare = CollisionModel(arm.model, "<robot name='x'><link name='base'/></robot>".replace("x", "insomniac"), None)
    assert bare.pairs == [] and bare.first_contact(arm.neutral) is None


def test_obstacles_in_robot_toml(arm_copy: Callable[..., Path]) -> None:
    """A crate in front of insomniac: the gripper reaching into it is a contact naming it;
    names, sizes and keys are checked when the arm loads."""
    toml = (robots.CATALOGUE_DIR / "insomniac" / "robot.toml").read_text()
    ground = next(line for line in toml.splitlines() if line.startswith("ground ="))
    crate = '\n[[world.boxes]]\nname = "crate"\nsize = [0.1, 0.1, 0.1]\nposition = [0.3, 0.0, 0.05]\n'
    arm = robots.load_folder(arm_copy("insomniac", [(ground, ground + crate)], as_name="a"))
    cm = arm.collision
    assert cm is not None and [o.name for o in cm.obstacles] == ["crate"]
    assert Contact("gripper", "crate") in cm.pairs and cm.first_contact(arm.neutral) is None
    q = solvers.solve_ik(arm, [0.3, 0.0, 0.05], approach="perpendicular").q  # the gripper in the crate
    assert "crate" in (cm.first_contact(q) or ())
    assert [o.name for o in cm.with_obstacles([]).obstacles] == [] and cm.obstacles  # a new model; this one stays
    world = arm.describe()["world"]
    assert isinstance(world, dict) and world["ground"] == 0.0 and ["gripper", "crate"] in world["pairs"]
    assert world["obstacles"] == [
        {"name": "crate", "shape": "box", "size": [0.1, 0.1, 0.1], "position": [0.3, 0.0, 0.05], "rpy": [0.0, 0.0, 0.0]}
    ]
    for edit, says in (
        (crate.replace('"crate"', '"gripper"'), "is taken"),
        (crate.replace("[0.1, 0.1, 0.1]", "[0.1, 0.0, 0.1]"), "must be positive"),
        (crate + "colour = 1\n", "unknown key"),
        ("\n[[world.spheres]]\nposition = [0.3, 0, 0.05]\n", "radius"),
    ):
        with pytest.raises(RobotFileError, match=says):
            robots.load_folder(arm_copy("insomniac", [(ground, ground + edit)], as_name=f"b{len(says)}"))


def test_an_arm_whose_collision_mesh_cannot_be_read_loads_only_where_robot_toml_says_so(
    arm_copy: Callable[..., Path], caplog: pytest.LogCaptureFixture
) -> None:
    """An unreadable mesh refuses the arm (tests/test_user_arms.py); with ``[collision]
    meshes_optional = true`` it is said and left out, and the arm is served with its other links,
    the floor and its obstacles checked (as before, it was served with no check at all)."""
    box = '<collision><origin xyz="0.05 0 0"/><geometry><box size="0.1 0.05 0.02"/></geometry></collision>'
    mesh = '<collision><geometry><mesh filename="meshes/nosuch.stl"/></geometry></collision>'
    optional = ("[world]\n", "[collision]\nmeshes_optional = true\n\n[world]\n")
    with caplog.at_level(logging.WARNING, logger="armd.robots.catalogue"):
        arm = robots.load_folder(arm_copy("insomniac", [optional], urdf_edits=[(box, mesh)], as_name="m"))
    assert any("left out" in r.getMessage() and "nosuch.stl" in r.getMessage() for r in caplog.records)
    plain = robots.load("insomniac")
    assert arm.collision is not None and plain.collision is not None
    (link,) = arm.describe()["collision"]["links"]
    assert "nosuch.stl" in arm.describe()["collision"]["links"][link]
    left = {(p.first, p.second) for p in plain.collision.pairs if link not in (p.first, p.second)}
    assert {(p.first, p.second) for p in arm.collision.pairs} == left and left
    assert solvers.solve_ik(arm, arm.fk(arm.neutral)).status == "ok"
    assert solvers.solve_ik(arm, [0.2, 0.0, -0.01]).status == "collision"  # (the floor: still checked)


def test_a_target_reachable_only_with_the_gripper_turned_is_found() -> None:
    """Insomniac beside a box: at the seed's wrist roll (0) every branch at every pitch puts the
    gripper in the box; turned (the truth has -1.12 rad) it clears it. The answer is ``ok``,
    clear, on the target (bench/collision.py's IK table found it missing, 1 target in 1,500)."""
    arm = robots.load_folder(robots.CATALOGUE_DIR / "insomniac")
    arm.collision = arm.collision.with_obstacles(  # type: ignore[union-attr]
        [Obstacle("box1", "box", (0.06, 0.06, 0.06), (0.0, -0.22986, 0.29335))]
    )
    truth = np.array([-1.388, 1.6788, -1.3167, -0.8294, -1.1182])
    assert arm.collision.first_contact(truth) is None  # type: ignore[union-attr]
    target = arm.fk(truth)
    level = truth.copy()
    level[4] = 0.0
    assert arm.collision.first_contact(level) is not None  # (the seed's roll collides)
    r = solvers.solve_ik(arm, target)
    assert r.status == "ok" and r.position_error < 1e-9 and arm.collision.first_contact(r.q) is None  # type: ignore[union-attr]
    assert abs(r.q[4]) > 0.1  # turned
