"""Two service replicas on one Zenoh network: each request answered exactly once; one dies,
the other keeps answering."""

from __future__ import annotations

import time

import zenoh

from armd import robots
from armd.clients import ArmClient
from armd.service.server import Service
from armd.service.zconfig import network_config
from tests.conftest import wait_for


def test_two_replicas_answer_each_request_once(router: str) -> None:
    arms = {n: robots.load(n) for n in ("gupta3", "sg5ut")}
    sessions = [zenoh.open(network_config(connect=[router])) for _ in range(2)]
    replicas = [Service(s, arms, prefix="replicated") for s in sessions]
    try:
        with ArmClient(router, prefix="replicated", timeout=10.0) as c:
            for i in range(60):
                replies = list(c.session.get("replicated/gupta3/fk", payload=b'{"q": [0, 1, -1]}', timeout=10.0))
                assert len(replies) == 1 and replies[0].ok is not None, i
            # each request processed by exactly one replica (counted just after its reply is sent)
            wait_for(lambda: sum(r.stats()["served"] for r in replicas) >= 60, timeout=2, what="the counts")
            time.sleep(0.1)
            served = [r.stats()["served"] for r in replicas]
            assert sum(served) == 60
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
