"""Actuator maps: joints -> actuator angles -> pulses or micro-steps, and back."""

from __future__ import annotations

import math

import numpy as np
import pytest

from armd import robots
from armd.errors import ActuatorMapError, ActuatorRangeError, BadRequest
from tests.test_fk import random_in_limits


def servo_pulse(angle: float, centre_pulse: float, centre_angle: float, direction: int) -> float:
    """ROBOTS.md: pulse_us = centre_pulse + direction * (angle - centre_angle) * 2000/pi."""
    return centre_pulse + direction * (angle - centre_angle) * 2000 / math.pi


def test_insomniac_pulses_follow_robots_md() -> None:
    arm = robots.load("insomniac")
    table = [(1500, 0.0, 1), (1500, math.pi / 2, 1), (1500, -math.pi / 2, -1), (1500, 0.0, 1), (1500, 0.0, 1)]
    for q in random_in_limits(arm, 500):
        expected = [round(servo_pulse(q[i], *table[i])) for i in range(5)]
        assert arm.actuators.commands(q).tolist() == expected


def test_sg5ut_shoulder_is_a_mirrored_pair() -> None:
    arm = robots.load("sg5ut")
    assert arm.actuators.names == ("base_yaw", "shoulder_a", "shoulder_b", "elbow", "wrist")
    for q in random_in_limits(arm, 300):
        cmd = arm.actuators.commands(q)
        assert cmd[1] + cmd[2] == 3000 or abs(cmd[1] + cmd[2] - 3000) == 1  # mirrored about 1500 (rounding)
        assert cmd[1] == round(servo_pulse(q[1], 1500, math.pi / 2, 1))
    channels = [a.channel for a in arm.actuators.actuators]
    assert channels == [0, 1, 2, 3, 4]
    assert arm.gripper is not None and arm.gripper.channel == 5


def test_desk4_minor_servo_turns_through_its_linkage() -> None:
    """Its angle is the four-bar's (tests/test_linkages.py checks it the seed's way); M's row
    is its slope at mid-range: the servo turns with major and minor."""
    arm = robots.load("desk4")
    M = arm.actuators.M
    assert M[:2].tolist() == [[1, 0, 0], [0, 1, 0]]
    assert M[2, 0] == 0 and M[2, 1] == pytest.approx(1.0) and 0.4 < M[2, 2] < 1.0
    q = np.array([0.1, 1.0, -0.7])
    a = arm.actuators.angles(q)
    assert np.allclose(a[:2], [0.1, 1.0])
    assert arm.actuators.commands(q)[2] == round(1500 + a[2] * 2000 / math.pi)


def test_gupta3_microsteps() -> None:
    arm = robots.load("gupta3")
    for act in arm.actuators.actuators:
        assert isinstance(act, robots.Stepper)
        assert math.isclose(math.degrees(act.step_angle), 0.1125)  # seed 002 Table II, 16 micro-steps
        assert math.isclose(act.steps_per_degree, 3200 / 360)
    for q in random_in_limits(arm, 500):
        steps = arm.actuators.commands(q)
        assert steps.tolist() == [round(x * 16 * 200 / (2 * math.pi)) for x in q]


@pytest.mark.parametrize("name", ["insomniac", "sg5ut", "gupta3", "desk4", "so101"])
def test_round_trip_within_one_quantum(name: str) -> None:
    arm = robots.load(name)
    amap = arm.actuators
    quantum = max(a.resolution for a in amap.actuators)
    qs = random_in_limits(arm, 1000)
    cmds = amap.commands(qs)  # vectorised over samples
    back = amap.joints_from_commands(cmds)
    # each actuator is off by at most half a quantum; a joint read through several actuators
    # by the sum of what its row of pinv(M) gathers (desk4's minor, read through its linkage
    # after the major servo: tests/test_linkages.py bounds it)
    bound = np.abs(np.linalg.pinv(amap.M)).sum(axis=1) * quantum / 2
    if name == "desk4":
        bound[2] = quantum / 2 * (1 + amap.slopes[2, 1]) / amap.gentlest[2, 2]
    assert np.all(np.abs(back - qs) <= bound + 1e-12)
    # and a second trip is exact: quantised configurations are fixed points
    assert np.array_equal(amap.commands(back), cmds)
    assert np.allclose(amap.quantise(qs), back)


def test_so101_bus_servo_counts() -> None:
    """counts = zero + direction * angle * 4096 / (2 pi): the factory's middle at the vendor's zero."""
    from dataclasses import replace

    arm = robots.load("so101")
    assert arm.actuators.commands(arm.neutral).tolist() == [2048] * 5
    q = np.array([0.5, -0.3, 0.2, 1.0, -2.0])
    assert arm.actuators.commands(q).tolist() == [round(2048 + x * 4096 / (2 * math.pi)) for x in q]
    flipped = replace(arm.actuators.actuators[0], direction=-1, zero=1000.0)  # type: ignore[type-var]
    assert float(flipped.to_command(np.array(0.5))) == pytest.approx(1000.0 - 0.5 * 4096 / (2 * math.pi))
    assert float(flipped.to_angle(flipped.to_command(np.array(0.5)))) == pytest.approx(0.5)


def test_commands_outside_range_are_errors_not_clamped() -> None:
    arm = robots.load("insomniac")
    q = arm.neutral.copy()
    q[0] = math.pi / 2 + 0.05  # yaw past its limit: pulse would be > 2500
    with pytest.raises(ActuatorRangeError) as e:
        arm.actuators.commands(q)
    assert e.value.name == "base_yaw"
    arm_d = robots.load("desk4")
    with pytest.raises(ActuatorRangeError) as e:
        arm_d.actuators.commands(np.array([0.0, 1.9, -0.5]))  # minor servo angle 1.4 > linkage's 0.9
    assert e.value.name == "minor"
    steps = robots.load("gupta3").actuators
    with pytest.raises(ActuatorRangeError):
        steps.commands(np.array([0.0, 3.3, -1.0]))


def test_mirrored_pair_that_disagrees_is_an_error() -> None:
    amap = robots.load("sg5ut").actuators
    cmds = amap.commands(robots.load("sg5ut").neutral).astype(float)
    cmds[2] += 40  # the mirrored servo reports something else
    with pytest.raises(ActuatorMapError):
        amap.joints_from_commands(cmds)
    with pytest.raises(BadRequest):
        amap.joints_from_commands(cmds[:3])


def test_gripper_pulses() -> None:
    g = robots.load("insomniac").gripper
    assert g is not None
    assert (g.pulse(0.0), g.pulse(1.0), g.pulse(0.5)) == (1000, 2000, 1500)
    for bad in (-0.1, 1.5, float("nan"), True, "0.5"):
        with pytest.raises(BadRequest):
            g.pulse(bad)
