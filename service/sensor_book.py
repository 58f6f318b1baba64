"""The service's record of the arms' range-sensor readings (``<prefix>/<robot>/sensors/<name>``,
docs/sensors.md), for ``detect``: each scanner's last sweeps, from one live adapter, believed as
the arm's states are (service.server): from a live adapter only, in order, plausible.

A reading is believed only if

- it is well formed (at most ``MAX_BYTES``), for a sensor of that arm under its own key, and
  carries its adapter's id, its number ``seq`` and its ``time``;
- it names a live adapter of the arm (its liveliness token, the key the states' trust uses);
- it is plausible: a ``range`` null or within the sensor's, a scanner's ``bearing`` within its
  sweep, a ``time`` within ``CLOCK_SLACK`` of the service's clock, a ``sweep`` count that is
  the adapter's last or the next;
- it is in order: one publisher's numbers only rise (Zenoh delivers a publisher's puts in
  order), so a number not above the last one seen under that id (the very same message twice
  is a double delivery, and dropped) is a second publisher or a replay;
- and nobody disputes the sensor.

Anything else is ignored and counted (``ignored``, logged at most every ``SAY_EVERY`` s):
nothing published on the key can make the service fail.

The adapter's id is no secret (every reading carries it), and an adapter's password may be
stolen: a forger may publish under the live adapter's id, or under a token of its own. Either is
a second publisher of the sensor: a number going back under the id, or readings under another
live adapter's id while the holder's token lives, dispute it. What was kept is forgotten (it may
have been the forger's), and no reading of it is believed until only one publisher has numbered
in order for ``DISPUTE_HOLD`` seconds; meanwhile ``detect`` answers ``not_ready`` naming the
dispute (:meth:`SensorBook.read`), never an answer on mixed readings. A forger numbering ahead is
believed until the adapter's next reading disputes it (a reading period): a sweep is looked at
only once the sweep after it has gone on for ``CONFIRM``, longer than that, so what it added
is gone first.

The first sweep heard from an adapter (or after a dispute) may have begun before: it is not
looked at. A sweep is complete once a reading of a later sweep has come; it is fresh while its
last reading came less than ``MAX_AGE`` ago (by the service's clock) and its adapter is alive.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections import OrderedDict
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import orjson

from armd.robots import Robot

log = logging.getLogger(__name__)

KEEP_SWEEPS = 8  # complete sweeps kept per sensor
MAX_AGE = 20.0  # [s] a sweep whose last reading is older than this is not looked at (a real-time
# sweep of 2 rad in 2 degree steps takes 2.2 s: the 4 a detect may ask for are younger)
MAX_BYTES = 4096  # a reading's payload, at most (one is about 200)
MAX_PER_SWEEP = 1000  # readings of one sweep (a sweep of 2 rad in 2 degree steps has 58)
CLOCK_SLACK = 5.0  # [s] a reading's ``time`` may be this far from the service's clock, either way
# (delivery takes milliseconds; NTP keeps two machines' clocks within a few)
DISPUTE_HOLD = 2.0  # [s] a sensor two publishers use is not believed until one alone has this long
# (the states' own hold, service.server.DISPUTE_HOLD)
CONFIRM = 0.5  # [s] a sweep is looked at once the next has gone on this long: longer than an
# adapter's reading period (the SSC-32's: 0.17 s), so a forger's readings have been disputed
SAY_EVERY = 5.0  # [s] ignored readings are logged at most this often, counted between
KEEP_IDS = 8  # ids whose numbers are kept per sensor (a gone adapter's are dropped beyond)


class Swept(NamedTuple):
    """What :meth:`SensorBook.read` has of a sensor: the ``adapter`` whose readings they are
    ("" if none), its fresh complete ``sweeps`` (oldest first), and the ids that dispute the
    sensor now (``disputed``: none, or readings of it are not used)."""

    adapter: str
    sweeps: list[list[dict[str, Any]]]
    disputed: tuple[str, ...]


@dataclass
class _Sensor:
    """One sensor's readings as the book keeps them."""

    holder: str = ""  # the adapter whose readings are kept
    # sweep number -> (readings, when its first came, when its last came) [s, the book's clock]
    sweeps: OrderedDict[int, tuple[list[dict[str, Any]], float, float]] = field(default_factory=OrderedDict)
    first: int | None = None  # the sweep its holder was first heard in (maybe begun before)
    seqs: dict[str, tuple[int, bytes]] = field(default_factory=dict)  # id: its last number, and message
    disputed_at: float = -math.inf  # [s] when a second publisher last showed
    disputants: tuple[str, ...] = ()  # the ids involved then

    def restart(self, holder: str) -> None:
        self.holder, self.sweeps, self.first = holder, OrderedDict(), None


class SensorBook:
    """Thread-safe: the Zenoh callback writes, ``detect`` reads."""

    def __init__(
        self,
        arms: Mapping[str, Robot],
        live: Callable[[str, str], bool],
        clock: Callable[[], float] = time.monotonic,
        wall: Callable[[], float] = time.time,
    ) -> None:
        self.arms = arms
        self.live = live  # (robot, adapter id) -> whether it is a live adapter of that arm
        self.clock = clock  # [s] ages, holds
        self.wall = wall  # [s] since the epoch: what a reading's ``time`` is compared with
        self._lock = threading.Lock()
        self._sensors: dict[tuple[str, str], _Sensor] = {}  # (robot, sensor name)
        self.ignored: dict[str, int] = {}  # readings ignored, by reason
        self._said = -math.inf  # when ignored readings were last logged

    def _ignore(self, robot: str, why: str) -> None:
        with self._lock:
            self.ignored[why] = self.ignored.get(why, 0) + 1
            now = self.clock()
            if now - self._said < SAY_EVERY:
                return
            self._said = now
            counts = ", ".join(f"{n} {reason}" for reason, n in sorted(self.ignored.items()))
        log.warning("ignoring range readings of %s (so far, by reason: %s)", robot, counts)

    def on_reading(self, key: str, payload: bytes) -> None:
        """A reading published on ``key``: recorded, or ignored and counted."""
        parts = key.split("/")
        if len(parts) < 3:
            return
        robot, name = parts[-3], parts[-1]
        arm = self.arms.get(robot)
        if arm is None or name not in arm.sensors:
            self._ignore(robot, "not a sensor of an arm served")
            return
        sensor = arm.sensors[name]
        scanner = sensor.mount == "scanner" and sensor.sweep is not None
        if len(payload) > MAX_BYTES:
            self._ignore(robot, "too large")
            return
        try:
            msg = orjson.loads(payload)
            ok = (
                isinstance(msg, dict)
                and msg.get("sensor") == name
                and isinstance(msg.get("adapter"), str)
                and _count(msg.get("seq"))
                and _number(msg.get("time"))
                and (msg.get("range") is None or _number(msg["range"]))
                and (sensor.mount != "scanner" or (_number(msg.get("bearing")) and _count(msg.get("sweep"))))
            )
        except Exception:  # (anything a payload can make a parser or a check raise: ignored, counted)
            ok = False
        if not ok:
            self._ignore(robot, "malformed")
            return
        adapter = msg["adapter"]
        if not self.live(robot, adapter):
            self._ignore(robot, "no live adapter of that id")
            return
        # plausible, before it counts: a reading that cannot be changes nothing
        if msg["range"] is not None and not sensor.range[0] <= msg["range"] <= sensor.range[1]:
            self._ignore(robot, "a range outside the sensor's")
            return
        if abs(msg["time"] - self.wall()) > CLOCK_SLACK:
            self._ignore(robot, "a time far from the service's clock")
            return
        lo, hi = sensor.sweep or (0.0, 0.0)
        if scanner and not lo - 1e-6 <= msg["bearing"] <= hi + 1e-6:
            self._ignore(robot, "a bearing outside the sensor's sweep")
            return
        with self._lock:
            s = self._sensors.get((robot, name)) or _Sensor()
            holder, disputants = s.holder, s.disputants
        holder_live = bool(holder) and holder != adapter and self.live(robot, holder)
        gone = () if any(self.live(robot, a) for a in disputants) else disputants
        why = self._record(robot, name, msg, payload, (holder, holder_live, gone), scanner)
        if why:
            self._ignore(robot, why)

    def _record(
        self,
        robot: str,
        name: str,
        msg: dict[str, Any],
        payload: bytes,
        seen: tuple[str, bool, tuple[str, ...]],
        scanner: bool,
    ) -> str:
        """Take a well-formed, plausible reading of a live adapter in turn (``seen``: the
        sensor's holder as it was, whether that is another live adapter, and the ids of a
        dispute all gone): "" if kept (or a double delivery, dropped), else why it is not."""
        adapter, seq = msg["adapter"], int(msg["seq"])
        holder, holder_live, gone = seen
        now = self.clock()
        with self._lock:
            s = self._sensors.setdefault((robot, name), _Sensor())
            if gone and s.disputants == gone:  # (everyone in it gone: nothing left to dispute)
                s.disputed_at, s.disputants = -math.inf, ()
            last = s.seqs.get(adapter)
            if last is not None and last == (seq, payload):
                return ""  # the same message delivered twice (Zenoh may, over two routes): nobody else's
            if len(s.seqs) >= KEEP_IDS and adapter not in s.seqs:
                s.seqs = {a: n for a, n in s.seqs.items() if a == s.holder}
            s.seqs[adapter] = (seq, payload)
            back = last is not None and seq <= last[0]
            other = s.holder == holder and holder_live  # (another live adapter's readings of it: two publishers)
            if back or other:
                began = now - s.disputed_at >= DISPUTE_HOLD
                s.disputed_at = now
                s.disputants = tuple(sorted({adapter, s.holder} - {""}))
                s.restart(adapter)  # what was kept may have been the forger's: forgotten
                if began:
                    log.warning(
                        "sensor %s of %s: %s; not believed for %g s",
                        name,
                        robot,
                        f"two publishers under adapter id {adapter}, or a replay"
                        if back
                        else f"readings from two live adapters ({', '.join(s.disputants)})",
                        DISPUTE_HOLD,
                    )
                return "numbered out of order, or a second adapter: the sensor disputed"
            if now - s.disputed_at < DISPUTE_HOLD:
                s.holder = adapter
                return "under dispute"
            if s.holder != adapter:  # another adapter reads it now (the last one gone): what it said is gone
                s.restart(adapter)
            if not scanner:
                return ""  # (only the scanners' sweeps are kept: detect looks at them)
            k = int(msg["sweep"])
            newest = next(reversed(s.sweeps)) if s.sweeps else None
            if newest is not None and k not in (newest, newest + 1):  # (one adapter counts its sweeps one by one)
                return "a sweep out of count"
            if newest is None:
                s.first = k  # (the sweep it was first heard in: maybe begun before)
            readings, began_at, _ = s.sweeps.get(k, ([], now, now))
            if len(readings) >= MAX_PER_SWEEP:
                return "too many readings in one sweep"
            readings.append(
                {"bearing": float(msg["bearing"]), "range": None if msg["range"] is None else float(msg["range"])}
            )
            s.sweeps[k] = (readings, began_at, now)
            while len(s.sweeps) > KEEP_SWEEPS + 1:
                s.sweeps.popitem(last=False)
        return ""

    def read(self, robot: str, sensor: str, n: int) -> Swept:
        """The newest ``n`` (at most) complete, fresh, confirmed sweeps of ``sensor`` and whose
        they are; none while the sensor is disputed (:attr:`Swept.disputed` names the ids)."""
        now = self.clock()
        with self._lock:
            s = self._sensors.get((robot, sensor))
            if s is None:
                return Swept("", [], ())
            disputed = s.disputants if now - s.disputed_at < DISPUTE_HOLD else ()
            adapter, first = s.holder, s.first
            items = list(s.sweeps.items())
        if any(self.live(robot, a) for a in disputed):  # (while one of its ids lives)
            return Swept("", [], disputed)
        if not adapter or not self.live(robot, adapter):  # (its adapter gone: what it read may be stale)
            return Swept("", [], ())
        complete = items[:-1]  # (the newest is still going)
        if items and now - items[-1][1][1] < CONFIRM:  # (the one before: not yet past a dispute's reach)
            complete = complete[:-1]
        fresh = [list(r) for k, (r, _, at) in complete if now - at <= MAX_AGE and k != first]
        return Swept(adapter, fresh[-n:], ())

    def sweeps(self, robot: str, sensor: str, n: int) -> list[list[dict[str, Any]]]:
        """The newest ``n`` (at most) complete, fresh sweeps of ``sensor``, oldest first (none
        while it is disputed)."""
        return self.read(robot, sensor, n).sweeps


def _number(v: object) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _count(v: object) -> bool:
    return isinstance(v, int) and not isinstance(v, bool) and v >= 0
