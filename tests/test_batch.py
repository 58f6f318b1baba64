"""solve_ik_batch: the same answers as solve_ik, for many targets at once."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from conftest import plain

from armd import robots
from armd.errors import BadRequest
from armd.solvers import BatchIKResult, solve_ik, solve_ik_batch
from tests.test_fk import random_in_limits


@pytest.mark.parametrize("name", ["insomniac", "sg5ut", "gupta3", "desk4"])
@pytest.mark.parametrize("approach", [None, "parallel"])
def test_batch_equals_single(name: str, approach: str | None) -> None:
    arm = plain(name)
    if approach and not (arm.geometry and (arm.geometry.has_wrist or arm.geometry.level)):
        pytest.skip("no approach on an arm without a wrist")
    rng = np.random.default_rng(30)
    reachable = np.array([arm.fk(q) for q in random_in_limits(arm, 400, seed=31)])
    far = rng.normal(size=(20, 3))
    far = far / np.linalg.norm(far, axis=1, keepdims=True) * 0.8
    targets = np.vstack([reachable, far])
    batch = solve_ik_batch(arm, targets, approach=approach)
    assert len(batch) == len(targets)
    for i, t in enumerate(targets):
        single = solve_ik(arm, t, approach=approach)
        assert batch.status[i] == single.status
        assert batch.branch[i] == single.branch
        assert np.allclose(batch.q[i], single.q, atol=1e-12), (i, batch.q[i], single.q)
        assert math.isclose(batch.position_error[i], single.position_error, abs_tol=1e-12)
        assert np.allclose(batch.reached[i], single.reached, atol=1e-12)
        assert abs(math.remainder(batch.pitch[i] - single.pitch, 2 * math.pi)) < 1e-12
        assert arm.limits.contains(batch.q[i], tol=0.0)
    assert np.all(batch.status[-20:] == "unreachable")


@pytest.mark.parametrize("name", robots.names())
@pytest.mark.parametrize("approach", [None, "parallel"])
def test_batch_with_the_world_equals_single(name: str, approach: str | None) -> None:
    """With the arm's world (itself, its floor) the batch still answers as solve_ik does, row by
    row: an answer that collides moved to the clear branch solve_ik chooses (in compiled code),
    a target under the floor ``collision``."""
    arm = robots.load(name)
    if approach and not (arm.geometry and (arm.geometry.has_wrist or arm.geometry.level)):
        pytest.skip("no approach on an arm without a wrist")
    targets = mixed_targets(arm, 400, seed=40)
    batch = solve_ik_batch(arm, targets, approach=approach)
    assert_same(arm, batch, targets, approach=approach)
    bare = solve_ik_batch(arm, targets, approach=approach, collisions=False)
    assert "collision" in batch.status.tolist() and "collision" not in bare.status.tolist()
    if name in ("insomniac", "so101") and approach is None:  # (where these targets show it)
        moved = (batch.status == "ok") & (bare.status == "ok") & np.any(batch.q != bare.q, axis=1)
        assert moved.any()  # the world chose another branch for some, as solve_ik does


@pytest.mark.parametrize("name", ["insomniac", "sg5ut"])
def test_batch_with_a_pitch_per_target(name: str) -> None:
    arm = plain(name)
    rng = np.random.default_rng(33)
    qs = random_in_limits(arm, 300, seed=34)
    targets = np.array([arm.fk(q) for q in qs])
    pitches = rng.uniform(-math.pi, math.pi, size=len(qs))
    batch = solve_ik_batch(arm, targets, approach=pitches)
    for i in range(len(qs)):
        single = solve_ik(arm, targets[i], approach=float(pitches[i]))
        assert batch.status[i] == single.status
        assert np.allclose(batch.q[i], single.q, atol=1e-12)
    assert {"ok", "approximate"} <= set(batch.status.tolist())
    with pytest.raises(BadRequest):
        solve_ik_batch(arm, targets, approach=pitches[:-1])
    with pytest.raises(BadRequest):
        solve_ik_batch(arm, targets[:1], approach=[7.0])


def test_batch_with_seeds() -> None:
    arm = plain("gupta3")
    qs = random_in_limits(arm, 200, seed=32)
    targets = np.array([arm.fk(q) for q in qs])
    r = solve_ik_batch(arm, targets, seeds=qs)
    assert np.allclose(r.q, qs, atol=1e-9)  # each seed's own branch
    one = solve_ik_batch(arm, targets, seeds=arm.neutral)
    assert np.all(one.status == "ok")


MYCOBOT = Path(__file__).resolve().parent.parent / "examples" / "arms" / "mycobot280"


@pytest.fixture(scope="module")
def mycobot() -> robots.Robot:
    """The vendor's myCobot 280, outside the closed-form family (the numerical batch), with its
    world: itself and its floor."""
    arm = robots.load_folder(MYCOBOT)
    assert arm.geometry is None and arm.collision is not None
    return arm


def mixed_targets(arm: robots.Robot, n: int, seed: int) -> np.ndarray:
    """Tool points of ``n`` random configurations within limits (some colliding, some under the
    floor), and a few out of reach."""
    reachable = np.array([arm.fk(q) for q in random_in_limits(arm, n, seed=seed)])
    far = np.random.default_rng(seed).normal(size=(max(n // 25, 4), 3))
    return np.vstack([reachable, far / np.linalg.norm(far, axis=1, keepdims=True) * 0.6])


def assert_same(arm: robots.Robot, batch: BatchIKResult, targets: np.ndarray, **kwargs: Any) -> None:
    for i, t in enumerate(targets):
        single = solve_ik(arm, t, **kwargs)
        assert batch.status[i] == single.status, (i, batch.status[i], single.status)
        assert batch.branch[i] == single.branch
        assert np.allclose(batch.q[i], single.q, rtol=0.0, atol=1e-9), (i, batch.q[i], single.q)
        assert math.isclose(batch.position_error[i], single.position_error, rel_tol=1e-9, abs_tol=1e-15)
        assert np.allclose(batch.reached[i], single.reached, rtol=0.0, atol=1e-9)
        assert abs(math.remainder(batch.pitch[i] - single.pitch, 2 * math.pi)) < 1e-9
        assert batch.contact[i] == single.contact
        assert arm.limits.contains(batch.q[i], tol=0.0)


@pytest.mark.parametrize("collisions", [False, True])
@pytest.mark.parametrize("approach", [None, "parallel"])
def test_numerical_batch_equals_single(mycobot: robots.Robot, collisions: bool, approach: str | None) -> None:
    """The numerical batch (compiled over the rows, the rest through solve_ik) answers row by row
    as solve_ik does, with the world and without it (``collisions=False`` was once ignored:
    targets under the floor answered ``collision``)."""
    targets = mixed_targets(mycobot, 300, seed=35)
    batch = solve_ik_batch(mycobot, targets, approach=approach, collisions=collisions)
    assert_same(mycobot, batch, targets, approach=approach, collisions=collisions)
    seen = set(batch.status.tolist())
    assert {"ok", "unreachable"} <= seen
    assert ("collision" in seen) == collisions


def test_numerical_batch_with_seeds_and_pitches(mycobot: robots.Robot) -> None:
    qs = random_in_limits(mycobot, 200, seed=36)
    targets = np.array([mycobot.fk(q) for q in qs])
    pitches = np.random.default_rng(37).uniform(-math.pi, math.pi, size=len(qs))
    seeds = np.clip(
        qs + np.random.default_rng(38).normal(scale=0.05, size=qs.shape), mycobot.limits.lower, mycobot.limits.upper
    )
    batch = solve_ik_batch(mycobot, targets, approach=pitches, seeds=seeds)
    for i in range(len(qs)):
        single = solve_ik(mycobot, targets[i], approach=float(pitches[i]), seed=seeds[i])
        assert batch.status[i] == single.status
        assert np.allclose(batch.q[i], single.q, rtol=0.0, atol=1e-9)


def test_numerical_batch_checks_its_deadline(mycobot: robots.Robot) -> None:
    """``check`` is called as the batch goes (between its compiled calls), and what it raises
    abandons the batch."""
    calls = 0

    class Late(Exception):
        pass

    def check() -> None:
        nonlocal calls
        calls += 1
        if calls > 3:
            raise Late

    targets = mixed_targets(mycobot, 100, seed=39)
    with pytest.raises(Late):
        solve_ik_batch(mycobot, targets, check=check)
    assert calls == 4


@pytest.mark.parametrize(
    ("targets", "kwargs"),
    [
        ([], {}),
        ([[0.1, 0.2]], {}),
        ([[0.1, 0.2, float("nan")]], {}),
        ("points", {}),
        ([[0.1, 0.0, 0.1]], {"seeds": [0.0, 1.0]}),
        ([[0.1, 0.0, 0.1], [0.2, 0.0, 0.1]], {"seeds": [[0.0, 1.0, -1.0]] * 3}),
        ([[0.1, 0.0, 0.1]], {"approach": "parallel"}),
        ([[0.1, 0.0, 0.1]], {"tolerance": 0.0}),
    ],
)
def test_batch_bad_input(targets: object, kwargs: dict[str, object]) -> None:
    with pytest.raises(BadRequest):
        solve_ik_batch(plain("gupta3"), targets, **kwargs)  # type: ignore[arg-type]
