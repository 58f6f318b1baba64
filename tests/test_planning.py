"""planning.plan / plan_stop: every sample within every limit, at the goal, on the line."""

from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import plain
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from armd import planning, robots
from armd.errors import ActuatorRangeError, BadRequest, JointLimitError, LimitError, PlanRejected
from armd.planning import JointState, plan, plan_stop

ARMS = ["insomniac", "sg5ut", "gupta3", "desk4"]
SETTINGS = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def in_limits(arm: robots.Robot, u: list[float]) -> np.ndarray | None:
    """A configuration from unit-cube coordinates, or None when it breaks a coupled limit."""
    q = arm.limits.lower + np.array(u) * (arm.limits.upper - arm.limits.lower)
    return q if arm.limits.contains(q, tol=0.0) else None


def unit(n: int) -> st.SearchStrategy[list[float]]:
    return st.lists(st.floats(0.0, 1.0), min_size=n, max_size=n)


def assert_safe(arm: robots.Robot, tr: planning.Trajectory) -> None:
    """Independent of planning.checks: every sample within every limit; commands = actuator map."""
    lim = arm.limits
    dt = 1.0 / tr.rate_hz
    assert abs(tr.duration / dt - round(tr.duration / dt)) < 1e-9  # whole cycles
    assert np.allclose(np.diff(tr.times), dt)
    assert np.all(tr.position >= lim.lower - 1e-9) and np.all(tr.position <= lim.upper + 1e-9)
    for c in lim.coupled:
        v = tr.position @ c.coefficients
        assert np.all(v >= c.lower - 1e-9) and np.all(v <= c.upper + 1e-9)
    assert np.all(np.abs(tr.velocity) <= lim.velocity * (1 + 1e-6))
    assert np.all(np.abs(tr.acceleration) <= lim.acceleration * (1 + 1e-6))
    jerk = np.diff(tr.acceleration, axis=0) / dt
    assert np.all(np.abs(jerk) <= lim.jerk * (1 + 1e-6))
    assert np.array_equal(tr.commands, arm.actuators.commands(tr.position))


@pytest.mark.parametrize("name", ARMS)
@SETTINGS
@given(a=st.data())
def test_joint_plans_are_safe_and_arrive(name: str, a: st.DataObject) -> None:
    arm = plain(name)
    q0 = in_limits(arm, a.draw(unit(arm.nq)))
    q1 = in_limits(arm, a.draw(unit(arm.nq)))
    if q0 is None or q1 is None:
        return
    speed = a.draw(st.sampled_from([1.0, 0.5, 0.2]))
    rate = a.draw(st.sampled_from([50.0, 100.0, 20.0]))
    tr = plan(arm, q0, q1, speed=speed, rate_hz=rate)
    assert_safe(arm, tr)
    assert np.allclose(tr.position[0], q0, atol=1e-12)
    assert np.allclose(tr.position[-1], q1, atol=1e-9)
    assert np.allclose(tr.velocity[-1], 0.0, atol=1e-9)
    assert np.all(np.abs(tr.velocity) <= arm.limits.velocity * speed * (1 + 1e-6))
    for k in (0, len(tr.times) // 2, len(tr.times) - 1):  # at() agrees with the samples
        s = tr.at(float(tr.times[k]))
        assert np.allclose(s.position, tr.position[k], atol=1e-12)


@pytest.mark.parametrize("name", ARMS)
@SETTINGS
@given(a=st.data())
def test_plans_from_a_moving_state_and_stops(name: str, a: st.DataObject) -> None:
    arm = plain(name)
    q0 = in_limits(arm, a.draw(unit(arm.nq)))
    q1 = in_limits(arm, a.draw(unit(arm.nq)))
    q2 = in_limits(arm, a.draw(unit(arm.nq)))
    if q0 is None or q1 is None or q2 is None:
        return
    first = plan(arm, q0, q1)
    k = int(a.draw(st.floats(0.05, 0.95)) * (len(first.times) - 1))
    moving = JointState(first.position[k], first.velocity[k], first.acceleration[k])
    # a new plan from the moving state: continuous, safe, at the new goal (braking first if
    # going straight on would cross a limit)
    tr = plan(arm, moving, q2)
    assert_safe(arm, tr)
    assert np.allclose(tr.velocity[0], moving.velocity, atol=1e-9)
    assert np.allclose(tr.position[-1], q2, atol=5e-8)  # (Ruckig lands on a target to ~1e-8 rad)
    # a stop from the same state: at rest, within limits
    stop = plan_stop(arm, moving)
    assert_safe(arm, stop)
    assert np.allclose(stop.velocity[-1], 0.0, atol=1e-9)
    assert np.allclose(stop.acceleration[-1], 0.0, atol=1e-9)
    assert stop.duration <= first.duration


@pytest.mark.parametrize("speed", [0.01, 0.001])
def test_a_slow_plan_from_a_fast_moving_state_brakes_first(speed: float) -> None:
    """Found by bench/load.py: a plan at a low speed from a moving arm made Ruckig brake within
    the slowed limits, which it cannot time (RuckigError: answered internal)."""
    arm = robots.load("insomniac")
    first = plan(arm, arm.neutral, [1.2, 1.0, -1.2, 0.5, 1.0])
    k = len(first.times) // 2
    moving = JointState(first.position[k], first.velocity[k], first.acceleration[k])
    tr = plan(arm, moving, [0.0, 1.0, -1.0, 0.0, 0.0], speed=speed)
    assert_safe(arm, tr)
    assert np.allclose(tr.velocity[0], moving.velocity, atol=1e-9)
    assert np.allclose(tr.position[-1], [0.0, 1.0, -1.0, 0.0, 0.0], atol=1e-9)


@pytest.mark.parametrize("name", ARMS)
@SETTINGS
@given(a=st.data())
def test_lines_stay_on_the_line(name: str, a: st.DataObject) -> None:
    arm = plain(name)
    q0 = in_limits(arm, a.draw(unit(arm.nq)))
    if q0 is None:
        return
    offset = np.array(a.draw(st.lists(st.floats(-0.08, 0.08), min_size=3, max_size=3)))
    p0 = arm.fk(q0)
    p1 = p0 + offset
    try:
        tr = plan(arm, q0, {"target": p1.tolist()}, path="line")
    except PlanRejected as e:
        assert e.code == "unreachable" and e.message
        return
    assert_safe(arm, tr)
    d = p1 - p0
    for q in tr.position:
        p = arm.fk(q)
        f = np.clip((p - p0) @ d / max(d @ d, 1e-300), 0.0, 1.0)
        assert np.linalg.norm(p - (p0 + f * d)) <= 1e-6
    assert np.linalg.norm(arm.fk(tr.position[-1]) - p1) <= 1e-6


def test_most_short_lines_are_planned() -> None:
    arm = robots.load("insomniac")
    rng = np.random.default_rng(40)
    done = 0
    for _ in range(20):
        q0 = arm.neutral + rng.uniform(-0.3, 0.3, size=arm.nq)
        q0 = np.clip(q0, arm.limits.lower, arm.limits.upper)
        p1 = arm.fk(q0) + rng.uniform(-0.04, 0.04, size=3)
        try:
            plan(arm, q0, {"target": p1.tolist(), "approach": arm.tool_pitch(q0)}, path="line")
            done += 1
        except PlanRejected:
            pass
    assert done >= 15


def test_waypoints_are_passed_without_stopping_where_possible() -> None:
    arm = robots.load("gupta3")
    start = np.array([0.0, 1.0, -1.0])
    via = [np.array([0.4, 1.1, -1.1]), np.array([0.8, 1.2, -1.2])]
    goal = np.array([1.2, 1.3, -1.3])
    tr = plan(arm, start, goal, via=via)
    assert_safe(arm, tr)
    for w in via:
        k = int(np.argmin(np.linalg.norm(tr.position - w, axis=1)))
        assert np.linalg.norm(tr.position[k] - w) < 1e-9
        assert np.linalg.norm(tr.velocity[k]) > 0.05  # passing through, not stopping
    stops = plan(arm, start, goal, via=[np.array([0.4, 1.1, -1.1]), np.array([0.0, 1.0, -1.0])])
    k = int(np.argmin(np.linalg.norm(stops.position[5:] - [0.4, 1.1, -1.1], axis=1))) + 5
    assert np.linalg.norm(stops.velocity[k]) < 1e-9  # the direction reverses: it stops there


def test_cartesian_goal_and_approach() -> None:
    arm = robots.load("insomniac")
    target = [0.22, 0.08, 0.10]
    tr = plan(arm, arm.neutral, {"target": target, "approach": "perpendicular"})
    assert np.linalg.norm(arm.fk(tr.position[-1]) - target) < 1e-9
    assert abs(arm.tool_pitch(tr.position[-1]) + math.pi / 2) < 1e-9
    with pytest.raises(PlanRejected):
        plan(arm, arm.neutral, {"target": [2.0, 0.0, 0.0]})


def test_desk4_coupled_limit_holds_between_goals() -> None:
    arm = plain("desk4")
    a = np.array([0.0, 0.2, -1.35])  # q2 + q3 = -1.15, near the lower bound
    b = np.array([0.0, 1.95, -1.1])  # q2 + q3 = 0.85, near the upper bound
    tr = plan(arm, a, b)
    assert_safe(arm, tr)


def test_safety_gate_names_joint_time_and_value() -> None:
    arm = robots.load("gupta3")
    tr = plan(arm, arm.neutral, [0.5, 1.0, -1.2])
    pos = tr.position.copy()
    pos[7, 2] = 0.3  # elbow above its upper limit 0
    with pytest.raises(JointLimitError) as e:
        planning.check_samples(arm, tr.times, pos, tr.velocity, tr.acceleration, tr.jerk)
    assert e.value.name == "elbow" and e.value.time == pytest.approx(tr.times[7]) and e.value.value == 0.3
    vel = tr.velocity.copy()
    vel[3, 0] = 1.5  # base_yaw vmax is 1.0
    with pytest.raises(LimitError) as e:
        planning.check_samples(arm, tr.times, tr.position, vel, tr.acceleration, tr.jerk)
    assert e.value.kind == "velocity" and e.value.name == "base_yaw" and e.value.time == pytest.approx(tr.times[3])
    ins = robots.load("insomniac")
    bad = np.tile(ins.neutral, (3, 1))
    bad[1, 0] = math.pi / 2 + 0.01
    with pytest.raises(ActuatorRangeError) as e:
        planning.actuator_commands(ins, np.array([0.0, 0.02, 0.04]), bad)
    assert e.value.time == pytest.approx(0.02)


BAD = [
    ({"speed": 0.0}, "speed"),
    ({"speed": 1.5}, "speed"),
    ({"speed": float("nan")}, "speed"),
    ({"rate_hz": 0}, "rate_hz"),
    ({"rate_hz": "fast"}, "rate_hz"),
    ({"path": "curve"}, "path"),
    ({"start": [0.0, 1.0]}, "start.position"),
    ({"start": [0.0, -0.5, -1.0]}, "start.position"),  # shoulder below 0
    ({"start": {"position": [0.0, 1.0, -1.0], "velocity": [5.0, 0, 0]}}, "start.velocity"),
    ({"start": {"velocity": [0.0, 0, 0]}}, "start"),
    ({"goal": [0.0, 1.0, 0.5]}, "goal"),  # elbow above 0
    ({"goal": [0.0, 1.0, float("nan")]}, "goal"),
    ({"goal": {"where": [0.1, 0.0, 0.1]}}, "goal"),
    ({"goal": {"target": [0.1, 0.0, float("inf")]}}, "target"),
    ({"via": "abc"}, "via"),
    ({"via": [[0.0, 1.0, 0.5]]}, "via[0]"),
    ({"path": "line", "via": [[0.0, 1.0, -1.0]]}, "via"),
]


@pytest.mark.parametrize(("change", "field"), BAD)
def test_bad_plan_requests(change: dict[str, object], field: str) -> None:
    arm = robots.load("gupta3")
    args: dict[str, object] = {"start": [0.0, 1.0, -1.0], "goal": [0.5, 1.2, -1.3]}
    args.update(change)
    start, goal = args.pop("start"), args.pop("goal")
    with pytest.raises(BadRequest) as e:
        plan(arm, start, goal, **args)  # type: ignore[arg-type]
    assert e.value.field == field, e.value.message


def test_line_from_a_moving_state_is_refused() -> None:
    arm = robots.load("gupta3")
    moving = {"position": [0.0, 1.0, -1.0], "velocity": [0.1, 0.0, 0.0]}
    with pytest.raises(PlanRejected):
        plan(arm, moving, {"target": [0.2, 0.0, 0.1]}, path="line")


def test_trajectory_to_dict_is_json_ready() -> None:
    import json

    arm = robots.load("sg5ut")
    tr = plan(arm, arm.neutral, [0.3, 1.2, -0.6, -0.4], rate_hz=25)
    d = json.loads(json.dumps(tr.to_dict()))
    assert d["rate_hz"] == 25 and len(d["commands"][0]) == 5 and d["actuator_units"][0] == "us"
    assert len(d["times"]) == len(d["position"]) == len(tr.times)


@pytest.mark.parametrize("name", ["insomniac", "sg5ut", "gupta3", "desk4"])
def test_compiled_gate_never_passes_what_the_checks_refuse(name: str) -> None:
    """``build``'s compiled fast path against the exact checks: every kind of violation, just
    over and just under each tolerance, gives the same verdict (and the same commands)."""
    from armd.planning.checks import POSITION_TOL, RATE_TOL
    from armd.planning.trajectory import build

    arm = plain(name)
    lim = arm.limits
    rng = np.random.default_rng(11)
    goal = rng.uniform(lim.lower, lim.upper)
    while not lim.contains(goal):
        goal = rng.uniform(lim.lower, lim.upper)
    tr = plan(arm, arm.neutral, goal)
    assert np.array_equal(tr.commands, arm.actuators.commands(tr.position))

    def verdict(pos: np.ndarray, vel: np.ndarray, acc: np.ndarray, jerk: np.ndarray) -> str:
        try:
            planning.check_samples(arm, tr.times, pos, vel, acc, jerk)
            expected = "ok"
        except LimitError as e:
            expected = f"{type(e).__name__} {e.message}"
        if expected == "ok":
            try:
                planning.actuator_commands(arm, tr.times, np.clip(pos, lim.lower, lim.upper))
            except LimitError as e:
                expected = f"{type(e).__name__} {e.message}"
        try:
            out = build(arm, "joint", tr.rate_hz, tr.duration, tr.times, pos, vel, acc, tr.evaluator, jerk=jerk)
        except LimitError as e:
            assert f"{type(e).__name__} {e.message}" == expected
            return "refused"
        assert expected == "ok", expected
        assert np.array_equal(out.commands, arm.actuators.commands(np.clip(pos, lim.lower, lim.upper)))
        return "ok"

    k, j = len(tr.times) // 2, arm.nq - 1
    seen = set()
    for over in (0.5, 2.0):  # half a tolerance over (inside the slack), twice over (a violation)
        for bound in (lim.upper[j] + over * POSITION_TOL, lim.lower[j] - over * POSITION_TOL):
            pos = tr.position.copy()
            pos[k, j] = bound
            seen.add(verdict(pos, tr.velocity, tr.acceleration, tr.jerk))
        for which, limit in ((1, lim.velocity[j]), (2, lim.acceleration[j]), (3, lim.jerk[j])):
            arrays = [tr.position, tr.velocity.copy(), tr.acceleration.copy(), tr.jerk.copy()]
            arrays[which][k, j] = -limit * (1 + over * RATE_TOL)
            seen.add(verdict(*arrays))
    for bad in (np.nan, np.inf):
        vel = tr.velocity.copy()
        vel[k, 0] = bad
        seen.add(verdict(tr.position, vel, tr.acceleration, tr.jerk))
    for c in lim.coupled:  # a sample moved onto and past a coupled limit
        pos = tr.position.copy()
        i = int(np.flatnonzero(c.coefficients)[-1])
        for over in (0.5, 2.0):
            pos[k, i] += (c.upper + over * POSITION_TOL - pos[k] @ c.coefficients) / c.coefficients[i]
            seen.add(verdict(pos, tr.velocity, tr.acceleration, tr.jerk))
    assert seen == {"ok", "refused"}
