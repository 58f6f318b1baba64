"""A jog: what the keyboard and the gamepad both put, the tool point moving at a velocity in
the arm's own directions (forward, left, up: :func:`.frames.heading`), its pitch and roll
turning at a rate, and the gripper's opening.

The speeds are steps the operator moves through (:meth:`Jog.faster`, :meth:`Jog.slower`); each
axis of a jog is a fraction in [-1, 1] of its step's speed (a key held: 1; a stick: how far it
is pushed). The service keeps the tool within every limit, clear of the floor, and says what it
does not follow; an arm without a wrist pitch, a wrist roll or a gripper is put none.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from armd.robots import Robot

from .frames import heading, turned
from .stream import Put

LINEAR = (0.01, 0.02, 0.05, 0.1, 0.2)  # [m/s] the tool point's speeds, step by step
ANGULAR = (0.1, 0.2, 0.5, 1.0, 2.0)  # [rad/s] its pitch's and roll's, with them
START = 2  # the step a jog starts at (0.05 m/s, 0.5 rad/s)


@dataclass(frozen=True)
class Axes:
    """A jog's axes, each in [-1, 1]: ``forward``, ``left``, ``up`` (the tool point), ``pitch``
    (the tool's tip up), ``roll`` (about the tool's axis, positive as the arm's roll)."""

    forward: float = 0.0
    left: float = 0.0
    up: float = 0.0
    pitch: float = 0.0
    roll: float = 0.0

    @property
    def still(self) -> bool:
        return not any((self.forward, self.left, self.up, self.pitch, self.roll))


class Jog:
    """The jog of ``robot`` (the follower's model: its forward, whether it has a wrist pitch,
    a wrist roll, a gripper)."""

    def __init__(self, robot: Robot) -> None:
        self.heading = heading(robot)
        self.has_pitch = robot.chooses_pitch
        self.has_roll = robot.roll_joint is not None
        self.has_gripper = robot.gripper is not None
        self.step = START
        self.gripper: float | None = None  # the opening put (None: not set yet: none is put)

    @property
    def linear(self) -> float:
        """[m/s] the tool point's speed now."""
        return LINEAR[self.step]

    @property
    def angular(self) -> float:
        """[rad/s] the pitch's and roll's rate now."""
        return ANGULAR[self.step]

    def faster(self) -> None:
        self.step = min(self.step + 1, len(LINEAR) - 1)

    def slower(self) -> None:
        self.step = max(self.step - 1, 0)

    def grip(self, opening: float) -> None:
        """The gripper to ``opening`` (0 closed, 1 open) with the next put (if the arm has one)."""
        if self.has_gripper:
            self.gripper = min(max(float(opening), 0.0), 1.0)

    def put(self, axes: Axes) -> Put:
        """The put of a jog along ``axes`` at the speed now."""
        v = turned(np.array([axes.forward, axes.left, axes.up]) * self.linear, self.heading)
        return Put(
            velocity=(float(v[0]), float(v[1]), float(v[2])),
            pitch_rate=axes.pitch * self.angular if self.has_pitch else None,
            roll_rate=axes.roll * self.angular if self.has_roll else None,
            gripper=self.gripper,
        )
