"""The numerical IK (solvers/lm.py, solve_chain) on an arm outside the closed-form family: the
myCobot 280's six joints, from its vendor's URDF (examples/arms/mycobot280). Every reachable
target met at 1e-9 m within the limits, an unreachable one answered as such within the limits,
never an exception; the iteration on the exact chain agrees with Pinocchio."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from armd import robots
from armd.solvers import solve_ik, solve_ik_batch
from armd.solvers.arm import arm_state
from armd.solvers.kinematics import pose

ROOT = Path(__file__).resolve().parent.parent
ARM = robots.load_folder(ROOT / "examples" / "arms" / "mycobot280")
ARM.collision = None  # (the arithmetic of the numerical IK; its world: tests/test_collision.py)


def test_the_six_joint_arm_is_outside_the_family_and_says_why() -> None:
    assert ARM.geometry is None and ARM.nq == 6
    assert ARM.solver.startswith("numerical: 6 joints move the tool")


def test_the_compiled_chain_is_pinocchios_model() -> None:
    chain = arm_state(ARM).packed_chain
    out = np.empty(3)
    rng = np.random.default_rng(1)
    for q in rng.uniform(ARM.limits.lower, ARM.limits.upper, size=(300, 6)):
        pitch = pose(chain, q, out)
        assert np.linalg.norm(out - ARM.fk(q)) < 1e-14
        assert abs((pitch - ARM.tool_pitch(q) + np.pi) % (2 * np.pi) - np.pi) < 1e-12


@pytest.mark.parametrize("seeded", [False, True])
def test_every_reachable_target_is_met(seeded: bool) -> None:
    rng = np.random.default_rng(2)
    for q in rng.uniform(ARM.limits.lower, ARM.limits.upper, size=(400, 6)):
        target = ARM.fk(q)
        seed = rng.uniform(ARM.limits.lower, ARM.limits.upper) if seeded else None
        r = solve_ik(ARM, target, seed=seed)
        assert r.status == "ok", (q.tolist(), r.reason)
        assert r.branch == "numerical" and ARM.limits.contains(r.q, tol=0.0)
        assert np.linalg.norm(ARM.fk(r.q) - target) <= 1e-9 and r.position_error <= 1e-9


def test_a_start_stuck_against_a_limit_is_left_early() -> None:
    # from a random seed, a third of the iterations creep toward an optimum pressed against a
    # joint limit; they are left after two slow steps (lm.STALL) for the atlas, instead of
    # spending all of lm.FIRST_STEPS there: 11 iterations a solve on average without the rule
    rng = np.random.default_rng(7)
    iterations = []
    for q in rng.uniform(ARM.limits.lower, ARM.limits.upper, size=(300, 6)):
        seed = rng.uniform(ARM.limits.lower, ARM.limits.upper)
        r = solve_ik(ARM, ARM.fk(q), seed=seed, tolerance=1e-6)
        assert r.status == "ok"
        iterations.append(r.iterations)
    assert np.mean(iterations) <= 9.0


def test_unreachable_targets_are_said_so_within_the_limits() -> None:
    rng = np.random.default_rng(3)
    for _ in range(60):
        d = rng.normal(size=3)
        target = d / np.linalg.norm(d) * rng.uniform(0.5, 2.0)  # the arm reaches about 0.45 m
        r = solve_ik(ARM, target)
        assert r.status == "unreachable" and ARM.limits.contains(r.q, tol=0.0)
        assert r.position_error == pytest.approx(float(np.linalg.norm(ARM.fk(r.q) - target)), abs=1e-12)
        assert "out of reach" in (r.reason or "") or "no start reached" in (r.reason or "")


def test_a_batch_answers_as_the_single_calls_do() -> None:
    rng = np.random.default_rng(4)
    qs = rng.uniform(ARM.limits.lower, ARM.limits.upper, size=(50, 6))
    targets = np.array([ARM.fk(q) for q in qs] + [[1.0, 1.0, 1.0]])
    b = solve_ik_batch(ARM, targets)
    assert list(b.status[:-1]) == ["ok"] * 50 and b.status[-1] == "unreachable"
    for i, t in enumerate(targets):
        assert np.linalg.norm(ARM.fk(b.q[i]) - t) == pytest.approx(b.position_error[i], abs=1e-12)
