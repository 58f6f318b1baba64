"""The simulator's range sensors (adapters/sim_sensors.py): beams against objects on the floor,
the scanners' sweeps, the sensors' outputs, published over Zenoh by the simulated arm."""

from __future__ import annotations

import json
import math
import threading
import time
from typing import Any

import numpy as np
import pytest
import zenoh

from armd import robots
from armd.adapters.sim import SimAdapter
from armd.adapters.sim_sensors import FloorObject, SimulatedSensors, objects_of
from armd.errors import BadRequest
from armd.robots.sensors import models

CAN = {"name": "can", "shape": "cylinder", "size": [0.03, 0.12], "position": [0.40, 0.10]}


def test_beams_meet_cylinders_boxes_spheres_and_the_floor_where_they_are() -> None:
    arm = robots.load("insomniac")
    sim = SimulatedSensors(arm, objects_of([CAN]), lambda *_: None, lambda: np.array(arm.neutral))
    o = np.array([0.12, 0.10, 0.10])
    assert math.isclose(sim.distance(o, np.array([1.0, 0.0, 0.0])), 0.40 - 0.03 - 0.12, abs_tol=1e-12)
    assert sim.distance(o, np.array([0.0, 1.0, 0.0])) == math.inf  # nothing that way
    down = np.array([0.0, 0.0, -1.0])
    assert math.isclose(sim.distance(np.array([0.40, 0.10, 0.30]), down), 0.30 - 0.12, abs_tol=1e-12)  # the can's top
    assert math.isclose(sim.distance(np.array([0.0, 0.0, 0.30]), down), 0.30, abs_tol=1e-12)  # the floor
    box = FloorObject("box", "box", (0.10, 0.04, 0.05), (0.5, 0.0), math.pi / 2)  # turned: 0.04 along x
    assert math.isclose(box.hit(np.array([0.0, 0.0, 0.02]), np.array([1.0, 0.0, 0.0]), 0.0), 0.48, abs_tol=1e-12)
    ball = FloorObject("ball", "sphere", (0.05,), (0.5, 0.0))
    assert math.isclose(ball.hit(np.array([0.0, 0.0, 0.05]), np.array([1.0, 0.0, 0.0]), 0.0), 0.45, abs_tol=1e-12)
    for bad in ([{"shape": "cone", "size": [1], "position": [0, 0]}], [{**CAN, "size": [0.03]}], [CAN, CAN], "can"):
        with pytest.raises(BadRequest):
            objects_of(bad)


def test_a_scanner_sees_the_can_between_its_edges_at_the_range_it_is() -> None:
    arm = robots.load("insomniac")
    sim = SimulatedSensors(arm, objects_of([CAN]), lambda *_: None, lambda: np.array(arm.neutral), seed=1)
    s = arm.sensors["et_left"]
    readings = [sim.read(s) for _ in range(200)]
    assert {r["sweep"] for r in readings} >= {0, 1, 2}  # reversing at the sweep's ends
    bearings = np.array([r["bearing"] for r in readings])
    assert bearings.min() >= s.sweep[0] - 1e-9 and bearings.max() <= s.sweep[1] + 1e-9  # type: ignore[index]
    # the can seen from et_left (0.12, 0.10): centre 0.28 m straight ahead, radius 0.03
    edge = math.asin(0.03 / 0.28)
    seen = [r for r in readings if r["range"] is not None]
    assert seen and all(abs(r["bearing"]) <= edge + 1e-9 for r in seen)
    assert all(abs(r["bearing"]) > edge for r in readings if r["range"] is None)
    straight = [r for r in seen if abs(r["bearing"]) < 0.02]
    assert straight and all(abs(r["range"] - 0.25) < 0.01 for r in straight)  # (noise: 10 mV, about 2 mm here)
    c = models()["Sharp GP2D12"]
    assert all(abs(r["volts"] - c.volts(math.inf)) < 0.06 for r in readings if r["range"] is None)


def test_the_simulated_arm_publishes_its_sensors_and_the_gripper_one_reads_where_the_arm_is(
    adapter_session: zenoh.Session, router: str
) -> None:
    arm = robots.load("insomniac")
    got: list[dict[str, Any]] = []
    lock = threading.Lock()

    def on(sample: zenoh.Sample) -> None:
        with lock:
            got.append(json.loads(sample.payload.to_bytes()))

    sub = adapter_session.declare_subscriber("armd/insomniac/sensors/*", on)
    low = {"name": "puck", "shape": "cylinder", "size": [0.03, 0.04], "position": [0.25, -0.08]}
    sim = SimAdapter(adapter_session, arm, objects=objects_of([CAN, low]), sensor_seed=2, time_scale=4.0)
    try:
        time.sleep(1.0)
        with lock:
            names = {r["sensor"] for r in got}
            rate = sum(r["sensor"] == "et_left" for r in got) / 1.0
        assert names == {"et_left", "et_right", "gripper_et"}
        assert rate > 50  # (26 a second at the GP2D12's 38.3 ms, four times faster)
        assert all(r["adapter"] == sim.id for r in got)
        # the tool straight down 0.10 m above the puck's top: the gripper's GP2D120 reads 0.10 m
        from armd.solvers import solve_ik

        r = solve_ik(arm, [0.25, -0.08, 0.04 + 0.10], approach="perpendicular")
        assert r.status == "ok"
        sim.position = r.q.copy()
        time.sleep(0.3)
        with lock:
            last = [x for x in got if x["sensor"] == "gripper_et"][-3:]
        assert all(abs(x["range"] - 0.10) < 0.005 for x in last), last
    finally:
        sub.undeclare()
        sim.close()
