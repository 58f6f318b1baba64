"""What the fault benches watch of an arm: its events and its state messages, each with when it
arrived [s, monotonic], from a client's session."""

from __future__ import annotations

import json
import threading
import time
from typing import Any

import zenoh


class ArmWatch:
    """``<prefix>/<robot>/events`` and ``.../state`` as they arrive; :meth:`close` when done."""

    def __init__(self, session: zenoh.Session, robot: str, prefix: str = "armd") -> None:
        self._lock = threading.Lock()
        self._events: list[tuple[float, dict[str, Any]]] = []
        self._states: list[float] = []
        self._subs = [
            session.declare_subscriber(f"{prefix}/{robot}/events", self._on_event),
            session.declare_subscriber(f"{prefix}/{robot}/state", self._on_state),
        ]

    def _on_event(self, sample: zenoh.Sample) -> None:
        with self._lock:
            self._events.append((time.monotonic(), json.loads(sample.payload.to_bytes())))

    def _on_state(self, _: zenoh.Sample) -> None:
        with self._lock:
            self._states.append(time.monotonic())

    def started(self, ident: str) -> bool:
        with self._lock:
            return any(e.get("event") == "started" and e.get("id") == ident for _, e in self._events)

    def first(self, since: float, kinds: tuple[str, ...]) -> float | None:
        """When the first event of ``kinds`` came at or after ``since`` [s], or None."""
        with self._lock:
            return next((t for t, e in self._events if t >= since and e.get("event") in kinds), None)

    def state_rate(self, since: float, until: float) -> float:
        """State messages a second between ``since`` and ``until`` [s]."""
        with self._lock:
            return sum(since <= t <= until for t in self._states) / (until - since)

    def close(self) -> None:
        for sub in self._subs:
            sub.undeclare()
