"""The loop every teleoperation source shares: a source's readings turned into puts on the
arm's tracking stream (``<prefix>/<robot>/track``, :meth:`ArmClient.track`) at a steady rate.

Each tick the loop asks its source for one :data:`Step` (:meth:`Source.poll`) and does what
it says:

- a :class:`Put`: put it (a session is opened for the first one, and again after the source
  was lost or stopped: a new session id each time);
- ``None``: nothing this tick (a reply lost on the leader's bus; the keyboard after a stop);
- :class:`Lost`: the source stopped answering (a leader unplugged, a gamepad gone): the session
  ends, nothing more is put (the arm brakes to rest at the deadman: the service's own, the arm
  keeps no goal of ours), said once until the source answers again, which starts a new session;
- :class:`Stop`: the ``stop`` verb (the arm brakes now, the session ends for good);
- :class:`Quit`: the loop ends.

The ticks keep their pace (``rate_hz``, from the first): a late one is not made up by a burst
of puts, the next comes a period after it.
"""

from __future__ import annotations

import dataclasses
import logging
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, Protocol

from armd.clients import ArmClient
from armd.clients.track import Track, TrackEvent
from armd.errors import ArmdError

log = logging.getLogger(__name__)

EVENTS_EVERY = 0.1  # [s] how often the stream's new events are handed on (``on_event``)


@dataclass(frozen=True)
class Put:
    """One put of the stream (:meth:`Track.send`): exactly one of ``joints`` [rad],
    ``target`` [x, y, z] [m] (with ``approach``: a pitch [rad] or a word, as ``ik`` takes it)
    and ``velocity`` [m/s] of the tool point (with ``pitch_rate``, ``roll_rate`` [rad/s]); and
    optionally ``speed`` (a fraction of the limits) and ``gripper`` (0 closed, 1 open)."""

    joints: tuple[float, ...] | None = None
    target: tuple[float, float, float] | None = None
    velocity: tuple[float, float, float] | None = None
    approach: float | str | None = None
    pitch_rate: float | None = None
    roll_rate: float | None = None
    speed: float | None = None
    gripper: float | None = None

    def fields(self) -> dict[str, Any]:
        """The keyword arguments of :meth:`Track.send` (those set)."""
        return {k: v for k, v in dataclasses.asdict(self).items() if v is not None}


@dataclass(frozen=True)
class Lost:
    """The source stopped answering: ``why``, for people."""

    why: str


@dataclass(frozen=True)
class Stop:
    """The operator asked for a stop (the ``stop`` verb)."""


@dataclass(frozen=True)
class Quit:
    """The operator is done: the loop ends."""


Step = Put | Lost | Stop | Quit | None


class Source(Protocol):
    """What the loop reads: a leader arm, the keyboard, a gamepad."""

    name: str  # for people: "the leader so101 on /dev/ttyACM0"

    def poll(self) -> Step:
        """This tick's step (at most a few ms: the loop keeps its pace)."""

    def close(self) -> None:
        """Release what it holds (its bus, its device, the terminal)."""


class Stream:
    """``robot``'s tracking stream, put by one source at ``rate_hz`` through ``client``.

    ``deadman`` [s]: each session's (None: the service's default, 0.25 s); ``speed``: a fraction
    of the limits, put with every put that sets none; ``say``: what the loop tells the operator
    (a lost source, its return, a stop refused), one line each; ``on_event``: each event the
    service says of the stream (``unreachable``, ``collision``, ``deadman`` ...), as it comes.
    """

    def __init__(
        self,
        client: ArmClient,
        robot: str,
        *,
        rate_hz: float,
        deadman: float | None = None,
        speed: float | None = None,
        say: Callable[[str], None] = print,
        on_event: Callable[[TrackEvent], None] | None = None,
    ) -> None:
        self.client = client
        self.robot = robot
        self.period = 1.0 / rate_hz
        self.deadman = deadman
        self.speed = speed
        self._say = say
        self._on_event = on_event
        self.said: list[tuple[float, str]] = []  # (when [s, monotonic], what): the loop's own lines
        self.track: Track | None = None  # the session now (None: not putting)
        self.last: Track | None = None  # the latest session, open or ended (its events)
        self.sessions = 0  # sessions opened
        self.puts = 0
        self._lost: Lost | None = None  # the source's outage, said
        self._seen: TrackEvent | None = None  # the latest event handed on
        self._events_at = 0.0

    # -- the loop ------------------------------------------------------------------------------

    def run(self, source: Source, until: threading.Event) -> None:
        """Tick until ``until`` is set or the source quits; the session ends when it returns."""
        next_at = time.monotonic()
        try:
            while not until.is_set():
                step = source.poll()
                if isinstance(step, Quit):
                    break
                self.tick(step, source.name)
                next_at += self.period
                now = time.monotonic()
                if next_at < now - self.period:  # (late by more than a tick: on from now, no burst)
                    next_at = now
                until.wait(max(next_at - now, 0.0))
        finally:
            self.end()

    def tick(self, step: Step, name: str = "the source") -> None:
        """Do what one step says (:class:`Put`, :class:`Lost`, :class:`Stop`, or nothing)."""
        if isinstance(step, Put):
            if self.track is None:
                self._open()
                if self._lost is not None:
                    self.say(f"{name} answers again: following in a new session")
                    self._lost = None
            assert self.track is not None
            if self.speed is not None and step.speed is None:
                step = dataclasses.replace(step, speed=self.speed)
            self.track.send(**step.fields())
            self.puts += 1
        elif isinstance(step, Lost):
            if self._lost is None:
                self.say(f"{step.why}: no more puts; {self.robot} brakes to rest at the deadman")
                self._lost = step
            self.end()
        elif isinstance(step, Stop):
            self.end()
            try:
                self.client.stop(self.robot)
            except ArmdError as e:
                self.say(f"the stop was not taken: {e.message}")
        self._hand_on_events()

    def end(self) -> None:
        """No more puts in this session (the next put opens another)."""
        if self.track is not None:
            self.track.close()
            self.track = None
        self._hand_on_events(now=True)

    def say(self, line: str) -> None:
        self.said.append((time.monotonic(), line))
        del self.said[:-100]
        self._say(line)

    # -- the service's word --------------------------------------------------------------------

    @property
    def events(self) -> list[TrackEvent]:
        """What the service said of the latest session (open or ended)."""
        return self.last.events if self.last is not None else []

    def _open(self) -> None:
        self.track = self.client.track(self.robot, deadman=self.deadman)
        self.last = self.track
        self._seen = None
        self.sessions += 1

    def _hand_on_events(self, now: bool = False) -> None:
        """Each event not handed on yet, to ``on_event`` (every ``EVENTS_EVERY``)."""
        t = time.monotonic()
        if self._on_event is None or self.last is None or (not now and t - self._events_at < EVENTS_EVERY):
            return
        self._events_at = t
        for e in new_events(self.last.events, self._seen):
            self._seen = e
            self._on_event(e)


def new_events(events: Sequence[TrackEvent], seen: TrackEvent | None) -> list[TrackEvent]:
    """Those of ``events`` after ``seen`` (the same object; all of them if it is not there)."""
    if seen is not None:
        for k in range(len(events) - 1, -1, -1):
            if events[k] is seen:
                return list(events[k + 1 :])
    return list(events)
