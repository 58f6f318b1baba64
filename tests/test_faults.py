"""Faults: a router restarted under a service and an adapter; a service restarted under
its adapters and clients; a client timeout."""

from __future__ import annotations

import time

import numpy as np
import pytest
import zenoh

import robots
from clients import ArmClient, NoReply
from clients.sim import SimAdapter
from service.server import Service
from service.zconfig import network_config
from tests.conftest import free_port, wait_for


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
