"""The vectorised sampling of Ruckig segments equals Ruckig's own at_time, in every case we use."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
import ruckig
from conftest import plain

from armd import planning, robots
from armd.errors import BadRequest, LimitError
from armd.planning import JointState
from armd.planning.ruckig_path import Limits, RuckigPath, _segment, joint_path, stop_path
from tests.test_fk import random_in_limits


@pytest.mark.parametrize("name", ["insomniac", "sg5ut", "gupta3", "desk4"])
def test_sample_equals_at_time(name: str) -> None:
    arm = plain(name)
    qs = random_in_limits(arm, 90, seed=9)
    worst = 0.0
    for i in range(0, 87, 3):
        tr = planning.plan(arm, qs[i], qs[i + 1])
        k = int(np.argmax(np.abs(tr.velocity / arm.limits.velocity).max(axis=1)))  # the fastest moment
        moving = JointState(tr.position[k], tr.velocity[k], tr.acceleration[k])
        paths = [
            joint_path(arm, moving, [qs[i + 2]], 1.0, 0.02),  # from a moving state
            joint_path(arm, moving, [qs[i + 2]], 0.3, 0.02),  # moving faster than the scaled limits: brake profile
            stop_path(arm, moving, 0.02),  # velocity interface, unsynchronised
            joint_path(arm, JointState.at_rest(qs[i]), [qs[i + 1], qs[i + 2]], 0.5, 0.01),  # waypoint chain
        ]
        for rp in paths:
            ts = np.linspace(0.0, rp.duration, 53)
            P, V, A, _ = rp.sample(ts)
            for j, t in enumerate(ts):
                p, v, a = rp.at(float(t))
                worst = max(
                    worst,
                    float(np.max(np.abs(P[j] - p))),
                    float(np.max(np.abs(V[j] - v))),
                    float(np.max(np.abs(A[j] - a))),
                )
    assert worst < 1e-9


def test_sample_equals_at_time_with_brake_profiles() -> None:
    """A state faster than the speed-scaled limits makes Ruckig prepend a brake profile."""
    arm = robots.load("gupta3")
    start = JointState(arm.neutral, 0.9 * arm.limits.velocity * np.array([1, -1, 1]), np.zeros(3))
    otg = ruckig.Ruckig(3, 0.02)
    seg = _segment(otg, start, np.array([1.5, 0.6, -0.5]), np.zeros(3), Limits.of(arm, 0.2))
    rp = RuckigPath([seg], 3)
    assert any(p.brake.duration > 0 for seg in rp.segments for p in seg.profiles[0])
    ts = np.linspace(0.0, rp.duration, 101)
    P, V, A, _ = rp.sample(ts)
    for j, t in enumerate(ts):
        p, v, a = rp.at(float(t))
        assert np.allclose(P[j], p, atol=1e-9) and np.allclose(V[j], v, atol=1e-9) and np.allclose(A[j], a, atol=1e-9)


def test_nan_samples_are_caught_by_the_safety_gate() -> None:
    arm = robots.load("gupta3")
    tr = planning.plan(arm, arm.neutral, [0.4, 1.1, -1.2])
    pos = tr.position.copy()
    pos[4, 1] = np.nan
    with pytest.raises(LimitError) as e:
        planning.check_samples(arm, tr.times, pos, tr.velocity, tr.acceleration, tr.jerk)
    assert e.value.name == "shoulder" and "not a number" in e.value.message
    with pytest.raises(BadRequest):
        arm.actuators.commands(pos)


@pytest.mark.parametrize("name", ["insomniac", "desk4", "so101"])
def test_a_straight_path_stays_on_its_straight_moves(name: str) -> None:
    """straight_path (the timing of a path round obstacles): every sample on one of the straight
    joint moves between the points, at rest on each, within every limit (the gate), ending on the
    last. (Ruckig's phase synchronisation falls back to time synchronisation, up to 0.06 rad off
    the line, on a few percent of random rest-to-rest moves: tested here to stay off it.)"""
    from armd.planning.plan import _sampled
    from armd.planning.ruckig_path import straight_path

    arm = plain(name)
    rng = np.random.default_rng(5)
    worst = 0.0
    for _ in range(40):
        pts = [rng.uniform(arm.limits.lower, arm.limits.upper) for _ in range(4)]
        pts = [p for p in pts if arm.limits.contains(p)]
        if len(pts) < 2:
            continue
        tr = _sampled(arm, "joint", 50.0, straight_path(arm, pts[0], pts[1:], 1.0, 0.02))  # (the gate checks)
        assert np.allclose(tr.position[-1], pts[-1], atol=1e-9) and np.allclose(tr.velocity[-1], 0.0, atol=1e-9)
        for q in tr.position:
            off = min(
                float(np.max(np.abs(q - a - np.clip((q - a) @ (b - a) / ((b - a) @ (b - a)), 0, 1) * (b - a))))
                for a, b in itertools.pairwise(pts)
            )
            worst = max(worst, off)
    assert worst < 1e-9
