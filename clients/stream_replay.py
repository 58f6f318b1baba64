"""A recorded tracking stream put again (``armd replay --stream``): each recorded put, as it was
sent, at its own time from the first, on ``<prefix>/<robot>/track``, so that the arm is driven
as it was; the service's tracker keeps every limit, as it did the first time.

Each recorded session is replayed as a new one (``replay-<id>-<n>``, its puts numbered from 1);
what a put says is kept whole: its target, joints or velocity, its speed and gripper, the
``deadman`` its session's first put set (a recording that began after that put: the service's
default). A put's ``time`` (its client's clock) becomes this one's: when it is due. A put that
named no session (refused by the service then: it would be again) is not put.

>>> with ArmClient() as armd, StreamReplay(armd.session, "armd", "so101") as replay:  # doctest: +SKIP
...     replay.run(commands, threading.Event())
...     replay.events
"""

from __future__ import annotations

import threading
import time
import uuid
from collections.abc import Mapping, Sequence
from typing import Any

import zenoh

from armd.service.protocol import encode

from .track import Track, TrackEvent

ID_CHARS = 64  # a session's id, at most (the protocol's)


class _Replayed(Track):
    """One recorded session, put again under a new id: its puts as they were recorded, but for
    the session, the ``seq`` (from 1) and the ``time``."""

    def put(self, recorded: Mapping[str, Any], due: float) -> None:
        msg = {**recorded, "session": self.session_id, "seq": self.seq}
        if type(recorded.get("time")) in (int, float):
            msg["time"] = due
        self._pub.put(encode(msg))
        self.seq += 1


class StreamReplay:
    """Puts recorded commands on ``robot``'s tracking stream through ``session``; hears what
    the service says of them (:attr:`events`). Use as a context manager (or :meth:`close`)."""

    def __init__(self, session: zenoh.Session, prefix: str, robot: str) -> None:
        self._session = session
        self._prefix = prefix.rstrip("/")
        self.robot = robot
        self.name = f"replay-{uuid.uuid4().hex[:8]}"
        self._tracks: dict[str, _Replayed] = {}  # the recorded session's id: its replay
        self.puts = 0
        self.skipped = 0  # puts that named no session

    def __enter__(self) -> StreamReplay:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    @property
    def sessions(self) -> int:
        return len(self._tracks)

    @property
    def events(self) -> list[TrackEvent]:
        """What the service said of the replayed sessions, in the order they were opened."""
        return [e for t in self._tracks.values() for e in t.events]

    def run(self, commands: Sequence[tuple[float, Mapping[str, Any]]], until: threading.Event) -> int:
        """Put ``commands`` (``(t [s], put)``, ``t`` never falling), the first at once and each
        ``t`` after it, until they are all put or ``until`` is set: the puts sent. A put that is
        late goes at once (the service follows the latest; its ``time`` says when it was due)."""
        if not commands:
            return 0
        origin = time.monotonic() - commands[0][0]
        for t, put in commands:
            due = origin + t
            wait = due - time.monotonic()
            if (wait > 0.0 and until.wait(wait)) or until.is_set():
                break
            recorded = put.get("session")
            if not isinstance(recorded, str):
                self.skipped += 1
                continue
            track = self._tracks.get(recorded)
            if track is None:
                name = f"{self.name}-{len(self._tracks) + 1}"[:ID_CHARS]
                track = self._tracks[recorded] = _Replayed(self._session, self._prefix, self.robot, name=name)
                track.seq = 1
            track.put(put, due)
            self.puts += 1
        return self.puts

    def close(self) -> None:
        """The puts end (the arm brakes to rest at the deadman); the events are no longer heard."""
        for track in self._tracks.values():
            track.close()


__all__ = ["StreamReplay"]
