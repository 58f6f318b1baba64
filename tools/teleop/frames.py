"""Where an arm faces: the direction its tool reaches at its neutral pose, about the vertical.

Vendors put an arm's forward on different axes of its base frame (the insomniac's is +x, the
SO-101's -y): a jog's "forward" and a leader's tool point are turned by these headings, so
that forward is each arm's own. Read from the arm's model, never written down.
"""

from __future__ import annotations

import math

import numpy as np

from armd.robots import Robot
from armd.robots.types import FloatArray


def heading(robot: Robot) -> float:
    """The direction [rad] about the base's z axis (0: +x) the arm faces at its neutral pose:
    its yaw joint's plane where the closed form knows it, else its tool point's bearing."""
    if robot.geometry is not None:
        return robot.geometry.heading(robot.neutral)
    p = robot.fk(robot.neutral)
    return math.atan2(float(p[1]), float(p[0]))


def turned(v: FloatArray, angle: float) -> FloatArray:
    """``v`` [x, y, z] turned by ``angle`` [rad] about the z axis."""
    c, s = math.cos(angle), math.sin(angle)
    return np.array([c * v[0] - s * v[1], s * v[0] + c * v[1], v[2]])
