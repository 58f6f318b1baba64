"""A request's deadline: the time the service may spend on it, counted from its arrival.

The service stamps every query when Zenoh hands it over (:func:`time.monotonic`), before it
waits in the queue. The budget is the operator's (``armd serve --deadline``), or shorter if
the request asks for less (its optional ``deadline`` field). Work checks the deadline where it
can stop cleanly (before it starts, between planning stages and IK batch chunks, and just
before anything is published), so a request that overruns is answered ``deadline`` and has
changed nothing.
"""

from __future__ import annotations

import time

from armd.errors import DeadlineExceeded


class Deadline:
    """``arrived`` + ``budget`` [s], on the monotonic clock."""

    __slots__ = ("arrived", "budget")  # one per request

    def __init__(self, arrived: float, budget: float) -> None:
        self.arrived = arrived
        self.budget = budget

    @property
    def at(self) -> float:
        return self.arrived + self.budget

    def shorten(self, budget: float) -> None:
        """A request asked for less time than the operator allows (never for more)."""
        self.budget = min(self.budget, budget)

    def elapsed(self) -> float:
        return time.monotonic() - self.arrived

    def passed(self) -> bool:
        return time.monotonic() > self.at

    def check(self, stage: str = "working") -> None:
        """Raise :class:`DeadlineExceeded` if the deadline has passed."""
        now = time.monotonic()
        if now > self.at:
            raise DeadlineExceeded(self.budget, now - self.arrived, stage)
