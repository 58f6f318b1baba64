"""IK answers: :class:`IKResult` and the :class:`Branch` es it chose among.

Named tuples: immutable values, and cheap to make (an answer is made per request).
"""

from __future__ import annotations

from typing import Any, NamedTuple

from armd.robots.types import FloatArray

OK = "ok"
APPROXIMATE = "approximate"
UNREACHABLE = "unreachable"
COLLISION = "collision"


class Branch(NamedTuple):
    """One valid IK solution: its name (``front/elbow_up`` ...), ``q`` [rad] and its errors."""

    name: str
    q: FloatArray
    position_error: float

    def to_dict(self) -> dict[str, Any]:
        return {"name": self.name, "q": self.q.tolist(), "position_error": self.position_error}


class IKResult(NamedTuple):
    """The answer to one IK request.

    Attributes:
        status: ``"ok"`` (on the target within tolerance, with the asked pitch),
            ``"approximate"`` (on the target, but the asked pitch or an exact position was
            not possible: see ``reason``), ``"unreachable"`` (the closest collision-free
            configuration found within limits; ``position_error`` says how far it stays),
            ``"collision"`` (every configuration that reaches the target collides with the arm
            itself, the ground or an obstacle, or the target is below the ground: ``contact``
            names the pair, ``q`` is the nearest such configuration; or no collision-free
            configuration was found near an unreachable target).
        q: the joint vector [rad], always within every joint limit; collision-free unless the
            status is ``"collision"``.
        position_error: distance [m] from the tool point at ``q`` to the target.
        reached: the tool point [m] at ``q``, in ``base``.
        target: the target point [m], in ``base``.
        pitch: the tool pitch [rad] at ``q``.
        pitch_error: reached minus asked pitch [rad], wrapped; None when the pitch was free.
        branch: the name of the chosen branch (``front``/``flipped`` yaw, elbow ``up``/``down``),
            or ``"numerical"`` when the QP produced it.
        branches: every other valid branch, nearest to the seed first (collision-free ones
            only, unless the status is ``"collision"``).
        iterations: QP refinement iterations used (0: the closed form was exact).
        reason: why the status is not ``ok``; None when it is.
        roll: the tool's roll [rad] about its axis at ``q`` (:meth:`Robot.tool_roll`); None for
            an arm without a wrist roll.
        contact: the pair in collision (link names, ``"ground"`` or an obstacle's name) when
            the status is ``"collision"``; else None.
    """

    status: str
    q: FloatArray
    position_error: float
    reached: FloatArray
    target: FloatArray
    pitch: float
    pitch_error: float | None
    branch: str
    branches: tuple[Branch, ...] = ()
    iterations: int = 0
    reason: str | None = None
    roll: float | None = None
    contact: tuple[str, str] | None = None

    @property
    def ok(self) -> bool:
        return self.status == OK

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready form (the protocol's IK reply)."""
        return {
            "status": self.status,
            "q": self.q.tolist(),
            "position_error": self.position_error,
            "reached": self.reached.tolist(),
            "target": self.target.tolist(),
            "pitch": self.pitch,
            "pitch_error": self.pitch_error,
            "branch": self.branch,
            "branches": [b.to_dict() for b in self.branches],
            "iterations": self.iterations,
            "reason": self.reason,
            "roll": self.roll,
            "contact": None if self.contact is None else list(self.contact),
        }
