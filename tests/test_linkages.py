"""Nonlinear actuator linkages (robots/linkages.py): desk4's minor servo behind a four-bar.

The expected angle is computed the seed's way (seed 004 section 4): the triangle ``O E C`` about
the elbow gives the red edge ``OC`` and theta5, the triangle ``O C H`` gives theta6 by the law of
cosines, and theta5 + theta6 is the servo's angle from the major arm. The library computes it
with vectors instead: the two must agree.
"""

from __future__ import annotations

import copy
import math
import time
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from armd import robots
from armd.errors import ActuatorMapError, ActuatorRangeError, RobotFileError
from armd.planning import plan
from armd.robots.linkages import FourBar
from tests.test_fk import random_in_limits

# desk4's linkage, as its README writes it down (robot.toml [actuators.linkage])
FRAME, LEVER, ROD, HORN, BEND = 0.135, 0.035, 0.140, 0.040, -0.22


def seed_angle(q2: float, q3: float) -> float:
    """The minor servo's angle, the horn from straight behind, by the seed's triangles."""
    elbow = abs(q3 + BEND)  # the angle O E C: between the major arm (back to O) and the bent lever
    red = math.sqrt(FRAME**2 + LEVER**2 - 2 * FRAME * LEVER * math.cos(elbow))  # OC
    theta5 = math.acos((FRAME**2 + red**2 - LEVER**2) / (2 * FRAME * red))  # E O C
    theta6 = math.acos((red**2 + HORN**2 - ROD**2) / (2 * red * HORN))  # C O H
    # C lies counter-clockwise of the major arm (q3 + bend is in (-pi, 0)) and the horn of OC
    return q2 + theta5 + theta6 - math.pi


def test_desk4_minor_servo_turns_through_the_seeds_bent_arm() -> None:
    arm = robots.load("desk4")
    amap = arm.actuators
    assert set(amap.linkages) == {2} and not amap.linear
    for q in random_in_limits(arm, 300):
        assert amap.angles(q)[2] == pytest.approx(seed_angle(q[1], q[2]), abs=1e-12)
        assert amap.commands(q)[2] == round(1500 + seed_angle(q[1], q[2]) * 2000 / math.pi)
    # not the ideal parallelogram's major + minor: off by up to 0.2 rad over the range
    qs = random_in_limits(arm, 2000)
    off = np.abs(amap.angles(qs)[:, 2] - (qs[:, 1] + qs[:, 2]))
    assert 0.1 < off.max() < 0.3
    # the pulses the README gives for the range
    lo, hi = amap.actuators[2].angle_range
    assert (round(1500 + lo * 2000 / math.pi), round(1500 + hi * 2000 / math.pi)) == (664, 1995)


def test_the_derivative_is_the_angles_slope() -> None:
    arm = robots.load("desk4")
    amap = arm.actuators
    h = 1e-6
    for q in random_in_limits(arm, 200):
        J = amap.jacobian(q)
        for j in range(arm.nq):
            step = np.zeros(arm.nq)
            step[j] = h
            numeric = (amap.angles(q + step) - amap.angles(q - step)) / (2 * h)
            assert np.allclose(J[:, j], numeric, atol=1e-7)
    qs = random_in_limits(arm, 50)
    assert np.allclose(amap.jacobian(qs), np.array([amap.jacobian(q) for q in qs]))  # vectorised
    v = np.array([0.3, -1.0, 0.7])
    assert np.allclose(amap.command_rates(qs[0], v), amap.jacobian(qs[0]) @ v * 2000 / math.pi)
    # the bounds hold everywhere in the range
    J = np.abs(amap.jacobian(random_in_limits(arm, 5000)))
    assert np.all(amap.slopes + 1e-9 >= J) and np.all(amap.gentlest - 1e-9 <= J)
    assert amap.gentlest[2, 2] > 0.4  # monotone, and steep enough: the servo holds the joint


def test_the_inverse_reads_the_joints_back() -> None:
    arm = robots.load("desk4")
    amap = arm.actuators
    qs = random_in_limits(arm, 2000)
    assert np.allclose(amap.joints_from_commands(amap.angles(qs) * 2000 / math.pi + 1500 - [0, 1000, 0]), qs)
    # through whole microseconds: off by at most half a microsecond over the gentlest slope
    back = amap.joints_from_commands(amap.commands(qs))
    half = 0.5 * math.pi / 2000
    assert np.all(np.abs(back[:, 1] - qs[:, 1]) <= half + 1e-12)
    assert np.all(np.abs(back[:, 2] - qs[:, 2]) <= half * (1 + amap.slopes[2, 1]) / amap.gentlest[2, 2] + 1e-12)
    assert np.array_equal(amap.commands(back), amap.commands(qs))
    # a reading the linkage cannot take is an error, never a made-up joint
    with pytest.raises(ActuatorMapError, match="minor"):
        amap.joints_from_commands(np.array([1500, 500, 2500]))  # the horn up, the major arm level


def test_the_gate_checks_the_linkage_at_every_sample() -> None:
    """With the minor servo's range narrowed (as a calibration could narrow it), a plan through
    it is refused at the sample it leaves it, though every joint is inside its limits."""
    arm = copy.copy(robots.load("desk4"))
    acts = list(arm.actuators.actuators)
    acts[2] = replace(acts[2], angle_range=(-1.0, 0.6))  # type: ignore[type-var]
    arm.actuators = arm.actuators.with_actuators(tuple(acts))
    start, goal = np.array([0.0, 1.2, -1.2]), np.array([0.0, 1.9, -1.0])
    assert arm.limits.contains(start) and arm.limits.contains(goal)
    assert arm.actuators.angles(goal)[2] > 0.6
    with pytest.raises(ActuatorRangeError) as e:
        plan(arm, start, goal)
    assert e.value.name == "minor" and e.value.fields["time"] > 0
    # the catalogue arm's range covers every joint vector in its limits: the same plan passes,
    # and every sample's command is the linkage's own
    desk4 = robots.load("desk4")
    ok = plan(desk4, start, goal)
    crossed = ok.times[np.argmax(desk4.actuators.angles(ok.position)[:, 2] > 0.6)]
    assert e.value.fields["time"] == pytest.approx(crossed, abs=1.5 / ok.rate_hz)
    angles = desk4.actuators.angles(ok.position)
    assert np.array_equal(ok.commands[:, 2], np.rint(1500 + angles[:, 2] * 2000 / math.pi))


LINKAGE = """[actuators.linkage]
type = "four_bar"
input = "major"     # the frame link O -> E is the major arm
driven = "minor"
frame = 0.135       # |OE| = a2
lever = 0.035       # |EC|, behind the elbow
rod = 0.140         # |CH|
horn = 0.040        # |OH|
bend = -0.22        # [rad] the lever, turned from straight behind the minor arm
"""


@pytest.mark.parametrize(
    ("edit", "said"),
    [
        (("rod = 0.140", "rod = 0.100"), "cannot be assembled"),
        (("bend = -0.22", "bend = -0.10"), "degrees from a line"),
        (("horn = 0.040", "horn = 0.080"), "monotone"),
        (('driven = "minor"', 'driven = "elbow"'), "not a joint"),
        (("frame = 0.135", "frame = -0.1"), "positive"),
        (('type = "four_bar"', 'type = "gear"'), "four_bar"),
    ],
)
def test_a_linkage_that_cannot_work_is_refused_at_load(
    arm_copy: Callable[..., Path], edit: tuple[str, str], said: str
) -> None:
    assert edit[0] in LINKAGE
    folder = arm_copy("desk4", toml_edits=[(LINKAGE, LINKAGE.replace(*edit))])
    with pytest.raises(RobotFileError) as e:
        robots.load_dir(folder)
    assert "linkage" in (e.value.field or "") and said in e.value.problem


def test_a_parallelogram_is_the_linear_row() -> None:
    """lever = horn, rod = frame, no bend: the servo's angle is major + minor exactly."""
    link = FourBar(input=1, driven=2, frame=0.135, lever=0.03, rod=0.135, horn=0.03)
    q = np.array([[0.0, 0.4, -0.3], [0.0, 1.5, -2.0], [0.0, 0.1, -0.5]])
    assert np.allclose(link.angle(q), q[:, 1] + q[:, 2])
    assert np.allclose(link.gradient(q)[:, 1:], 1.0)
    assert np.allclose(link.joint(link.angle(q), q, (-2.6, -0.1)), q[:, 2])


def test_the_linkage_is_in_the_arms_description() -> None:
    info = robots.load("desk4").describe()
    minor = info["actuators"][2]
    assert minor["linkage"]["type"] == "four_bar" and minor["linkage"]["rod"] == ROD
    assert "linkage" not in info["actuators"][1]


def test_a_board_holding_the_linkage_where_it_cannot_be_is_a_fault_then_recovers(
    client: object, service: object, adapter_session: object
) -> None:
    """Found by a review: someone puts desk4's minor servo where its linkage cannot be with the
    major arm where it is. The adapter faults saying so (not stuck on the exception), and
    recovers once the servo is back."""
    import serial

    from armd.adapters.emulators.ssc32 import SSC32Emulator
    from armd.adapters.ssc32 import SSC32Adapter
    from tests.conftest import wait_for

    arm = robots.load("desk4")
    with SSC32Emulator() as emu:
        adapter = SSC32Adapter(adapter_session, arm, emu.port, query_period=0.1)  # type: ignore[arg-type]
        try:
            wait_for(lambda: service._adapter_count(arm) == 1, what="the adapter's token")  # type: ignore[attr-defined]
            pulses = arm.actuators.commands(arm.neutral)
            with serial.Serial(emu.port, 115200, timeout=1) as other:
                other.write(b"#1P500#2P2500\r")  # the major arm level, the minor servo's horn up: no joint vector
                wait_for(lambda: adapter.fault is not None, timeout=5, what="the fault")
                time.sleep(0.5)
                assert adapter.fault is not None and "no joint vector" in adapter.fault, adapter.fault
                other.write(f"#1P{pulses[1]}#2P{pulses[2]}\r".encode())
            wait_for(lambda: adapter.fault is None, timeout=10, what="the recovery")
            assert np.allclose(adapter.measure().position, arm.neutral, atol=0.01)
        finally:
            adapter.close()


def test_a_chain_of_linkages_is_refused() -> None:
    """Found by a review: one linkage's input another's driven joint was read back in the
    wrong order (the input still 0). Refused: each input is a joint the linear rows give."""
    from armd.robots.actuators import ActuatorMap

    desk4 = robots.load("desk4").actuators
    first = FourBar(input=0, driven=1, frame=0.135, lever=0.03, rod=0.135, horn=0.03)
    with pytest.raises(ValueError, match="linkage"):
        ActuatorMap(desk4.actuators, desk4.M * [[1], [0], [0]], desk4.b, {1: first, 2: desk4.linkages[2]})


def test_adapters_whose_settings_assume_a_linear_map_refuse_a_linkage() -> None:
    from armd.adapters.base import actuators_of
    from armd.errors import BadRequest
    from armd.robots import Servo

    desk4 = robots.load("desk4")
    assert len(actuators_of(desk4, Servo, "SSC-32")) == 3
    with pytest.raises(BadRequest, match="minor turns through a four-bar linkage"):
        actuators_of(desk4, Servo, "Feetech")  # (as if its servos were on a bus)
