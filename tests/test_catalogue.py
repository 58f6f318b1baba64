"""Loading arm folders: the catalogue, a user's folder, and the errors of bad folders."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from armd import robots
from armd.errors import RobotFileError, UnknownRobot


def test_load_is_cached_and_unknown_names_list_the_catalogue() -> None:
    assert robots.load("gupta3") is robots.load("gupta3")
    with pytest.raises(UnknownRobot) as e:
        robots.load("gupta4")
    assert e.value.available == robots.names()
    assert "gupta3" in str(e.value)
    assert e.value.to_dict()["code"] == "unknown_robot"


def test_user_folder_adds_an_arm_with_data_only(arm_copy: Callable[..., Path], tmp_path: Path) -> None:
    # a user's own arm: the gupta3 with longer links, under a new name, in a folder of arms
    arm_copy(
        "gupta3",
        as_name="longarm",
        toml_edits=[("upper_arm = 0.150", "upper_arm = 0.200")],
        urdf_edits=[('<origin xyz="0.150 0 0"', '<origin xyz="0.200 0 0"')],
    )
    arms = robots.load_dir(tmp_path)
    assert list(arms) == ["longarm"]
    arm = arms["longarm"]
    assert np.allclose(arm.fk([0.0, 0.0, 0.0]), [0.330, 0.0, 0.0])
    assert robots.load_dir(tmp_path / "longarm")["longarm"].nq == 3


def test_load_dir_errors(tmp_path: Path) -> None:
    with pytest.raises(RobotFileError):
        robots.load_dir(tmp_path / "missing")
    with pytest.raises(RobotFileError) as e:
        robots.load_dir(tmp_path)
    assert "holds no arm" in str(e.value)


BAD_TOML = [
    # (arm, old, new, field the error must name, words in the problem)
    (
        "gupta3",
        "[joints.elbow]\nacceleration = 3.0",
        "[joints.elbow]\nacceleraton = 3.0",
        "joints.elbow.acceleraton",
        "unknown key (a misspelling of 'acceleration'?)",
    ),
    ("gupta3", "jerk = 20.0\n", "jerk = 20.0\nspeed = 3\n", "joints.base_yaw.speed", "unknown key"),
    ("gupta3", "jerk = 15.0", "jerk = -15.0", "joints.shoulder.jerk", "positive"),
    ("gupta3", "jerk = 15.0", 'jerk = "fast"', "joints.shoulder.jerk", "number"),
    (
        "gupta3",
        'joints = ["base_yaw", "shoulder", "elbow"]',
        'joints = ["base_yaw", "shoulder", "knee"]',
        "robot.joints",
        "no movable joint 'knee'",
    ),
    (
        "gupta3",
        'joints = ["base_yaw", "shoulder", "elbow"]',
        'joints = ["shoulder", "base_yaw", "elbow"]',
        "robot.joints",
        "chain order",
    ),
    ("gupta3", 'neutral = [0.0, "pi/2", "-pi/2"]', "neutral = [0.0, 0.5, 0.5]", "robot.neutral", "elbow"),
    ("gupta3", 'neutral = [0.0, "pi/2", "-pi/2"]', "neutral = [0.0, 0.5]", "robot.neutral", "list of 3"),
    ("gupta3", 'neutral = [0.0, "pi/2", "-pi/2"]', 'neutral = [0.0, "pie/2", 0.0]', "robot.neutral[1]", "pi/2"),
    ("gupta3", 'tool_frame = "tool"', 'tool_frame = "toolz"', "robot.tool_frame", "no frame 'toolz'"),
    ("gupta3", 'urdf = "robot.urdf"', 'urdf = "missing.urdf"', "robot.urdf", "not found"),
    ("gupta3", "upper_arm = 0.150", "upper_arm = 0.500", "geometry", "does not describe the URDF"),
    ("gupta3", 'elbow = "elbow"\npivot', 'elbow = "shoulder"\npivot', "geometry", "different joints"),
    ("gupta3", 'axis = "Y"', 'axis = "X"', "actuators[1].axis", "already used"),
    ("gupta3", "joints = { elbow = 1.0 }", "joints = { shoulder = 2.0 }", "actuators", "rank"),
    ("gupta3", 'type = "stepper"', 'type = "hydraulic"', "actuators[0].type", "'servo', 'stepper' or 'bus_servo'"),
    ("gupta3", "joints = { base_yaw = 1.0 }", "joints = { turret = 1.0 }", "actuators[0].joints.turret", "not a joint"),
    ("insomniac", "channel = 3", "channel = 2", "actuators[3].channel", "already used"),
    (
        "insomniac",
        'centre_pulse = 1500.0\ncentre_angle = "-pi/2"',
        'centre_pulse = 1900.0\ncentre_angle = "-pi/2"',
        "actuators[2]",
        "outside its pulse range",
    ),
    ("insomniac", "direction = -1", "direction = 0", "actuators[2].direction", "1 or -1"),
    ("insomniac", 'mount = "frame"', 'mount = "wall"', "sensors[2].mount", "'scanner' or 'frame'"),
    ("insomniac", 'frame = "tool" ', 'frame = "nose" ', "sensors[2].frame", "no frame"),
    ("insomniac", "range = [0.04, 0.30]", "range = [0.30, 0.04]", "sensors[2].range", "min < max"),
    ("insomniac", "[gripper]\nchannel = 5", "[gripper]\nchannel = 4", "gripper.channel", "already used"),
    (
        "desk4",
        "coefficients = { major = 1.0, minor = 1.0 }",
        "coefficients = { major = 1.0, wrist = 1.0 }",
        "coupled_limits[0].coefficients.wrist",
        "not a joint",
    ),
    (
        "desk4",
        "lower = -1.2\nupper = 0.9",
        "lower = 0.9\nupper = -1.2",
        "coupled_limits[0].upper",
        "greater than lower",
    ),
    ("desk4", "neutral = [0.0, 1.2, -1.2]", "neutral = [0.0, 1.9, -0.5]", "robot.neutral", "linkage"),
    ("desk4", 'pitch = "level"', 'pitch = "tilted"', "geometry.pitch", "'joints' or 'level'"),
    ("so101", "id = 3", "id = 2", "actuators[2].id", "already used"),
    ("so101", "id = 5", "id = 253", "actuators[4].id", "0..252"),
    (
        "so101",
        'zero = 2048\ndirection = 1\nrange = [0, 4095]\n\n[[actuators]]\nname = "elbow_flex"',
        'zero = 3500\ndirection = 1\nrange = [0, 4095]\n\n[[actuators]]\nname = "elbow_flex"',
        "actuators[1]",
        "outside its range",
    ),
    (
        "so101",
        'range = [0, 4095]\n\n[[actuators]]\nname = "wrist_flex"',
        'range = [4095, 0]\n\n[[actuators]]\nname = "wrist_flex"',
        "actuators[2].range",
        "lower < upper",
    ),
    ("so101", "[gripper]\nid = 6", "[gripper]\nid = 5", "gripper.id", "already used"),
    (
        "so101",
        "tracking_tolerance = 0.1",
        "tracking_tolerance = -0.1",
        "joints.shoulder_pan.tracking_tolerance",
        "positive",
    ),
]


@pytest.mark.parametrize(("arm", "old", "new", "field", "words"), BAD_TOML)
def test_bad_robot_toml(arm_copy: Callable[..., Path], arm: str, old: str, new: str, field: str, words: str) -> None:
    folder = arm_copy(arm, toml_edits=[(old, new)])
    with pytest.raises(RobotFileError) as e:
        robots.load_folder(folder)
    assert e.value.file.endswith("robot.toml")
    assert e.value.field == field, str(e.value)
    assert words in e.value.problem, str(e.value)


def test_invalid_toml_syntax(arm_copy: Callable[..., Path]) -> None:
    folder = arm_copy("gupta3", toml_edits=[("[joints.elbow]", "[joints.elbow")])
    with pytest.raises(RobotFileError) as e:
        robots.load_folder(folder)
    assert "not valid TOML" in e.value.problem and "line" in e.value.problem


def test_broken_urdf_names_the_urdf(arm_copy: Callable[..., Path]) -> None:
    folder = arm_copy("gupta3", urdf_edits=[("</robot>", "")])
    with pytest.raises(RobotFileError) as e:
        robots.load_folder(folder)
    assert e.value.file.endswith("robot.urdf")
    assert "Pinocchio cannot load it" in e.value.problem


def test_urdf_without_velocity_limit(arm_copy: Callable[..., Path]) -> None:
    folder = arm_copy("gupta3", urdf_edits=[('velocity="0.8"', 'velocity="0"')])
    with pytest.raises(RobotFileError) as e:
        robots.load_folder(folder)
    assert e.value.field == "joints.shoulder.velocity"


def test_toml_may_override_urdf_limits(arm_copy: Callable[..., Path]) -> None:
    folder = arm_copy("gupta3", toml_edits=[("[joints.elbow]\n", '[joints.elbow]\nlower = "-pi/2"\nvelocity = 0.5\n')])
    arm = robots.load_folder(folder)
    assert np.isclose(arm.limits.lower[2], -np.pi / 2)
    assert arm.limits.velocity[2] == 0.5


def test_missing_toml(tmp_path: Path) -> None:
    with pytest.raises(RobotFileError) as e:
        robots.load_folder(tmp_path)
    assert "not found" in str(e.value)
