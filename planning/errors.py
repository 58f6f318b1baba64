"""Planning errors: a motion armd will not plan, with the reason and where."""

from __future__ import annotations

from typing import Any

from robots import ArmdError


class PlanRejected(ArmdError):
    """The motion cannot be planned as asked (a line that leaves the reachable space or needs
    a branch flip, a goal out of reach). Nothing is planned; ``reason`` says why."""

    code = "unreachable"

    def __init__(self, message: str, **fields: Any) -> None:
        super().__init__(message, **fields)
