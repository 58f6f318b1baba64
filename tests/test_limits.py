"""Box and coupled joint limits."""

from __future__ import annotations

import numpy as np
import pytest

from armd import robots
from armd.errors import CoupledLimitError, JointLimitError


def test_desk4_coupled_limit_rejects_what_it_must() -> None:
    arm = robots.load("desk4")
    lim = arm.limits
    inside_box_outside_linkage = [
        np.array([0.0, 1.9, -0.5]),  # q2 + q3 = 1.4 > 0.9
        np.array([0.0, 0.2, -1.5]),  # q2 + q3 = -1.3 < -1.2
    ]
    for q in inside_box_outside_linkage:
        assert np.all(q >= lim.lower) and np.all(q <= lim.upper)
        assert not lim.contains(q)
        with pytest.raises(CoupledLimitError) as e:
            lim.check(q)
        assert e.value.name == "linkage"
        assert e.value.code == "limit"
        assert A_q_le_b(lim, q) is False
    ok = np.array([0.3, 1.0, -0.5])
    assert lim.contains(ok)
    assert A_q_le_b(lim, ok) is True
    lim.check(ok)


def A_q_le_b(lim: robots.JointLimits, q: np.ndarray) -> bool:  # noqa: N802
    return bool(np.all(lim.A @ q <= lim.b + 1e-12))


def test_coupled_limit_edges_are_inclusive() -> None:
    lim = robots.load("desk4").limits
    assert lim.contains(np.array([0.0, 1.0, -0.1]))  # q2 + q3 = 0.9 exactly
    assert not lim.contains(np.array([0.0, 1.0, -0.1 + 1e-6]))


def test_box_limit_error_names_the_joint() -> None:
    lim = robots.load("insomniac").limits
    q = np.array([0.0, 0.1, -1.0, 0.0, 0.0])  # shoulder below 0.26
    with pytest.raises(JointLimitError) as e:
        lim.check(q)
    assert e.value.name == "shoulder"
    assert e.value.bounds == (0.26, 2.88)
    assert "shoulder" in str(e.value)


def test_batch_matches_single() -> None:
    for name in robots.names():
        lim = robots.load(name).limits
        rng = np.random.default_rng(0)
        qs = rng.uniform(lim.lower - 0.3, lim.upper + 0.3, size=(2000, len(lim.names)))
        batch = lim.contains_batch(qs)
        assert batch.tolist() == [lim.contains(q) for q in qs]
        assert 0 < batch.sum() < len(qs)


def test_limits_from_robots_md() -> None:
    lim = robots.load("insomniac").limits
    assert np.allclose(lim.lower, [-np.pi / 2, 0.26, -2.79, -np.pi / 2, -np.pi / 2])
    assert np.allclose(lim.upper, [np.pi / 2, 2.88, 0.0, np.pi / 2, np.pi / 2])
    assert lim.velocity.tolist() == [3.0, 1.5, 2.0, 3.0, 3.0]
    assert lim.acceleration.tolist() == [8.0, 5.0, 6.0, 10.0, 10.0]
    assert lim.jerk.tolist() == [60.0, 40.0, 50.0, 80.0, 80.0]
    g = robots.load("gupta3").limits
    assert np.allclose(g.lower, [-np.pi, 0.0, -2.8]) and np.allclose(g.upper, [np.pi, np.pi, 0.0])


def test_the_one_limits_helper_agrees_with_itself() -> None:
    """clip, in_box, first_outside, contains and contains_batch: one idea of "within the
    limits", the one the planner's gate, the solver and the adapters use."""
    arm = robots.load("desk4")
    lim = arm.limits
    rng = np.random.default_rng(1)
    qs = rng.uniform(lim.lower - 0.3, lim.upper + 0.3, size=(400, arm.nq))
    inside = lim.contains_batch(qs)
    assert inside.any() and not inside.all()
    for q, ok in zip(qs, inside, strict=True):
        assert lim.contains(q) == ok
        assert lim.in_box(lim.clip(q)) and (lim.in_box(q) == np.array_equal(lim.clip(q), q))
        assert (lim.first_outside(q[None]) is None) == ok
    k, err = lim.first_outside(qs)  # type: ignore[misc]
    assert not inside[k]
    assert isinstance(err, (JointLimitError, CoupledLimitError)) and err.code == "limit"
    box_ok = np.array([lim.in_box(q) for q in qs])
    if not box_ok.all():  # a box violation is named before any coupled one
        assert isinstance(err, JointLimitError) and k == int(np.argmin(box_ok))
