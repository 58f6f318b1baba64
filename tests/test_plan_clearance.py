"""planning.clearance: every plan clear of the arm's world, at every sample and between them.

The plans are held against an independent computation: coal's distance between each checked
pair's shapes, placed by Pinocchio data made for each configuration alone, along the joint
polyline through the samples at 1 mm of travel."""

from __future__ import annotations

import logging
import math

import coal
import numpy as np
import pinocchio as pin
import pytest
from conftest import clear_configs

from armd import planning, robots
from armd.errors import CollisionError, PlanRejected
from armd.planning.clearance import CONTACT, check_clear
from armd.robots.collision import GROUND, Obstacle

ARMS = robots.names()


def distances(arm: robots.Robot, q: np.ndarray) -> dict[tuple[str, str], float]:
    """Each checked pair's distance at ``q`` [m], from scratch: Pinocchio data made for ``q``
    alone, coal's distance between the two shapes so placed."""
    cm = arm.collision
    assert cm is not None
    data, gdata = cm.model.createData(), pin.GeometryData(cm.geometry)
    pin.updateGeometryPlacements(cm.model, data, cm.geometry, gdata, q)
    objs = cm.geometry.geometryObjects
    out = {}
    for k, cp in enumerate(cm.geometry.collisionPairs):
        a, b = cp.first, cp.second
        out[(cm.pairs[k].first, cm.pairs[k].second)] = coal.distance(
            objs[a].geometry,
            coal.Transform3s(gdata.oMg[a].rotation, gdata.oMg[a].translation),
            objs[b].geometry,
            coal.Transform3s(gdata.oMg[b].rotation, gdata.oMg[b].translation),
            coal.DistanceRequest(),
            coal.DistanceResult(),
        )
    return out


def distance(arm: robots.Robot, q: np.ndarray) -> tuple[float, tuple[str, str]]:
    """The smallest distance between a checked pair at ``q`` and the pair, from scratch."""
    pair, d = min(distances(arm, q).items(), key=lambda kv: kv[1])
    return d, pair


def swing(arm: robots.Robot, yaw: float) -> tuple[np.ndarray, np.ndarray]:
    """The neutral pose turned to yaw -``yaw`` and +``yaw`` [rad]: a move that sweeps the tool
    round an arc through the neutral tool point."""
    start = arm.neutral.copy()
    start[0] = -yaw
    goal = start.copy()
    goal[0] = yaw
    return start, goal


def along(times: np.ndarray, P: np.ndarray, step: float, until: float = math.inf):  # type: ignore[no-untyped-def]
    """(t, q) along the straight joint moves between the samples, at most ``step`` [rad] apart
    in every joint, up to time ``until``."""
    for k in range(len(P) - 1):
        n = max(1, math.ceil(float(np.max(np.abs(P[k + 1] - P[k]))) / step))
        for i in range(n):
            f = i / n
            t = float(times[k] + f * (times[k + 1] - times[k]))
            if t >= until:
                return
            yield t, P[k] + f * (P[k + 1] - P[k])
    if times[-1] < until:
        yield float(times[-1]), P[-1]


def with_box(arm: robots.Robot, size: tuple[float, float, float], centre: tuple[float, float, float]) -> robots.Robot:
    copy = robots.load_folder(robots.CATALOGUE_DIR / arm.name)
    copy.collision = arm.collision.with_obstacles([Obstacle("crate", "box", size, centre)])  # type: ignore[union-attr]
    return copy


@pytest.mark.parametrize("name", ARMS)
def test_the_travel_bound_holds(name: str) -> None:
    """No corner of any moving shape's box moves farther than ``abs(dq) @ travel`` along a
    straight move of the joints (the bound the walk's steps rest on)."""
    arm = robots.load(name)
    cm = arm.collision
    assert cm is not None
    rng = np.random.default_rng(sum(name.encode()))
    corners = []
    for g in cm.geometry.geometryObjects:
        if g.parentJoint == 0:
            continue
        g.geometry.computeLocalAABB()
        lo, hi = np.asarray(g.geometry.aabb_local.min_), np.asarray(g.geometry.aabb_local.max_)
        corners.append([np.where(np.array(bits), hi, lo) for bits in np.ndindex(2, 2, 2)])
    data = cm.model.createData()

    def points(q: np.ndarray) -> np.ndarray:
        pin.framesForwardKinematics(cm.model, data, q)
        pin.updateGeometryPlacements(cm.model, data, cm.geometry, gdata, q)
        out = []
        moving = [g for g in range(len(cm.geometry.geometryObjects)) if cm.geometry.geometryObjects[g].parentJoint]
        for g, cs in zip(moving, corners, strict=True):
            out += [gdata.oMg[g].act(c) for c in cs]
        return np.array(out)

    gdata = pin.GeometryData(cm.geometry)
    worst = 0.0
    for _ in range(300):
        qa = rng.uniform(arm.limits.lower, arm.limits.upper)
        qb = np.clip(qa + rng.normal(scale=0.3, size=arm.nq), arm.limits.lower, arm.limits.upper)
        bound = float(np.abs(qb - qa) @ cm.travel)
        pa = points(qa)
        path = 0.0
        prev = pa
        for f in np.linspace(0, 1, 9)[1:]:
            p = points(qa + f * (qb - qa))
            path += float(np.max(np.linalg.norm(p - prev, axis=1)))  # (a lower bound of the longest path)
            prev = p
        assert float(np.max(np.linalg.norm(prev - pa, axis=1))) <= bound + 1e-12
        worst = max(worst, path / bound)
    assert worst <= 1.0 + 1e-9
    assert worst > 0.3  # (the bound is not vacuous: a tenth of the arm's reach per radian would fail this)


@pytest.mark.parametrize("name", ARMS)
def test_every_plan_is_clear_and_every_contact_found_is_real(name: str) -> None:
    """Random clear starts and goals among a random box. The straight motion (planned without the
    world): where the clearance walk finds a contact, the pair it names is in contact at the
    time it says and the motion before is clear; where it finds none, the motion is clear. The
    plan with the world: clear along the whole motion (independently, at 1 mm steps), around
    the box where the straight one hits it."""
    base = robots.load(name)
    rng = np.random.default_rng(sum(name.encode()) + 17)
    made = hits = around = 0
    for trial in range(12):
        reach = float(np.linalg.norm(base.fk(base.neutral)))
        start, goal = clear_configs(base, rng, 2)
        while True:  # a box, half the time where the tool passes halfway, that leaves both ends clear
            if trial % 2:
                centre = rng.uniform([-reach, -reach, 0.02], [reach, reach, reach])
            else:
                centre = base.fk(0.5 * (start + goal)) + rng.normal(scale=0.02, size=3)
            size = tuple(rng.uniform(0.03, 0.12, size=3))
            arm = with_box(base, size, tuple(centre))  # type: ignore[arg-type]
            cm = arm.collision
            assert cm is not None
            if min(cm.clearance(start)[0], cm.clearance(goal)[0]) >= CONTACT:  # (nearer is contact)
                break
            start, goal = clear_configs(base, rng, 2)
        step = 0.001 / float(np.max(cm.travel))
        rate = float(rng.choice([5.0, 50.0]))
        straight = planning.plan(_plain(arm), start, goal, rate_hz=rate)
        hit = None
        try:
            check_clear(arm, straight.times, straight.position)
        except CollisionError as e:
            hit = e
        if hit is not None:
            hits += 1
            assert hit.time is not None and hit.time > 0.0
            pair_d = _pair_distance(arm, _at(straight, hit.time), hit.pair)
            assert pair_d < CONTACT, (trial, hit.pair, pair_d)  # (nearer than 10 um counts as contact)
            for t, q in along(straight.times, straight.position, step, until=hit.time - 1e-9):
                assert distance(arm, q)[0] > -1e-9, (trial, t)
        else:
            for t, q in along(straight.times, straight.position, step):
                assert distance(arm, q)[0] > -1e-9, (trial, t)
        try:
            tr = planning.plan(arm, start, goal, rate_hz=rate)
        except CollisionError as e:
            assert hit is not None and "no way around" in e.message, e.message
            continue
        made += 1
        around += hit is not None
        for t, q in along(tr.times, tr.position, step):
            d, pair = distance(arm, q)
            assert d > -1e-9, (trial, t, pair, d)
        assert np.allclose(tr.position[-1], goal, atol=1e-9) and np.allclose(tr.position[0], start)
    assert made >= 8 and hits >= 2 and around >= 1, (made, hits, around)


def _plain(arm: robots.Robot) -> robots.Robot:
    """The same arm without its world: the motion the checked plan would have been."""
    copy = robots.load_folder(robots.CATALOGUE_DIR / arm.name)
    copy.collision = None
    return copy


def _at(tr: planning.Trajectory, t: float) -> np.ndarray:
    """The configuration on the straight joint move between the samples around time ``t``."""
    k = min(int(np.searchsorted(tr.times, t, side="right")) - 1, len(tr.times) - 2)
    f = (t - tr.times[k]) / (tr.times[k + 1] - tr.times[k])
    return np.asarray(tr.position[k] + f * (tr.position[k + 1] - tr.position[k]))


def _pair_distance(arm: robots.Robot, q: np.ndarray, pair: tuple[str, str]) -> float:
    return float(distances(arm, q)[tuple(pair)])  # type: ignore[index]


def test_a_thin_plate_between_two_clear_samples_is_found() -> None:
    """Two samples, both clear, on either side of a 2 mm plate the arm sweeps through: the check
    between them finds it (the samples alone would not)."""
    base = robots.load("insomniac")
    qa, qb = swing(base, 0.4)
    tip = base.fk(base.neutral)
    arm = with_box(base, (0.3, 0.002, 0.3), (float(tip[0]) * 0.8, 0.0, float(tip[2])))
    assert arm.collision.first_contact(qa) is None and arm.collision.first_contact(qb) is None  # type: ignore[union-attr]
    with pytest.raises(CollisionError) as e:
        check_clear(arm, np.array([0.0, 1.0]), np.array([qa, qb]))
    assert "crate" in e.value.pair and 0.0 < e.value.time < 1.0  # type: ignore[operator]
    assert e.value.to_dict()["code"] == "collision"
    n = check_clear(base, np.array([0.0, 1.0]), np.array([qa, qb]))  # (without the plate: clear, few checks)
    assert 1 <= n <= 20


def test_a_joint_move_goes_around_a_box_and_a_line_through_it_is_refused() -> None:
    """A crate on the way: the joint move's straight path hits it, the plan goes around it (the
    sampling planner), clear all the way, longer than the straight one; the line through the
    crate is refused with ``collision``, the arm's link and the crate named, the time inside
    the motion; the same moves without the crate are planned."""
    arm = robots.load("insomniac")
    start, goal = swing(arm, 0.8)
    tip = arm.fk(arm.neutral)
    straight = planning.plan(arm, start, goal)
    boxed = with_box(arm, (0.06, 0.06, 0.06), (float(tip[0]), 0.0, float(tip[2])))
    with pytest.raises(CollisionError):
        check_clear(boxed, straight.times, straight.position)
    tr = planning.plan(boxed, start, goal)
    assert tr.duration > straight.duration and np.allclose(tr.position[-1], goal, atol=1e-9)
    step = 0.001 / float(np.max(boxed.collision.travel))  # type: ignore[union-attr]
    assert min(distance(boxed, q)[0] for _, q in along(tr.times, tr.position, step)) > 0.0
    line_goal = {"target": arm.fk(goal).tolist()}
    line = planning.plan(arm, start, line_goal, path="line")
    # the line runs along the chord of the tool's arc: a crate on its middle
    boxed = with_box(arm, (0.06, 0.06, 0.06), (float(tip[0] * math.cos(0.8)), 0.0, float(tip[2])))
    with pytest.raises(CollisionError) as e:
        planning.plan(boxed, start, line_goal, path="line")
    assert e.value.pair[1] == "crate" and e.value.pair[0] in boxed.collision.links  # type: ignore[union-attr]
    assert e.value.time is not None and 0.0 < e.value.time < line.duration
    assert f"t = {e.value.time:.4f} s" in e.value.message


def test_a_goal_no_path_is_found_to_is_refused_naming_the_pair_and_the_time(monkeypatch: pytest.MonkeyPatch) -> None:
    """When the sampling planner finds no way round in its time (here given 10 us), the plan is
    refused naming the pair and the time of the straight move's contact; from a moving state
    no way round is looked for."""
    from armd.planning import sampling

    arm = robots.load("insomniac")
    start, goal = swing(arm, 0.8)
    tip = arm.fk(arm.neutral)
    boxed = with_box(arm, (0.06, 0.06, 0.06), (float(tip[0]), 0.0, float(tip[2])))
    monkeypatch.setattr(sampling, "TIME", 1e-5)
    with pytest.raises(CollisionError) as e:
        planning.plan(boxed, start, goal)
    assert e.value.pair[1] == "crate" and e.value.time is not None and e.value.time > 0.0
    assert "no way around in 1e-05 s" in e.value.message
    monkeypatch.undo()
    moving = planning.JointState(start, np.full(arm.nq, 0.05), np.zeros(arm.nq))
    with pytest.raises(CollisionError) as e:
        planning.plan(boxed, moving, goal)
    assert e.value.pair[1] == "crate"
    assert planning.plan(boxed, start, goal).duration > 0.0  # (with its time, it finds one)


def test_goals_that_collide_are_refused_naming_the_pair() -> None:
    arm = robots.load("insomniac")
    with pytest.raises(CollisionError) as e:
        planning.plan(arm, arm.neutral, {"target": [0.3, 0.0, -0.05]})  # under the floor (seed 001)
    assert e.value.pair[1] == GROUND and e.value.fields["field"] == "goal"
    tip = arm.fk(arm.neutral)
    boxed = with_box(arm, (0.08, 0.08, 0.08), (float(tip[0]), float(tip[1]), float(tip[2])))
    with pytest.raises(CollisionError) as e:
        planning.plan(boxed, clear_configs(boxed, np.random.default_rng(3), 1)[0], arm.neutral)
    assert "crate" in e.value.pair and e.value.time is None
    with pytest.raises((CollisionError, PlanRejected)):
        planning.plan(boxed, arm.neutral, {"target": tip.tolist()}, path="line")


def test_stops_are_never_checked() -> None:
    """A stop is never refused: from a state already in contact, it is planned all the same."""
    arm = robots.load("insomniac")
    tip = arm.fk(arm.neutral)
    boxed = with_box(arm, (0.08, 0.08, 0.08), (float(tip[0]), float(tip[1]), float(tip[2])))
    assert boxed.collision.first_contact(arm.neutral) is not None  # type: ignore[union-attr]
    moving = planning.JointState(arm.neutral, np.full(arm.nq, 0.3), np.zeros(arm.nq))
    stop = planning.plan_stop(boxed, moving)
    assert stop.duration > 0.0


def test_a_refusal_over_the_service_is_a_collision_error_naming_the_pair(client: object) -> None:
    """The client raises the same class as the planner in-process, with the pair."""
    from armd.clients import ArmClient

    assert isinstance(client, ArmClient)
    with pytest.raises(CollisionError) as e:
        client.plan("insomniac", {"target": [0.3, 0.0, -0.05]})
    assert e.value.code == "collision" and tuple(e.value.pair) == ("tool", GROUND)


def test_ompls_chatter_goes_to_the_log_never_the_terminal(
    capfd: pytest.CaptureFixture[str], caplog: pytest.LogCaptureFixture
) -> None:
    """A search from a start in contact: OMPL's "Error: RRTConnect: Motion planning start tree
    could not be initialized!" is in armd's log at debug, and nothing reaches stdout or stderr."""
    from armd.planning import sampling

    arm = robots.load("insomniac")
    start, goal = swing(arm, 0.8)
    tip = arm.fk(start)
    boxed = with_box(arm, (0.06, 0.06, 0.06), (float(tip[0]), float(tip[1]), float(tip[2])))
    with caplog.at_level(logging.DEBUG, logger="armd.planning.sampling"):
        assert sampling.path_around(boxed, start, goal, time_limit=0.05) is None
    out, err = capfd.readouterr()
    assert "RRTConnect" not in out + err, out + err
    said = [r for r in caplog.records if r.name == "armd.planning.sampling" and r.levelno == logging.DEBUG]
    assert any("RRTConnect: Motion planning start tree could not be initialized" in r.getMessage() for r in said)
