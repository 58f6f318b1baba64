"""Replicas of one service (the same arms under the same prefix): who serves what changes the
world, and the run-time world they share.

- **One request, served once.** Every replica declares its liveliness token
  ``<prefix>/service/<id>``; each follows the others' and agrees, from the same set, on the
  one that serves: the live replica with the smallest id (the *leader*). The leader declares
  its queryable *complete*, the others not: a query with Zenoh's default target
  (``BEST_MATCHING``) reaches only the complete one, the leader. A query asked of ``ALL``
  reaches every replica: the followers answer what only reads (``info``, ``fk``, ``ik``,
  ``plan``, ``detect``, a ``world`` listed) and ``stop`` (a stop twice is a stop), and say
  nothing to a verb that changes something (``move``, ``gripper``, ``pick``, ``place``, a
  ``world`` changed): the leader alone executes it, once.
- **The run-time world, shared.** After a ``world`` change the leader puts the arm's run-time
  obstacles (all of them, as ``world``'s ``add`` takes them) on ``<prefix>/<robot>/obstacles``;
  every other replica takes them as its own. When a replica joins, every replica puts its
  run-time obstacles again, so the newcomer has them before it may lead; when the leader dies,
  the next one has them already.

What it cannot do: the replicas see a join or a death at slightly different moments (the
liveliness of Zenoh, milliseconds on one network; a frozen machine's token lasts its lease, 10
s by default). In that window two replicas may both lead (an ``ALL`` query then runs twice) or
none (a default query reaches the non-complete queryables, and the one that counts itself the
leader serves it). docs/deployment.md says so.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable, Mapping
from typing import Any

import orjson
import zenoh

log = logging.getLogger(__name__)

CHANGES = frozenset({"move", "gripper", "pick", "place"})  # the verbs a follower leaves to the leader
OBSTACLES_BYTES = 256 * 1024  # a shared world's message, at most (64 obstacles: about 10 KB)
WHO_TIMEOUT = 2.0  # [s] the most a start waits to hear which replicas are alive


def changes(verb: str, req: Mapping[str, Any]) -> bool:
    """Whether a request of ``verb`` changes something only one replica may change."""
    return verb in CHANGES or (verb == "world" and bool(req.get("add") or req.get("remove") or req.get("clear")))


class Replicas:
    """This replica's view of the others: :meth:`leading`, and the shared run-time world.

    ``on_lead(leading)`` is called when this replica starts or stops leading; ``adopt(robot,
    obstacles)`` when another replica shares an arm's run-time obstacles; ``runtime()`` gives
    this replica's, by arm, to share when one joins."""

    def __init__(
        self,
        session: zenoh.Session,
        prefix: str,
        me: str,
        *,
        on_lead: Callable[[bool], None],
        adopt: Callable[[str, list[dict[str, Any]]], None],
        runtime: Callable[[], Mapping[str, list[dict[str, Any]]]],
    ) -> None:
        self.prefix, self.me = prefix, me
        self._on_lead, self._adopt, self._runtime = on_lead, adopt, runtime
        self._lock = threading.Lock()
        self._live: set[str] = {me}
        self._leading = True
        self._session = session
        self._subs: list[Any] = [
            session.declare_subscriber(f"{prefix}/*/obstacles", self._on_obstacles),
            session.liveliness().declare_subscriber(f"{prefix}/service/*", self._on_replica, history=True),
        ]
        # (the replicas alive now, asked before this one declares its queryable: it must not
        # take itself for the leader while the others' tokens are on their way)
        for reply in session.liveliness().get(f"{prefix}/service/*", timeout=WHO_TIMEOUT):
            if reply.ok is not None:
                self._on_replica(reply.ok)

    def leading(self) -> bool:
        with self._lock:
            return self._leading

    def others(self) -> list[str]:
        with self._lock:
            return sorted(self._live - {self.me})

    def share(self, robot: str, obstacles: list[dict[str, Any]]) -> None:
        """Put an arm's run-time obstacles for the other replicas (after a change here)."""
        try:
            self._session.put(
                f"{self.prefix}/{robot}/obstacles",
                orjson.dumps({"service": self.me, "robot": robot, "obstacles": obstacles}),
                congestion_control=zenoh.CongestionControl.BLOCK,
            )
        except zenoh.ZError:  # (the session closing)
            log.debug("could not share %s's obstacles", robot, exc_info=True)

    def _on_replica(self, sample: zenoh.Sample) -> None:
        ident = str(sample.key_expr).rsplit("/", 1)[-1]
        joined = False
        with self._lock:
            if sample.kind == zenoh.SampleKind.PUT:
                joined = ident not in self._live
                self._live.add(ident)
            else:
                self._live.discard(ident)
            self._live.add(self.me)
            leading = self.me == min(self._live)
            flipped, self._leading = leading != self._leading, leading
        if flipped:
            log.info(
                "replica %s %s (replicas: %s)",
                self.me,
                "now serves what changes the arms" if leading else f"leaves what changes the arms to {min(self._live)}",
                ", ".join(sorted(self._live)),
            )
            self._on_lead(leading)
        if joined and ident != self.me:  # (a newcomer gets the world before it may lead)
            for robot, obstacles in self._runtime().items():
                self.share(robot, obstacles)

    def _on_obstacles(self, sample: zenoh.Sample) -> None:
        if len(sample.payload) > OBSTACLES_BYTES:
            return
        try:
            msg = orjson.loads(sample.payload.to_bytes())
            sender, obstacles = msg["service"], msg["obstacles"]
            if not isinstance(obstacles, list):
                raise TypeError("obstacles must be a list")
            robot = str(sample.key_expr).split("/")[-2]
        except (orjson.JSONDecodeError, KeyError, TypeError) as e:
            log.warning("ignoring a shared world on %s: %s", sample.key_expr, e)
            return
        with self._lock:
            known = sender in self._live and sender != self.me
        if not known:  # (this replica's own, or from no live replica)
            return
        self._adopt(robot, obstacles)

    def close(self) -> None:
        for sub in self._subs:
            try:
                sub.undeclare()
            except Exception:  # already gone with the session
                log.debug("undeclare failed", exc_info=True)
