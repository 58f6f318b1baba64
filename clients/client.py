"""``ArmClient``: armd from Python, over Zenoh.

>>> with ArmClient() as armd:                      # doctest: +SKIP
...     r = armd.ik("insomniac", [0.25, 0.05, 0.12], approach="perpendicular")
...     r.status, r.q
"""

from __future__ import annotations

import time
import uuid
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import orjson
import zenoh
from numpy.typing import NDArray

from armd.errors import NoReply, from_reply
from armd.robots.types import FloatArray
from armd.service.protocol import encode
from armd.service.zconfig import client_config

from .track import Track

JSON = zenoh.Encoding.APPLICATION_JSON
MAX_QUERIERS = 256  # kept per client: (key, timeout) pairs
RETRY_PAUSE = 0.02  # [s] a request that ended at once with no reply is asked again after this, doubling ...
NOBODY_S = 1.0  # [s] ... for this long (or half the timeout): then nothing serves its key


@dataclass(frozen=True)
class IKReply:
    status: str
    q: FloatArray
    position_error: float
    reached: FloatArray
    pitch: float
    pitch_error: float | None
    branch: str
    branches: list[dict[str, Any]]
    reason: str | None
    raw: dict[str, Any] = field(default_factory=dict, repr=False, compare=False)  # the reply as the service sent it

    @property
    def ok(self) -> bool:
        return self.status == "ok"

    @property
    def roll(self) -> float | None:
        """The tool's roll about its axis [rad] (None: the arm has no wrist roll)."""
        value = self.raw.get("roll")
        return None if value is None else float(value)

    @property
    def contact(self) -> tuple[str, str] | None:
        """The colliding pair when the status is ``"collision"`` (link names, ``"ground"`` or an
        obstacle's name); else None."""
        pair = self.raw.get("contact")
        return None if pair is None else (str(pair[0]), str(pair[1]))


@dataclass(frozen=True)
class FKReply:
    q: FloatArray
    position: FloatArray
    pitch: float
    within_limits: bool
    raw: dict[str, Any] = field(default_factory=dict, repr=False, compare=False)  # the reply as the service sent it


@dataclass(frozen=True)
class TrajectoryReply:
    path: str
    duration: float
    rate_hz: float
    joint_names: list[str]
    times: FloatArray
    position: FloatArray
    velocity: FloatArray
    acceleration: FloatArray
    commands: NDArray[np.int64]
    raw: dict[str, Any] = field(default_factory=dict, repr=False, compare=False)  # the reply as the service sent it

    @classmethod
    def of(cls, r: dict[str, Any]) -> TrajectoryReply:
        """From the JSON of a ``plan`` reply."""
        return cls(
            r["path"],
            r["duration"],
            r["rate_hz"],
            r["joint_names"],
            np.array(r["times"]),
            np.array(r["position"]),
            np.array(r["velocity"]),
            np.array(r["acceleration"]),
            np.array(r["commands"], dtype=np.int64),
            r,
        )


@dataclass(frozen=True)
class MoveReply:
    id: str
    path: str
    duration: float
    goal: FloatArray
    start_source: str
    adapter: str = ""  # the adapter that accepted the trajectory
    raw: dict[str, Any] = field(default_factory=dict, repr=False, compare=False)  # the reply as the service sent it


class ArmClient:
    """A Zenoh session to an armd network, and one method per verb.

    Args:
        connect: endpoint(s) of a Zenoh router or of ``armd serve`` (default tcp/127.0.0.1:7447).
        config: a Zenoh configuration file instead (credentials, TLS ...).
        prefix: the service's key prefix.
        timeout: seconds to wait for a reply [s].
        deadline: ask the service to give up on each request after this many seconds [s]
            (answered ``deadline``, nothing done); the service's own limit applies if shorter.
    """

    def __init__(
        self,
        connect: str | Sequence[str] | None = None,
        *,
        config: str | None = None,
        prefix: str = "armd",
        timeout: float = 5.0,
        deadline: float | None = None,
    ) -> None:
        endpoints = [connect] if isinstance(connect, str) else (list(connect) if connect else None)
        try:
            self.session = zenoh.open(client_config(endpoints, config))
        except zenoh.ZError as e:
            where = ", ".join(endpoints or ["tcp/127.0.0.1:7447"])
            raise NoReply(f"cannot reach an armd network at {where}: is `armd serve` running? ({e})") from None
        self.prefix = prefix.rstrip("/")
        self.timeout = timeout
        self.deadline = deadline
        self._queriers: dict[tuple[str, float], zenoh.Querier] = {}

    def __enter__(self) -> ArmClient:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        self.session.close()

    # -- the verbs ---------------------------------------------------------------------------

    def call(
        self,
        key: str,
        request: dict[str, Any] | None = None,
        timeout: float | None = None,
        deadline: float | None = None,
    ) -> dict[str, Any]:
        """One request to ``<prefix>/<key>``: the reply object, or :class:`ServiceError` /
        :class:`NoReply`. ``deadline`` [s]: for this request, instead of the client's."""
        asked = self.deadline if deadline is None else deadline
        if asked is not None:
            request = {**request, "deadline": asked} if request else {"deadline": asked}  # (the caller's untouched)
        payload = encode(request) if request else b"{}"
        wait = self.timeout if timeout is None else timeout
        querier = self._querier(key, wait)
        started = time.monotonic()
        pause, timeouts, at_once = RETRY_PAUSE, 0, False
        while True:
            asked = time.monotonic()
            for reply in querier.get(payload=payload, encoding=JSON):
                if reply.ok is not None:
                    out: dict[str, Any] = orjson.loads(reply.ok.payload.to_bytes())
                    return out
                err = reply.err
                assert err is not None
                body = err.payload.to_bytes()
                try:
                    obj = orjson.loads(body)
                except ValueError:  # Zenoh's own error (a timeout): not a service reply
                    break
                raise from_reply(obj if isinstance(obj, dict) else {"code": "internal", "message": str(obj)})
            now = time.monotonic()
            at_once = now - asked < wait / 2
            if not at_once:  # (a replica that died with the query in flight: ask once more)
                timeouts += 1
                if timeouts >= 2:
                    break
                continue
            # ended at once: nothing serves the key now (replicas handing over who serves what
            # changes the arms, for milliseconds; or nothing at all): asked again for a while
            if now - started >= min(wait / 2, NOBODY_S):
                break
            time.sleep(pause)
            pause = min(2.0 * pause, 0.2)
        if at_once:
            raise NoReply(
                f"no armd service answered {self.prefix}/{key}: nothing on the network serves it "
                "(no service for this robot, or an access-control list that refuses it to this user "
                "or hides the service's queryable: docs/security.md)"
            )
        raise NoReply(f"no armd service answered {self.prefix}/{key} within {wait} s")

    def _querier(self, key: str, wait: float) -> zenoh.Querier:
        """The querier of ``<prefix>/<key>`` with this timeout, declared on first use and kept:
        a plain ``session.get`` declares one and drops it on every call, and sends the key as
        text; a kept one sends it as a number the router already knows. Bounded (robot names
        come from callers): past ``MAX_QUERIERS`` keys, one is declared per call as before."""
        querier = self._queriers.get((key, wait))
        if querier is None:
            querier = self.session.declare_querier(
                f"{self.prefix}/{key}",
                timeout=wait,  # BLOCK: DROP loses big ones
                congestion_control=zenoh.CongestionControl.BLOCK,
            )
            if len(self._queriers) < MAX_QUERIERS:
                querier = self._queriers.setdefault((key, wait), querier)  # (two threads at once: one kept)
        return querier

    def robots(self) -> list[dict[str, Any]]:
        return list(self.call("robots")["robots"])

    def info(self, robot: str) -> dict[str, Any]:
        return self.call(f"{robot}/info")

    def state(self, robot: str) -> dict[str, Any]:
        """Where the service thinks the arm is: ``position``, ``velocity``, ``source``, ``moving``."""
        return dict(self.info(robot)["state"])

    def fk(self, robot: str, q: Sequence[float]) -> FKReply:
        r = self.call(f"{robot}/fk", {"q": list(q)})
        return FKReply(np.array(r["q"]), np.array(r["position"]), r["pitch"], r["within_limits"], r)

    def ik(
        self,
        robot: str,
        target: object,
        *,
        approach: object = None,
        seed: Sequence[float] | None = None,
        tolerance: float | None = None,
        quantise: bool = False,
        roll: float | None = None,
    ) -> IKReply:
        req: dict[str, Any] = {"target": _jsonable(target)}
        if approach is not None:
            req["approach"] = approach
        if roll is not None:
            req["roll"] = roll
        if seed is not None:
            req["seed"] = list(seed)
        if tolerance is not None:
            req["tolerance"] = tolerance
        if quantise:
            req["quantise"] = True
        r = self.call(f"{robot}/ik", req)
        return IKReply(
            r["status"],
            np.array(r["q"]),
            r["position_error"],
            np.array(r["reached"]),
            r["pitch"],
            r["pitch_error"],
            r["branch"],
            r["branches"],
            r["reason"],
            r,
        )

    def ik_batch(self, robot: str, targets: object, *, approach: object = None, seeds: object = None) -> dict[str, Any]:
        req: dict[str, Any] = {"targets": _jsonable(targets)}
        if approach is not None:
            req["approach"] = _jsonable(approach)
        if seeds is not None:
            req["seeds"] = _jsonable(seeds)
        return self.call(f"{robot}/ik", req)

    def plan(
        self,
        robot: str,
        goal: object,
        *,
        start: object = None,
        path: str = "joint",
        speed: float = 1.0,
        rate_hz: float | None = None,
        via: Sequence[object] = (),
    ) -> TrajectoryReply:
        req = _motion(goal, path, speed, rate_hz, via)
        if start is not None:
            req["start"] = _jsonable(start)
        r = self.call(f"{robot}/plan", req)
        return TrajectoryReply.of(r)

    def move(
        self,
        robot: str,
        goal: object,
        *,
        path: str = "joint",
        speed: float = 1.0,
        rate_hz: float | None = None,
        via: Sequence[object] = (),
        wait: bool = False,
        wait_timeout: float | None = None,
    ) -> MoveReply:
        """Plan from where the arm is and send it to the adapters. ``wait``: return when the
        arm has arrived (the service's state of it says at rest at the goal)."""
        r = self.call(f"{robot}/move", _motion(goal, path, speed, rate_hz, via))
        reply = MoveReply(
            r["id"], r["path"], r["duration"], np.array(r["goal"]), r["start_source"], str(r.get("adapter", "")), r
        )
        if wait:
            self.wait_until_still(robot, reply.goal, timeout=wait_timeout or reply.duration + 5.0)
        return reply

    def stop(self, robot: str) -> dict[str, Any]:
        return self.call(f"{robot}/stop")

    def estop(self, robot: str, *, wait: float = 0.0) -> list[dict[str, Any]]:
        """Emergency stop, put straight to the arm's adapters (``<prefix>/<robot>/estop``: no
        service needed). Each brakes from its own state within every limit. ``wait`` [s]: how
        long to collect the adapters' ``accepted`` events for it (returned; [] if none came)."""
        ident = uuid.uuid4().hex
        return self._tell(
            robot,
            "estop",
            {"id": ident, "by": "client"},
            wait,
            lambda e: e.get("event") == "accepted" and e.get("id") == ident,
            every=True,
        )

    def unlock(self, robot: str, how: str, *, wait: float = 60.0) -> dict[str, Any] | None:
        """Tell the adapter that lost the arm's position where it is: ``how`` ``"home"`` (run the
        homing cycle) or ``"assume_rest"`` (the arm is at its rest pose). Returns the adapter's
        ``unlocked`` or ``rejected`` event, or None if none came within ``wait`` [s]."""
        answers = self._tell(
            robot,
            "unlock",
            {"how": how},
            wait,
            lambda e: (
                e.get("event") == "unlocked" or (e.get("event") == "rejected" and "unlock" in str(e.get("reason", "")))
            ),
        )
        return answers[0] if answers else None

    def _tell(
        self, robot: str, key: str, message: dict[str, Any], wait: float, match: Any, every: bool = False
    ) -> list[dict[str, Any]]:
        """Put ``message`` on ``<prefix>/<robot>/<key>``, and collect the arm's events that
        ``match`` for ``wait`` seconds (the first one only unless ``every``)."""
        import threading

        got: list[dict[str, Any]] = []
        first = threading.Event()

        def on_event(sample: zenoh.Sample) -> None:
            try:
                event = orjson.loads(sample.payload.to_bytes())
            except ValueError:
                return
            if isinstance(event, dict) and match(event):
                got.append(event)
                first.set()

        sub = self.session.declare_subscriber(f"{self.prefix}/{robot}/events", on_event) if wait > 0 else None
        try:
            self.session.put(
                f"{self.prefix}/{robot}/{key}",
                encode(message),
                encoding=JSON,
                congestion_control=zenoh.CongestionControl.BLOCK,
                priority=zenoh.Priority.REAL_TIME,
            )
            if sub is not None:
                if every:
                    time.sleep(wait)
                else:
                    first.wait(wait)
        finally:
            if sub is not None:
                sub.undeclare()
        return list(got)

    def track(self, robot: str, *, deadman: float | None = None, session: str | None = None) -> Track:
        """A tracking stream of ``robot`` (:class:`~clients.track.Track`): ``send`` targets as
        they come (joints, a point, a velocity), the arm follows each within every limit, and
        brakes to rest when no put comes for ``deadman`` [s] (the service's default: 0.25).
        ``session``: the stream's id (default: a new one)."""
        return Track(self.session, self.prefix, robot, deadman=deadman, name=session)

    def gripper(self, robot: str, opening: float) -> dict[str, Any]:
        """Open (1) or close (0) the gripper, or anything between."""
        return self.call(f"{robot}/gripper", {"opening": opening})

    def world(
        self,
        robot: str,
        *,
        add: Sequence[Mapping[str, Any]] = (),
        remove: Sequence[str] = (),
        clear: bool = False,
    ) -> dict[str, Any]:
        """The arm's world (its floor and obstacles), after removing every run-time obstacle
        (``clear``), those named in ``remove``, then adding ``add``: each
        ``{"name", "shape": "box"|"sphere"|"cylinder", "size", "position", "rpy"}`` [m, rad] in
        the base frame. All or nothing. Reply: ``world`` (``ground``, ``obstacles``, ``pairs``),
        ``fixed`` (the obstacles of robot.toml, which stay) and ``contacts`` (what the arm
        touches now, where the service knows it to be)."""
        request: dict[str, Any] = {}
        if add:
            request["add"] = [dict(o) for o in add]
        if remove:
            request["remove"] = list(remove)
        if clear:
            request["clear"] = True
        return self.call(f"{robot}/world", request)

    def pick(self, robot: str, target: object, **options: Any) -> dict[str, Any]:
        """Seed 000's grasp of ``target`` (``approach``, ``above``, ``lift``, ``speed``: the verb's
        options): open, above, descend, close, lift. The reply lists the steps, ``done``, and where
        it stopped and why if it did. It waits for the arm: ``timeout`` [s] (default 60)."""
        return self._sequence("pick", robot, target, options)

    def place(self, robot: str, target: object, **options: Any) -> dict[str, Any]:
        """The grasp reversed: above, descend, open, rise (as :meth:`pick`)."""
        return self._sequence("place", robot, target, options)

    def _sequence(self, verb: str, robot: str, target: object, options: dict[str, Any]) -> dict[str, Any]:
        timeout = float(options.pop("timeout", 60.0))
        req = {"target": _jsonable(target), **{k: v for k, v in options.items() if v is not None}}
        return self.call(f"{robot}/{verb}", req, timeout=timeout)

    def detect(
        self, robot: str, *, sweeps: int | None = None, sensors: Sequence[str] | None = None, wait: float = 0.0
    ) -> dict[str, Any]:
        """The objects ``robot``'s scanning sensors see (the reply of ``detect``: its ``objects``).

        ``wait`` [s]: while the scanners have not swept enough yet (``not_ready``: a real
        scanner's sweep takes seconds, docs/sensors.md), ask again until then."""
        import time

        from armd.errors import ArmdError

        req: dict[str, Any] = {}
        if sweeps is not None:
            req["sweeps"] = sweeps
        if sensors is not None:
            req["sensors"] = list(sensors)
        until = time.monotonic() + wait
        while True:
            try:
                return self.call(f"{robot}/detect", req)
            except ArmdError as e:
                if e.code != "not_ready" or time.monotonic() >= until:
                    raise
            time.sleep(0.25)

    def wait_until_still(
        self, robot: str, goal: FloatArray | None = None, *, timeout: float = 10.0, tolerance: float = 2e-3
    ) -> dict[str, Any]:
        """Poll the arm's state until it is at rest (at ``goal`` within ``tolerance`` [rad])."""
        import time

        deadline = time.monotonic() + timeout
        while True:
            s = self.state(robot)
            here = np.array(s["position"])
            if not s["moving"] and (goal is None or np.max(np.abs(here - goal)) <= tolerance):
                return s
            if time.monotonic() > deadline:
                raise NoReply(f"{robot} did not come to rest at its goal within {timeout:.1f} s")
            time.sleep(0.05)


def _motion(goal: object, path: str, speed: float, rate_hz: float | None, via: Sequence[object]) -> dict[str, Any]:
    req: dict[str, Any] = {"goal": _jsonable(goal), "path": path, "speed": speed}
    if rate_hz is not None:
        req["rate_hz"] = rate_hz
    if via:
        req["via"] = [_jsonable(v) for v in via]
    return req


_PLAIN = frozenset({float, int, str, bool, type(None)})  # JSON as they are


def _jsonable(x: object) -> Any:
    if type(x) in _PLAIN:  # (most of what a request holds: first, and without a look for dataclass fields)
        return x
    if isinstance(x, np.ndarray):
        return x.tolist()
    if isinstance(x, dict):
        return {k: _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [v if type(v) in _PLAIN else _jsonable(v) for v in x]
    if hasattr(x, "__dataclass_fields__"):
        return {k: _jsonable(getattr(x, k)) for k in x.__dataclass_fields__}
    return x
