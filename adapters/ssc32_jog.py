"""An SSC-32 arm's hobby servos jogged from the keyboard (``armd calibrate ROBOT --adapter
ssc32``): each servo's centre pulse (its pulse at its ``centre_angle``) and its direction.

A hobby servo says nothing of where it is: the operator looks. One joint at a time, its
servos get the pulse robot.toml says is their centre (a servo's first pulse is a jump: the
board cannot know where the horn is), then the operator jogs them (``+``/``-`` 10 us,
``++``/``--`` 50 us, slowly, no farther than ``JOG_MAX`` from that pulse and never outside a
servo's pulse range) until the joint is at its centre angle, and presses Enter. The servos then
turn ``TEST_STEP`` the way robot.toml says is positive (or negative, where the joint's limits
leave no room that way), and the operator answers whether the joint turned the way a positive
(negative) angle turns it; they go back to the centre.

- The servos of one joint (a mirrored pair) are jogged together, each its own way; then each
  is trimmed alone (the same keys) until it stops straining against the other.
- A servo behind a linkage (a row of the actuator map with more than one joint, desk4's minor
  servo: ``q2 + q3``) is jogged alone, its own angle asked for, and the direction asked of its
  own angle.
- A row's sign counts: a servo whose angle is minus its joint's is turned round.

Each joint is checked as soon as it is done: a centre whose joint limits would need a pulse
beyond a servo's range is refused there (:class:`RobotFileError`: calibrate again, or narrow
the limits; a joint whose limits use the servo's whole range cannot be offset at all). What
was found is written as ``calibration.toml`` tables (``centre_pulse``, ``direction``), which
the SSC-32 adapter reads at start.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import numpy as np
import serial

from armd.errors import RobotFileError
from armd.robots import Robot, Servo
from armd.robots import calibration as robots_calibration

from .base import actuators_of, calibration_file
from .serial_port import open_port

log = logging.getLogger(__name__)

JOGS = {"+": 10, "-": -10, "++": 50, "--": -50}  # [us] what each answer moves
JOG_MAX = 400  # [us] the farthest a jog goes from robot.toml's centre pulse
TEST_STEP = 100  # [us] the turn that shows a joint's direction
JOG_SPEED = 500  # [us/s] how fast a jog moves a servo (the SSC-32's S)
SOURCE = "the jogged calibration"


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
    M = robot.actuators.M
    groups: dict[object, list[int]] = {}  # a joint's own servos together; a linkage's servo alone
    for k in range(len(servos)):
        nonzero = np.flatnonzero(M[k])
        groups.setdefault(int(nonzero[0]) if len(nonzero) == 1 else ("servo", k), []).append(k)
    found: dict[str, tuple[float, int]] = {}
    try:
        say(
            f"{robot.name}: {len(servos)} servos on {port}; each joint's servos first get robot.toml's centre "
            "pulse (a hobby servo jumps to its first pulse: keep clear)"
        )
        for key, members in groups.items():
            group = [servos[k] for k in members]
            if isinstance(key, int):  # a joint: its angle asked for, and signs from the map's rows
                name = robot.joint_names[key]
                label = name if [s.name for s in group] == [name] else f"{name} ({', '.join(s.name for s in group)})"
                signs = [int(np.sign(M[k, key])) for k in members]
                angle = (group[0].centre_angle - robot.actuators.b[members[0]]) / M[members[0], key]
            else:
                label = f"servo {group[0].name} (its own angle: {_row(robot, members[0])})"
                signs = [1]
                angle = group[0].centre_angle
            deltas = _centre(ser, group, float(angle), label, ask, say)
            if len(group) > 1:
                deltas = _trim(ser, group, deltas, ask, say)
            positive = _direction(ser, group, deltas, signs, label, ask)
            for s, d in zip(group, deltas, strict=True):
                new = replace(s, centre_pulse=s.centre_pulse + s.direction * d, direction=s.direction * positive)
                problem = robots_calibration.servo_misfit(new)
                if problem:
                    raise RobotFileError(
                        SOURCE,
                        s.name,
                        f"contradicts the joint limits: {problem}: calibrate again, or narrow the limits",
                    )
                found[s.name] = (new.centre_pulse, new.direction)
                say(f"{s.name}: centre {new.centre_pulse:g} us, direction {new.direction:+d}")
        tables = {n: {"centre_pulse": c, "direction": d} for n, (c, d) in found.items()}
        robots_calibration.apply_tables(robot, tables, SOURCE)
        path = output or calibration_file(robot, state_dir)
        robots_calibration.write_servos(path, found)
        return path
    finally:
        if serial_port is None:
            ser.close()


def _row(robot: Robot, k: int) -> str:
    """A linkage row as a sum of joints (``major + minor``), or a four-bar's."""
    link = robot.actuators.linkages.get(k)
    if link is not None:
        return (
            f"its horn from straight behind, turning {robot.joint_names[link.driven]} through a four-bar "
            f"with {robot.joint_names[link.input]}"
        )
    terms = [
        f"{'-' if c < 0 else '+'} {'' if abs(c) == 1 else f'{abs(c):g} '}{robot.joint_names[j]}"
        for j, c in enumerate(robot.actuators.M[k])
        if c != 0
    ]
    return " ".join(terms).removeprefix("+ ")


def _fits(servo: Servo, delta: float) -> bool:
    """Whether ``servo``'s pulse ``delta`` [us] from its centre, its way, is inside its range."""
    return bool(servo.pulse_range[0] <= servo.centre_pulse + servo.direction * delta <= servo.pulse_range[1])


def _send(ser: serial.SerialBase, group: list[Servo], deltas: list[float]) -> None:
    line = "".join(
        f"#{s.channel}P{round(s.centre_pulse + s.direction * d)}S{JOG_SPEED}"
        for s, d in zip(group, deltas, strict=True)
    )
    ser.write((line + "\r").encode())
    ser.flush()


def _jog(
    ser: serial.SerialBase,
    group: list[Servo],
    deltas: list[float],
    moving: list[bool],
    prompt: str,
    ask: Callable[[str], str],
    say: Callable[[str], None],
) -> list[float]:
    """The operator's jogs of the servos marked ``moving`` (each its own way) until Enter alone."""
    deltas = list(deltas)
    _send(ser, group, deltas)
    while True:
        answer = ask(prompt)
        if answer == "":
            return deltas
        if answer not in JOGS:
            say("type +, -, ++ or -- (then Enter), or press Enter alone when it is there")
            continue
        new = [d + JOGS[answer] if m else d for d, m in zip(deltas, moving, strict=True)]
        if any(abs(d) > JOG_MAX or not _fits(s, d) for s, d in zip(group, new, strict=True)):
            say(f"that would go past the jog's end ({JOG_MAX} us from robot.toml's centre, or the servo's range)")
            continue
        deltas = new
        _send(ser, group, deltas)


def _centre(
    ser: serial.SerialBase,
    group: list[Servo],
    angle: float,
    label: str,
    ask: Callable[[str], str],
    say: Callable[[str], None],
) -> list[float]:
    """How far [us, along robot.toml's directions] from robot.toml's centres the operator jogged
    ``group`` to bring it to ``angle`` [rad] (its joint's at the servos' centre angle; the
    servos of a joint together)."""
    prompt = (
        f"Jog {label} to {angle:.4f} rad ({np.degrees(angle):.1f} deg): + or - moves it 10 us, ++ or -- 50 us; "
        "press Enter alone when it is there"
    )
    return _jog(ser, group, [0.0] * len(group), [True] * len(group), prompt, ask, say)


def _trim(
    ser: serial.SerialBase,
    group: list[Servo],
    deltas: list[float],
    ask: Callable[[str], str],
    say: Callable[[str], None],
) -> list[float]:
    """Each servo of a pair trimmed alone, until it stops straining against the other."""
    for k, s in enumerate(group):
        prompt = (
            f"Trim {s.name} alone until it stops straining against the others (listen, feel its horn): "
            "+ - ++ --; press Enter alone when it is quiet"
        )
        deltas = _jog(ser, group, deltas, [i == k for i in range(len(group))], prompt, ask, say)
    return deltas


def _direction(
    ser: serial.SerialBase,
    group: list[Servo],
    deltas: list[float],
    signs: list[int],
    label: str,
    ask: Callable[[str], str],
) -> int:
    """+1 if robot.toml's directions turn ``group``'s joint the way they say (its row's sign
    ``signs`` counted), else -1: the operator's answer, after a turn of ``TEST_STEP`` of the
    servos' angle (the other way where the joint's limits or a servo's range leave no room);
    back to the centre after."""

    def room(step: float) -> bool:
        return all(
            _fits(s, d + step) and s.angle_range[0] <= s.centre_angle + step / s.us_per_rad <= s.angle_range[1]
            for s, d in zip(group, deltas, strict=True)
        )

    step = TEST_STEP if room(TEST_STEP) else -TEST_STEP
    _send(ser, group, [d + step for d in deltas])
    way = "a positive" if step * signs[0] > 0 else "a negative"
    try:
        while True:
            answer = ask(f"{label} turned a little: the way {way} angle turns it? (y/n)").lower()
            if answer in ("y", "yes", "n", "no"):
                return 1 if answer.startswith("y") else -1
    finally:
        _send(ser, group, deltas)
