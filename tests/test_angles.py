"""One angle wrap, [-pi, pi): the same for one value, an array, the compiled solver, and the
pitches single and batch IK and FK report."""

from __future__ import annotations

import math

import numpy as np
from conftest import plain
from hypothesis import given, settings
from hypothesis import strategies as st

from armd import solvers
from armd.robots.angles import wrap, wrap_array
from armd.solvers.geometric import wrap_angle


@settings(deadline=None)  # (the first call compiles wrap_angle)
@given(st.floats(min_value=-1e3, max_value=1e3))
def test_wrap_is_in_range_and_a_whole_number_of_turns_away(x: float) -> None:
    w = wrap(x)
    assert -math.pi <= w < math.pi
    turns = (x - w) / (2 * math.pi)
    assert abs(turns - round(turns)) < 1e-9
    assert wrap_array(np.array([x]))[0] == w == wrap_angle(x)


def test_the_ends_of_the_range() -> None:
    assert wrap(math.pi) == -math.pi and wrap(-math.pi) == -math.pi and wrap(3 * math.pi) == -math.pi
    assert wrap(0.5) == 0.5 and wrap(-0.5) == -0.5  # (exact inside the range)


def test_single_and_batch_ik_and_fk_report_a_tool_pointing_back_alike() -> None:
    """A target reached with the tool pointing straight back (pitch pi): before the one wrap,
    single IK said +pi and batch IK -pi."""
    arm = plain("insomniac")
    rng = np.random.default_rng(0)
    cases = 0
    while cases < 5:
        q = rng.uniform(arm.limits.lower, arm.limits.upper)
        q[3] += math.pi - arm.tool_pitch(q)  # the wrist turned until the tool points back
        if not arm.limits.contains(q):
            continue
        target = arm.fk(q)
        for asked in (math.pi, -math.pi):
            one = solvers.solve_ik(arm, target, approach=asked)
            many = solvers.solve_ik_batch(arm, target[None], approach=asked)
            if one.status != "ok":
                continue
            cases += 1
            assert one.pitch == many.pitch[0] and -math.pi <= one.pitch < math.pi, (one.pitch, many.pitch[0])
            assert abs(one.pitch_error or 0.0) < 1e-9
            assert abs(wrap(arm.tool_pitch(one.q) - one.pitch)) < 1e-9 and -math.pi <= arm.tool_pitch(one.q) < math.pi
