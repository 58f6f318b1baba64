"""``pick`` and ``place`` (service/sequence.py): seed 000's grasp as checked steps through the
adapters, on a simulated insomniac: the steps in order, the gripper between them, the descent
a straight line, a stop ending it where it is, a target out of reach moving nothing."""

from __future__ import annotations

import threading
import time
from typing import Any

import numpy as np
import pytest
import zenoh
from conftest import collect, wait_for

from armd import robots
from armd.adapters.sim import SimAdapter
from armd.clients import ArmClient
from armd.errors import ArmdError

SPOT = [0.25, 0.05, 0.06]  # an object's centre where it is held (the README's reachable point, lower)


@pytest.fixture
def sim(router: str, service: Any) -> Any:
    from armd.service.zconfig import network_config

    arm = robots.load("insomniac")
    session = zenoh.open(network_config(connect=[router]))
    adapter = SimAdapter(session, arm, time_scale=5.0)
    wait_for(lambda: service._adapter_count(arm) == 1, what="the sim's token")
    yield adapter
    adapter.close()
    session.close()


def test_a_pick_opens_goes_above_descends_on_a_line_closes_and_lifts(client: ArmClient, sim: Any) -> None:
    arm = robots.load("insomniac")
    trajectories, sub = collect(client, "armd/insomniac/trajectory")
    grips, gsub = collect(client, "armd/insomniac/gripper")
    r = client.pick("insomniac", SPOT)
    sub.undeclare()  # type: ignore[attr-defined]
    gsub.undeclare()  # type: ignore[attr-defined]
    assert r["done"] and r["stopped_at"] is None, r
    assert [s["step"] for s in r["steps"]] == ["open", "above", "descend", "close", "lift"]
    assert [g["opening"] for g in grips] == [1.0, 0.0] and sim.gripper_opening == 0.0
    assert [t["path"] for t in trajectories] == ["joint", "line", "line"]
    above, descend, lift = (np.array(s["target"]) for s in r["steps"] if "target" in s)
    assert np.allclose(above, [SPOT[0], SPOT[1], SPOT[2] + 0.06]) and np.allclose(lift, above)
    assert np.allclose(descend, SPOT)
    # the descent: the tool on the vertical line down to the spot, straight down (pitch -pi/2)
    line = np.array([arm.fk(q) for q in trajectories[1]["position"]])
    assert np.max(np.linalg.norm(line[:, :2] - np.array(SPOT[:2]), axis=1)) < 1e-3
    assert abs(line[-1, 2] - SPOT[2]) < 1e-3 and np.all(np.diff(line[:, 2]) <= 1e-9)
    assert np.linalg.norm(arm.fk(sim.position) - lift) < 1e-3
    # and put it down farther out, level this time
    there = [0.30, 0.05, 0.10]
    r = client.place("insomniac", there, approach="parallel", above=0.05)
    assert r["done"], r
    assert [s["step"] for s in r["steps"]] == ["above", "descend", "open", "rise"] and sim.gripper_opening == 1.0
    pre = np.array(r["steps"][0]["target"])
    radial = np.array([there[0], there[1], 0.0]) / np.linalg.norm(there[:2])
    assert np.allclose(pre, np.array(there) - 0.05 * radial)  # back toward the base, level
    assert abs(arm.tool_pitch(sim.position)) < 1e-3  # (level as it rose)


def test_a_target_out_of_reach_or_colliding_moves_nothing(client: ArmClient, sim: Any) -> None:
    trajectories, sub = collect(client, "armd/insomniac/trajectory")
    grips, gsub = collect(client, "armd/insomniac/gripper")
    for target, approach, code in [
        ([0.9, 0.0, 0.1], "perpendicular", "unreachable"),
        ([0.25, 0.05, 0.06], "parallel", "collision"),  # (level so low, the forearm meets the base)
        ([0.25, 0.05, -0.02], "perpendicular", None),  # (below the floor)
    ]:
        with pytest.raises(ArmdError) as e:
            client.pick("insomniac", target, approach=approach)
        assert e.value.message.startswith(("above:", "descend:")), e.value
        if code:
            assert e.value.code == code, e.value
    for bad, field in [({"approach": "sideways"}, "approach"), ({"above": 0.5}, "above"), ({"speed": 0}, "speed")]:
        with pytest.raises(ArmdError) as e:
            client.call("insomniac/pick", {"target": SPOT, **bad})
        assert e.value.code == "bad_request" and e.value.fields.get("field") == field, (bad, e.value)
    time.sleep(0.2)
    sub.undeclare()  # type: ignore[attr-defined]
    gsub.undeclare()  # type: ignore[attr-defined]
    assert trajectories == [] and grips == []


@pytest.mark.parametrize("how", ["stop", "estop"])
def test_a_stop_or_an_estop_ends_a_pick_where_it_is(client: ArmClient, sim: Any, router: str, how: str) -> None:
    """A ``stop`` through the service, or an ``estop`` straight to the adapters (the service
    hears of it from their events): the pick ends at the step it was at."""
    from armd.clients import ArmClient as Client

    done: list[dict[str, Any]] = []
    runner = threading.Thread(target=lambda: done.append(client.pick("insomniac", SPOT, speed=0.2)))
    runner.start()
    with Client(router) as other:
        wait_for(lambda: other.state("insomniac")["moving"], timeout=10, what="the pick moving")
        other.stop("insomniac") if how == "stop" else other.estop("insomniac", wait=1.0)
        runner.join(timeout=30)
        (r,) = done
        assert not r["done"] and r["stopped_at"] in ("above", "descend") and "stop" in r["reason"], r
        assert not any(s["done"] for s in r["steps"] if s["step"] in ("close", "lift"))
        assert sim.gripper_opening == 1.0  # (opened, never closed)
        time.sleep(0.5)  # and the arm stays stopped: no step went on after the stop
        still = sim.position.copy()
        time.sleep(0.5)
        assert np.allclose(sim.position, still) and not other.state("insomniac")["moving"]


def test_a_pick_at_real_time_is_answered_when_done_and_a_second_at_once_is_busy(
    router: str, service: Any, client: ArmClient
) -> None:
    """Seconds of motion, past the service's 4 s deadline: the reply comes when the pick is over
    (the deadline bounds its planning), and a second pick meanwhile is refused as busy."""
    from armd.service.zconfig import network_config

    arm = robots.load("insomniac")
    session = zenoh.open(network_config(connect=[router]))
    sim = SimAdapter(session, arm, time_scale=1.0)
    try:
        wait_for(lambda: service._adapter_count(arm) == 1, what="the sim's token")
        done: list[dict[str, Any]] = []
        started = time.monotonic()
        runner = threading.Thread(target=lambda: done.append(client.pick("insomniac", SPOT)))
        runner.start()
        time.sleep(0.5)
        with pytest.raises(ArmdError) as e:
            client.pick("insomniac", SPOT)
        assert e.value.code == "busy"
        runner.join(timeout=60)
        (r,) = done
        assert r["done"] and time.monotonic() - started > 4.0, (r, time.monotonic() - started)
        assert np.linalg.norm(arm.fk(sim.position) - np.array(r["steps"][-1]["target"])) < 1e-3
    finally:
        sim.close()
        session.close()


def test_the_simulated_gripper_carries_what_it_closes_on_and_drops_it_where_it_opens(
    router: str, service: Any, client: ArmClient
) -> None:
    """A can on the simulated insomniac's floor: picked at its middle, it rises with the tool;
    placed on the arm's left, it stands there; a gripper closed on nothing holds nothing."""
    from armd.adapters.sim_sensors import objects_of
    from armd.service.zconfig import network_config

    arm = robots.load("insomniac")
    session = zenoh.open(network_config(connect=[router]))
    can = {"name": "can", "shape": "cylinder", "size": [0.03, 0.12], "position": [0.28, 0.0]}
    sim = SimAdapter(session, arm, time_scale=5.0, objects=objects_of([can]))
    try:
        wait_for(lambda: service._adapter_count(arm) == 1, what="the sim's token")
        client.gripper("insomniac", 0.0)  # (closed on nothing, at neutral)
        time.sleep(0.2)
        assert sim.held is None
        r = client.pick("insomniac", [0.28, 0.0, 0.06], lift=0.08)
        assert r["done"], r
        (held,) = sim.sensors.objects
        assert sim.held is not None and held.position == pytest.approx((0.28, 0.0), abs=1e-3)
        assert held.z == pytest.approx(0.08, abs=2e-3)  # lifted with the tool
        r = client.place("insomniac", [0.05, 0.25, 0.06])
        assert r["done"], r
        (put,) = sim.sensors.objects
        assert sim.held is None and put.z == 0.0 and put.position == pytest.approx((0.05, 0.25), abs=2e-3)
    finally:
        sim.close()
        session.close()
