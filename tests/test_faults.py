"""Faults: a router restarted under a service and an adapter; a service restarted under
its adapters and clients; a client timeout; clients that leave mid-request."""

from __future__ import annotations

import json
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import zenoh

from armd import robots, solvers
from armd.adapters.sim import SimAdapter
from armd.clients import ArmClient
from armd.errors import NoReply
from armd.service.protocol import Limits
from armd.service.server import Service
from armd.service.zconfig import network_config
from tests.conftest import free_port, wait_for

ROOT = Path(__file__).resolve().parent.parent


def test_router_restart_under_service_and_adapter() -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    arm = robots.load("gupta3")
    router = zenoh.open(network_config(listen=[endpoint], mode="router"))
    svc_session = zenoh.open(network_config(connect=[endpoint]))
    service = Service(svc_session, {"gupta3": arm})
    sim_session = zenoh.open(network_config(connect=[endpoint]))
    sim = SimAdapter(sim_session, arm, time_scale=5.0)
    client = ArmClient(endpoint, timeout=5.0)
    try:
        wait_for(lambda: service._adapter_count(arm) == 1, what="the adapter")
        assert client.fk("gupta3", [0, 1, -1]).within_limits
        router.close()  # the router goes away ...
        time.sleep(0.5)
        router = zenoh.open(network_config(listen=[endpoint], mode="router"))  # ... and comes back
        deadline = time.monotonic() + 10
        while True:  # everyone reconnects and re-declares by themselves
            try:
                assert client.fk("gupta3", [0, 1, -1]).within_limits
                break
            except NoReply:
                assert time.monotonic() < deadline, "no answer 10 s after the router came back"
                time.sleep(0.2)
        wait_for(lambda: service._adapter_count(arm) == 1, timeout=10, what="the adapter's token again")
        client.move("gupta3", [0.3, 1.1, -1.2], wait=True, wait_timeout=10)
        assert np.allclose(sim.position, [0.3, 1.1, -1.2], atol=1e-9)
    finally:
        client.close()
        sim.close()
        sim_session.close()
        service.close()
        svc_session.close()
        router.close()


def test_service_restart_under_adapters_and_clients(router: str) -> None:
    arm = robots.load("sg5ut")
    sim_session = zenoh.open(network_config(connect=[router]))
    sim = SimAdapter(sim_session, arm, prefix="restart", time_scale=5.0)
    client = ArmClient(router, prefix="restart", timeout=5.0)
    session = zenoh.open(network_config(connect=[router]))
    service = Service(session, {"sg5ut": arm}, prefix="restart")
    try:
        wait_for(lambda: service._adapter_count(arm) == 1, what="the adapter")
        goal = [0.4, 1.2, -0.6, -0.5]
        client.move("sg5ut", goal, wait=True, wait_timeout=10)
        service.close()  # the service goes away; adapters and clients stay up
        session.close()
        with pytest.raises(NoReply):
            client.info("sg5ut")
        session = zenoh.open(network_config(connect=[router]))
        service = Service(session, {"sg5ut": arm}, prefix="restart")  # a new service: it knows nothing yet
        wait_for(lambda: service._adapter_count(arm) == 1, what="the adapter, seen again")
        wait_for(lambda: client.state("sg5ut")["source"] == "adapter", what="the state, re-learnt")
        assert np.allclose(client.state("sg5ut")["position"], goal, atol=1e-9)  # from the adapter, not neutral
        r = client.move("sg5ut", [0.0, 1.3, -0.7, -0.6], wait=True, wait_timeout=10)
        assert r.start_source == "adapter"
    finally:
        client.close()
        sim.close()
        sim_session.close()
        service.close()
        session.close()


def test_client_timeout_is_a_typed_error() -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    router = zenoh.open(network_config(listen=[endpoint], mode="router"))  # a network with no service on it
    try:
        with ArmClient(endpoint, timeout=0.5) as c:
            t0 = time.monotonic()
            with pytest.raises(NoReply):
                c.robots()
            assert time.monotonic() - t0 < 5
    finally:
        router.close()


LEAVER = """
import sys, zenoh
from armd.service.zconfig import client_config
session = zenoh.open(client_config([sys.argv[1]]))
# until the router has told this new session of the service's queryable, a get finds no route and
# is sent nowhere: ask something quick first
prefix = sys.argv[2].split("/")[0]
for _ in range(100):
    if any(r.ok is not None for r in session.get(prefix + "/robots", timeout=1.0)):
        break
pending = session.get(sys.argv[2], payload=open(sys.argv[3], "rb").read(), timeout=60.0,
                      congestion_control=zenoh.CongestionControl.BLOCK)  # (DROP may lose a big one: protocol.md)
print("sent", flush=True)
sys.stdin.readline()  # until told to leave (or killed)
session.close()
print("left", flush=True)
"""


def _leaver(endpoint: str, key: str, request: dict[str, object], tmp_path: Path) -> subprocess.Popen[str]:
    """A client process that sends one request and leaves before its reply: killed, or told to
    close its session."""
    payload = tmp_path / f"{key.replace('/', '_')}.json"
    payload.write_text(json.dumps(request))
    proc = subprocess.Popen(
        [sys.executable, "-c", LEAVER, endpoint, key, str(payload)],
        cwd=ROOT,
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )
    assert proc.stdout is not None and proc.stdout.readline().strip() == "sent"
    return proc


def test_a_client_that_leaves_mid_request(router: str, tmp_path: Path) -> None:
    """A client killed while its slow IK batch is worked on, another that closes its session
    while its move is planned: the service keeps answering everyone else correctly, the IK
    publishes nothing, the accepted move is published (and can be stopped), and afterwards
    nothing is left in flight or queued and the service has no more threads than its pools."""
    arm = robots.load("gupta3")
    session = zenoh.open(network_config(connect=[router]))
    service = Service(session, {"gupta3": arm}, prefix="leave", limits=Limits(max_samples=200_000))
    sim = SimAdapter(session, arm, prefix="leave", time_scale=1.0)
    published: list[dict[str, object]] = []
    sub = session.declare_subscriber(
        "leave/gupta3/trajectory", lambda s: published.append(json.loads(s.payload.to_bytes()))
    )
    events: list[dict[str, object]] = []
    events_sub = session.declare_subscriber(
        "leave/gupta3/events", lambda s: events.append(json.loads(s.payload.to_bytes()))
    )
    estops: list[dict[str, object]] = []
    estop_sub = session.declare_subscriber(
        "leave/gupta3/estop", lambda s: estops.append(json.loads(s.payload.to_bytes()))
    )
    client = ArmClient(router, prefix="leave", timeout=10.0)
    killed = closed = None
    try:
        wait_for(lambda: service._adapter_count(arm) == 1, what="the adapter")
        # 1. killed while its IK batch (6,000 unreachable targets, 1.5 s of its deadline) is worked on
        rng = np.random.default_rng(5)
        d = rng.normal(size=(6_000, 3))
        far = np.round(0.8 * d / np.linalg.norm(d, axis=1)[:, None], 6).tolist()
        killed = _leaver(router, "leave/gupta3/ik", {"targets": far, "deadline": 1.5}, tmp_path)
        wait_for(lambda: service.stats()["in_flight"] >= 1, timeout=30, what="the batch to arrive")
        killed.kill()
        killed.wait(10)
        for q in ([0.2, 1.1, -1.2], [-0.4, 0.9, -0.8], [0.0, 1.3, -1.5]):  # the others are served, and right
            target = arm.fk(np.array(q))
            r = client.ik("gupta3", target.tolist())
            assert r.status == "ok" and np.allclose(r.q, solvers.solve_ik(arm, target).q, atol=1e-12)
        wait_for(lambda: service.stats()["in_flight"] == 0, what="the dead client's batch to end")
        assert published == []  # an IK answer publishes nothing, client or not
        # 2. leaves (closes its session) as soon as its move has arrived: a line of 16,643 samples
        # (planned in tens of milliseconds, so the move may be answered before the client is gone:
        # once the test waited for a window of "in flight" that planning got too fast to show)
        goal = (arm.fk(sim.position) + np.array([0.0, 0.05, 0.05])).tolist()
        closed = _leaver(
            router,
            "leave/gupta3/move",
            {"goal": {"target": goal}, "path": "line", "speed": 0.1, "rate_hz": 1000},
            tmp_path,
        )
        wait_for(lambda: service.stats()["in_flight"] >= 1 or published, timeout=30, what="the move to arrive")
        assert closed.stdin is not None
        closed.stdin.write("leave\n")
        closed.stdin.flush()
        assert closed.stdout is not None and closed.stdout.readline().strip() == "left"
        # the move was accepted: it is published once, though nobody reads its reply; stop ends it
        wait_for(lambda: len(published) == 1, what="the move's trajectory")
        assert published[0]["kind"] == "move" and published[0]["path"] == "line"
        wait_for(
            lambda: any(e.get("event") == "accepted" and e.get("id") == published[0]["id"] for e in events),
            what="the adapter's acceptance",
        )
        stopped = client.stop("gupta3")
        wait_for(lambda: any(e["id"] == stopped["id"] for e in estops), what="the stop")
        assert [e["id"] for e in estops] == [stopped["id"]]  # (no estop for a move nobody accepted)
        assert len(published) == 1  # (a stop goes out on estop: the adapter brakes from its own state)
        client.wait_until_still("gupta3", timeout=10)
        assert np.allclose(client.fk("gupta3", [0, 1, -1]).position, arm.fk([0, 1, -1]), atol=1e-15)
        wait_for(lambda: service.stats()["in_flight"] == 0, what="an idle service")
        names = [t.name for t in threading.enumerate()]  # the pools' threads, no more (this test's service: 4 + 2)
        assert sum(n.startswith("armd-req") for n in names) <= 4 and sum(n.startswith("armd-stop") for n in names) <= 2
        assert service._pool._work_queue.empty() and service._stops._work_queue.empty()  # type: ignore[attr-defined]
    finally:
        for p in (killed, closed):
            if p is not None and p.poll() is None:
                p.kill()
                p.wait(10)
        client.close()
        sub.undeclare()
        events_sub.undeclare()
        estop_sub.undeclare()
        sim.close()
        service.close()
        session.close()
