"""The armd service on a Zenoh session: queryables for every verb, trajectories published,
adapters' state and liveliness followed.

Key expressions (``prefix`` = ``armd`` by default):

- ``<prefix>/robots``, ``<prefix>/<robot>/{info,fk,ik,plan,move,stop,gripper}``: queryables (JSON in, JSON out);
- ``<prefix>/<robot>/trajectory``: what ``move`` publishes, for the adapters;
- ``<prefix>/<robot>/estop``: what ``stop`` puts: every adapter brakes from its own state;
- ``<prefix>/<robot>/gripper``: what ``gripper`` publishes, for the adapters;
- ``<prefix>/<robot>/state``: adapters' reports, followed to plan from where the arm is;
- ``<prefix>/<robot>/adapter/<id>``: adapters' liveliness tokens (``move`` needs one);
- ``<prefix>/service/<id>``: this service's liveliness token.

One queryable on ``<prefix>/**`` takes every request, so a request for an unknown robot or
verb gets an error reply too. It is declared ``complete``: with several replicas on one
network, a query (target ``BEST_MATCHING``, the default) reaches exactly one of them.
Quick requests (``fk``, ``info``, ``robots``, IK of one target: microseconds to a couple of
milliseconds) are answered on the thread Zenoh hands them to (zenoh-python's callback thread
for the queryable), where a hand-over to a worker would cost more than the work
(bench/service.py); their path is kept short, as it runs once per request on a CPU that the
router and the clients share: keys are routed with one look-up, an IK of one plain point is
checked in one pass (:func:`.protocol.plain_point`), counters take one lock, and the debug
line is formatted only when debug is on. The rest are served on a thread
pool, ``stop`` on a pool of its own and ``move`` and ``gripper`` on another, so that a queue of
IK batches and plans cannot delay them (measured by bench/load.py and bench/flood.py); every
request gets exactly one reply, an error reply for anything that goes wrong, and an
unexpected exception is logged with its traceback and answered ``internal``: the service
keeps serving.

Every request has a deadline (:mod:`service.deadline`), counted from when Zenoh handed it
over: one that waited in the queue past it is answered ``deadline`` without being worked
on, and work that overruns it is abandoned and answered ``deadline`` with nothing published.
"""

from __future__ import annotations

import copy
import functools
import logging
import math
import threading
import time
import uuid
from collections.abc import Callable, Iterable, Mapping
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import numpy as np
import orjson
import zenoh

from armd.errors import (
    ArmdError,
    DeadlineExceeded,
    Internal,
    NoAdapter,
    PayloadTooLarge,
    Rejected,
    UnknownRobot,
    UnknownVerb,
)
from armd.robots import Robot
from armd.robots import names as catalogue_names

from .deadline import Deadline
from .handlers import Handlers, unread_request
from .protocol import VERBS, WORLD_BYTES, Limits, decode, encode, request_deadline
from .replicas import Replicas, changes
from .sensor_book import SensorBook
from .state import StateBook, implausible, reported_state
from .track_message import TRACK_BYTES
from .tracking import Tracker, ahead_of_requests

log = logging.getLogger(__name__)
QUICK_BYTES = 2048  # an IK request this small is one target: answered without queueing
JSON = zenoh.Encoding.APPLICATION_JSON
Route = tuple[Robot | None, str]  # (arm, verb); (None, "robots") for the service-wide verb
ACCEPT_TIMEOUT = 1.0  # [s] how long a move waits for an adapter to accept its trajectory ...
ACCEPT_PER_SAMPLE = 1e-4  # [s] ... plus this per sample (an adapter parses and checks all of them first)
JUMP_SLACK = 0.05  # [rad] what a report may move beyond what the velocity limits allow since the last one
SETTLE = 0.1  # [s] the time a report may move over, beyond the time between reports (bunched deliveries)
RESET_AFTER = 0.5  # [s] an adapter whose every report was discontinuous this long starts afresh
DISPUTE_HOLD = 2.0  # [s] an adapter id that two publishers use (or a replay) is not believed this long
SAY_EVERY = 5.0  # [s] ignored states are logged at most this often, counted between
SWITCH_INTERVAL = 0.0005  # [s] how often `armd serve` hands Python's GIL over (sys.setswitchinterval; default 5 ms)
ADOPT_S = 5.0  # [s] the most taking another replica's world may take
REPORT_BYTES = 64 * 1024  # an adapter's state or event, at most (one is under 2 KB): larger is dropped unread
UNPROVEN_MAX = 64  # early states kept for tokens not seen yet


class _Acceptance:
    """A published trajectory waiting for an adapter's word."""

    def __init__(self) -> None:
        self.done = threading.Event()
        self.adapter: str | None = None  # who accepted it
        self.by: str | None = None  # who last refused it, and why
        self.reason = ""
        self.error: dict[str, Any] | None = None  # ... and its error object
        self.rejections = 0


class Service:
    """Serves ``arms`` on ``session`` until :meth:`close`."""

    def __init__(
        self,
        session: zenoh.Session,
        arms: Mapping[str, Robot],
        *,
        prefix: str = "armd",
        limits: Limits | None = None,
        workers: int = 4,
    ) -> None:
        self.session = session
        # each arm copied (its solver state shared): the world verb changes this service's copy,
        # never the caller's robot (tests and embedders pass robots.load()'s, shared in-process)
        self.arms = {name: copy.copy(arm) for name, arm in arms.items()}
        self.prefix = prefix.rstrip("/")
        self.id = uuid.uuid4().hex[:12]
        self.book = StateBook()
        self._adapters: dict[str, set[str]] = {name: set() for name in self.arms}
        self._lock = threading.Lock()
        self._pending: dict[str, tuple[str, _Acceptance]] = {}  # trajectory id: (robot, its acceptance)
        self._seqs: dict[tuple[str, str], int] = {}  # (robot, adapter): the last sequence number seen under that id
        self._epochs: dict[
            tuple[str, str], int
        ] = {}  # (robot, adapter): the last epoch seen (where the arm is, set anew)
        self._disputed: dict[tuple[str, str], float] = {}  # (robot, adapter): when its numbers last went back
        self._payloads: dict[tuple[str, str], bytes] = {}  # (robot, adapter): the last message seen under that id
        self._unproven: dict[tuple[str, str], zenoh.Sample] = {}  # a state that came before its token
        self._ignored: dict[str, int] = {}  # states ignored, by reason
        self._said = 0.0  # when ignored states were last logged
        self.sensor_book = SensorBook(self.arms, self._is_live)
        self.handlers = Handlers(
            self.arms,
            self.book,
            limits or Limits(),
            self._publish,
            self._adapter_count,
            self._publish_gripper,
            self._publish_estop,
            sensor_book=self.sensor_book,
            end_tracking=self._end_tracking,
        )
        self._trackers: dict[str, Tracker] = {}  # each arm's tracking stream, made at its first put
        self._track_thread: int | None = None  # the thread Zenoh hands track puts to (raised at its first)
        self._pool = ThreadPoolExecutor(max_workers=workers, thread_name_prefix="armd-req")
        self._stops = ThreadPoolExecutor(max_workers=2, thread_name_prefix="armd-stop")  # never behind the queue
        self._commands = ThreadPoolExecutor(max_workers=2, thread_name_prefix="armd-move")  # nor behind batches
        # picks and places wait for the arm for seconds, detect for sweeps: never in the way of the rest
        self._sequences = ThreadPoolExecutor(max_workers=4, thread_name_prefix="armd-wait")
        # trajectories are never dropped under congestion (the default drops bursts)
        self._publishers = {
            name: session.declare_publisher(
                f"{self.prefix}/{name}/trajectory", encoding=JSON, congestion_control=zenoh.CongestionControl.BLOCK
            )
            for name in self.arms
        }
        self._served = 0
        self._errors = 0
        self._late = 0  # answered ``deadline``
        self._in_flight = 0  # handed to a pool, not yet answered
        # Every key this service answers, parsed once: a request finds its arm and verb with one
        # dict look-up. Any other key (a glob, an unknown robot or verb) takes the general path
        # in _dispatch, which names the error. Bounded: robots x verbs, never grown by requests.
        self._routes: dict[str, Route] = {f"{self.prefix}/robots": (None, "robots")}
        for name, arm in self.arms.items():
            for verb in VERBS:
                self._routes[f"{self.prefix}/{name}/{verb}"] = (arm, verb)
        # Warm up before declaring anything: a request that arrived during the warm-up would wait
        # behind the compiler (a minute on a cold cache) and time out, and with replicas this one
        # would take queries another could answer. Until it is declared, clients are told at once
        # that nothing serves the key, and other replicas answer.
        # The catalogue's arms take every compiled path, in a second or two: they are warmed up
        # first; any other arm (a user's, a vendor's with heavy meshes: a minute) is warmed up
        # after the service is declared, on a thread of its own, so that it delays nothing.
        catalogue = set(catalogue_names())
        first = {n: a for n, a in self.arms.items() if n in catalogue} or dict(list(self.arms.items())[:1])
        later = [a for n, a in self.arms.items() if n not in first]
        started = time.monotonic()
        log.info(
            "armd service %s warming up %s (compiling on a first start: about a minute)", self.id, ", ".join(first)
        )
        self._warm_up(first.values())
        log.info("warmed up in %.1f s", time.monotonic() - started)
        self._closed = threading.Event()  # (set by close(): a warm-up in the background stops)
        self._warming = threading.Thread(target=self._warm_later, args=(later,), name="armd-warm", daemon=True)
        # (which replica serves what changes the arms: docs/deployment.md; before the queryable)
        self._session = session
        self._queryable: Any = None
        self._queryable_lock = threading.Lock()
        self._closing = False
        self._switching = False
        self.replicas = Replicas(
            session,
            self.prefix,
            self.id,
            on_lead=self._lead,
            adopt=self._adopt_world,
            runtime=self._runtime_world,
        )
        self._lead(self.replicas.leading())
        self._entities: list[Any] = [
            session.declare_subscriber(f"{self.prefix}/*/state", self._on_state),
            session.declare_subscriber(f"{self.prefix}/*/events", self._on_event),
            session.declare_subscriber(f"{self.prefix}/*/track", self._on_track),
            session.declare_subscriber(f"{self.prefix}/*/estop", self._on_estop),
            session.declare_subscriber(
                f"{self.prefix}/*/sensors/*",
                lambda sample: self.sensor_book.on_reading(str(sample.key_expr), sample.payload.to_bytes()),
            ),
            session.liveliness().declare_subscriber(f"{self.prefix}/*/adapter/*", self._on_adapter, history=True),
            session.liveliness().declare_token(f"{self.prefix}/service/{self.id}"),
        ]
        log.info("armd service %s serving %s under %s/", self.id, ", ".join(self.arms), self.prefix)
        if later:
            self._warming.start()

    def _lead(self, leading: bool) -> None:
        """The queryable declared anew, *complete* while this replica leads (a default query
        reaches the complete one), not otherwise (it still hears queries asked of all). The
        new one is declared before the old goes (no moment without one), and while both are
        there only the complete one serves: a query both hear is served once."""
        with self._queryable_lock:
            if self._closing:
                return
            self._switching = True
            try:
                new = self._session.declare_queryable(
                    f"{self.prefix}/**", functools.partial(self._on_query_of, leading), complete=leading
                )
                old, self._queryable = self._queryable, new
                if old is not None:
                    old.undeclare()
            except Exception:  # the session closing
                log.debug("queryable not declared anew", exc_info=True)
            finally:
                self._switching = False

    def _on_query_of(self, complete: bool, query: zenoh.Query) -> None:
        if self._switching and not complete:  # (the complete one of this replica hears it too)
            return
        self._on_query(query)

    def _adopt_world(self, robot: str, obstacles: list[dict[str, Any]]) -> None:
        """Another replica's run-time obstacles of ``robot``, taken as this one's."""
        arm = self.arms.get(robot)
        if arm is None or arm.collision is None:
            return
        try:
            change = {"clear": True, "add": obstacles} if obstacles else {"clear": True}
            self.handlers.world(arm, change, Deadline(time.monotonic(), ADOPT_S))
        except ArmdError as e:
            log.warning("%s: the world another replica shared is not taken: %s", robot, e.message)
            return
        log.info("%s: %d run-time obstacles as another replica has them", robot, len(obstacles))

    def _runtime_world(self) -> dict[str, list[dict[str, Any]]]:
        """Each arm's run-time obstacles (not robot.toml's), as ``world``'s ``add`` takes them."""
        out = {}
        for name, arm in self.arms.items():
            if arm.collision is not None:
                out[name] = _runtime(self.handlers.world(arm, {}, Deadline(time.monotonic(), ADOPT_S)))
        return out

    def _warm_up(self, arms: Iterable[Robot]) -> None:
        """Compile (or load from Numba's cache) the solver's and the planner's code, and build each
        arm's solver state, now rather than on the first requests: compiling holds the GIL for
        seconds on a cold cache, and every request in flight would wait behind it. Each arm
        takes every path a request can: IK reachable and not, with an approach, batches with
        one approach and with one per target, joint plans from rest and while moving, a stop,
        a line."""
        for arm in arms:
            _warm_arm(arm)

    def _warm_later(self, arms: list[Robot]) -> None:
        """:meth:`_warm_up` of ``arms`` while the service serves (each is served meanwhile: a
        request of its own builds what it needs on the way), until :meth:`close`."""
        for arm in arms:
            started = time.monotonic()
            _warm_arm(arm, self._closed.is_set)
            if self._closed.is_set():
                return
            log.info("%s warmed up in %.1f s (in the background)", arm.name, time.monotonic() - started)

    # -- queries ------------------------------------------------------------------------

    def _on_query(self, query: zenoh.Query) -> None:
        arrived = time.monotonic()  # the deadline counts from here, queue included
        key_expr = query.key_expr  # (made once: the reply goes on it too)
        key = str(key_expr)
        payload = query.payload
        body = payload.to_bytes() if payload is not None else b""
        route = self._routes.get(key)
        if _quick(key, body, route):  # answered here, on this thread: no hand-over to a worker
            self._serve(query, key_expr, arrived, key, body, route, False)
            return
        pool = self._pool_for(key, route)
        with self._lock:
            self._in_flight += 1
        try:
            pool.submit(self._serve, query, key_expr, arrived, key, body, route, True)
        except RuntimeError:  # the pool is shut down: the service is closing
            with self._lock:
                self._in_flight -= 1
            query.drop()

    def _pool_for(self, key: str, route: Route | None) -> ThreadPoolExecutor:
        """``stop`` on a pool of its own; ``move`` and ``gripper`` on another (what moves the arm
        never waits behind IK batches and plans); everything else on the workers."""
        verb = (
            route[1]
            if route is not None
            else (key.rsplit("/", 1)[-1] if key.count("/") == self.prefix.count("/") + 2 else "")
        )
        if verb == "stop":
            return self._stops
        if verb in ("pick", "place", "detect"):  # (they wait: for the arm, for sweeps)
            return self._sequences
        return self._commands if verb in ("move", "gripper") else self._pool

    def _serve(
        self,
        query: zenoh.Query,
        key_expr: zenoh.KeyExpr,
        arrived: float,
        key: str,
        body: bytes,
        route: Route | None,
        pooled: bool,
    ) -> None:
        outcome = "error"
        try:
            with query:  # finalises the query when done: one reply, then the end
                try:
                    reply = self._dispatch(key, body, Deadline(arrived, self.handlers.limits.deadline), route)
                    if reply is None:  # (asked of every replica, it changes an arm: the leader's alone)
                        log.debug("%s: left to the leading replica", key)
                        outcome = "lost"  # (no reply: the query ends with the leader's alone)
                    else:
                        reply["service"] = self.id  # (which replica answered: for the operator, and the logs)
                        # (a reply travels with its query's congestion control: clients ask with BLOCK)
                        query.reply(key_expr, encode(reply), encoding=JSON)
                        outcome = "ok"
                except ArmdError as e:
                    query.reply_err(encode({**e.to_dict(), "service": self.id}), encoding=JSON)
                    outcome = "late" if isinstance(e, DeadlineExceeded) else "error"
                except Exception as e:  # a bug: logged with its traceback, answered, never fatal
                    log.exception("internal error serving %s", key)
                    err = Internal(f"internal error: {type(e).__name__}: {e}")
                    query.reply_err(encode({**err.to_dict(), "service": self.id}), encoding=JSON)
        except Exception:  # the query went away (client gone, session closing)
            log.debug("could not reply to %s", key, exc_info=True)
            outcome = "lost"
        finally:
            with self._lock:  # one acquisition per request: the counters move together
                if pooled:
                    self._in_flight -= 1
                if outcome != "lost":
                    self._served += 1
                    if outcome != "ok":
                        self._errors += 1
                        if outcome == "late":
                            self._late += 1
        if log.isEnabledFor(logging.DEBUG):  # (the level is looked up per request: it may be changed live)
            log.debug("%s %s in %.2f ms", key, outcome, (time.monotonic() - arrived) * 1e3)

    def _dispatch(
        self, key: str, payload: bytes, deadline: Deadline, route: Route | None = None
    ) -> dict[str, Any] | None:
        """The reply to a request, or None: no reply (one that changes an arm, heard by a
        replica that does not lead: :mod:`.replicas`)."""
        if route is None:  # not a key of ours as it stands: parsed here, and refused once the payload is read
            rest = key[len(self.prefix) + 1 :] if key.startswith(self.prefix + "/") else key
            parts = rest.split("/")
            urgent = len(parts) == 2 and parts[1] == "stop"
        else:
            rest, parts = key, []
            urgent = route[1] == "stop"
        if not urgent:  # a stop is never refused for lateness
            deadline.check("queued")
        unread: ArmdError | None = None
        if route is not None and route[1] == "world" and len(payload) > WORLD_BYTES:
            raise PayloadTooLarge(len(payload), WORLD_BYTES)  # (before it is parsed)
        try:
            req = decode(payload, self.handlers.limits)
        except ArmdError as e:
            if not (urgent and route is not None):
                raise
            req, unread = {}, e  # (a stop is never refused: the arm stops, the reply says why it was not read)
        asked = request_deadline(req)
        if asked is not None:
            deadline.shorten(asked)
            if not urgent:
                deadline.check("queued")
        if route is None:
            route = self._route(rest, parts)
        arm, verb = route
        if arm is None:
            return self._finish(self.handlers.robots(req, deadline), deadline)
        if changes(verb, req) and not self.replicas.leading():
            return None  # (asked of every replica: the leader executes it, once)
        handler = getattr(self.handlers, verb)
        result: dict[str, Any] = handler(arm, req, deadline)
        if unread is not None:
            result |= unread_request(unread)
        if verb == "world" and changes(verb, req):
            self.replicas.share(arm.name, _runtime(result))
        if verb in ("move", "stop", "gripper", "pick", "place"):  # published: the reply says so, however late
            return result
        return self._finish(result, deadline)

    def _route(self, rest: str, parts: list[str]) -> Route:
        """The arm and verb of a key that is not in the table, or the error that says why not."""
        if parts == ["robots"]:
            return None, "robots"
        if len(parts) != 2:
            raise UnknownVerb(rest, VERBS)
        name, verb = parts
        arm = self.arms.get(name)
        if arm is None:
            raise UnknownRobot(name, self.arms)
        if verb not in VERBS:
            raise UnknownVerb(verb, VERBS)
        return arm, verb

    @staticmethod
    def _finish(result: dict[str, Any], deadline: Deadline) -> dict[str, Any]:
        """A result that is ready after the deadline is not given: the client was told when to
        stop waiting."""
        deadline.check()
        return result

    # -- adapters ----------------------------------------------------------------------------

    def _publish(self, arm: Robot, message: dict[str, Any]) -> str:
        """Publish a trajectory and wait until a live adapter of ``arm`` accepts it: its id.
        Refused by every adapter: :class:`Rejected` with the reason. No answer in
        ``ACCEPT_TIMEOUT`` plus ``ACCEPT_PER_SAMPLE`` a sample: an estop (so that a late adapter
        does not move the arm after the caller was told it would not), then :class:`NoAdapter`."""
        ident = str(message["id"])
        wait = ACCEPT_TIMEOUT + ACCEPT_PER_SAMPLE * len(message.get("times", ()))
        waiter = _Acceptance()
        with self._lock:
            self._pending[ident] = (arm.name, waiter)
        try:
            self._publishers[arm.name].put(encode(message))
            if not waiter.done.wait(wait):
                self._publish_estop(
                    arm, {"id": uuid.uuid4().hex, "by": "service", "reason": f"no adapter accepted trajectory {ident}"}
                )
                raise NoAdapter(
                    f"no adapter of {arm.name} accepted the trajectory within {wait:.1f} s "
                    "(an estop was sent, so that a late one does not move the arm)",
                    robot=arm.name,
                )
        finally:
            with self._lock:
                self._pending.pop(ident, None)
        if waiter.adapter is None:
            raise Rejected(
                f"{arm.name}'s adapter refused the trajectory: {waiter.reason}",
                robot=arm.name,
                adapter=waiter.by,
                reason=waiter.reason,
                error=waiter.error,
            )
        return waiter.adapter

    def _on_event(self, sample: zenoh.Sample) -> None:
        """Adapters' events: an ``accepted`` or ``rejected`` of a trajectory a ``move`` waits for."""
        if len(sample.payload) > REPORT_BYTES:  # (not copied, not parsed)
            return
        try:
            msg = orjson.loads(sample.payload.to_bytes())
            event, ident, adapter = msg.get("event"), msg.get("id"), msg.get("adapter")
        except (orjson.JSONDecodeError, AttributeError):
            return
        robot = str(sample.key_expr).split("/")[-2]
        # a stop (an estop's, a fault's): a pick or place under way ends there (a trajectory replaced
        # by the next one is no stop: a sequence's next step may come before its adapter said done)
        stopped = event == "accepted" and msg.get("trajectory") == "stop"
        aborted = event == "aborted" and not str(msg.get("reason", "")).startswith("replaced by")
        if (stopped or aborted) and self._is_live(robot, str(adapter)):
            self.handlers.note_stop(robot)
        if event in ("rejected", "aborted") and isinstance(ident, str) and self._is_live(robot, str(adapter)):
            tracker = self._trackers.get(robot)
            if tracker is not None:
                error = msg.get("error")
                tracker.adapter_said(
                    event, ident, str(msg.get("reason", "no reason given")), error if isinstance(error, dict) else None
                )
        if event not in ("accepted", "rejected") or not isinstance(ident, str) or not isinstance(adapter, str):
            return
        with self._lock:
            pending = self._pending.get(ident)
            live = adapter in self._adapters.get(robot, ())
            if pending is None or pending[0] != robot or not live:
                return
            waiter = pending[1]
            if event == "accepted":
                waiter.adapter = adapter
                waiter.done.set()
            else:
                waiter.by, waiter.reason = adapter, str(msg.get("reason", "no reason given"))
                error = msg.get("error")
                waiter.error = error if isinstance(error, dict) else None
                waiter.rejections += 1
                if waiter.rejections >= len(self._adapters.get(robot, ())):  # every live adapter said no
                    waiter.done.set()

    # -- tracking streams --------------------------------------------------------------------

    def _on_track(self, sample: zenoh.Sample) -> None:
        """A put on ``<prefix>/<robot>/track``: to the arm's :class:`Tracker` (the leading
        replica's alone: one service drives an arm). Zenoh hands a subscriber's samples to a
        thread of its own: this one is raised to the streams' priority at its first put, so that
        a guest's flood of requests (their threads at normal priority, Python's lock handed over
        every SWITCH_INTERVAL) does not hold a put back."""
        if self._track_thread != threading.get_ident():
            self._track_thread = threading.get_ident()
            ahead_of_requests("the thread that takes track puts")
        robot = str(sample.key_expr).split("/")[-2]
        arm = self.arms.get(robot)
        if arm is None or not self.replicas.leading():
            return
        tracker = self._tracker(arm)
        if tracker is None:
            return
        size = len(sample.payload)
        if size > TRACK_BYTES:  # (not copied, not parsed)
            tracker.say("bad_request", "payload", f"a track put has at most {TRACK_BYTES} bytes, this one {size}")
            return
        tracker.put(sample.payload.to_bytes())

    def _tracker(self, arm: Robot) -> Tracker | None:
        with self._lock:
            tracker = self._trackers.get(arm.name)
            if tracker is None and not self._closing:
                publisher = self._publishers[arm.name]
                events = f"{self.prefix}/{arm.name}/events"
                tracker = Tracker(
                    arm,
                    publish=lambda msg: publisher.put(encode(msg)),
                    publish_gripper=lambda msg: self._publish_gripper(arm, msg),
                    event=lambda msg: self.session.put(
                        events,
                        encode({**msg, "robot": arm.name, "service": self.id, "time": time.time()}),
                        encoding=JSON,
                    ),
                    current=lambda: self.book.current(arm),
                    adapters=lambda: self._adapter_count(arm),
                )
                self._trackers[arm.name] = tracker
        return tracker

    def _on_estop(self, sample: zenoh.Sample) -> None:
        """Any estop of an arm (whoever put it) ends its tracking stream."""
        self._end_tracking(str(sample.key_expr).split("/")[-2], "estop")

    def _end_tracking(self, robot: str, reason: str) -> None:
        tracker = self._trackers.get(robot)
        if tracker is not None:
            tracker.end(reason)

    def _publish_estop(self, arm: Robot, message: dict[str, Any]) -> None:
        self.session.put(
            f"{self.prefix}/{arm.name}/estop",
            encode(message),
            encoding=JSON,
            congestion_control=zenoh.CongestionControl.BLOCK,
            priority=zenoh.Priority.REAL_TIME,
        )

    def _publish_gripper(self, arm: Robot, message: dict[str, Any]) -> None:
        self.session.put(
            f"{self.prefix}/{arm.name}/gripper",
            encode(message),
            encoding=JSON,
            congestion_control=zenoh.CongestionControl.BLOCK,
        )

    def _is_live(self, robot: str, adapter: str) -> bool:
        with self._lock:
            return adapter in self._adapters.get(robot, ())

    def _adapter_count(self, arm: Robot) -> int:
        with self._lock:
            return len(self._adapters.get(arm.name, ()))

    def _on_adapter(self, sample: zenoh.Sample) -> None:
        parts = str(sample.key_expr).split("/")
        if len(parts) < 3:
            return
        robot, ident = parts[-3], parts[-1]
        with self._lock:
            alive = self._adapters.setdefault(robot, set())
            if sample.kind == zenoh.SampleKind.PUT:
                alive.add(ident)
                early = self._unproven.pop((robot, ident), None)
            else:
                alive.discard(ident)
                early = None
        if sample.kind != zenoh.SampleKind.PUT:
            self.book.forget(robot, ident)
            with self._lock:
                self._seqs.pop((robot, ident), None)
                self._epochs.pop((robot, ident), None)
                self._disputed.pop((robot, ident), None)
                self._payloads.pop((robot, ident), None)
        elif early is not None:  # its state came before its token: trusted now, if still fresh
            self._on_state(early)
        log.info("adapter %s of %s %s", ident, robot, "up" if sample.kind == zenoh.SampleKind.PUT else "gone")

    def _on_state(self, sample: zenoh.Sample) -> None:
        """An adapter's state, trusted only from a live adapter (its liveliness token), in order
        (its sequence number), and plausible: within the limits (with a slack), its speed within
        them, and continuous with that adapter's last report. Anything else is ignored, counted,
        and logged at most every ``SAY_EVERY`` seconds.

        The id is no secret (every report carries it): a forger may publish under it. One
        publisher's numbers only rise (Zenoh delivers a publisher's puts in order), so a number
        not above the last one seen under the id, whatever else that report said, means a
        second publisher or a replay (the very same message twice is a double delivery, and
        dropped): the id is disputed, what it said before is forgotten (it may have been the
        forger's), and none of its reports is believed until its numbers have risen for
        ``DISPUTE_HOLD`` seconds; meanwhile moves plan from what was commanded, which the
        adapter checks against where the arm is. A forged report numbered ahead may be
        believed until the adapter's next one (20 ms at 50 Hz), within the continuity slack;
        then it is forgotten. It never locks the adapter out."""
        robot = str(sample.key_expr).split("/")[-2]
        arm = self.arms.get(robot)
        if arm is None:
            return
        if len(sample.payload) > REPORT_BYTES:  # (not copied, not parsed)
            self._ignore(robot, "too large")
            return
        try:
            msg = orjson.loads(sample.payload.to_bytes())
            adapter, seq, epoch = msg["adapter"], msg["seq"], msg.get("epoch", 0)
            if not isinstance(adapter, str) or not all(
                isinstance(n, int) and not isinstance(n, bool) for n in (seq, epoch)
            ):
                raise ValueError("no adapter id, sequence number or epoch")
            state = reported_state(arm, msg)
        except (ValueError, KeyError, TypeError, AttributeError, orjson.JSONDecodeError):
            self._ignore(robot, "malformed")
            return
        disputed = anew = False
        with self._lock:
            if adapter not in self._adapters.get(robot, ()):
                if len(self._unproven) < UNPROVEN_MAX or (robot, adapter) in self._unproven:
                    self._unproven[(robot, adapter)] = sample
                known = False
            else:
                known = True
                key = (robot, adapter)
                last_seq = self._seqs.get(key)
                payload = sample.payload.to_bytes()
                if last_seq == seq and self._payloads.get(key) == payload:
                    return  # the same message delivered twice (Zenoh may, over two routes): nobody else's
                last_epoch = self._epochs.get(key)
                self._seqs[key] = seq
                self._epochs[key] = epoch
                self._payloads[key] = payload
                now = time.monotonic()
                # (an adapter's epochs, like its numbers, only rise: one that falls is a second publisher)
                began = last_seq is not None and (seq <= last_seq or epoch < (last_epoch or 0))
                anew = last_epoch is not None and epoch > last_epoch
                if began:
                    self._disputed[key] = now
                disputed = now - self._disputed.get(key, -math.inf) < DISPUTE_HOLD
        if not known:
            self._ignore(robot, "no live adapter of that id")
            return
        if disputed:
            if began:  # what it said before may have been the forger's: forgotten
                self.book.forget(robot, adapter)
                log.warning(
                    "adapter %s of %s: two publishers under its id, or a replay: not believed for %g s",
                    adapter,
                    robot,
                    DISPUTE_HOLD,
                )
            self._ignore(robot, "numbered out of order under a live adapter's id (a second publisher or a replay)")
            return
        why = implausible(arm, state)
        if why is not None:
            self._ignore(robot, why)
            return
        lim, q = arm.limits, state.position
        last = self.book.last(robot, adapter)
        now = self.book.now()
        if last is not None and not anew:  # (a new epoch: where the arm is was set anew, a jump is no fault)
            dt = now - last[0]
            if np.any(np.abs(q - last[1].position) > lim.velocity * (dt + SETTLE) + JUMP_SLACK) and dt < RESET_AFTER:
                self._ignore(robot, "not continuous with its last report")
                return
        homed = msg.get("homed", True) is not False
        self.book.report(robot, state, bool(msg.get("moving", False)), homed, adapter=adapter)

    def _ignore(self, robot: str, why: str) -> None:
        with self._lock:
            self._ignored[why] = self._ignored.get(why, 0) + 1
            now = time.monotonic()
            if now - self._said < SAY_EVERY:
                return
            self._said = now
            counts = ", ".join(f"{n} {reason}" for reason, n in sorted(self._ignored.items()))
        log.warning("ignoring states on %s/%s/state (so far, by reason: %s)", self.prefix, robot, counts)

    # -- life ------------------------------------------------------------------------------

    def stats(self) -> dict[str, int]:
        """Requests ``served`` (answered), of them ``errors`` (error replies) and ``late``
        (answered ``deadline``), and ``in_flight``: handed to a pool and not answered yet."""
        with self._lock:
            return {
                "served": self._served,
                "errors": self._errors,
                "late": self._late,
                "in_flight": self._in_flight,
                "states_ignored": sum(self._ignored.values()),
            }

    def close(self) -> None:
        self._closed.set()
        self.replicas.close()
        with self._queryable_lock:
            queryable, self._queryable, self._closing = self._queryable, None, True
        with self._lock:
            trackers = list(self._trackers.values())
        for tracker in trackers:
            tracker.close()
        if queryable is not None:
            try:
                queryable.undeclare()
            except Exception:
                log.debug("undeclare failed", exc_info=True)
        for entity in self._entities:
            try:
                entity.undeclare()
            except Exception:  # already gone with the session
                log.debug("undeclare failed", exc_info=True)
        for pub in self._publishers.values():
            try:
                pub.undeclare()
            except Exception:
                log.debug("undeclare failed", exc_info=True)
        self._pool.shutdown(wait=True, cancel_futures=True)
        self._stops.shutdown(wait=True, cancel_futures=True)
        self._commands.shutdown(wait=True, cancel_futures=True)
        self._sequences.shutdown(wait=True, cancel_futures=True)
        log.info("armd service %s closed: %s", self.id, self.stats())


def _runtime(world_reply: Mapping[str, Any]) -> list[dict[str, Any]]:
    """The run-time obstacles of a ``world`` reply (robot.toml's are fixed), as ``add`` takes them."""
    world = world_reply.get("world") or {}
    fixed = set(world_reply.get("fixed", ()))
    return [o for o in world.get("obstacles", ()) if o["name"] not in fixed]


def _quick(key: str, body: bytes, route: Route | None) -> bool:
    """A request short enough to answer on the thread that received it (microseconds to a
    couple of milliseconds): fk, info, robots, and IK of one target. Handing it to a worker
    would cost more than the work; everything else queues for the workers."""
    verb = route[1] if route is not None else key[key.rfind("/") + 1 :]
    if verb in ("fk", "info", "robots"):
        return True
    return verb == "ik" and len(body) <= QUICK_BYTES and b'"targets"' not in body


def _attempt(fn: Any, *args: Any, **kwargs: Any) -> Any:
    """``fn(*args, **kwargs)``, or None where it refuses (a warm-up path an arm does not take),
    or fails (a bug on one arm's path: logged with its traceback; the other arms are served)."""
    try:
        return fn(*args, **kwargs)
    except ArmdError:
        return None
    except Exception:
        log.exception("warming up %s failed (the arm is served; requests on this path may fail)", fn.__name__)
        return None


def _warm_arm(arm: Robot, stop: Callable[[], bool] = lambda: False) -> None:
    """Every path a request can take on ``arm`` (:meth:`Service._warm_up`); ``stop()``, asked
    between paths, ends it early."""
    from armd import planning, solvers

    def attempt(fn: Any, *args: Any, **kwargs: Any) -> Any:
        return None if stop() else _attempt(fn, *args, **kwargs)

    home = arm.fk(arm.neutral)
    far = 10.0 * home + 1.0  # unreachable: the closest-point code and the arm's atlas
    attempt(solvers.solve_ik, arm, home)
    attempt(solvers.solve_ik, arm, far)
    attempt(solvers.solve_ik_batch, arm, [home, far])
    if arm.geometry is not None and arm.geometry.has_wrist:
        attempt(solvers.solve_ik, arm, home, approach="parallel")
        attempt(solvers.solve_ik, arm, far, approach="perpendicular")
        attempt(solvers.solve_ik_batch, arm, [home, home], approach=[0.0, 0.1])
    mid = (arm.limits.lower + arm.limits.upper) / 2
    if arm.limits.contains(mid):
        there = attempt(planning.plan, arm, arm.neutral, mid)
        if there is not None:
            attempt(planning.plan_stop, arm, there.at(0.2))
            attempt(planning.plan, arm, there.at(0.2), arm.neutral)  # from a moving state
    attempt(planning.plan, arm, arm.neutral, {"target": (home - 0.01).tolist()}, path="line")
