"""calibration.toml: a bus-servo arm's measured zeros, directions and ranges, checked at load."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from armd import robots
from armd.errors import RobotFileError
from armd.robots import calibration


def test_a_calibration_overrides_the_factory_values_and_round_trips(tmp_path: Path) -> None:
    arm = robots.load("so101")
    path = tmp_path / "calibration.toml"
    calibration.write(path, {"shoulder_pan": (2100.0, -1, (500.0, 3700.0)), "wrist_roll": (1990.0, 1, (100.0, 4000.0))})
    cal = calibration.apply(arm, path)
    q = np.array([0.5, 0.0, 0.0, 0.0, -1.0])
    per = 4096 / (2 * math.pi)
    assert cal.actuators.commands(q).tolist() == [round(2100 - 0.5 * per), 2048, 2048, 2048, round(1990 - per)]
    assert np.allclose(cal.actuators.joints_from_commands(cal.actuators.commands(q)), q, atol=1e-3)
    assert arm.actuators.commands(q)[0] == round(2048 + 0.5 * per)  # (the arm given is not changed)


@pytest.mark.parametrize(
    ("text", "field", "words"),
    [
        ("[knee]\nzero = 2048\n", "knee", "not a servo of so101"),
        ("[gripper]\nclosed = 2048\n", "gripper", "takes closed and open"),
        ("[gripper]\nclosed = 2048\nopen = 2048\n", "gripper", "two different counts"),
        ("[elbow_flex]\ndirection = 2\n", "elbow_flex", "direction must be 1 or -1"),
        ("[elbow_flex]\nzero = 'middle'\n", "elbow_flex", "zero must be a finite number"),
        ("[elbow_flex]\nzero = nan\n", "elbow_flex", "zero must be a finite number"),
        ("[elbow_flex]\ndirection = true\n", "elbow_flex", "direction must be 1 or -1"),
        ("[elbow_flex]\nrange = [1, 2, 3]\n", "elbow_flex", "range must be [lower, upper]"),
        ("[elbow_flex]\noffset = 3\n", "elbow_flex", "zero, direction and range only"),
        ("[elbow_flex]\nrange = [1500, 2600]\n", "elbow_flex", "contradicts the joint limits"),
        ("[elbow_flex\n", None, "cannot be read"),
    ],
)
def test_a_bad_calibration_is_refused_naming_what(tmp_path: Path, text: str, field: str | None, words: str) -> None:
    path = tmp_path / "calibration.toml"
    path.write_text(text)
    with pytest.raises(RobotFileError) as e:
        calibration.apply(robots.load("so101"), path)
    assert e.value.field == field and words in e.value.problem, e.value


def test_a_hobby_servo_takes_its_centre_pulse_and_direction_within_its_range(tmp_path: Path) -> None:
    """An SSC-32 arm's calibration (armd calibrate --adapter ssc32): a centre pulse and a
    direction per servo; one whose limits would then need a pulse beyond the servo's is refused."""
    arm = robots.load("insomniac")
    path = tmp_path / "calibration.toml"
    calibration.write_servos(path, {"shoulder": (1530.0, 1), "elbow": (1480.0, 1)})
    cal = calibration.apply(arm, path)
    assert cal.actuators.commands(np.array([0.0, np.pi / 2, -np.pi / 2, 0.0, 0.0])).tolist()[1:3] == [1530, 1480]
    for text, words in [
        ("[base_yaw]\nzero = 1500\n", "takes centre_pulse and direction only"),
        ("[base_yaw]\ncentre_pulse = 1520\n", "contradicts the joint limits"),  # (its ±90 deg need 500..2500 us)
        ("[gripper]\nclosed = 1\nopen = 2\n", "no gripper on a bus"),
    ]:
        path.write_text(text)
        with pytest.raises(RobotFileError) as e:
            calibration.apply(arm, path)
        assert words in e.value.problem, e.value
