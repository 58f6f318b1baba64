"""solvers.world, solvers.collide, solvers.narrowphase, solvers.tree: the compiled collision stage
holds every answer against coal's.

On every catalogue arm, alone and among obstacles, at random configurations within the limits
and along bisections toward contact; and on random pairs of random primitive shapes in random
poses against coal directly:

- distances: every separated pair's within 1e-9 m of coal's with its GJK run to a 1e-10 gap
  (:data:`TIGHT`), where they are at least :data:`NEAR` apart; and below coal's default
  answer (an upper bound) within its tolerance (~1e-6 (1 + d) m);
- yes/no: the same pairs in contact as :class:`CollisionModel` (coal's default), the same first
  pair, the same clearance and nearest pair (ties within coal's tolerance aside);

except where coal is proven wrong. Nearer contact than :data:`NEAR`, coal's GJK stops short
(its distance off by up to ~3e-7 m even at a 1e-10 gap), and its default collision check misses
shallow overlaps (a 20 um one was seen); there each disagreement is settled by bounds found
independently of both GJKs (:func:`bracket`: two points of the shapes, and a separating plane):
the compiled answer must lie within them, and the disagreements are counted. Two answers
within 1e-9 m of contact are both right.
"""

from __future__ import annotations

import math
import struct
import warnings
from collections.abc import Callable
from pathlib import Path

import coal
import numpy as np
import pinocchio as pin
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from test_collision import among_obstacles

from armd import robots
from armd.robots.collision import CollisionModel, Obstacle
from armd.solvers.collide import first_collision, first_collisions, min_distance, min_distances, primitive_distance
from armd.solvers.narrowphase import BOX, CAPSULE, CYLINDER, HALFSPACE, KINDS, SPHERE, TOUCH
from armd.solvers.world import CompiledWorld, compile_world, compiled, primitive, tree_of

ARMS = robots.names()
EXACT = 1e-9  # [m]: compiled distances against coal's at a 1e-10 GJK gap
TIGHT = 1e-10  # coal's GJK tolerance for the reference distances
NEAR = 1e-4  # [m]: nearer than this, coal's GJK (even at a 1e-10 gap) is not held to EXACT
BAND = 1e-5  # [m]: coal's default GJK (tolerance 1e-6) says shapes this near contact touching, or clear
CONFIGS = 1500  # random configurations per arm and world
BISECTIONS = 25  # bisections toward contact per arm
STEPS = 40  # halvings of each

SEEN: dict[str, float] = {}  # the largest differences found, and counts, by what was compared (printed with -s)


def _seen(key: str, value: float) -> None:
    SEEN[key] = max(SEEN.get(key, -math.inf), value)


def _count(key: str) -> None:
    SEEN[key] = SEEN.get(key, 0) + 1


def coal_data(cm: CollisionModel, tolerance: float | None = None) -> pin.GeometryData:
    """Pinocchio's geometry data for ``cm``, every GJK from its default guess (as CollisionModel
    runs it), at ``tolerance`` (None: coal's default)."""
    gdata = pin.GeometryData(cm.geometry)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        for request in [*gdata.collisionRequests, *gdata.distanceRequests]:
            request.enable_cached_gjk_guess = False
            request.gjk_initial_guess = coal.GJKInitialGuess.DefaultGuess
            if tolerance is not None:
                request.gjk_tolerance = tolerance
    return gdata


def coal_distances(cm: CollisionModel, gdata: pin.GeometryData, q: np.ndarray, pairs: np.ndarray) -> np.ndarray:
    """coal's distance [m] of each of ``pairs`` (indices of ``cm.pairs``) at ``q``."""
    pin.updateGeometryPlacements(cm.model, cm.model.createData(), cm.geometry, gdata, q)
    return np.array([pin.computeDistance(cm.geometry, gdata, int(k)).min_distance for k in pairs])


def judge(
    kinds: tuple[int, int],
    sizes: np.ndarray,
    M: np.ndarray,
    d: float,
    ref: float,
    default: float,
    collides: bool,
    start: np.ndarray,
) -> bool:
    """One pair's compiled distance ``d`` (<= TOUCH: in contact) against coal's at a 1e-10 gap
    (``ref``), coal's default (``default``) and coal's default collision check (``collides``),
    the shapes (``kinds``, ``sizes``, placed by ``M``) at hand for a certificate (from coal's
    witness point ``start``): the module's doc. Returns whether the pair's yes/no differs from
    coal's default (within its fuzz of contact, or with coal proven wrong)."""
    what = (kinds, sizes.tolist(), M.tolist(), d, ref)
    if d > TOUCH and ref > 0.0:
        if d >= NEAR:
            _seen("distance vs coal at a 1e-10 gap, 1e-4 m apart or more [m]", abs(d - ref))
            assert abs(d - ref) <= EXACT, what
        elif abs(d - ref) > EXACT:
            _count("coal's distance off by more than 1e-9 m near contact (settled)")
            certify(kinds, sizes, M, d, ref, start)
        if default > BAND:  # coal's default: an upper bound, within about its tolerance
            _seen("distance vs coal's default [m]", abs(d - default))
            assert d <= default + EXACT and default - d <= 2e-6 * (1 + d), (*what, default)
    contact = d <= TOUCH
    if contact != (ref <= 0.0) and not (
        TOUCH < d < EXACT or abs(ref) < EXACT
    ):  # (both within 1e-9 m of contact: either)
        _count("yes/no unlike coal's at a 1e-10 gap (settled)")
        certify(kinds, sizes, M, d, ref, start)
    if contact == collides:
        return False
    if TOUCH < d < BAND or abs(ref) < BAND:  # (coal's default fuzz)
        _count("yes/no unlike coal's default within 1e-5 m of contact (pairs)")
        return True
    _count("yes/no unlike coal's default farther from contact: coal proven wrong (pairs)")
    certify(kinds, sizes, M, d, ref, start)
    return True


def certify(kinds: tuple[int, int], sizes: np.ndarray, M: np.ndarray, d: float, ref: float, start: np.ndarray) -> None:
    """The compiled distance ``d`` (<= TOUCH: in contact) against the bounds :func:`bracket`
    finds: in contact, two points of the shapes within EXACT and no plane separating them by
    more; apart, ``d`` at least the best separating plane's distance and at most the distance of
    the two nearest points found (and coal's), and within EXACT of one of them (the points':
    SLSQP's optimum of a convex problem, the truth)."""
    lower, upper = bracket(kinds, sizes, M, start, d)
    what = (kinds, sizes.tolist(), M.tolist(), d, ref, lower, upper)
    if d <= TOUCH:
        _seen("where the compiled check says contact and coal not: two points of the shapes apart by [m]", upper)
        assert lower <= EXACT and upper <= EXACT, what
        return
    _seen("where coal is off: the compiled distance vs the truth [m]", min(d - lower, abs(d - upper)))
    assert lower - EXACT <= d <= min(upper, ref if ref > 0.0 else math.inf) + EXACT, what
    assert min(d - lower, abs(d - upper)) <= EXACT, what


def compare(
    cm: CollisionModel, cw: CompiledWorld, q: np.ndarray, gdata: pin.GeometryData, tight: pin.GeometryData
) -> int:
    """Every pair at ``q``, compiled against coal (:func:`judge`), and the configuration's first
    contact, contacts and clearance; returns how many pairs' yes/no differ from coal's default
    (within its fuzz of contact, or with coal proven wrong)."""
    d = cw.distances(q)
    default = coal_distances(cm, gdata, q, cw.compiled_pairs)
    ref = coal_distances(cm, tight, q, cw.compiled_pairs)
    coal_hits = cm.contacts(q)
    wrong, touching = set(), set()  # (unlike coal's default, settled; both within EXACT of contact)
    for i, k in enumerate(cw.compiled_pairs.tolist()):
        if TOUCH < d[i] < EXACT or abs(ref[i]) < EXACT:
            touching.add(cm.pairs[k])
        cp = cm.geometry.collisionPairs[k]
        objects = (cm.geometry.geometryObjects[cp.first], cm.geometry.geometryObjects[cp.second])
        got = [primitive(o.geometry) for o in objects]
        M = np.array([tight.oMg[cp.first].homogeneous, tight.oMg[cp.second].homogeneous])
        if judge(
            (got[0][0], got[1][0]),  # type: ignore[index]
            np.array([got[0][1], got[1][1]]),  # type: ignore[index]
            M,
            float(d[i]),
            float(ref[i]),
            float(default[i]),
            cm.pairs[k] in coal_hits,
            np.asarray(pin.computeDistance(cm.geometry, tight, k).getNearestPoint1()),
        ):
            wrong.add(cm.pairs[k])
    mine = [cm.pairs[k] for k in cw.compiled_pairs[d <= TOUCH].tolist()]
    assert cw.contacts(q) == mine and cw.first_contact(q) == (mine[0] if mine else None)
    settled = wrong | touching
    assert [p for p in mine if p not in settled] == [p for p in coal_hits if p not in settled], q.tolist()
    if not settled & (set(mine) | set(coal_hits)):
        assert cw.first_contact(q) == cm.first_contact(q), q.tolist()
    near, pair = cw.clearance(q)
    coal_near, coal_pair = cm.clearance(q)
    if not mine and not coal_hits and coal_near > BAND:
        assert abs(near - coal_near) <= 2e-6 * (1 + near), (near, coal_near)
        second = np.sort(d)[1] if len(d) > 1 else math.inf
        assert pair == coal_pair or second - near <= 2e-6, (pair, coal_pair)  # (or a tie within coal's tolerance)
    if mine:
        assert near <= TOUCH and pair == mine[0]
    return len(wrong)


# -- where coal is not exact: the truth bracketed ----------------------------------------------


def _project(kind: int, size: np.ndarray, M: np.ndarray, p: np.ndarray) -> np.ndarray:
    """The point of a shape (``kind``, ``size``, placed by ``M``) nearest ``p`` (not a half-space)."""
    x = M[:3, :3].T @ (p - M[:3, 3])
    if kind == BOX:
        x = np.clip(x, -size[:3], size[:3])
    elif kind == CYLINDER:
        rho = math.hypot(x[0], x[1])
        if rho > size[0]:
            x[:2] *= size[0] / rho
        x[2] = min(max(x[2], -size[1]), size[1])
    else:  # a sphere, a capsule: within the radius of the point, the segment
        c = np.array([0.0, 0.0, min(max(x[2], -size[1]), size[1]) if kind == CAPSULE else 0.0])
        e = x - c
        if np.linalg.norm(e) > size[0]:
            x = c + e * size[0] / np.linalg.norm(e)
    return M[:3, :3] @ x + M[:3, 3]


def _lowest(kind: int, size: np.ndarray, M: np.ndarray, u: np.ndarray) -> float:
    """min of u . x over the shape (u unit, in the base frame; not a half-space)."""
    d = -(M[:3, :3].T @ u)
    if kind == BOX:
        x = np.where(d >= 0, size[:3], -size[:3])
    elif kind == CYLINDER:
        rho = math.hypot(d[0], d[1])
        x = np.array(
            [size[0] * d[0] / rho if rho else 0.0, size[0] * d[1] / rho if rho else 0.0, size[1] * np.sign(d[2])]
        )
    else:
        x = np.array([0.0, 0.0, size[1] * np.sign(d[2]) if kind == CAPSULE else 0.0]) + size[0] * d
    return float(u @ (M[:3, :3] @ x + M[:3, 3]))


def _nearest_points(
    kinds: tuple[int, int], sizes: np.ndarray, M: np.ndarray, x: np.ndarray, y: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Two points of the shapes, one in each, as near each other as SLSQP finds from ``x``, ``y``
    (each shape's points as variables under its own constraints, in its own frame), projected
    into the shapes."""
    from scipy.optimize import minimize

    jac, starts, bounds, cons, at = [], [], [], [], [0]
    for i, (kind, size, p) in enumerate(zip(kinds, sizes, (x, y), strict=True)):
        local = M[i][:3, :3].T @ (p - M[i][:3, 3])
        f = at[-1]
        if kind == CAPSULE:  # (an offset within the radius from a point of the segment)
            t = min(max(local[2], -size[1]), size[1])
            starts.append(np.array([local[0], local[1], local[2] - t, t]))
            bounds += [(None, None)] * 3 + [(-size[1], size[1])]
            jac.append(np.array([[1.0, 0, 0, 0], [0, 1.0, 0, 0], [0, 0, 1.0, 1.0]]))
        else:
            starts.append(local)
            h = size[:3] if kind == BOX else (math.inf, math.inf, size[1] if kind == CYLINDER else math.inf)
            bounds += [(-v, v) if math.isfinite(v) else (None, None) for v in h]
            jac.append(np.eye(3))
        at.append(f + len(starts[-1]))
        n = {CYLINDER: 2, SPHERE: 3, CAPSULE: 3}.get(kind, 0)
        if n:

            def fun(z: np.ndarray, f: int = f, n: int = n, r: float = size[0]) -> float:
                return float(r * r - z[f : f + n] @ z[f : f + n])

            def grad(z: np.ndarray, f: int = f, n: int = n) -> np.ndarray:
                g = np.zeros(len(z))
                g[f : f + n] = -2.0 * z[f : f + n]
                return g

            cons.append({"type": "ineq", "fun": fun, "jac": grad})

    def ends(z: np.ndarray) -> list[np.ndarray]:
        return [M[i][:3, :3] @ (jac[i] @ z[at[i] : at[i + 1]]) + M[i][:3, 3] for i in range(2)]

    def gap(z: np.ndarray) -> tuple[float, np.ndarray]:
        e = ends(z)
        r = e[0] - e[1]
        g0 = 2.0 * jac[0].T @ (M[0][:3, :3].T @ r)
        g1 = -2.0 * jac[1].T @ (M[1][:3, :3].T @ r)
        return float(r @ r), np.concatenate([g0, g1])

    z = minimize(
        gap,
        np.concatenate(starts),
        jac=True,
        method="SLSQP",
        bounds=bounds,
        constraints=cons,
        options={"ftol": 1e-30, "maxiter": 200},
    ).x
    e = ends(z)
    return _project(kinds[0], sizes[0], M[0], e[0]), _project(kinds[1], sizes[1], M[1], e[1])


def bracket(
    kinds: tuple[int, int], sizes: np.ndarray, M: np.ndarray, start: np.ndarray, claim: float
) -> tuple[float, float]:
    """Bounds [m] on the distance of two shapes, found independently of both GJKs, to check the
    claim that it is ``claim``: above, the distance of two points in them (alternating
    projections from ``start``, then SLSQP on the points); below, a separating plane's (min over
    a of u . x less max over b of u . x: for the direction between those points, then, if that
    is not within EXACT of ``claim``, the best Nelder-Mead finds on the sphere of directions).
    A half-space and a shape: the shape's lowest point along its normal, both."""
    from scipy.optimize import minimize

    if HALFSPACE in kinds:
        h = kinds.index(HALFSPACE)
        n = M[h][:3, :3] @ sizes[h][:3]
        exact = _lowest(kinds[1 - h], sizes[1 - h], M[1 - h], n) - (sizes[h][3] + n @ M[h][:3, 3])
        return exact, exact

    def plane(u: np.ndarray) -> float:
        u = u / np.linalg.norm(u)
        return _lowest(kinds[0], sizes[0], M[0], u) + _lowest(kinds[1], sizes[1], M[1], -u)

    x = _project(kinds[0], sizes[0], M[0], start)
    y = _project(kinds[1], sizes[1], M[1], x)
    for _ in range(50):
        x = _project(kinds[0], sizes[0], M[0], y)
        y = _project(kinds[1], sizes[1], M[1], x)
    x, y = _nearest_points(kinds, sizes, M, x, y)
    upper = float(np.linalg.norm(x - y))
    lower = plane(x - y) if upper > 0.0 else -math.inf
    if lower < claim - EXACT and upper > 0.0:
        found = minimize(
            lambda u: -plane(u),
            (x - y) / upper,
            method="Nelder-Mead",
            options={"xatol": 1e-15, "fatol": 1e-18, "maxiter": 1000},
        )
        lower = max(lower, -float(found.fun))
    return lower, upper


# -- the catalogue ------------------------------------------------------------------------------


@pytest.mark.parametrize("name", ARMS)
def test_every_catalogue_arm_is_compiled_whole(name: str) -> None:
    """The catalogue's shapes are primitives on revolute joints (and mimic ones): every pair is
    compiled, none left to coal, in the collision model's order, a half-space always second."""
    cm = among_obstacles(robots.load_folder(robots.CATALOGUE_DIR / name)).collision
    assert cm is not None
    cw = compile_world(cm)
    assert cw.unsupported == () and cw.on_coal == () and cw.coal_pairs == ()
    assert cw.compiled_pairs.tolist() == list(range(len(cw.world.pairs)))
    assert not np.any(cw.shapes.kind[cw.shapes.pairs[:, 0]] == HALFSPACE)
    assert {SPHERE, BOX, CYLINDER, HALFSPACE} <= set(
        cw.shapes.kind.tolist()
    )  # (the obstacles: a ball, a crate, a post)


@pytest.mark.parametrize("among", [False, True], ids=["alone", "among obstacles"])
@pytest.mark.parametrize("name", ARMS)
def test_random_configurations_answer_as_coal(name: str, among: bool) -> None:
    """CONFIGS random configurations within the box limits: every pair, the first contact, the
    contacts and the clearance as coal's (:func:`compare`); coal proven wrong on a handful at most;
    the batch check gives the single check's answers."""
    arm = robots.load_folder(robots.CATALOGUE_DIR / name)
    if among:
        arm = among_obstacles(arm)
    cm = arm.collision
    assert cm is not None
    cw = compile_world(cm)
    gdata, tight = coal_data(cm), coal_data(cm, TIGHT)
    rng = np.random.default_rng(sum(name.encode()) + 36 + among)
    qs = rng.uniform(arm.limits.lower, arm.limits.upper, size=(CONFIGS, arm.nq))
    wrong = hits = 0
    for q in qs:
        wrong += compare(cm, cw, q, gdata, tight)
        hits += cw.first_contact(q) is not None
    assert wrong <= CONFIGS // 100
    assert 0.02 * CONFIGS <= hits <= 0.98 * CONFIGS  # both answers were compared, many times
    out = np.empty(CONFIGS, dtype=np.int64)
    assert first_collisions(cw.packed_shapes, qs, out) == hits
    assert out.tolist() == [first_collision(cw.packed_shapes, q) for q in qs]  # (the batch is the single check)
    near, pair = np.empty(CONFIGS), np.empty(CONFIGS, dtype=np.int64)
    assert min_distances(cw.packed_shapes, qs, near, pair) == hits
    assert list(zip(near.tolist(), pair.tolist(), strict=True)) == [min_distance(cw.packed_shapes, q) for q in qs]


@pytest.mark.slow  # (5-15 s an arm: coal and the independent bounds near contact)
@pytest.mark.parametrize("name", ARMS)
def test_near_contact_answers_as_coal(name: str) -> None:
    """From a clear configuration toward a colliding one, STEPS halvings of the segment (the
    compiled check deciding), among obstacles: at every step, every pair and the configuration as
    coal's (:func:`compare`), down to within 1e-9 m of contact."""
    arm = among_obstacles(robots.load_folder(robots.CATALOGUE_DIR / name))
    cm = arm.collision
    assert cm is not None
    cw = compile_world(cm)
    gdata, tight = coal_data(cm), coal_data(cm, TIGHT)
    rng = np.random.default_rng(sum(name.encode()) + 37)
    nearest = math.inf
    for _ in range(BISECTIONS):
        while True:
            a, b = rng.uniform(arm.limits.lower, arm.limits.upper, size=(2, arm.nq))
            if cw.first_contact(a) is None and cw.first_contact(b) is not None:
                break
        for _ in range(STEPS):
            mid = 0.5 * (a + b)
            compare(cm, cw, mid, gdata, tight)
            if cw.first_contact(mid) is None:
                a = mid
            else:
                b = mid
        nearest = min(nearest, float(min_distance(cw.packed_shapes, a)[0]))
    assert nearest < 1e-9  # (the bisections did reach contact)


def test_the_tree_reads_mimic_joints_from_their_leaders() -> None:
    """desk4's levelling joints are mimic joints (multiplier -1) of major and minor: the tree
    turns them by the leaders' coordinates, scaled."""
    arm = robots.load("desk4")
    tree, bad = tree_of(arm.model)
    assert bad == {}
    names = list(arm.model.names)
    for mimic, leader in (("level_major", "major"), ("level_minor", "minor")):
        j, k = names.index(mimic), names.index(leader)
        assert tree.coordinate[j] == arm.model.joints[k].idx_q and tree.scale[j] == -1.0 and tree.offset[j] == 0.0


# -- what stays on coal ---------------------------------------------------------------------------


def _box_stl(path: Path, half: tuple[float, float, float]) -> None:
    """A binary STL of a box of half-sides ``half`` [m] about the origin."""
    corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=float) * half
    faces = [
        (0, 1, 3),
        (0, 3, 2),
        (4, 6, 7),
        (4, 7, 5),
        (0, 4, 5),
        (0, 5, 1),
        (2, 3, 7),
        (2, 7, 6),
        (0, 2, 6),
        (0, 6, 4),
    ]
    faces += [(1, 5, 7), (1, 7, 3)]
    body = b"".join(
        struct.pack("<3f", 0, 0, 0) + struct.pack("<9f", *corners[list(f)].ravel()) + b"\0\0" for f in faces
    )
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(b"\0" * 80 + struct.pack("<I", len(faces)) + body)


def test_a_mesh_stays_on_coal_and_the_answers_do_not_change(arm_copy: Callable[..., Path]) -> None:
    """insomniac with its gripper's box as a mesh: the builder says the mesh and its pairs stay on
    coal; the compiled world answers as the collision model at random configurations (the
    mesh's pairs through coal, merged in the model's order)."""
    box = '<collision><origin xyz="0.05 0 0"/><geometry><box size="0.1 0.05 0.02"/></geometry></collision>'
    mesh = '<collision><origin xyz="0.05 0 0"/><geometry><mesh filename="meshes/gripper.stl"/></geometry></collision>'
    folder = arm_copy("insomniac", urdf_edits=[(box, mesh)], as_name="meshy")
    _box_stl(folder / "meshes" / "gripper.stl", (0.05, 0.025, 0.01))
    arm = among_obstacles(robots.load_folder(folder))
    cm = arm.collision
    assert cm is not None
    cw = compile_world(cm)
    assert [u.name for u in cw.unsupported] == ["gripper_0"] and "a mesh" in cw.unsupported[0].reason
    assert cw.on_coal and all("gripper" in (p.first, p.second) for p in cw.on_coal)
    assert len(cw.on_coal) + len(cw.compiled_pairs) == len(cm.pairs)
    rng = np.random.default_rng(36)
    meshy = 0
    for q in rng.uniform(arm.limits.lower, arm.limits.upper, size=(600, arm.nq)):
        hit = cm.first_contact(q)
        assert cw.first_contact(q) == hit and cw.contacts(q) == cm.contacts(q), q.tolist()
        meshy += hit is not None and "gripper" in hit
        near, pair = cw.clearance(q)
        coal_near, _ = cm.clearance(q)
        if hit is None:
            assert abs(near - coal_near) <= 2e-6 * (1 + near) and pair is not None
    assert meshy >= 5  # (the mesh's pairs were first in contact, and found)


def test_unsupported_shapes_and_joints_are_named() -> None:
    """A cone, a mesh and a continuous joint's links: each said, with why."""
    assert isinstance(primitive(coal.Cone(0.1, 0.2)), str) and "Cone" in str(primitive(coal.Cone(0.1, 0.2)))
    mesh = coal.BVHModelOBBRSS()
    mesh.beginModel(1, 3)
    mesh.addTriangle(np.array([0.0, 0, 0]), np.array([1.0, 0, 0]), np.array([0.0, 1, 0]))
    mesh.endModel()
    assert "a mesh" in str(primitive(mesh))
    model = pin.Model()
    j = model.addJoint(0, pin.JointModelRUBZ(), pin.SE3.Identity(), "spin")
    model.addJoint(j, pin.JointModelRY(), pin.SE3.Identity(), "tilt")
    _, bad = tree_of(model)
    assert set(bad) == {1, 2} and "'spin'" in bad[1] and bad[2] == bad[1]


# -- primitive pairs against coal directly -----------------------------------------------------------

SHAPES = (SPHERE, CAPSULE, BOX, CYLINDER, HALFSPACE)


def _coal_shape(kind: int, size: np.ndarray) -> object:
    if kind == SPHERE:
        return coal.Sphere(size[0])
    if kind == CAPSULE:
        return coal.Capsule(size[0], 2 * size[1])
    if kind == BOX:
        return coal.Box(*(2 * size[:3]))
    if kind == CYLINDER:
        return coal.Cylinder(size[0], 2 * size[1])
    return coal.Halfspace(size[:3], size[3])


def _size(kind: int, numbers: np.ndarray) -> np.ndarray:
    """A shape's size from three numbers in [0.005, 0.3) (a half-space's: a normal and an offset)."""
    size = np.zeros(4)
    if kind == HALFSPACE:
        n = numbers - 0.15
        size[:3] = n / np.linalg.norm(n) if np.linalg.norm(n) > 1e-3 else (0.0, 0.0, 1.0)
        size[3] = numbers[0] - 0.15
    else:
        size[:3] = numbers
    return size


def check_pair(kinds: tuple[int, int], numbers: np.ndarray, rotations: np.ndarray, positions: np.ndarray) -> None:
    """Two shapes' compiled distance against coal's (:func:`judge`)."""
    sizes = np.ascontiguousarray([_size(k, numbers[i]) for i, k in enumerate(kinds)])
    shapes = [_coal_shape(k, sizes[i]) for i, k in enumerate(kinds)]
    sizes = np.ascontiguousarray([primitive(s)[1] for s in shapes])  # type: ignore[index] (coal's normalised)
    M = np.ascontiguousarray([pin.SE3(rotations[i], positions[i]).homogeneous for i in range(2)])
    mine = primitive_distance(np.array(kinds, dtype=np.int64), sizes, M)
    tf = [coal.Transform3s(rotations[i], positions[i]) for i in range(2)]
    req = coal.DistanceRequest()
    req.gjk_initial_guess = coal.GJKInitialGuess.DefaultGuess
    req.gjk_tolerance = TIGHT
    result = coal.DistanceResult()
    ref = coal.distance(shapes[0], tf[0], shapes[1], tf[1], req, result)
    default = coal.distance(shapes[0], tf[0], shapes[1], tf[1], coal.DistanceRequest(), coal.DistanceResult())
    collides = coal.collide(shapes[0], tf[0], shapes[1], tf[1], coal.CollisionRequest(), coal.CollisionResult())
    if mine > TOUCH and ref > 0.0 and mine >= NEAR:
        _seen(f"{KINDS[kinds[0]]} and {KINDS[kinds[1]]} vs coal at a 1e-10 gap [m]", abs(mine - ref))
    judge(kinds, sizes, M, mine, ref, default, bool(collides), np.asarray(result.getNearestPoint1()))


def _rotation(rng: np.random.Generator) -> np.ndarray:
    """A rotation: any, about one axis, or a multiple of quarter turns (faces and axes parallel)."""
    kind = rng.integers(3)
    if kind == 0:
        return pin.exp3(rng.normal(size=3))
    if kind == 1:
        return pin.exp3(np.eye(3)[rng.integers(3)] * rng.uniform(-math.pi, math.pi))
    R = np.eye(3)
    for axis in range(3):
        R = R @ pin.exp3(np.eye(3)[axis] * rng.integers(4) * math.pi / 2)
    return R


def test_random_primitive_pairs_answer_as_coal() -> None:
    """20,000 random pairs of random primitives (sphere, capsule, box, cylinder, half-space) in
    random poses, some of them concentric or a hair apart: the same distance as coal's within
    1e-9 m where apart, the same yes/no outside coal's fuzz."""
    rng = np.random.default_rng(36)
    for _ in range(20_000):
        kinds = tuple(sorted(rng.choice(SHAPES, size=2)))
        if kinds == (HALFSPACE, HALFSPACE):
            continue
        numbers = rng.uniform(0.005, 0.3, size=(2, 3))
        rotations = np.array([_rotation(rng), _rotation(rng)])
        positions = rng.uniform(-0.3, 0.3, size=(2, 3))
        if rng.random() < 0.1:  # (the same centre)
            positions[1] = positions[0]
        check_pair(kinds, numbers, rotations, positions)  # type: ignore[arg-type]


@settings(max_examples=400, deadline=None, derandomize=True)  # (the same examples every run)
@given(
    kinds=st.tuples(st.sampled_from(SHAPES), st.sampled_from(SHAPES)).filter(lambda k: k != (HALFSPACE, HALFSPACE)),
    numbers=st.lists(st.floats(0.005, 0.3), min_size=6, max_size=6),
    turns=st.lists(st.floats(-4.0, 4.0), min_size=6, max_size=6),
    positions=st.lists(st.floats(-0.3, 0.3), min_size=6, max_size=6),
)
def test_primitive_pairs_answer_as_coal(
    kinds: tuple[int, int], numbers: list[float], turns: list[float], positions: list[float]
) -> None:
    """Hypothesis's shapes and poses (rotation vectors, so 0 and axis-aligned turns too)."""
    rotations = np.array([pin.exp3(np.array(turns[:3])), pin.exp3(np.array(turns[3:]))])
    check_pair(kinds, np.reshape(numbers, (2, 3)), rotations, np.reshape(positions, (2, 3)))


def test_what_was_seen() -> None:
    """(Prints the largest differences the tests above found: run with -s.)"""
    for key, value in sorted(SEEN.items()):
        print(f"{key}: {value:.3g}")
    assert all(v <= EXACT for k, v in SEEN.items() if "1e-10 gap" in k and k.endswith("[m]"))


def test_a_shape_deep_inside_another_is_in_contact() -> None:
    """Every primitive (a sphere, capsule, box or cylinder a few centimetres across) anywhere
    well inside a large one (or on its centre) in any pose: in contact. (GJK came to the origin only to rounding,
    3e-12 m, and a gripper deep in a crate was called clear, where coal said -0.04 m.)"""
    rng = np.random.default_rng(3612)
    solids = [k for k in SHAPES if k != HALFSPACE]
    for _ in range(4_000):
        outer, inner = int(rng.choice(solids)), int(rng.choice(solids))
        sizes = np.zeros((2, 4))
        sizes[0, :3] = rng.uniform(0.2, 0.3, size=3)
        sizes[1, :3] = rng.uniform(0.005, 0.03, size=3)
        kinds = np.array([outer, inner], dtype=np.int64)
        shapes = [_coal_shape(int(k), sizes[i]) for i, k in enumerate(kinds)]
        sizes = np.ascontiguousarray([primitive(s)[1] for s in shapes])  # type: ignore[index]
        R = np.array([_rotation(rng), _rotation(rng)])
        at = rng.uniform(-0.3, 0.3, size=3)
        p = np.array([at, at + (rng.uniform(-0.05, 0.05, size=3) if rng.random() < 0.7 else 0.0)])  # (or concentric)
        M = np.ascontiguousarray([pin.SE3(R[i], p[i]).homogeneous for i in range(2)])
        d = primitive_distance(kinds, sizes, M)
        assert d <= TOUCH, (KINDS[outer], KINDS[inner], d)
        d = primitive_distance(kinds[::-1].copy(), sizes[::-1].copy(), M[::-1].copy())
        assert d <= TOUCH, (KINDS[inner], KINDS[outer], d)


def test_a_gripper_deep_in_a_crate_is_in_contact() -> None:
    """The insomniac's gripper reaching into a crate 0.08 m across (coal: 0.04 m deep): the
    compiled world names the pair, as coal does."""
    arm = robots.load("insomniac")
    crate = Obstacle("crate", "box", (0.08, 0.08, 0.08), (0.26, 0.0, 0.12))
    world = arm.collision.with_obstacles([crate])  # type: ignore[union-attr]
    q = np.array([0.0, 0.99575131130219974, -1.2651697300669531, -1.3013779079374548, -0.64708221602355276])
    assert world.clearance(q)[0] < -0.03
    assert compiled(world).first_contact(q) == world.first_contact(q) == ("gripper", "crate")
    assert compiled(world).colliding(q[None, :]).tolist() == [True]
