"""Planning errors: a motion armd will not plan, with the reason and where."""

from __future__ import annotations

from typing import Any

from armd.robots import ArmdError


class PlanRejected(ArmdError):
    """The motion cannot be planned as asked (a line that leaves the reachable space or needs
    a branch flip, a goal out of reach). Nothing is planned; ``reason`` says why."""

    code = "unreachable"

    def __init__(self, message: str, **fields: Any) -> None:
        super().__init__(message, **fields)


class TrajectoryTooLong(ArmdError):
    """The trajectory would have more samples than the caller allows (``size``, ``limit``):
    nothing is sampled. A lower ``rate_hz`` or a higher ``speed`` makes fewer."""

    code = "too_large"

    def __init__(self, samples: int, limit: int, duration: float, rate_hz: float) -> None:
        super().__init__(f"the trajectory would have {samples} samples ({duration:.1f} s at {rate_hz:g} Hz); "
                         f"this service allows at most {limit}: raise speed or lower rate_hz",
                         size=samples, limit=limit, field="speed")
