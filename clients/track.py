"""A tracking stream from Python: :meth:`ArmClient.track` gives a :class:`Track`, whose
:meth:`Track.send` puts the latest target on ``<prefix>/<robot>/track`` with the session and a
rising ``seq``; the arm follows it within every limit and brakes to rest when the puts stop for
the deadman (docs/protocol.md, "Tracking"; docs/teleop.md).

>>> with ArmClient() as armd, armd.track("so101") as t:      # doctest: +SKIP
...     for k in range(300):                                 # 3 s at 100 Hz
...         t.send(target=[0.2, 0.05 * math.sin(k / 50), 0.1])
...         time.sleep(0.01)
...     t.events                                             # what the stream did not follow, and why
"""

from __future__ import annotations

import contextlib
import threading
import time
import uuid
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import orjson
import zenoh

from armd.service.protocol import encode

JSON = zenoh.Encoding.APPLICATION_JSON
KEPT = 1000  # events kept per stream (the oldest go first)


@dataclass(frozen=True)
class TrackEvent:
    """What the service said of the stream: ``status`` (``started``, ``unreachable``,
    ``collision``, ``bad_request``, ``busy``, ``deadman``, ``ended``, ``rejected``, ``waiting``,
    ``error``), a short ``reason`` and a ``message`` for people."""

    status: str
    reason: str
    message: str
    session: str | None
    repeated: int = 0  # the same status and reason not said this many times since it last was
    raw: dict[str, Any] = field(default_factory=dict, repr=False, compare=False)


class Track:
    """A session of the arm's tracking stream. Use as a context manager (or :meth:`close`)."""

    def __init__(
        self, session: zenoh.Session, prefix: str, robot: str, *, deadman: float | None = None, name: str | None = None
    ) -> None:
        self.robot = robot
        self.session_id = name or uuid.uuid4().hex[:16]
        self.deadman = deadman
        self.seq = 0
        self._events: list[TrackEvent] = []
        self._lock = threading.Lock()
        self._changed = threading.Condition(self._lock)
        base = f"{prefix}/{robot}"
        # the latest put matters, not every one: dropped under congestion, sent at once (no batching)
        self._pub = session.declare_publisher(
            f"{base}/track",
            encoding=JSON,
            congestion_control=zenoh.CongestionControl.DROP,
            priority=zenoh.Priority.INTERACTIVE_HIGH,
            express=True,
        )
        self._sub = session.declare_subscriber(f"{base}/events", self._on_event)

    def __enter__(self) -> Track:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def send(
        self,
        *,
        joints: Sequence[float] | None = None,
        target: Sequence[float] | None = None,
        velocity: Sequence[float] | None = None,
        approach: object = None,
        roll: float | None = None,
        pitch_rate: float | None = None,
        roll_rate: float | None = None,
        speed: float | None = None,
        gripper: float | None = None,
    ) -> int:
        """Put the stream's latest target: exactly one of ``joints`` [rad], ``target`` [x, y, z]
        [m] (``approach``, ``roll`` as :meth:`ArmClient.ik`) or ``velocity`` [m/s] of the tool
        point (``pitch_rate``, ``roll_rate`` [rad/s]); ``speed``: a fraction of the limits;
        ``gripper``: 0 (closed) to 1. Returns the put's ``seq``."""
        msg: dict[str, Any] = {"session": self.session_id, "seq": self.seq, "time": time.monotonic()}
        if self.seq == 0 and self.deadman is not None:
            msg["deadman"] = self.deadman
        for key, value in (
            ("joints", joints),
            ("target", target),
            ("velocity", velocity),
            ("approach", approach),
            ("roll", roll),
            ("pitch_rate", pitch_rate),
            ("roll_rate", roll_rate),
            ("speed", speed),
            ("gripper", gripper),
        ):
            if value is None:
                continue
            msg[key] = _plain(value)
        self._pub.put(encode(msg))
        self.seq += 1
        return self.seq - 1

    @property
    def events(self) -> list[TrackEvent]:
        """This session's events so far (and those naming no session: a put that could not be read)."""
        with self._lock:
            return list(self._events)

    def wait_for(self, status: str, timeout: float = 5.0) -> TrackEvent | None:
        """The first event of ``status`` (one already come, or the next within ``timeout`` [s])."""
        with self._changed:
            found = self._changed.wait_for(
                lambda: next((e for e in self._events if e.status == status), None), timeout=timeout
            )
        return found or None

    def close(self) -> None:
        """Stop putting (the arm brakes to rest at the deadman); the subscription ends."""
        for entity in (self._sub, self._pub):
            with contextlib.suppress(zenoh.ZError):  # (the session closed first)
                entity.undeclare()

    def _on_event(self, sample: zenoh.Sample) -> None:
        try:
            msg = orjson.loads(sample.payload.to_bytes())
        except orjson.JSONDecodeError:
            return
        if not isinstance(msg, dict) or msg.get("event") != "track":
            return
        session = msg.get("session")
        if session not in (None, self.session_id):
            return
        event = TrackEvent(
            str(msg.get("status")),
            str(msg.get("reason", "")),
            str(msg.get("message", "")),
            session if isinstance(session, str) else None,
            int(msg.get("repeated", 0)) if isinstance(msg.get("repeated"), int) else 0,
            msg,
        )
        with self._changed:
            self._events.append(event)
            del self._events[:-KEPT]
            self._changed.notify_all()


def _plain(value: object) -> object:
    """A value as JSON takes it: a NumPy array or a sequence as a list of floats."""
    tolist = getattr(value, "tolist", None)
    if tolist is not None:
        return tolist()
    if isinstance(value, Sequence) and not isinstance(value, str):
        return [float(x) for x in value]
    return value


__all__ = ["Track", "TrackEvent"]
