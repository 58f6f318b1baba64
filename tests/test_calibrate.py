"""``armd calibrate`` as a user runs it, answered line by line: the so101's Feetech servos and
the OpenManipulator-X's Dynamixels moved by hand on their emulators (through the vendors'
SDKs), and an SSC-32 arm jogged; the file it writes read back by the adapters."""

from __future__ import annotations

import math
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import zenoh
from conftest import converse, wait_for

from armd import robots
from armd.adapters.emulators.feetech import FeetechEmulator
from armd.adapters.emulators.process import EmulatorProcess
from armd.adapters.emulators.ssc32 import SSC32Emulator
from armd.robots import calibration

pytest.importorskip("scservo_sdk")
from armd.adapters.feetech import FeetechAdapter

ROOT = Path(__file__).resolve().parent.parent
CPR = 4096


class Arm:
    """A bus arm as it really is (zeros, directions), moved by hand on its emulator."""

    def __init__(
        self, emu: Any, arm: robots.Robot, zero: dict[int, float], direction: dict[int, int], margin: float = 40.0
    ) -> None:
        self.emu, self.arm, self.zero, self.direction, self.margin = emu, arm, zero, direction, margin
        self.servos = list(arm.actuators.actuators)

    def counts(self, k: int, a: float) -> float:
        """Servo ``k``'s count at its actuator angle ``a`` [rad], as the arm really is."""
        s = self.servos[k]
        return self.zero[s.id] + self.direction[s.id] * a * CPR / (2 * math.pi)

    def ends(self, s: Any) -> tuple[float, float]:
        """The counts the arm reaches at its joint's limits, and a margin beyond."""
        k = self.servos.index(s)
        a, b = sorted(self.counts(k, x) for x in s.angle_range)
        return a - self.margin, b + self.margin

    def pose(self, q: np.ndarray) -> None:
        """The arm by hand at the joint vector ``q`` (through its map: a = M q + b)."""
        amap = self.arm.actuators
        for k, (s, a) in enumerate(zip(self.servos, amap.M @ q + amap.b, strict=True)):
            self.emu.move_by_hand(s.id, self.counts(k, float(a)))

    def sweep(self, short: str | None = None) -> None:
        """Every joint to both ends and back, in small steps (a hand's pace); ``short``: that
        joint stops well short of its upper limit."""
        for s in self.servos:
            lo, hi = self.ends(s)
            if s.name == short:
                hi = (lo + hi) / 2
            for c in [
                *np.linspace(self.zero[s.id], lo, 15),
                *np.linspace(lo, hi, 30),
                *np.linspace(hi, self.zero[s.id], 15),
            ]:
                self.emu.move_by_hand(s.id, float(c))
                time.sleep(0.004)
            time.sleep(0.02)


TRUE_ZERO = {1: 2100.0, 2: 1990.0, 3: 2048.0, 4: 2200.0, 5: 1900.0}
TRUE_DIRECTION = {1: 1, 2: -1, 3: 1, 4: -1, 5: 1}


def answers(
    arm: Arm, *, gripper: tuple[float, float] = (1500.0, 2900.0), short: str | None = None, still: str | None = None
) -> Any:
    """What an operator does at each prompt of ``armd calibrate`` (then presses Enter)."""

    def answer(prompt: str) -> str:
        if prompt.startswith("Put the arm at its reference pose"):
            arm.pose(np.zeros(arm.arm.nq))
        elif prompt.startswith("Turn "):
            name = prompt.split()[1]
            j = arm.arm.joint_names.index(name)
            if name != still:
                q = np.zeros(arm.arm.nq)
                q[j] = 0.3 if arm.arm.limits.upper[j] > 0.3 else -0.3
                arm.pose(q)
        elif prompt.startswith("Move every joint"):
            arm.pose(np.zeros(arm.arm.nq))
            arm.sweep(short)
        elif prompt.startswith("Close the gripper"):
            arm.emu.move_by_hand(arm.arm.gripper.channel, gripper[0])
        elif prompt.startswith("Open the gripper"):
            arm.emu.move_by_hand(arm.arm.gripper.channel, gripper[1])
        return ""

    return answer


def test_the_so101_is_calibrated_by_hand_and_its_adapter_reads_it(
    tmp_path: Path, adapter_session: zenoh.Session, service: Any
) -> None:
    """Zeros off the factory's, two servos turned round: what the user's hands show is what the
    file says, and the adapter then reads the arm's pose right."""
    arm = robots.load("so101")
    state = tmp_path / "state"
    with EmulatorProcess(FeetechEmulator, ids=[1, 2, 3, 4, 5, 6]) as emu:
        real = Arm(emu, arm, TRUE_ZERO, TRUE_DIRECTION)
        code, said, err = converse(
            ["calibrate", "so101", "--adapter", "feetech", "--port", emu.port],
            answers(real),
            env={"ARMD_STATE_DIR": str(state)},
        )
        assert code == 0, (said, err)
        assert all(emu.register(i, 40) == 0 for i in range(1, 7))  # torque off, and left off
        path = state / "so101.calibration.toml"
        assert f"wrote {path}" in said[-1]
        data = calibration.read(path)
        for s in real.servos:
            t = data[s.name]
            assert abs(t["zero"] - TRUE_ZERO[s.id]) <= 1 and t["direction"] == TRUE_DIRECTION[s.id], (s.name, t)
            lo, hi = real.ends(s)
            assert abs(t["range"][0] - round(lo)) <= 1 and abs(t["range"][1] - round(hi)) <= 1, (s.name, t)
        assert data["gripper"] == {"closed": 1500, "open": 2900}
        # the adapter reads the file from the state dir: the arm at a pose by hand is read as that pose
        q = np.array([0.4, -0.5, 0.6, -0.3, 1.0])
        real.pose(q)
        adapter = FeetechAdapter(adapter_session, arm, emu.port, calibration=path)
        try:
            assert np.max(np.abs(adapter.measure().position - q)) < 2e-3
            assert adapter.robot.gripper.closed == 1500  # type: ignore[union-attr]
        finally:
            adapter.close()


def test_a_servo_turned_round_by_its_map_and_offset_is_calibrated_right(tmp_path: Path, arm_copy: Any) -> None:
    """A so101 whose shoulder_pan servo turns minus the joint, offset by 0.2 rad (a = -q + 0.2):
    the zero is the count at actuator angle 0, not at the reference pose, and the direction is
    the servo's against its angle, not the joint's."""
    folder = arm_copy(
        "so101",
        toml_edits=[
            ("joints = { shoulder_pan = 1.0 }\nid = 1", "joints = { shoulder_pan = -1.0 }\noffset = 0.2\nid = 1")
        ],
        as_name="so101",
    )
    arm = robots.load_folder(folder)
    assert arm.actuators.M[0, 0] == -1.0 and arm.actuators.b[0] == 0.2
    out = tmp_path / "cal.toml"
    with EmulatorProcess(FeetechEmulator, ids=[1, 2, 3, 4, 5, 6]) as emu:
        real = Arm(emu, arm, TRUE_ZERO, TRUE_DIRECTION)
        code, said, err = converse(
            [
                "calibrate",
                "so101",
                "--robots-dir",
                str(folder.parent),
                "--adapter",
                "feetech",
                "--port",
                emu.port,
                "--output",
                str(out),
            ],
            answers(real),
        )
        assert code == 0, (said, err)
        data = calibration.read(out)
        assert abs(data["shoulder_pan"]["zero"] - TRUE_ZERO[1]) <= 1 and data["shoulder_pan"]["direction"] == 1
        # and the adapter then reads the arm's pose right, shoulder_pan included
        cal = calibration.apply(arm, out)
        q = np.array([0.4, -0.5, 0.6, -0.3, 1.0])
        real.pose(q)
        counts = np.array([emu.position(s.id) for s in real.servos])
        assert np.allclose(cal.actuators.joints_from_commands(counts, tol=np.inf), q, atol=2e-3)


def test_the_openmanipulator_x_is_calibrated_on_its_dynamixels(tmp_path: Path) -> None:
    pytest.importorskip("dynamixel_sdk")
    from armd.adapters.emulators.dynamixel import DynamixelEmulator

    arm = robots.load_folder(ROOT / "examples" / "arms" / "openmanipulator-x")
    zero = {11: 2048.0, 12: 2000.0, 13: 2100.0, 14: 2048.0}
    direction = {11: 1, 12: 1, 13: -1, 14: 1}
    out = tmp_path / "omx.toml"
    with EmulatorProcess(DynamixelEmulator, ids=[11, 12, 13, 14, 15]) as emu:
        real = Arm(emu, arm, zero, direction, margin=1.0)  # (joint1 turns all but the encoder's wrap)
        code, said, err = converse(
            [
                "calibrate",
                "openmanipulator-x",
                "--robots-dir",
                str(ROOT / "examples" / "arms"),
                "--adapter",
                "dynamixel",
                "--port",
                emu.port,
                "--output",
                str(out),
            ],
            answers(real, gripper=(2048.0, 3100.0)),
        )
        assert code == 0, (said, err)
        assert all(emu.register(i, 64) == 0 for i in (11, 12, 13, 14, 15))  # Torque Enable: off
    data = calibration.read(out)
    for s in real.servos:
        assert abs(data[s.name]["zero"] - zero[s.id]) <= 1 and data[s.name]["direction"] == direction[s.id]
    assert data["gripper"] == {"closed": 2048, "open": 3100}


def so101_refused(tmp_path: Path, **hands: Any) -> tuple[list[str], str]:
    """``armd calibrate so101`` with the hands doing ``hands`` (:func:`answers`): refused, no file written."""
    out = tmp_path / "cal.toml"
    with EmulatorProcess(FeetechEmulator, ids=[1, 2, 3, 4, 5, 6]) as emu:
        real = Arm(emu, robots.load("so101"), TRUE_ZERO, TRUE_DIRECTION)
        code, said, err = converse(
            ["calibrate", "so101", "--adapter", "feetech", "--port", emu.port, "--output", str(out)],
            answers(real, **hands),
        )
    assert code == 1 and not out.exists(), (said, err)
    return said, err


def test_a_calibration_that_contradicts_the_limits_is_refused_and_nothing_is_written(tmp_path: Path) -> None:
    said, err = so101_refused(tmp_path, short="elbow_flex")
    assert "elbow_flex" in err and "contradicts the joint limits" in err, (said, err)


def test_a_joint_that_does_not_turn_is_asked_again_then_refused(tmp_path: Path) -> None:
    said, err = so101_refused(tmp_path, still="wrist_flex")
    assert "wrist_flex (servo id 4) did not turn" in err, (said, err)
    assert sum(p.startswith("> Turn wrist_flex") for p in said) == 3


def test_a_silent_servo_and_a_closed_input_are_told_and_nothing_is_written(tmp_path: Path) -> None:
    out = tmp_path / "cal.toml"
    with EmulatorProcess(FeetechEmulator, ids=[1, 2, 4, 5, 6]) as emu:
        code, _, err = converse(
            ["calibrate", "so101", "--adapter", "feetech", "--port", emu.port, "--output", str(out)], lambda p: ""
        )
        assert code == 1 and "no answer from servo id 3 (elbow_flex)" in err, err
    with EmulatorProcess(FeetechEmulator, ids=[1, 2, 3, 4, 5, 6]) as emu:
        import subprocess
        import sys

        done = subprocess.run(
            [
                sys.executable,
                "-m",
                "armd.cli",
                "calibrate",
                "so101",
                "--adapter",
                "feetech",
                "--port",
                emu.port,
                "--output",
                str(out),
            ],
            cwd=ROOT,
            input="",
            capture_output=True,
            text=True,
            timeout=60,
        )
        assert done.returncode == 1 and "abandoned" in done.stderr, done.stderr
    assert not out.exists()


def test_an_ssc32_arm_is_jogged_to_its_centres_and_directions(tmp_path: Path, adapter_session: zenoh.Session) -> None:
    """The insomniac's shoulder sits 20 us off robot.toml's centre and its elbow servo is
    mounted the other way round: jogged, answered, written; the adapter's map then agrees."""
    arm = robots.load("insomniac")
    out = tmp_path / "insomniac.calibration.toml"
    script = {
        "shoulder": ["+", "++", "-", "-", "-", "", "y"],  # +10 +50 -30: 30 us
        "elbow": ["++", "-", "-", "-", "", "n"],  # +50 -30: 20 us, and turned the wrong way
        "wrist_roll": ["++"] * 9 + ["--"] * 8 + ["", "y"],  # the ninth past the jog's end (400 us): refused
    }
    seen: list[str] = []
    with SSC32Emulator() as emu:

        def answer(prompt: str) -> str:
            seen.append(prompt)
            joint = prompt.split()[1] if prompt.startswith("Jog ") else prompt.split()[0]
            todo = script.get(joint)
            if todo:
                return todo.pop(0)
            return "y" if prompt.endswith("(y/n)") else ""

        code, said, err = converse(
            ["calibrate", "insomniac", "--adapter", "ssc32", "--port", emu.port, "--output", str(out)], answer
        )
        assert code == 0, (said, err)
        wait_for(lambda: not emu.moving(), what="the servos still")
        pulses = emu.pulses()
        # the adapter reads it: the board's pulses, where the operator left the arm, are the reference pose
        from armd.adapters.ssc32 import SSC32Adapter

        adapter = SSC32Adapter(adapter_session, arm, emu.port, calibration=out)
        try:
            assert np.allclose(adapter.measure().position[:3], [0.0, np.pi / 2, -np.pi / 2], atol=2e-3)
        finally:
            adapter.close()
    data = calibration.read(out)
    assert data["shoulder"] == {"centre_pulse": 1530, "direction": 1}
    assert data["elbow"] == {"centre_pulse": 1480, "direction": 1}  # (robot.toml's direction -1: +20 us is 1480)
    assert data["base_yaw"] == {"centre_pulse": 1500, "direction": 1}
    assert data["wrist_roll"] == {"centre_pulse": 1500, "direction": 1}
    assert abs(pulses[1] - 1530) < 1 and abs(pulses[2] - 1480) < 1  # each left at its centre
    cal = calibration.apply(arm, out)
    assert cal.actuators.actuators[1].centre_pulse == 1530  # type: ignore[union-attr]
    assert sum("past the jog's end" in line for line in said) == 1
    assert any(p.startswith("Jog base_yaw to 0.0000 rad") for p in seen)


def jog_script(script: dict[str, list[str]], seen: list[str]) -> Any:
    """An operator at the keyboard: each prompt answered from ``script`` by the word it names
    (a joint, ``servo``, or a servo being trimmed), else Enter, or ``y`` to a direction."""

    def answer(prompt: str) -> str:
        seen.append(prompt)
        words = prompt.split()
        key = words[1] if words[0] in ("Jog", "Trim") else words[0]
        todo = script.get(key)
        if todo:
            return todo.pop(0)
        return "y" if prompt.endswith("(y/n)") else ""

    return answer


def test_a_linkage_servo_is_jogged_alone_and_asked_of_its_own_angle(tmp_path: Path) -> None:
    """desk4's minor servo turns with major and minor through its four-bar: jogged on its own
    (major's jog leaves it be), its direction asked of its own angle, the horn's."""
    out = tmp_path / "desk4.toml"
    seen: list[str] = []
    script = {"major": ["+", "+", "", "y"], "servo": ["-", "", "n"]}
    with SSC32Emulator() as emu:
        code, said, err = converse(
            ["calibrate", "desk4", "--adapter", "ssc32", "--port", emu.port, "--output", str(out)],
            jog_script(script, seen),
        )
        assert code == 0, (said, err)
        wait_for(lambda: not emu.moving(), what="the servos still")
        pulses = emu.pulses()
    assert calibration.read(out) == {
        "steer": {"centre_pulse": 1500, "direction": 1},
        "major": {"centre_pulse": 1520, "direction": 1},
        "minor": {"centre_pulse": 1490, "direction": -1},
    }
    own = "Jog servo minor (its own angle: its horn from straight behind, turning minor through a four-bar with major)"
    assert any(p.startswith(f"{own} to 0.0000 rad") for p in seen), seen
    assert abs(pulses[1] - 1520) < 1 and abs(pulses[2] - 1490) < 1


def test_a_jog_the_limits_cannot_take_is_refused_at_once(tmp_path: Path) -> None:
    """desk4's major uses the servo's range down to 500 us at 0 rad: centred 10 us lower, its
    limits would need 490 us. Refused at that joint (minor never jogged), nothing written. And
    sg5ut's shoulder pair, jogged together then trimmed one by one, cannot be offset at all."""
    for arm, script, servo in [
        ("desk4", {"major": ["-", "", "y"]}, "major"),
        ("sg5ut", {"shoulder": ["+", ""], "shoulder_b": ["+", ""]}, "shoulder_a"),
    ]:
        out = tmp_path / f"{arm}.toml"
        seen: list[str] = []
        with SSC32Emulator() as emu:
            code, said, err = converse(
                ["calibrate", arm, "--adapter", "ssc32", "--port", emu.port, "--output", str(out)],
                jog_script(script, seen),
            )
        assert code == 1 and f"{servo}: contradicts the joint limits" in err, (arm, said, err)
        assert not out.exists()
        if arm == "desk4":
            assert not any("minor" in p for p in seen)
        else:
            assert [p.split()[1] for p in seen if p.startswith("Trim")] == ["shoulder_a", "shoulder_b", "shoulder_b"]
