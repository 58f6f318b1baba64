"""Reading numbers from robot files: plain numbers, or angles written with ``pi``.

``robot.toml`` may write an angle as a number of radians or as a short expression in
``pi`` (``"pi"``, ``"-pi/2"``, ``"3*pi/4"``, ``"pi/2 + 0.1"`` is not accepted: keep it plain).
"""

from __future__ import annotations

import math
import re

_PI_EXPR = re.compile(
    r"^\s*(?P<sign>[-+]?)\s*(?:(?P<mul>\d+(?:\.\d*)?)\s*\*\s*)?pi\s*(?:/\s*(?P<div>\d+(?:\.\d*)?))?\s*$"
)


def parse_angle(value: object) -> float:
    """A number, or ``[sign][k*]pi[/d]``, as a float [rad]. Raises ValueError otherwise."""
    if isinstance(value, bool):
        raise ValueError(f"expected a number, got {value!r}")
    if isinstance(value, (int, float)):
        return float(value)
    if isinstance(value, str):
        m = _PI_EXPR.match(value)
        if m:
            out = math.pi * float(m.group("mul") or 1.0) / float(m.group("div") or 1.0)
            return -out if m.group("sign") == "-" else out
    raise ValueError(f"expected a number or an angle like 'pi/2', got {value!r}")
