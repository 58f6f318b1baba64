"""Two service replicas on one Zenoh network: each request answered exactly once; one dies,
the other keeps answering."""

from __future__ import annotations

import contextlib
import time
from collections.abc import Iterator

import orjson
import zenoh

from armd import robots
from armd.adapters.sim import SimAdapter
from armd.clients import ArmClient
from armd.service.server import Service
from armd.service.zconfig import network_config
from tests.conftest import collect, wait_for


def test_two_replicas_answer_each_request_once(router: str) -> None:
    arms = {n: robots.load(n) for n in ("gupta3", "sg5ut")}
    sessions = [zenoh.open(network_config(connect=[router])) for _ in range(2)]
    replicas = [Service(s, arms, prefix="replicated") for s in sessions]
    try:
        with ArmClient(router, prefix="replicated", timeout=10.0) as c:

            def ask() -> list[zenoh.Reply]:
                return list(c.session.get("replicated/gupta3/fk", payload=b'{"q": [0, 1, -1]}', timeout=10.0))

            # (the replicas' queryables reach the router a moment after they start: on a busy
            # machine the first get may find none; from the first answer on, each is counted)
            wait_for(lambda: len(ask()) == 1, timeout=10, what="a replica answering")
            time.sleep(0.1)
            before = sum(r.stats()["served"] for r in replicas)
            for i in range(60):
                replies = ask()
                assert len(replies) == 1 and replies[0].ok is not None, i
            # each request processed by exactly one replica (counted just after its reply is sent)
            wait_for(lambda: sum(r.stats()["served"] for r in replicas) >= before + 60, timeout=2, what="the counts")
            time.sleep(0.1)
            served = [r.stats()["served"] for r in replicas]
            assert sum(served) == before + 60
            # the replica that answered goes away; the other answers from then on
            busy = served.index(max(served))
            replicas[busy].close()
            sessions[busy].close()
            for _ in range(20):
                assert c.fk("gupta3", [0.0, 1.0, -1.0]).within_limits
            other = replicas[1 - busy].stats()["served"]
            assert other >= served[1 - busy] + 20
    finally:
        for r, s in zip(replicas, sessions, strict=True):
            try:
                r.close()
                s.close()
            except Exception:  # already closed
                pass


@contextlib.contextmanager
def replicated(router: str, n: int, arms: dict[str, robots.Robot]) -> Iterator[list[tuple[Service, zenoh.Session]]]:
    """``n`` replicas of one service on the router, closed at the end (those still open)."""
    out: list[tuple[Service, zenoh.Session]] = []
    try:
        for _ in range(n):
            session = zenoh.open(network_config(connect=[router]))
            out.append((Service(session, arms, prefix="replicated"), session))
        yield out
    finally:
        for service, session in out:
            with contextlib.suppress(Exception):  # (closed by the test already)
                service.close()
            with contextlib.suppress(Exception):
                session.close()


def test_a_move_asked_of_every_replica_runs_once(router: str) -> None:
    """The red team's: one ``move`` asked of ALL replicas published two trajectories (the second
    replaced the first). The leader (the smallest id) executes it; the other says nothing to a
    verb that changes the arm, and answers one that reads."""
    arm = robots.load("gupta3")
    with replicated(router, 2, {"gupta3": arm}) as reps:
        sim_session = zenoh.open(network_config(connect=[router]))
        sim = SimAdapter(sim_session, arm, prefix="replicated", time_scale=5.0)
        try:
            with ArmClient(router, prefix="replicated", timeout=10.0) as c:
                wait_for(lambda: all(s._adapter_count(arm) == 1 for s, _ in reps), what="the adapter")  # type: ignore[attr-defined]
                time.sleep(0.3)  # (each has heard of the other)
                trajectories, sub = collect(c, "replicated/gupta3/trajectory")
                body = orjson.dumps({"goal": [0.4, 1.1, -1.0]})
                replies = list(
                    c.session.get("replicated/gupta3/move", payload=body, target=zenoh.QueryTarget.ALL, timeout=10.0)
                )
                time.sleep(0.5)
                sub.undeclare()  # type: ignore[attr-defined]
                assert len(trajectories) == 1, [t.get("id") for t in trajectories]
                said = [orjson.loads(r.ok.payload.to_bytes()) for r in replies if r.ok is not None]
                assert [r["service"] for r in said] == [min(s.id for s, _ in reps)], said  # (the leader)
                # one that reads: both answer (nothing happens twice)
                fk = orjson.dumps({"q": [0.0, 1.0, -1.0]})
                got = list(c.session.get("replicated/gupta3/fk", payload=fk, target=zenoh.QueryTarget.ALL, timeout=5))
                assert all(r.ok is not None for r in got) and got
        finally:
            sim.close()
            sim_session.close()


def test_run_time_obstacles_are_shared_and_outlive_the_replica_that_took_them(router: str) -> None:
    """The red team's: an obstacle added on a replica vanished when it died, and the other
    planned through it. The leader shares the arm's run-time obstacles; after it dies the other
    has them, and so does a replica that joins later."""
    arm = robots.load("gupta3")
    box = {"name": "crate", "shape": "box", "size": [0.1, 0.1, 0.1], "position": [0.25, 0.0, 0.05]}
    with replicated(router, 2, {"gupta3": arm}) as reps, ArmClient(router, prefix="replicated", timeout=10.0) as c:
        time.sleep(0.3)  # (each has heard of the other)
        reply = c.world("gupta3", add=[box])
        names = lambda s: {o.name for o in s.arms["gupta3"].collision.obstacles}  # noqa: E731
        wait_for(lambda: all("crate" in names(s) for s, _ in reps), timeout=5, what="the world shared")
        took = next(i for i, (s, _) in enumerate(reps) if s.id == reply["service"])
        reps[took][0].close()
        reps[took][1].close()
        other = reps[1 - took][0]
        listed = c.world("gupta3")
        assert listed["service"] == other.id and "crate" in [o["name"] for o in listed["world"]["obstacles"]]
        # a replica that joins now gets it too
        session = zenoh.open(network_config(connect=[router]))
        late = Service(session, {"gupta3": arm}, prefix="replicated")
        try:
            wait_for(lambda: "crate" in names(late), timeout=5, what="the newcomer has the world")
        finally:
            late.close()
            session.close()
