"""Every error armd raises on purpose, in one tree.

Each class has a ``code``: the protocol's error code (docs/protocol.md), which the service
puts in its error reply, and keyword fields that name what was wrong (the file, the joint,
the value, the bounds), so that a caller can act on it without parsing the message. A code
belongs to one class; its subclasses say more but keep it (``JointLimitError`` is a
``limit``). Over the wire, the client raises a :class:`ServiceError` that is also of its
code's class: ``except BadRequest`` catches a ``bad_request`` reply as it catches the same
error in-process.

::

    ArmdError                    internal          (the root; also every bug)
    |-- BadRequest               bad_request       (a ValueError: the caller's input is wrong)
    |   |-- StartMismatch        start_mismatch    (an adapter's: the trajectory does not start where the arm is)
    |   |-- ActuatorMapError     bad_request       (actuator readings no joint vector explains)
    |   `-- TooLarge             too_large         (over a limit of the service)
    |       |-- PayloadTooLarge, BatchTooLarge, TrajectoryTooLong
    |-- UnknownRobot             unknown_robot     (a LookupError)
    |-- UnknownVerb              unknown_verb      (a LookupError)
    |-- RobotFileError           robot_file        (a robot folder that does not load)
    |-- LimitError               limit             (a value outside a limit)
    |   |-- JointLimitError, CoupledLimitError, ActuatorRangeError
    |-- PlanRejected             unreachable       (a motion that cannot be planned as asked)
    |-- CollisionError           collision         (a motion or goal that puts two things in contact)
    |-- PositionUnknown          position_unknown  (the controller lost the arm's position)
    |-- NoAdapter                no_adapter        (nothing would execute a move)
    |-- Rejected                 rejected          (every live adapter refused the trajectory)
    |-- DeadlineExceeded         deadline          (the request's deadline passed)
    |-- ControllerFault          fault             (an adapter's controller stopped answering, or alarmed)
    |-- ViewerError              viewer            (the 3-D viewer cannot start or lost its server)
    |-- NoReply                  timeout           (a TimeoutError: no service answered)
    |-- Internal, PlannerError   internal          (bugs and numerical corner cases)
    `-- ServiceError             (the reply's)     (the service answered with an error)
"""

from __future__ import annotations

import keyword
from collections.abc import Iterable, Mapping
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


# -- the caller's input -------------------------------------------------------------------------


class BadRequest(ArmdError, ValueError):
    """A caller's input is malformed: wrong type, wrong length, not finite, out of its range."""

    code = "bad_request"

    def __init__(self, message: str, *, field: str | None = None, **fields: Any) -> None:
        super().__init__(message, field=field, **fields)
        self.field = field


class StartMismatch(BadRequest):
    """A trajectory whose first sample is not where the arm is (an adapter's refusal): planned
    from another state. ``state``: where the adapter says the arm is (``position``,
    ``velocity``, ``acceleration``), so that the planner can start again from there."""

    code = "start_mismatch"


class ActuatorMapError(BadRequest):
    """Actuator readings that no joint vector explains (a mirrored pair that disagrees)."""


class TooLarge(BadRequest):
    """Over a limit of the service (``size``, ``limit``)."""

    code = "too_large"


class PayloadTooLarge(TooLarge):
    def __init__(self, size: int, limit: int) -> None:
        super().__init__(f"the payload is {size} bytes; this service accepts at most {limit}", size=size, limit=limit)


class BatchTooLarge(TooLarge):
    def __init__(self, size: int, limit: int) -> None:
        super().__init__(
            f"{size} targets; this service accepts at most {limit} per request", field="targets", size=size, limit=limit
        )


class TrajectoryTooLong(TooLarge):
    """The trajectory would have more samples than the caller allows (``size``, ``limit``):
    nothing is sampled. A lower ``rate_hz`` or a higher ``speed`` makes fewer."""

    def __init__(self, samples: int, limit: int, duration: float, rate_hz: float) -> None:
        super().__init__(
            f"the trajectory would have {samples} samples ({duration:.1f} s at {rate_hz:g} Hz); "
            f"this service allows at most {limit}: raise speed or lower rate_hz",
            size=samples,
            limit=limit,
            field="speed",
        )


class UnknownRobot(ArmdError, LookupError):
    """No arm of that name in the catalogue."""

    code = "unknown_robot"

    def __init__(self, name: str, available: Iterable[str]) -> None:
        avail = sorted(available)
        super().__init__(
            f"unknown robot {name!r}; the catalogue has: {', '.join(avail) or '(none)'}", robot=name, available=avail
        )
        self.name = name
        self.available = avail


class UnknownVerb(ArmdError, LookupError):
    code = "unknown_verb"

    def __init__(self, verb: str, verbs: Iterable[str]) -> None:
        known = list(verbs)
        super().__init__(f"unknown verb {verb!r}; verbs: {', '.join(known)}", verb=verb, verbs=known)


# -- robots and their limits --------------------------------------------------------------------


class FileProblem(Exception):
    """(Within robots.checks, before it becomes a :class:`RobotFileError` naming the arm's file.)
    What is wrong with one file an arm names. ``forbidden``: outside the arm's folder or not a
    regular file, never opened whatever robot.toml says; else it cannot be used (missing, too
    large, not a mesh armd reads)."""

    def __init__(self, problem: str, forbidden: bool) -> None:
        super().__init__(problem)
        self.problem = problem
        self.forbidden = forbidden


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
        super().__init__(message, name=name, value=value, bounds=list(bounds), kind=kind, time=time)
        self.name = name
        self.value = value
        self.bounds = bounds
        self.kind = kind
        self.time = time


class JointLimitError(LimitError):
    """A joint position outside its box limits ``[lower, upper]`` [rad]."""

    def __init__(self, joint: str, value: float, bounds: tuple[float, float]) -> None:
        super().__init__(
            f"joint {joint!r} at {value:.6g} rad is outside its limits [{bounds[0]:.6g}, {bounds[1]:.6g}]",
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


# -- planning and moving ------------------------------------------------------------------------


class PlanRejected(ArmdError):
    """The motion cannot be planned as asked (a line that leaves the reachable space or needs
    a branch flip, a goal out of reach). Nothing is planned; ``reason`` says why."""

    code = "unreachable"


class CollisionError(ArmdError):
    """The motion would put two things in contact (``pair``: link names, an obstacle's name or
    ``ground``) at ``time`` [s] from its start (absent: the goal itself collides), or nothing
    clear reaches the goal. Nothing is planned, nothing moves."""

    code = "collision"

    def __init__(
        self, message: str, *, pair: tuple[str, str] | list[str], time: float | None = None, **fields: Any
    ) -> None:
        super().__init__(message, pair=list(pair), time=time, **fields)
        self.pair = tuple(pair)
        self.time = time


class PositionUnknown(ArmdError):
    """The controller does not know where the arm is (GRBL after a reset, before homing or an
    operator's confirmation): nothing may move it until it does."""

    code = "position_unknown"


class NoAdapter(ArmdError):
    """No live adapter of the arm would execute the command (none alive, or none accepted it)."""

    code = "no_adapter"


class Busy(ArmdError):
    """The arm is doing what this would need it for (a pick or place under way)."""

    code = "busy"


class NotReady(ArmdError):
    """What was asked needs readings that have not come yet (a scanner's sweeps, after a start)."""

    code = "not_ready"


class Rejected(ArmdError):
    """Every live adapter of the arm refused the trajectory (``reason``: the last one's word,
    ``error``: its error object)."""

    code = "rejected"


class DeadlineExceeded(ArmdError):
    """The request's deadline passed: nothing was published, no result is given.

    Fields: ``deadline`` (the budget [s]), ``elapsed`` (since arrival [s]) and ``stage``:
    ``"queued"`` (it waited too long to start; no work was done) or ``"working"`` (it was
    abandoned part way).
    """

    code = "deadline"

    def __init__(self, budget: float, elapsed: float, stage: str) -> None:
        what = "waited in the queue" if stage == "queued" else "was being worked on"
        super().__init__(
            f"the request {what} past its deadline of {budget:g} s ({elapsed:.3f} s since it arrived); "
            "nothing was done",
            deadline=budget,
            elapsed=round(elapsed, 6),
            stage=stage,
        )


class ControllerFault(ArmdError):
    """The controller stopped answering, or reported an error or alarm."""

    code = "fault"


class ViewerError(ArmdError):
    """The viewer cannot start (its port is taken, meshcat is missing) or lost its server."""

    code = "viewer"


# -- bugs and numerical corner cases (all ``internal``) ------------------------------------------


class Internal(ArmdError):
    """A bug in armd, as the service reports it (logged with its traceback where it happened)."""


class PlannerError(ArmdError):
    """Ruckig could not compute a segment (reported as ``internal``: a bug or a corner case)."""


# -- over the wire -----------------------------------------------------------------------------


class NoReply(ArmdError, TimeoutError):
    """No service answered within the timeout (none running, or the network is down)."""

    code = "timeout"


class ServiceError(ArmdError):
    """The service answered with an error: ``code`` is the protocol's (``bad_request``,
    ``unknown_robot``, ``unreachable``, ``limit``, ``no_adapter``, ``too_large``, ``deadline``,
    ``internal`` ...), the reply's other fields are attributes and :attr:`fields`. Made by
    :func:`from_reply`, an instance is also of its code's class (:data:`BY_CODE`)."""

    def __init__(self, reply: Mapping[str, Any]) -> None:
        fields = {k: v for k, v in reply.items() if k not in ("code", "message")}
        ArmdError.__init__(self, str(reply.get("message", "error")), **fields)
        self.code = str(reply.get("code", "internal"))
        self.field = fields.get("field")
        for k, v in fields.items():
            if k.isidentifier() and not keyword.iskeyword(k) and k not in ("args", "fields", "message", "code"):
                setattr(self, k, v)


def _codes() -> dict[str, type[ArmdError]]:
    """Each code and the class it belongs to: the topmost class that declares it."""
    out: dict[str, type[ArmdError]] = {}
    pending: list[type[ArmdError]] = [ArmdError]
    while pending:
        cls = pending.pop(0)
        if "code" in vars(cls) and cls is not ServiceError:
            out.setdefault(cls.code, cls)
        pending += cls.__subclasses__()
    return out


BY_CODE: dict[str, type[ArmdError]] = _codes()


_REMOTE: dict[str, type[ServiceError]] = {}  # code: its ServiceError class


def _remote(code: str, owner: type[ArmdError]) -> type[ServiceError]:
    cls = _REMOTE.get(code)
    if cls is None:  # (two threads at once: either class does)
        cls = _REMOTE.setdefault(
            code, type(owner.__name__, (ServiceError, owner), {"__module__": __name__, "__doc__": owner.__doc__})
        )
    return cls


def from_reply(reply: Mapping[str, Any]) -> ServiceError:
    """The :class:`ServiceError` of an error reply, also of its code's class (an unknown code,
    or ``internal``: a plain :class:`ServiceError`)."""
    code = str(reply.get("code", "internal"))
    owner = BY_CODE.get(code)
    cls = ServiceError if owner is None or owner is ArmdError else _remote(code, owner)
    return cls(reply)
