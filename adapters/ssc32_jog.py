"""An SSC-32 arm's hobby servos jogged from the keyboard (``armd calibrate ROBOT --adapter
ssc32``): each servo's centre pulse (its pulse at its ``centre_angle``) and its direction.

A hobby servo says nothing of where it is: the operator looks. One joint at a time, its servos
get the pulse robot.toml says is their centre (a servo's first pulse is a jump: the board
cannot know where the horn is), then the operator jogs them (``+``/``-`` 10 us, ``++``/``--``
50 us, slowly, no farther than ``JOG_MAX`` from that pulse and never outside the servo's pulse
range) until the joint is at its centre angle, and presses Enter. The servos then turn
``TEST_STEP`` the way robot.toml says is positive, and the operator answers whether the joint
turned the way a positive angle turns it; they go back to the centre. The servos of one joint
(a mirrored pair) are jogged together, each in its own direction from robot.toml.

What was found is checked against the arm (the joint limits must need no pulse beyond a
servo's range) and written as ``calibration.toml`` tables (``centre_pulse``, ``direction``),
which the SSC-32 adapter reads at start.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import serial

from armd.robots import Robot, Servo
from armd.robots import calibration as robots_calibration

from .base import actuators_of, calibration_file
from .serial_port import open_port

log = logging.getLogger(__name__)

JOGS = {"+": 10, "-": -10, "++": 50, "--": -50}  # [us] what each answer moves
JOG_MAX = 400  # [us] the farthest a jog goes from robot.toml's centre pulse
TEST_STEP = 100  # [us] the turn that shows a joint's direction
JOG_SPEED = 500  # [us/s] how fast a jog moves a servo (the SSC-32's S)


def jog(
    robot: Robot,
    port: str,
    baud: int | None,
    ask: Callable[[str], str],
    say: Callable[[str], None],
    *,
    output: Path | None = None,
    state_dir: str | Path | None = None,
    serial_port: serial.SerialBase | None = None,
) -> Path:
    """Jog ``robot``'s servos on the SSC-32 at ``port`` with the operator (``ask(prompt)``: their
    answer, a line), check what was found, write it (to ``output``, else beside the adapters'
    state) and return where."""
    servos = actuators_of(robot, Servo, "SSC-32")
    rate = int(baud or robot.controller.get("baud", 9600))  # type: ignore[call-overload]
    ser = serial_port or open_port(port, rate, 0.5, 0.5, exclusive=True)
    amap = robot.actuators
    joints: dict[int, list[int]] = {}  # joint -> its servos (a servo belongs to the joint that turns it most)
    for k in range(len(servos)):
        joints.setdefault(int(np.argmax(np.abs(amap.M[k]))), []).append(k)
    found: dict[str, tuple[float, int]] = {}
    try:
        say(
            f"{robot.name}: {len(servos)} servos on {port}; each joint's servos first get robot.toml's centre "
            "pulse (a hobby servo jumps to its first pulse: keep clear)"
        )
        for j, members in joints.items():
            name = robot.joint_names[j]
            group = [servos[k] for k in members]
            label = (
                name if len(group) == 1 and group[0].name == name else f"{name} ({', '.join(s.name for s in group)})"
            )
            delta = _centre(ser, group, label, ask, say)
            positive = _direction(ser, group, delta, label, ask)
            for s in group:
                found[s.name] = (s.centre_pulse + s.direction * delta, s.direction * (1 if positive else -1))
                say(f"{s.name}: centre {found[s.name][0]:g} us, direction {found[s.name][1]:+d}")
        tables: dict[str, Any] = {n: {"centre_pulse": c, "direction": d} for n, (c, d) in found.items()}
        robots_calibration.apply_tables(robot, tables, "the jogged calibration")
        path = output or calibration_file(robot, state_dir)
        robots_calibration.write_servos(path, found)
        return path
    finally:
        if serial_port is None:
            ser.close()


def _fits(servo: Servo, delta: float) -> bool:
    """Whether ``servo``'s pulse ``delta`` [us] from its centre, its way, is inside its range."""
    return bool(servo.pulse_range[0] <= servo.centre_pulse + servo.direction * delta <= servo.pulse_range[1])


def _send(ser: serial.SerialBase, group: list[Servo], delta: float) -> None:
    line = "".join(f"#{s.channel}P{round(s.centre_pulse + s.direction * delta)}S{JOG_SPEED}" for s in group)
    ser.write((line + "\r").encode())
    ser.flush()


def _centre(
    ser: serial.SerialBase, group: list[Servo], label: str, ask: Callable[[str], str], say: Callable[[str], None]
) -> float:
    """How far [us, along robot.toml's directions] from robot.toml's centre the operator jogged ``group``."""
    angle = group[0].centre_angle
    delta = 0.0
    _send(ser, group, delta)
    while True:
        answer = ask(
            f"Jog {label} to {angle:.4f} rad ({np.degrees(angle):.1f} deg): + or - moves it 10 us, ++ or -- 50 us; "
            "press Enter alone when it is there"
        )
        if answer == "":
            return delta
        if answer not in JOGS:
            say("type +, -, ++ or -- (then Enter), or press Enter alone when it is there")
            continue
        new = delta + JOGS[answer]
        pulses = [s.centre_pulse + s.direction * new for s in group]
        if abs(new) > JOG_MAX or any(
            not s.pulse_range[0] <= p <= s.pulse_range[1] for s, p in zip(group, pulses, strict=True)
        ):
            say(f"that would go past the jog's end ({JOG_MAX} us from robot.toml's centre, or the servo's range)")
            continue
        delta = new
        _send(ser, group, delta)


def _direction(ser: serial.SerialBase, group: list[Servo], delta: float, label: str, ask: Callable[[str], str]) -> bool:
    """Whether robot.toml's direction turns ``group`` the way a positive angle does (the
    operator's answer, after a turn of ``TEST_STEP`` that way; back to the centre after)."""
    step = TEST_STEP
    if not all(_fits(s, delta + step) for s in group):  # (no room that way: the other, and the question turned round)
        step = -TEST_STEP
    _send(ser, group, delta + step)
    way = "a positive" if step > 0 else "a negative"
    try:
        while True:
            answer = ask(f"{label} turned a little: the way {way} angle turns it? (y/n)").lower()
            if answer in ("y", "yes", "n", "no"):
                return answer.startswith("y")
    finally:
        _send(ser, group, delta)
