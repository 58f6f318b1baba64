"""solve_ik: every answer lands where it says, within every limit, with an honest status."""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from conftest import plain

from armd import robots, solvers
from armd.errors import BadRequest
from armd.solvers import SensorReading, solve_ik
from tests.test_fk import random_in_limits

ARMS = ["insomniac", "sg5ut", "gupta3", "desk4"]
WRIST_ARMS = ["insomniac", "sg5ut"]
N = 1500
TOL = 1e-9


def assert_valid(arm: robots.Robot, q: np.ndarray, target: np.ndarray, tol: float = TOL) -> None:
    assert arm.limits.contains(q, tol=0.0), arm.limits.violations(q, 0.0)
    assert np.linalg.norm(arm.fk(q) - target) <= tol


@pytest.mark.parametrize("name", ARMS)
def test_reachable_targets_are_solved_exactly(name: str) -> None:
    arm = plain(name)
    for q in random_in_limits(arm, N, seed=11):
        target = arm.fk(q)
        r = solve_ik(arm, target)
        assert r.status == "ok", (q.tolist(), r.reason)
        assert_valid(arm, r.q, target)
        assert r.position_error <= TOL
        assert np.allclose(r.reached, arm.fk(r.q), atol=1e-15)
        for b in r.branches:  # every other branch returned is valid too
            assert_valid(arm, b.q, target)


@pytest.mark.parametrize("name", ARMS)
def test_random_seeds(name: str) -> None:
    arm = plain(name)
    seeds = random_in_limits(arm, 300, seed=12)
    for q, seed in zip(random_in_limits(arm, 300, seed=13), seeds, strict=True):
        r = solve_ik(arm, arm.fk(q), seed=seed)
        assert r.status == "ok"
        assert_valid(arm, r.q, arm.fk(q))


def pitched_configs(arm: robots.Robot, pitch: float, n: int, seed: int) -> np.ndarray:
    """In-limit configurations whose tool pitch is exactly ``pitch`` (wrist = pitch - shoulder - elbow)."""
    g = arm.geometry
    assert g is not None and g.wrist is not None
    qs = random_in_limits(arm, 4 * n, seed=seed)
    qs[:, g.wrist] = pitch - qs[:, g.shoulder] - qs[:, g.elbow]
    return qs[arm.limits.contains_batch(qs)][:n]


@pytest.mark.parametrize("name", WRIST_ARMS)
@pytest.mark.parametrize(
    ("approach", "pitch"), [("parallel", 0.0), ("perpendicular", -math.pi / 2), (0.4, 0.4), (-1.0, -1.0)]
)
def test_approach_modes(name: str, approach: object, pitch: float) -> None:
    arm = plain(name)
    qs = pitched_configs(arm, pitch, 300, seed=14)
    assert len(qs) > 50
    for q in qs:
        target = arm.fk(q)
        r = solve_ik(arm, target, approach=approach)
        assert r.status == "ok", r.reason
        assert_valid(arm, r.q, target)
        assert r.pitch_error is not None and abs(r.pitch_error) <= 1e-9
        assert abs(math.remainder(arm.tool_pitch(r.q) - pitch, 2 * math.pi)) <= 1e-9
        for b in r.branches:
            assert_valid(arm, b.q, target)
            assert abs(math.remainder(arm.tool_pitch(b.q) - pitch, 2 * math.pi)) <= 1e-9


@pytest.mark.parametrize("name", WRIST_ARMS)
def test_free_pitch_prefers_parallel_then_perpendicular(name: str) -> None:
    arm = plain(name)
    for q in pitched_configs(arm, 0.0, 100, seed=15):
        r = solve_ik(arm, arm.fk(q))
        assert abs(r.pitch) <= 1e-9  # level whenever level is reachable
    for q in pitched_configs(arm, -math.pi / 2, 100, seed=16):
        target = arm.fk(q)
        r = solve_ik(arm, target)
        if solve_ik(arm, target, approach="parallel").status == "ok":
            assert abs(r.pitch) <= 1e-9
        else:
            assert abs(r.pitch + math.pi / 2) <= 1e-9


@pytest.mark.parametrize("name", WRIST_ARMS)
def test_free_pitch_otherwise_nearest_reachable(name: str) -> None:
    """When neither level nor down is reachable, no reachable pitch is nearer to them than armd's."""
    arm = plain(name)
    grid = np.linspace(-math.pi, math.pi, 721)
    checked = 0
    for q in random_in_limits(arm, 400, seed=17):
        target = arm.fk(q)
        r = solve_ik(arm, target)
        if abs(r.pitch) < 1e-9 or abs(r.pitch + math.pi / 2) < 1e-9:
            continue
        checked += 1
        chosen = min(abs(math.remainder(r.pitch - p, 2 * math.pi)) for p in (0.0, -math.pi / 2))
        for phi in grid:
            d = min(abs(math.remainder(phi - p, 2 * math.pi)) for p in (0.0, -math.pi / 2))
            if d < chosen - 1e-6:
                assert solve_ik(arm, target, approach=float(phi)).status != "ok", (q.tolist(), phi, r.pitch)
        if checked >= 25:
            break
    assert checked >= 10


@pytest.mark.parametrize("name", WRIST_ARMS)
def test_unreachable_pitch_is_approximate(name: str) -> None:
    arm = plain(name)
    seen = 0
    for q in random_in_limits(arm, 300, seed=18):
        target = arm.fk(q)
        r = solve_ik(arm, target, approach="perpendicular")
        if r.status == "ok":
            continue
        assert r.status == "approximate"
        assert_valid(arm, r.q, target)  # the position is still reached exactly
        assert r.pitch_error is not None and abs(r.pitch_error) > 1e-9
        assert r.reason and "pitch" in r.reason
        seen += 1
    assert seen > 10


@pytest.mark.parametrize("name", ARMS)
def test_unreachable_targets_get_the_closest_point(name: str) -> None:
    arm = plain(name)
    rng = np.random.default_rng(19)
    samples = random_in_limits(arm, 20000, seed=20)
    points = np.array([arm.fk(q) for q in samples])
    for _ in range(40):
        direction = rng.normal(size=3)
        direction /= np.linalg.norm(direction)
        target = direction * rng.uniform(0.5, 1.5)  # far beyond every arm's reach
        r = solve_ik(arm, target)
        assert r.status == "unreachable"
        assert arm.limits.contains(r.q, tol=0.0)
        assert np.allclose(r.reached, arm.fk(r.q), atol=1e-15)
        assert math.isclose(r.position_error, float(np.linalg.norm(r.reached - target)), rel_tol=1e-12)
        assert r.reason
        # no sampled configuration within limits gets closer
        best_sampled = float(np.min(np.linalg.norm(points - target, axis=1)))
        assert r.position_error <= best_sampled + 1e-6


@pytest.mark.parametrize("name", ARMS)
def test_enumerated_closest_point_is_never_worse_than_the_iteration(name: str) -> None:
    """The enumerated closest point answers every catalogue arm (desk4 too, with its offset pivot
    and coupled limit: tests/test_closest.py), and a many-start iteration finds nothing nearer."""
    from armd.solvers.arm import arm_state
    from armd.solvers.closest import closest_box
    from armd.solvers.lm import refine_family

    arm = plain(name)
    a = arm_state(arm)
    fp = a.packed_family
    assert fp is not None
    rng = np.random.default_rng(23)
    used = 0
    for i in range(600):
        direction = rng.normal(size=3) + (np.array([0.0, 0.0, 50.0]) if i % 5 == 0 else 0.0)  # some near the axis
        target = direction / np.linalg.norm(direction) * rng.uniform(0.05, 1.0)
        r = solve_ik(arm, target)
        if r.status != "unreachable":
            continue  # (the enumeration is asked only when no configuration reaches the target)
        q = np.empty(arm.nq)
        err = closest_box(fp, target, arm.neutral, q, True)  # (the catalogue's family angles are the URDF's)
        assert err >= 0.0, target.tolist()
        used += 1
        assert arm.limits.contains(q, tol=0.0)
        assert math.isclose(err, float(np.linalg.norm(arm.fk(q) - target)), rel_tol=1e-12)
        assert r.iterations == 0 and math.isclose(r.position_error, err, rel_tol=1e-12)
        for k in rng.choice(len(a.atlas.q), 12, replace=False):
            q0 = a.atlas.q[k].copy()
            other, _, _ = refine_family(fp, target, 0.0, 0.0, q0, 300, 0.4, 1e-12)
            assert err <= other + 1e-9, (target.tolist(), err, other)
        if used >= 40:
            break
    assert used >= 40


def test_seed_picks_the_nearest_branch_deterministically() -> None:
    arm = plain("gupta3")
    for q in random_in_limits(arm, 300, seed=21):
        target = arm.fk(q)
        r = solve_ik(arm, target, seed=q)
        assert np.allclose(r.q, q, atol=1e-9)  # the seed's own branch is the nearest
        again = solve_ik(arm, target, seed=q)
        assert np.array_equal(r.q, again.q) and r.branch == again.branch
    # elbow up and down both valid: the seed decides
    target = arm.fk(np.array([0.2, 0.9, -1.2]))
    up = solve_ik(arm, target, seed=[0.2, 0.9, -1.2])
    assert up.branch == "front/elbow_up" and up.q[2] < 0
    assert {b.name for b in up.branches} >= {"front/elbow_down"} or len(up.branches) >= 0


def test_elbow_names_match_the_geometry() -> None:
    """elbow_up: the elbow lies above the line from the shoulder to the wrist."""
    for name in ARMS:
        arm = plain(name)
        g = arm.geometry
        assert g is not None
        for q in random_in_limits(arm, 200, seed=22):
            r = solve_ik(arm, arm.fk(q))
            for b in (r, *r.branches):
                qq = b.q
                phi1 = qq[g.shoulder]
                elbow = np.array([g.upper_arm * math.cos(phi1), g.upper_arm * math.sin(phi1)])
                wrist = elbow + g.forearm * np.array([math.cos(phi1 + qq[g.elbow]), math.sin(phi1 + qq[g.elbow])])
                side = wrist[0] * elbow[1] - wrist[1] * elbow[0]  # > 0: elbow left of shoulder->wrist
                if abs(side) < 1e-9:
                    continue
                above = side > 0 if wrist[0] >= 0 else side < 0
                name_b = b.branch if hasattr(b, "branch") else b.name
                assert name_b.endswith("elbow_up") == above, (name, qq.tolist(), name_b)


def test_sensor_reading_target_matches_seed_000() -> None:
    arm = plain("insomniac")
    reading = SensorReading("et_left", 0.25, -0.3)
    r = solve_ik(arm, reading, approach="parallel")
    expected = np.array([0.12 + 0.25 * math.cos(-0.3), 0.10 + 0.25 * math.sin(-0.3), 0.10])
    assert np.allclose(r.target, expected, atol=1e-15)
    assert r.status == "ok"
    assert_valid(arm, r.q, expected)
    r2 = solve_ik(arm, {"sensor": "et_right", "range": 0.3, "bearing": 0.2})
    assert np.allclose(r2.target, [0.12 + 0.3 * math.cos(0.2), -0.10 + 0.3 * math.sin(0.2), 0.10])


def test_a_reading_of_a_sensor_on_the_arm_is_converted_at_the_seed_and_refused_without_one() -> None:
    """Issue 19's bug: the gripper's GP2D120 looks along the tool; its reading was converted at
    the neutral pose when no seed was given (0.52 m off, and ``ok``)."""
    arm = plain("insomniac")
    q = np.array([0.5, 1.4, -1.3, -0.4, 0.2])
    r = solve_ik(arm, {"sensor": "gripper_et", "range": 0.08}, seed=q)
    assert np.allclose(r.target, arm.sensor_point("gripper_et", 0.08, q=q), atol=1e-12)
    assert np.linalg.norm(r.target - arm.sensor_point("gripper_et", 0.08, q=arm.neutral)) > 0.05
    with pytest.raises(BadRequest) as e:
        solve_ik(arm, {"sensor": "gripper_et", "range": 0.08})
    assert e.value.field == "seed" and "gripper_et" in e.value.message


BAD = [
    ("insomniac", {"target": [0.2, float("nan"), 0.1]}, "target"),
    ("insomniac", {"target": [0.2, 0.1]}, "target"),
    ("insomniac", {"target": "0.2 0.1 0.1"}, "target"),
    ("insomniac", {"target": [0.2, 0.1, float("inf")]}, "target"),
    ("insomniac", {"target": SensorReading("nose", 0.3)}, "sensor"),
    ("insomniac", {"target": {"sensor": "et_left"}}, "target"),
    ("insomniac", {"target": SensorReading("et_left", 2.0)}, "range"),
    ("insomniac", {"target": [0.2, 0.0, 0.1], "approach": 4.0}, "approach"),
    ("insomniac", {"target": [0.2, 0.0, 0.1], "approach": float("nan")}, "approach"),
    ("insomniac", {"target": [0.2, 0.0, 0.1], "approach": "sideways"}, "approach"),
    ("insomniac", {"target": [0.2, 0.0, 0.1], "approach": True}, "approach"),
    ("insomniac", {"target": [0.2, 0.0, 0.1], "seed": [0.0, 1.0]}, "seed"),
    ("insomniac", {"target": [0.2, 0.0, 0.1], "seed": [0, 1, 2, 3, float("nan")]}, "seed"),
    ("insomniac", {"target": [0.2, 0.0, 0.1], "tolerance": -1.0}, "tolerance"),
    ("gupta3", {"target": [0.2, 0.0, 0.1], "approach": "parallel"}, "approach"),
    ("desk4", {"target": [0.2, 0.0, 0.1], "approach": "perpendicular"}, "approach"),
    ("desk4", {"target": [0.2, 0.0, 0.1], "quantise": True}, "quantise"),
]


@pytest.mark.parametrize(("name", "kwargs", "field"), BAD)
def test_bad_input_raises_the_typed_error(name: str, kwargs: dict[str, object], field: str) -> None:
    arm = plain(name)
    target = kwargs.pop("target")
    with pytest.raises(BadRequest) as e:
        solve_ik(arm, target, **kwargs)  # type: ignore[arg-type]
    assert e.value.field == field
    assert e.value.code == "bad_request"


def test_desk4_parallel_is_its_only_pitch() -> None:
    arm = plain("desk4")
    q = np.array([0.3, 1.0, -0.8])
    r = solve_ik(arm, arm.fk(q), approach="parallel")
    assert r.status == "ok" and abs(r.pitch) < 1e-12


def test_quantised_answers_are_whole_microsteps() -> None:
    arm = plain("gupta3")
    steps = arm.actuators
    for q in random_in_limits(arm, 200, seed=23):
        target = arm.fk(q)
        exact = solve_ik(arm, target, seed=q)
        r = solve_ik(arm, target, seed=q, quantise=True)
        cmds = steps.commands(r.q)
        assert np.allclose(steps.joints_from_commands(cmds), r.q, atol=1e-12)  # on the step grid
        assert arm.limits.contains(r.q, tol=0.0)
        assert math.isclose(r.position_error, float(np.linalg.norm(arm.fk(r.q) - target)), rel_tol=1e-9)
        # no worse than rounding the exact answer to the nearest step
        rounded = steps.quantise(exact.q)
        if arm.limits.contains(rounded, tol=0.0):
            assert r.position_error <= np.linalg.norm(arm.fk(rounded) - target) + 1e-15
        assert r.position_error < 1e-3
        assert r.status in ("ok", "approximate")
        if r.status == "approximate":
            assert r.reason and "quantised" in r.reason


def test_idealised_geometry_is_refined_on_the_exact_model(arm_copy: Callable[..., Path]) -> None:
    """Seed 004's planar model (y_steer = 0) as [geometry]: the QP makes up the difference."""
    folder = arm_copy("desk4", toml_edits=[("pivot = [0.012, 0.008, 0.138]", "pivot = [0.012, 0.0, 0.138]")])
    arm = robots.load_folder(folder)
    arm.collision = None  # (the refinement's arithmetic, at every configuration within the limits)
    refined = 0
    for q in random_in_limits(arm, 300, seed=24):
        target = arm.fk(q)
        r = solve_ik(arm, target)
        assert r.status == "ok", r.reason
        assert_valid(arm, r.q, target)
        refined += r.iterations > 0
    assert refined > 250


def test_arm_outside_the_family_gets_the_qp(arm_copy: Callable[..., Path]) -> None:
    """gupta3 with no [geometry] and its elbow's axis tilted 0.1 rad: no longer parallel to the
    shoulder's, so no closed form; the numerical IK answers, and the catalogue says why."""
    text_start = "# Seed 002: r = sqrt"
    folder = arm_copy("gupta3")
    toml = (folder / "robot.toml").read_text()
    head, rest = toml.split(text_start)
    tail = rest[rest.index("# Arduino") :]
    (folder / "robot.toml").write_text(head + tail)
    urdf = (folder / "robot.urdf").read_text()
    elbow = urdf.index('<joint name="elbow"')
    axis = urdf.index('<axis xyz="0 -1 0"/>', elbow)
    tilted = f'<axis xyz="0 {-math.cos(0.1)!r} {math.sin(0.1)!r}"/>'
    (folder / "robot.urdf").write_text(urdf[:axis] + tilted + urdf[axis + len('<axis xyz="0 -1 0"/>') :])
    arm = robots.load_folder(folder)
    arm.collision = None  # (the numerical IK's arithmetic, at every configuration within the limits)
    assert arm.geometry is None
    assert (
        arm.solver
        == "numerical: joint 'elbow''s axis is not parallel to 'shoulder''s: one pitch joint, the family needs 2 or 3"
    )
    for q in random_in_limits(arm, 100, seed=25):
        target = arm.fk(q)
        r = solve_ik(arm, target)
        assert r.status == "ok", r.reason
        assert r.branch == "numerical"
        assert_valid(arm, r.q, target)
    far = solve_ik(arm, [1.0, 1.0, 1.0])
    assert far.status == "unreachable" and arm.limits.contains(far.q, tol=0.0)


def test_result_to_dict_is_json_ready() -> None:
    import json

    arm = plain("sg5ut")
    r = solve_ik(arm, arm.fk(arm.neutral), approach="parallel")
    d = json.loads(json.dumps(r.to_dict()))
    assert d["status"] == "ok" and len(d["q"]) == 4 and d["pitch_error"] == pytest.approx(0.0, abs=1e-9)
    assert solvers.OK == "ok"


def test_targets_on_the_yaw_axis_do_not_crash() -> None:
    """Regression: near the yaw axis the closest-point QP's Hessian is singular; it once wrote
    out of bounds in compiled code and killed the process."""
    cases = [
        ("sg5ut", [7.744009405302617e-05, 0.0002055236077616692, -0.5092999526438997]),
        ("insomniac", [1.7792167880040976e-05, 7.348709174289033e-05, 0.2506667112265063]),
        ("gupta3", [0.0, 0.0, 0.5]),
        ("desk4", [0.0, 0.0, 0.9]),
    ]
    for name, target in cases:
        arm = plain(name)
        r = solve_ik(arm, target)
        assert arm.limits.contains(r.q, tol=0.0)
        assert r.status in ("ok", "unreachable")
        assert math.isclose(r.position_error, float(np.linalg.norm(arm.fk(r.q) - np.array(target))), abs_tol=1e-12)
