"""An arm as a user has it: its URDF and a robot.toml of two lines (joints, neutral). It loads,
with acceleration and jerk limits from its velocity limits (said once, in the log), and with no
actuators it is served for IK, plans and a simulated arm; a hardware adapter says what it lacks."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest
import zenoh

from armd import planning, robots, solvers
from armd.adapters.base import actuators_of
from armd.adapters.sim import SimAdapter
from armd.clients import ArmClient
from armd.errors import BadRequest, RobotFileError
from armd.robots import Servo, Stepper
from armd.robots.catalogue import ACCELERATION_PER_VELOCITY, JERK_PER_ACCELERATION
from armd.service.server import Service
from armd.service.zconfig import network_config
from tests.conftest import wait_for

JOINTS = ("base_yaw", "shoulder", "elbow", "wrist", "wrist_roll")
MINIMAL = (
    "[robot]\njoints = [" + ", ".join(f'"{j}"' for j in JOINTS) + ']\nneutral = [0.0, "pi/2", "-pi/2", 0.0, 0.0]\n'
)
STEP = np.array([0.0, 0.02, -0.02])


def _folder(tmp_path: Path, toml: str = MINIMAL, urdf_edits: tuple[tuple[str, str], ...] = ()) -> Path:
    folder = tmp_path / "myarm"
    folder.mkdir(parents=True)
    urdf = (robots.CATALOGUE_DIR / "insomniac" / "robot.urdf").read_text()
    for old, new in urdf_edits:
        assert old in urdf
        urdf = urdf.replace(old, new)
    (folder / "robot.urdf").write_text(urdf)
    (folder / "robot.toml").write_text(toml)
    return folder


def test_two_lines_load_with_limits_from_the_velocity_said_once(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    with caplog.at_level(logging.WARNING, logger="armd.robots.catalogue"):
        arm = robots.load_folder(_folder(tmp_path))
    velocity = robots.load("insomniac").limits.velocity  # (the same URDF: its <limit velocity>)
    assert np.allclose(arm.limits.velocity, velocity)
    assert np.allclose(arm.limits.acceleration, ACCELERATION_PER_VELOCITY * velocity)
    assert np.allclose(arm.limits.jerk, JERK_PER_ACCELERATION * ACCELERATION_PER_VELOCITY * velocity)
    said = [r.getMessage() for r in caplog.records if "no acceleration or jerk limit" in r.getMessage()]
    assert len(said) == 1 and all(j in said[0] for j in arm.joint_names), said
    assert len(arm.actuators) == 0 and arm.gripper is None


def test_a_link_and_a_joint_of_one_name_load_and_the_link_is_meant(tmp_path: Path) -> None:
    """A URDF that gives a link and a joint the same name (the Braccio's ``gripper_fix``), that name
    the tool frame: the arm loads, and the tool is the link."""
    renamed = ('<joint name="tool_joint" type="fixed">', '<joint name="tool" type="fixed">')
    arm = robots.load_folder(_folder(tmp_path, urdf_edits=(renamed,)))
    plain = robots.load("insomniac")
    q = np.array([0.2, 1.2, -1.0, -0.3, 0.1])
    assert np.allclose(arm.fk(q), plain.fk(q), atol=1e-12)
    assert arm.model.frames[arm.tool_frame_id].type == pin.FrameType.BODY
    assert np.allclose(arm.frame_position(q, "tool"), plain.frame_position(q, "tool"), atol=1e-12)
    r = solvers.solve_ik(arm, plain.fk(q))
    assert r.status == "ok"


def test_given_limits_are_kept_and_only_the_missing_ones_defaulted(tmp_path: Path) -> None:
    arm = robots.load_folder(_folder(tmp_path, MINIMAL + "[joints.elbow]\nacceleration = 2.0\n"))
    e = arm.joint_names.index("elbow")
    assert arm.limits.acceleration[e] == 2.0 and arm.limits.jerk[e] == JERK_PER_ACCELERATION * 2.0


def test_without_actuators_ik_and_plans_work(tmp_path: Path) -> None:
    arm = robots.load_folder(_folder(tmp_path))
    q = np.array([0.2, 1.2, -1.0, -0.3, 0.1])
    r = solvers.solve_ik(arm, arm.fk(q))
    assert r.status == "ok" and np.linalg.norm(arm.fk(r.q) - arm.fk(q)) < 1e-6
    traj = planning.plan(arm, arm.neutral, {"target": arm.fk(q).tolist()})
    assert traj.commands.shape == (len(traj.times), 0)  # (no actuators: no commands)
    end = arm.fk(arm.neutral) + STEP
    line = planning.plan(arm, arm.neutral, {"target": end.tolist()}, path="line")
    assert np.linalg.norm(arm.fk(line.position[-1]) - end) < 1e-6


def test_a_hardware_adapter_says_what_an_arm_without_actuators_lacks(tmp_path: Path) -> None:
    arm = robots.load_folder(_folder(tmp_path))
    for kind, adapter in ((Servo, "SSC-32"), (Stepper, "GRBL")):
        with pytest.raises(BadRequest) as e:
            actuators_of(arm, kind, adapter)
        assert "no [[actuators]]" in e.value.message and adapter in e.value.message and "--sim" in e.value.message


def test_a_gripper_needs_actuators(tmp_path: Path) -> None:
    with pytest.raises(RobotFileError) as e:
        robots.load_folder(_folder(tmp_path, MINIMAL + "[gripper]\nchannel = 5\nclosed = 1000\nopen = 2000\n"))
    assert e.value.field == "gripper" and "[[actuators]]" in e.value.problem


def test_a_urdf_without_velocity_limits_says_where_to_put_them(tmp_path: Path) -> None:
    urdf = (robots.CATALOGUE_DIR / "insomniac" / "robot.urdf").read_text()
    edits = tuple((f'velocity="{v}"', 'velocity="0"') for v in sorted(set(_velocities(urdf))))
    with pytest.raises(RobotFileError) as e:
        robots.load_folder(_folder(tmp_path, urdf_edits=edits))
    assert e.value.field == "joints.base_yaw.velocity" and "[joints.base_yaw] velocity = " in e.value.problem
    given = MINIMAL + "".join(f"[joints.{j}]\nvelocity = 2.0\n" for j in JOINTS)  # (what the message says)
    arm = robots.load_folder(_folder(tmp_path / "fixed", given, urdf_edits=edits))
    assert np.allclose(arm.limits.velocity, 2.0)


def _velocities(urdf: str) -> list[str]:
    import re

    return re.findall(r'velocity="([^"]+)"', urdf)


def test_served_with_a_simulated_arm(tmp_path: Path, router: str) -> None:
    arm = robots.load_folder(_folder(tmp_path))
    session = zenoh.open(network_config(connect=[router]))
    service = Service(session, {"myarm": arm}, prefix="mini")
    sim = SimAdapter(session, arm, prefix="mini", time_scale=4.0)
    try:
        with ArmClient(router, prefix="mini", timeout=10.0) as client:
            wait_for(lambda: client.state("myarm")["source"] == "adapter", what="the simulated arm")
            target = arm.fk(np.array([0.3, 1.3, -1.1, -0.2, 0.0]))
            moved = client.move("myarm", {"target": target.tolist()}, wait=True)
            assert np.linalg.norm(arm.fk(sim.position) - target) < 1e-5 and moved.adapter == sim.id
            assert client.info("myarm")["actuators"] == []
    finally:
        sim.close()
        service.close()
        session.close()


def test_a_continuous_joint_is_a_joint_of_q_over_two_turns(tmp_path: Path) -> None:
    limits = '<limit lower="-1.5707963267948966" upper="1.5707963267948966" velocity="3.0" effort="1"/>'
    after = '\n  </joint>\n  <link name="gripper">'  # (the roll's <limit>: the last joint's)
    urdf_edits = (
        ('<joint name="wrist_roll" type="revolute">', '<joint name="wrist_roll" type="continuous">'),
        (limits + after, '<limit velocity="3.0" effort="1"/>' + after),
    )
    arm = robots.load_folder(_folder(tmp_path, urdf_edits=urdf_edits))
    r = arm.joint_names.index("wrist_roll")
    assert arm.model.nq == arm.nq == 5  # (not cos and sin: one coordinate)
    assert arm.limits.lower[r] == -2 * np.pi and arm.limits.upper[r] == 2 * np.pi
    q = np.array([0.2, 1.2, -1.0, -0.3, 4.0])  # (a roll past half a turn)
    assert np.allclose(arm.fk(q), robots.load("insomniac").fk(np.array([0.2, 1.2, -1.0, -0.3, 4.0 - 2 * np.pi])))
    assert solvers.solve_ik(arm, arm.fk(q)).status == "ok"
    narrowed = robots.load_folder(
        _folder(tmp_path / "narrow", MINIMAL + '[joints.wrist_roll]\nlower = "-pi"\nupper = "pi"\n', urdf_edits)
    )
    assert narrowed.limits.upper[r] == np.pi


def test_a_joint_armd_does_not_take_is_named(tmp_path: Path) -> None:
    edits = (('<joint name="wrist_roll" type="revolute">', '<joint name="wrist_roll" type="floating">'),)
    with pytest.raises(RobotFileError) as e:
        robots.load_folder(_folder(tmp_path, urdf_edits=edits))
    assert "'wrist_roll'" in e.value.problem and "revolute, continuous and prismatic" in e.value.problem


MOUNTED = (
    '<robot name="insomniac">',
    '<robot name="insomniac">\n  <link name="world"/>\n  <joint name="mount" type="fixed"><parent link="world"/>'
    '<child link="base"/><origin xyz="0.1 0.2 0.05" rpy="0.1 0 1.5707963267948966"/></joint>',
)


def test_targets_are_in_the_base_frame_wherever_the_urdf_puts_it(tmp_path: Path) -> None:
    """The arm mounted in its URDF under a 'world' link (moved, turned and tilted): with
    base_frame = "base", FK, IK and lines are the catalogue arm's, in its base frame."""
    arm = robots.load_folder(_folder(tmp_path, urdf_edits=(MOUNTED,)))
    plain = robots.load_folder(_folder(tmp_path / "plain"))  # (the same folder, not mounted)
    rng = np.random.default_rng(3)
    for q in rng.uniform(plain.limits.lower, plain.limits.upper, size=(20, plain.nq)):
        assert np.allclose(arm.fk(q), plain.fk(q), atol=1e-12)
        assert abs(arm.tool_pitch(q) - plain.tool_pitch(q)) < 1e-9
    q = np.array([0.2, 1.2, -1.0, -0.3, 0.1])
    r = solvers.solve_ik(arm, plain.fk(q))
    assert r.status == "ok" and np.linalg.norm(plain.fk(r.q) - plain.fk(q)) < 1e-6
    world = robots.load_folder(
        _folder(tmp_path / "world", MINIMAL.replace("[robot]\n", '[robot]\nbase_frame = "world"\n'), (MOUNTED,))
    )
    assert not np.allclose(world.fk(q), plain.fk(q), atol=1e-3)  # (the same arm, targets in the world frame)


def test_a_base_frame_that_moves_is_refused(tmp_path: Path) -> None:
    toml = MINIMAL.replace("[robot]\n", '[robot]\nbase_frame = "humerus"\n')
    with pytest.raises(RobotFileError) as e:
        robots.load_folder(_folder(tmp_path, toml))
    assert e.value.field == "robot.base_frame" and "moves with joint" in e.value.problem


def test_catalogue_and_info_say_which_solver_an_arm_gets_and_why(tmp_path: Path) -> None:
    assert robots.load("insomniac").solver == "closed form: yaw + 3 pitch + roll (robot.toml [geometry])"
    assert robots.load("gupta3").solver == "closed form: yaw + 2 pitch (robot.toml [geometry])"
    assert "held level by a linkage" in robots.load("desk4").solver
    mine = robots.load_folder(_folder(tmp_path))
    assert mine.solver == "closed form: yaw + 3 pitch + roll (found from the URDF's chain)"
    assert mine.describe()["solver"] == mine.solver
