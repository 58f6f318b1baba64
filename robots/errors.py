"""The armd error hierarchy: one root, subclasses that carry the facts.

Every error armd raises on purpose is an :class:`ArmdError`. Each subclass has a
``code`` (the protocol's error code, turned into a reply in one place at the service
edge) and keyword fields that name what was wrong (the file, the joint, the value,
the bounds), so a caller can act on it without parsing the message.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any


class ArmdError(Exception):
    """Root of every error armd raises on purpose."""

    code = "internal"

    def __init__(self, message: str, **fields: Any) -> None:
        super().__init__(message)
        self.message = message
        self.fields = fields

    def to_dict(self) -> dict[str, Any]:
        """The error as the protocol's JSON object: ``code``, ``message`` and its fields."""
        out: dict[str, Any] = {"code": self.code, "message": self.message}
        out.update({k: v for k, v in self.fields.items() if v is not None})
        return out


class BadRequest(ArmdError):
    """A caller's input is malformed: wrong type, wrong length, not finite."""

    code = "bad_request"

    def __init__(self, message: str, *, field: str | None = None, **fields: Any) -> None:
        super().__init__(message, field=field, **fields)
        self.field = field


class StartMismatch(BadRequest):
    """A trajectory whose first sample is not where the arm is (an adapter's refusal): planned
    from another state. ``state``: where the adapter says the arm is (``position``,
    ``velocity``, ``acceleration``), so that the planner can start again from there."""

    code = "start_mismatch"


class UnknownRobot(ArmdError):
    """No arm of that name in the catalogue."""

    code = "unknown_robot"

    def __init__(self, name: str, available: Iterable[str]) -> None:
        avail = sorted(available)
        super().__init__(
            f"unknown robot {name!r}; the catalogue has: {', '.join(avail) or '(none)'}",
            robot=name,
            available=avail,
        )
        self.name = name
        self.available = avail


class RobotFileError(ArmdError):
    """A robot folder is malformed or inconsistent: names the file, the field and the problem."""

    code = "robot_file"

    def __init__(self, file: str, field: str | None, problem: str) -> None:
        where = f"{file}: {field}" if field else file
        super().__init__(f"{where}: {problem}", file=file, field=field, problem=problem)
        self.file = file
        self.field = field
        self.problem = problem


class LimitError(ArmdError):
    """A value lies outside a limit: a joint, a coupled limit or an actuator range."""

    code = "limit"

    def __init__(
        self,
        message: str,
        *,
        name: str,
        value: float,
        bounds: tuple[float, float],
        kind: str,
        time: float | None = None,
    ) -> None:
        super().__init__(
            message, name=name, value=value, bounds=list(bounds), kind=kind, time=time
        )
        self.name = name
        self.value = value
        self.bounds = bounds
        self.kind = kind
        self.time = time


class JointLimitError(LimitError):
    """A joint position outside its box limits ``[lower, upper]`` [rad]."""

    def __init__(self, joint: str, value: float, bounds: tuple[float, float]) -> None:
        super().__init__(
            f"joint {joint!r} at {value:.6g} rad is outside its limits "
            f"[{bounds[0]:.6g}, {bounds[1]:.6g}]",
            name=joint,
            value=value,
            bounds=bounds,
            kind="position",
        )


class CoupledLimitError(LimitError):
    """A linear combination of joints outside its coupled limit ``lower <= c.q <= upper``."""

    def __init__(self, limit: str, value: float, bounds: tuple[float, float]) -> None:
        super().__init__(
            f"coupled limit {limit!r} at {value:.6g} is outside [{bounds[0]:.6g}, {bounds[1]:.6g}]",
            name=limit,
            value=value,
            bounds=bounds,
            kind="coupled",
        )


class ActuatorRangeError(LimitError):
    """An actuator command (servo pulse [us], stepper angle) outside the actuator's range."""

    def __init__(self, actuator: str, value: float, bounds: tuple[float, float], unit: str) -> None:
        super().__init__(
            f"actuator {actuator!r} would be commanded to {value:.6g} {unit}, outside its range "
            f"[{bounds[0]:.6g}, {bounds[1]:.6g}] {unit}",
            name=actuator,
            value=value,
            bounds=bounds,
            kind="actuator",
        )
        self.unit = unit


class ActuatorMapError(ArmdError):
    """Actuator readings that no joint vector explains (a mirrored pair that disagrees)."""

    code = "bad_request"


class PositionUnknown(ArmdError):
    """The controller does not know where the arm is (GRBL after a reset, before homing or an
    operator's confirmation): nothing may move it until it does."""

    code = "position_unknown"
