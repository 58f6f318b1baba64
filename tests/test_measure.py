"""The measure of what reached a board (adapters/emulators/measure.py): a change of speed over the
time since the same joint's previous change, and a line held on its way told from a rushed one."""

from __future__ import annotations

import numpy as np

from armd import robots
from armd.adapters.emulators.measure import Motion, ratios

PERIOD = 0.02


def _path(arm: robots.Robot, corners: dict[int, list[float]], step: float) -> Motion:
    """Joints that start at rest and gain ``step`` of their acceleration limit's change of speed a
    period (``step`` x amax x PERIOD) at each of their corners [s]; the others stay still."""
    times = np.array(sorted({0.0, *[t for ts in corners.values() for t in ts], 0.2}))
    q = np.zeros((len(times), arm.nq))
    for j, ts in corners.items():
        dv = step * arm.limits.acceleration[j] * PERIOD
        v = np.array([dv * np.sum(np.array(ts) <= t) for t in times[:-1]])  # the speed after each breakpoint
        q[1:, j] = np.cumsum(v * np.diff(times))
    return Motion(times, np.array(arm.neutral) + q, 0)


def test_each_joint_is_measured_at_its_own_changes() -> None:
    """Two joints whose commands arrive a millisecond apart (one line, two commands): each one's
    change over its own period, not over the millisecond between them."""
    arm = robots.load("insomniac")
    m = _path(arm, {0: [0.02, 0.04, 0.06, 0.08], 1: [0.021, 0.041, 0.061, 0.081]}, step=0.9)
    r = ratios(arm, m, PERIOD)
    assert abs(r.acceleration - 0.9) < 1e-6, r


def test_a_held_line_is_told_from_a_rushed_one() -> None:
    """A line 8 ms late and the next on the rhythm (12 ms after it), and two lines in a row held:
    counted over the period with ``held`` (and counted as held); lines every 12 ms (an adapter
    that rushes) soon count as they are."""
    arm = robots.load("insomniac")
    once = _path(arm, {0: [0.02, 0.04, 0.068, 0.08, 0.10, 0.12]}, step=1.0)
    plain = ratios(arm, once, PERIOD)
    assert abs(plain.acceleration - 20 / 12) < 1e-6 and plain.held == 0, plain
    told = ratios(arm, once, PERIOD, held=True)
    assert abs(told.acceleration - 1.0) < 1e-6 and told.held == 1, told
    twice = _path(arm, {0: [0.02, 0.04, 0.072, 0.084, 0.10, 0.12]}, step=1.0)  # held 12 ms, then 4 ms
    r = ratios(arm, twice, PERIOD, held=True)
    assert abs(r.acceleration - 1.0) < 1e-6 and r.held == 2, r
    rushed = _path(arm, {0: [0.02 + 0.012 * k for k in range(10)]}, step=1.0)
    r = ratios(arm, rushed, PERIOD, held=True)
    assert abs(r.acceleration - 20 / 12) < 1e-6 and r.held <= 2, r
