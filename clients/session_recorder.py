"""A teleoperated session heard over Zenoh (``armd record --teleop``): the follower's state as
its adapter publishes it (``<prefix>/<robot>/state``), the puts on ``<prefix>/<robot>/track``
(the commands) as they were sent, and the gripper openings the adapter says it commanded
(its ``gripper`` events), all on one clock.

>>> with ArmClient() as armd, SessionRecorder(armd.session, "armd", "so101", nq=5) as rec:  # doctest: +SKIP
...     time.sleep(10.0)                          # (someone drives the arm meanwhile)
...     heard = rec.heard()

The clock: each reading and put is stamped when it arrived here, and also carries its sender's
own time (an adapter's state and events its wall clock, a put its client's ``time``). A
sender's time, moved onto this clock by the least delay seen from that sender (an adapter, a
session), gives the spacing the sender meant, free of the network's and this machine's delays
(a burst of states that came late together is not a jump of the arm). Without one, or with
times that stray from this clock by more than ``CLOCK_SLACK``, the arrival.

Only one adapter's states are kept (the first heard: the follower); those of another are
counted. What is not a state or a put (not JSON, the wrong shape, too large) is counted, not kept.
"""

from __future__ import annotations

import contextlib
import math
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import orjson
import zenoh

from armd.robots.types import FloatArray

PUT_BYTES = 4096  # a put, at most: the service reads none larger (service.track_message.TRACK_BYTES)
STATE_BYTES = 65536  # a state or an event, at most (the service's own limit)
CLOCK_SLACK = 1.0  # [s] a sender's times that stray further from this clock are not its clock's


@dataclass(frozen=True)
class HeardSession:
    """What was heard, on one clock from the first thing heard [s]: the follower's readings
    (``times``, ``position`` [rad]; ``gripper``: the opening it last commanded at each, the
    first one standing for those before it; None: it commanded none), and the ``commands``:
    each put as sent, with its time."""

    times: FloatArray
    position: FloatArray
    gripper: FloatArray | None
    commands: list[tuple[float, dict[str, Any]]]
    adapter: str | None  # the follower's adapter (None: none heard)
    source: str | None  # "measured" or "commanded": what its state is, as it says
    other_states: int = 0  # states of another adapter, not kept
    unread: int = 0  # payloads that were not a state or a put (not JSON, the wrong shape, too large)

    @property
    def sessions(self) -> int:
        """How many sessions the commands name."""
        return len({p.get("session") for _, p in self.commands if isinstance(p.get("session"), str)})

    @property
    def skipped(self) -> int:
        """The numbers each session's ``seq`` skips: puts not heard (a stream's puts may be dropped
        on the way, the latest being what matters), or a client that numbers so."""
        seqs: dict[str, list[int]] = {}
        for _, p in self.commands:
            if isinstance(p.get("session"), str) and type(p.get("seq")) is int:
                seqs.setdefault(p["session"], []).append(p["seq"])
        return sum(max(s) - min(s) + 1 - len(set(s)) for s in seqs.values())


class SessionRecorder:
    """Hears ``robot``'s state, tracking stream and gripper events on ``session`` from when it is
    made until :meth:`close`; :meth:`heard` says what so far. ``nq``: the arm's joints (a state of
    another length is not the arm's). Use as a context manager."""

    def __init__(self, session: zenoh.Session, prefix: str, robot: str, *, nq: int) -> None:
        self.nq = nq
        self._lock = threading.Lock()
        self._states: list[tuple[float, str, int, float | None, tuple[float, ...], str | None]] = []
        self._puts: list[tuple[float, dict[str, Any]]] = []
        self._grips: list[tuple[float, str, float | None, float]] = []
        self._unread = 0
        base = f"{prefix.rstrip('/')}/{robot}"
        self._subs = [
            session.declare_subscriber(f"{base}/state", self._heard(self._on_state, STATE_BYTES)),
            session.declare_subscriber(f"{base}/track", self._heard(self._on_put, PUT_BYTES)),
            session.declare_subscriber(f"{base}/events", self._heard(self._on_event, STATE_BYTES)),
        ]

    def __enter__(self) -> SessionRecorder:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """Stop hearing (what was heard stays: :meth:`heard`)."""
        for sub in self._subs:
            with contextlib.suppress(zenoh.ZError):  # (the session closed first)
                sub.undeclare()
        self._subs = []

    @property
    def counts(self) -> tuple[int, int]:
        """States and puts heard so far (every adapter's states)."""
        with self._lock:
            return len(self._states), len(self._puts)

    # -- on Zenoh's threads: stamped, read, kept ---------------------------------------------------

    def _heard(self, take: Callable[[float, dict[str, Any]], bool], most: int) -> Callable[[zenoh.Sample], None]:
        def on(sample: zenoh.Sample) -> None:
            now = time.monotonic()
            raw = sample.payload.to_bytes()
            try:
                msg = orjson.loads(raw) if len(raw) <= most else None
            except orjson.JSONDecodeError:
                msg = None
            if not isinstance(msg, dict) or not take(now, msg):
                with self._lock:
                    self._unread += 1

        return on

    def _on_state(self, now: float, msg: dict[str, Any]) -> bool:
        q, adapter, seq, source = (
            _vector(msg.get("position"), self.nq),
            msg.get("adapter"),
            msg.get("seq"),
            msg.get("source"),
        )
        if q is None or not isinstance(adapter, str) or type(seq) is not int:
            return False
        entry = (now, adapter, seq, _time(msg.get("time")), q, source if isinstance(source, str) else None)
        with self._lock:
            self._states.append(entry)
        return True

    def _on_put(self, now: float, msg: dict[str, Any]) -> bool:
        with self._lock:
            self._puts.append((now, msg))
        return True

    def _on_event(self, now: float, msg: dict[str, Any]) -> bool:
        opening, adapter = _time(msg.get("opening")), msg.get("adapter")
        if msg.get("event") == "gripper" and isinstance(adapter, str) and opening is not None and 0.0 <= opening <= 1.0:
            with self._lock:
                self._grips.append((now, adapter, _time(msg.get("time")), opening))
        return True  # (the other events are not this recorder's: not counted as unread)

    # -- what was heard ----------------------------------------------------------------------------

    def heard(self) -> HeardSession:
        """Everything heard so far, on one clock (the module's docstring), ``t = 0`` the first."""
        with self._lock:
            states, puts, grips, unread = list(self._states), list(self._puts), list(self._grips), self._unread
        adapter = min(states)[1] if states else None
        mine = sorted((s for s in states if s[1] == adapter), key=lambda s: s[2])  # (by its seq)
        other = len(states) - len(mine)
        offset = _offset([(s[0], s[3]) for s in mine] + [(g[0], g[2]) for g in grips if g[1] == adapter])
        times: list[float] = []
        position: list[tuple[float, ...]] = []
        last_seq = None
        for arrived, _, seq, sent, q, _ in mine:
            t = arrived if sent is None or offset is None else sent + offset
            if seq == last_seq or (times and t <= times[-1]):  # (a repeat, or a clock that went back)
                continue
            times.append(t)
            position.append(q)
            last_seq = seq
        grip = sorted(
            (arrived if sent is None or offset is None else sent + offset, g)
            for arrived, who, sent, g in grips
            if who == adapter
        )
        commands = _on_one_clock(puts)
        zero = min([*times[:1], *(t for t, _ in commands[:1]), *(t for t, _ in grip[:1])], default=0.0)
        t_states = np.array(times, dtype=float) - zero
        opening = None
        if grip:
            at = np.array([t for t, _ in grip]) - zero
            k = np.searchsorted(at, t_states, side="right") - 1
            opening = np.array([g for _, g in grip], dtype=float)[np.maximum(k, 0)]
        return HeardSession(
            times=t_states,
            position=np.array(position, dtype=float).reshape(-1, self.nq),
            gripper=opening,
            commands=[(t - zero, p) for t, p in commands],
            adapter=adapter,
            source=mine[-1][5] if mine else None,
            other_states=other,
            unread=unread,
        )


def _on_one_clock(puts: list[tuple[float, dict[str, Any]]]) -> list[tuple[float, dict[str, Any]]]:
    """The puts in time order, each at its client's ``time`` moved onto this clock by the least
    delay seen from its session (else when it came)."""
    by_session: dict[object, list[tuple[float, float | None]]] = {}
    for arrived, p in puts:
        session = p.get("session")
        by_session.setdefault(session if isinstance(session, str) else None, []).append((arrived, _time(p.get("time"))))
    offsets = {s: _offset(v) for s, v in by_session.items()}
    out = []
    for arrived, p in puts:
        session = p.get("session")
        offset = offsets[session if isinstance(session, str) else None]
        sent = _time(p.get("time"))
        out.append((arrived if sent is None or offset is None else sent + offset, p))
    out.sort(key=lambda c: c[0])  # (stable: puts of one time keep the order they came in)
    return out


def _offset(stamps: Sequence[tuple[float, float | None]]) -> float | None:
    """The least ``arrived - sent`` of the stamps that have a sender's time: a sender's clock
    moved onto this one. None: none has one, or they disagree with this clock by more than
    ``CLOCK_SLACK`` (a clock stepped, a sender's time that is not its clock: the arrivals then)."""
    delays = [arrived - sent for arrived, sent in stamps if sent is not None]
    if not delays or max(delays) - min(delays) > CLOCK_SLACK:
        return None
    return min(delays)


def _time(value: object) -> float | None:
    """``value`` if it is a finite number (not a boolean), else None."""
    return (
        float(value) if isinstance(value, (int, float)) and type(value) is not bool and math.isfinite(value) else None
    )


def _vector(value: object, n: int) -> tuple[float, ...] | None:
    """``value`` as ``n`` finite numbers (not booleans), else None."""
    if not isinstance(value, list) or len(value) != n:
        return None
    out = [_time(x) for x in value]
    return tuple(x for x in out if x is not None) if None not in out else None


__all__ = ["HeardSession", "SessionRecorder"]
