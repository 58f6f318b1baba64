"""The service's record of the arms' range-sensor readings (``<prefix>/<robot>/sensors/<name>``,
docs/sensors.md), for ``detect``: each scanner's last sweeps, from live adapters only.

A reading is believed only if it names a live adapter of its arm (its liveliness token), for
a sensor of that arm, under that sensor's own key, well formed (at most ``MAX_BYTES``): a
``range`` that is null or a number in the sensor's range, a ``bearing`` inside its sweep, a
``sweep`` count that is the adapter's last or the next. Anything else is ignored and counted
(``ignored``): nothing published on the key can make the service fail. The adapter's id is no
secret (its readings carry it): who may put on an arm's sensor keys at all is the router's ACL
(docs/security.md), as for its state. The first sweep heard from an adapter may have begun
before: it is not looked at. A sweep is complete once a reading of a later sweep has come; it is fresh
while its last reading came less than ``MAX_AGE`` ago (by the service's clock: a reading's own
``time`` is the adapter's word) and its adapter is still alive. An adapter's readings replace
another's: one sensor, one adapter reading it at a time.
"""

from __future__ import annotations

import math
import threading
import time
from collections import OrderedDict
from collections.abc import Callable, Mapping
from typing import Any

import orjson

from armd.robots import Robot

KEEP_SWEEPS = 8  # complete sweeps kept per sensor
MAX_AGE = 20.0  # [s] a sweep whose last reading is older than this is not looked at (a real-time
# sweep of 2 rad in 2 degree steps takes 2.2 s: the 4 a detect may ask for are younger)
MAX_BYTES = 4096  # a reading's payload, at most (one is about 200)
MAX_PER_SWEEP = 1000  # readings of one sweep (a sweep of 2 rad in 2 degree steps has 58)


class SensorBook:
    def __init__(
        self, arms: Mapping[str, Robot], live: Callable[[str, str], bool], clock: Callable[[], float] = time.monotonic
    ) -> None:
        self.arms = arms
        self.live = live  # (robot, adapter id) -> whether it is a live adapter of that arm
        self.clock = clock
        self._lock = threading.Lock()
        # (robot, sensor) -> (adapter, sweeps: sweep number -> (readings, when the last came))
        self._sweeps: dict[tuple[str, str], tuple[str, OrderedDict[int, tuple[list[dict[str, Any]], float]]]] = {}
        self._first: dict[tuple[str, str], int] = {}  # (robot, sensor): the sweep its adapter was first heard in
        self.ignored: dict[str, int] = {}

    def _ignore(self, why: str) -> None:
        self.ignored[why] = self.ignored.get(why, 0) + 1

    def on_reading(self, key: str, payload: bytes) -> None:
        """A reading published on ``key``: recorded, or ignored and counted."""
        parts = key.split("/")
        if len(parts) < 3:
            return
        robot, name = parts[-3], parts[-1]
        arm = self.arms.get(robot)
        if arm is None or name not in arm.sensors:
            self._ignore("not a sensor of an arm served")
            return
        sensor = arm.sensors[name]
        if len(payload) > MAX_BYTES:
            self._ignore("too large")
            return
        try:
            msg = orjson.loads(payload)
            ok = (
                isinstance(msg, dict)
                and msg.get("sensor") == name
                and isinstance(msg.get("adapter"), str)
                and (msg.get("range") is None or _number(msg["range"]))
                and (sensor.mount != "scanner" or (_number(msg.get("bearing")) and _count(msg.get("sweep"))))
            )
        except Exception:  # (anything a payload can make a parser or a check raise: ignored, counted)
            ok = False
        if not ok:
            self._ignore("malformed")
            return
        if not self.live(robot, msg["adapter"]):
            self._ignore("no live adapter of that id")
            return
        if msg["range"] is not None and not sensor.range[0] <= msg["range"] <= sensor.range[1]:
            self._ignore("a range outside the sensor's")
            return
        if sensor.mount != "scanner" or sensor.sweep is None:
            return  # (only the scanners' sweeps are kept: detect looks at them)
        if not sensor.sweep[0] - 1e-6 <= msg["bearing"] <= sensor.sweep[1] + 1e-6:
            self._ignore("a bearing outside the sensor's sweep")
            return
        reading = {"bearing": float(msg["bearing"]), "range": None if msg["range"] is None else float(msg["range"])}
        now = self.clock()
        with self._lock:
            adapter, sweeps = self._sweeps.get((robot, name), ("", OrderedDict()))
            if adapter != msg["adapter"]:  # another adapter reads it now: what the last one said is gone
                adapter, sweeps = msg["adapter"], OrderedDict()
                self._sweeps[(robot, name)] = (adapter, sweeps)
            k = int(msg["sweep"])
            last = next(reversed(sweeps)) if sweeps else None
            if last is not None and k not in (last, last + 1):  # (one adapter counts its sweeps one by one)
                self._ignore("a sweep out of count")
                return
            if last is None:
                self._first[(robot, name)] = k  # (the sweep it was first heard in: maybe begun before)
            readings, _ = sweeps.get(k, ([], now))
            if len(readings) >= MAX_PER_SWEEP:
                self._ignore("too many readings in one sweep")
                return
            readings.append(reading)
            sweeps[k] = (readings, now)
            while len(sweeps) > KEEP_SWEEPS + 1:
                sweeps.popitem(last=False)

    def sweeps(self, robot: str, sensor: str, n: int) -> list[list[dict[str, Any]]]:
        """The newest ``n`` (at most) complete, fresh sweeps of ``sensor``, oldest first."""
        now = self.clock()
        with self._lock:
            adapter, sweeps = self._sweeps.get((robot, sensor), ("", OrderedDict()))
        if not adapter or not self.live(robot, adapter):  # (its adapter gone: what it read may be stale)
            return []
        with self._lock:
            first = self._first.get((robot, sensor))
            complete = list(sweeps.items())[:-1]  # (the newest is still going)
            fresh = [list(r) for k, (r, at) in complete if now - at <= MAX_AGE and k != first]
        return fresh[-n:]


def _number(v: object) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _count(v: object) -> bool:
    return isinstance(v, int) and not isinstance(v, bool) and v >= 0
