"""``detect``: the objects the insomniac's scanning GP2D12s see, through the service, from a
simulated arm with objects on its floor (seed 000 sections 4 and 7); and the detection alone
(solvers/detect.py) on sweeps the simulated sensors make."""

from __future__ import annotations

import json
import math
import time
from typing import Any

import numpy as np
import pytest
import zenoh
from conftest import wait_for

from armd import robots
from armd.adapters.sim import SimAdapter
from armd.adapters.sim_sensors import SimulatedSensors, objects_of
from armd.clients import ArmClient
from armd.errors import ArmdError
from armd.solvers import detect

CAN = {"name": "can", "shape": "cylinder", "size": [0.03, 0.12], "position": [0.40, 0.10]}
POST = {"name": "post", "shape": "cylinder", "size": [0.02, 0.20], "position": [0.30, -0.25]}
LOW = {"name": "low", "shape": "box", "size": [0.05, 0.05, 0.05], "position": [0.35, 0.0]}  # under the beams


def sweeps_of(arm: robots.Robot, objects: list[dict[str, Any]], n: int, seed: int) -> dict[str, list[Any]]:
    """Each scanner's first ``n`` complete sweeps, read by the simulated sensors."""
    sim = SimulatedSensors(arm, objects_of(objects), lambda *_: None, lambda: np.array(arm.neutral), seed=seed)
    by: dict[str, dict[int, list[Any]]] = {}
    scanners = [s for s in sim.sensors if s.mount == "scanner"]
    while min((len(by.get(s.name, {})) for s in scanners), default=0) < n + 2:
        for s in scanners:
            r = sim.read(s)
            by.setdefault(s.name, {}).setdefault(r["sweep"], []).append(r)
    return {name: [v[k] for k in sorted(v)[1 : n + 1]] for name, v in by.items()}  # (the first may be partial)


@pytest.mark.parametrize("seed", range(5))
def test_each_object_is_found_where_it_is_within_its_uncertainty(seed: int) -> None:
    arm = robots.load("insomniac")
    found = detect(arm, sweeps_of(arm, [CAN, POST, LOW], 2, seed))
    assert len(found) == 2  # (the low box is under the beams: 0.05 m tall, the beams at 0.10 m)
    for o, truth in zip(found, (POST, CAN), strict=True):  # (nearest first: the post is 0.33 m off, the can 0.41)
        err = float(np.linalg.norm(o.position[:2] - np.array(truth["position"])))
        assert err <= 3 * o.uncertainty, (truth["name"], err, o.uncertainty)
        assert abs(o.width - 2 * truth["size"][0]) < 0.012, (truth["name"], o.width)
        assert o.stable and o.seen == 2 and o.position[2] == pytest.approx(0.10)
    assert set(found[1].sensors) == {"et_left", "et_right"}  # (the can: seen by both, given once)


def test_an_object_that_moved_between_sweeps_is_not_stable() -> None:
    arm = robots.load("insomniac")
    before = sweeps_of(arm, [CAN], 1, 0)
    moved = {**CAN, "position": [0.40, 0.16]}
    after = sweeps_of(arm, [moved], 1, 1)
    found = detect(arm, {k: before[k] + after[k] for k in before})
    assert found and not any(o.stable for o in found)
    assert all(o.seen == 1 and o.sweeps == 2 for o in found)


def test_detect_through_the_service(router: str, service: Any, client: ArmClient) -> None:
    from armd.service.zconfig import network_config

    arm = robots.load("insomniac")
    session = zenoh.open(network_config(connect=[router]))
    sim = SimAdapter(session, arm, time_scale=10.0, objects=objects_of([CAN, POST]), sensor_seed=4)
    try:
        wait_for(lambda: service._adapter_count(arm) == 1, what="the sim's token")
        r = client.call("insomniac/detect", {"sweeps": 2, "deadline": 3.0})
        found = r["objects"]
        assert [round(o["position"][1], 1) for o in found] == [-0.2, 0.1]  # the post, then the can
        for o, truth in zip(found, (POST, CAN), strict=True):
            err = math.dist(o["position"][:2], truth["position"])
            assert o["stable"] and err <= 3 * o["uncertainty"], (o, err)
        assert r["sensors"] == ["et_left", "et_right"] and r["sweeps"] == 2
        one = client.detect("insomniac", sensors=["et_right"], sweeps=1)
        assert one["sensors"] == ["et_right"] and one["objects"]
        for bad, field in [
            ({"sensors": ["gripper_et"]}, "sensors"),
            ({"sensors": ["nose"]}, "sensors"),
            ({"sweeps": 0}, "sweeps"),
            ({"sweeps": 9}, "sweeps"),
            ({"sweeps": 1.5}, "sweeps"),
            ({"sweeps": 2, "what": 1}, "what"),
        ]:
            with pytest.raises(ArmdError) as e:
                client.call("insomniac/detect", bad)
            assert e.value.code == "bad_request" and e.value.fields.get("field") == field, (bad, e.value)
    finally:
        sim.close()
        session.close()
    with pytest.raises(ArmdError) as e:  # no adapter alive
        client.call("insomniac/detect", {})
    assert e.value.code == "no_adapter"


def test_readings_from_no_live_adapter_or_malformed_are_ignored_and_a_start_is_not_ready(
    router: str, service: Any, client: ArmClient
) -> None:
    """A forger puts readings of a can on the sensors' keys: ignored (no live adapter of that
    id; malformed). Just after a (slow) simulated arm starts, detect answers not_ready."""
    from armd.service.zconfig import network_config

    arm = robots.load("insomniac")
    before = dict(service.sensor_book.ignored)
    forged = {"sensor": "et_left", "adapter": "forger", "range": 0.25, "bearing": 0.0, "sweep": 1, "volts": 1.2}
    with client.session.declare_publisher("armd/insomniac/sensors/et_left") as pub:  # type: ignore[attr-defined]
        for payload in (json.dumps(forged), "{not json", json.dumps({**forged, "sensor": "et_right"}), "[]"):
            pub.put(payload)
    wait_for(
        lambda: sum(service.sensor_book.ignored.values()) - sum(before.values()) >= 4, what="the forgeries ignored"
    )
    session = zenoh.open(network_config(connect=[router]))
    live = SimAdapter(session, arm, time_scale=10.0, objects=objects_of([CAN]), sensor_seed=5)
    try:  # a reading under a live adapter's (public) id with no number (seq), far ahead: ignored, the stream goes on
        # (one numbered, from another session, disputes the sensor: tests/test_sensor_trust.py)
        wait_for(lambda: service._adapter_count(arm) == 1, what="the sim's token")
        time.sleep(0.3)
        spoof = {**forged, "adapter": live.id, "sweep": 10**6}
        with client.session.declare_publisher("armd/insomniac/sensors/et_left") as pub:  # type: ignore[attr-defined]
            pub.put(json.dumps(spoof))
            pub.put("[" * 100_000)
            pub.put(json.dumps({**forged, "adapter": live.id, "range": 10**400}))
        (can,) = client.detect("insomniac", sweeps=2)["objects"]
        assert can["stable"] and math.dist(can["position"][:2], CAN["position"]) < 0.01
        assert service.sensor_book.ignored.get("malformed", 0) >= before.get("malformed", 0) + 6
    finally:
        live.close()
    wait_for(lambda: service._adapter_count(arm) == 0, what="the sim gone")
    sim = SimAdapter(session, arm, time_scale=0.5, objects=objects_of([CAN]))
    try:
        wait_for(lambda: service._adapter_count(arm) == 1, what="the sim's token")
        t0 = time.monotonic()
        with pytest.raises(ArmdError) as e:
            client.call("insomniac/detect", {"deadline": 0.5})
        assert e.value.code == "not_ready" and "et_left" in e.value.message, e.value
        assert time.monotonic() - t0 < 2.0
    finally:
        sim.close()
        session.close()
