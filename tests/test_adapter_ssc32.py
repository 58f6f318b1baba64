"""Service + adapters + controller emulators on pseudo-terminals: the code path a user's
/dev/ttyUSB0 takes, end to end, and the faults."""

from __future__ import annotations

import json
import time

import numpy as np
import pytest
import zenoh

import robots
from clients import ArmClient, ServiceError
from clients.emulators.ssc32 import SSC32Emulator
from clients.ssc32 import SSC32Adapter
from service.zconfig import network_config
from tests.conftest import collect, wait_for


def ssc32_joints(arm: robots.Robot, emu: SSC32Emulator) -> np.ndarray:
    pulses = np.array([emu.pulse(a.channel) for a in arm.actuators.actuators])  # type: ignore[union-attr]
    return arm.actuators.joints_from_commands(pulses)


def test_ssc32_move_end_to_end(client: ArmClient, service: object, adapter_session: zenoh.Session) -> None:
    arm = robots.load("insomniac")
    with SSC32Emulator() as emu:
        adapter = SSC32Adapter(adapter_session, arm, emu.port)
        try:
            wait_for(lambda: service._adapter_count(arm) == 1, what="the adapter's token")  # type: ignore[attr-defined]
            states, sub = collect(client, "armd/insomniac/state")
            target = [0.24, 0.06, 0.10]
            r = client.move("insomniac", {"target": target, "approach": "perpendicular"}, wait=True, wait_timeout=15)
            time.sleep(0.3)
            sub.undeclare()  # type: ignore[attr-defined]
            q = ssc32_joints(arm, emu)
            assert np.linalg.norm(arm.fk(q) - target) < 1e-3  # within 1 mm, through the real pulses
            assert emu.out_of_range == []  # no pulse ever left its channel's range
            for move in emu.history:
                for ch, pw in move.pulses.items():
                    assert 500 <= pw <= 2500, (ch, pw)
            moving = [s for s in states if s["moving"]]
            assert len(moving) >= 0.6 * 20 * r.duration  # the state stream followed it at >= 20 Hz
            for s in moving:
                assert arm.limits.contains(np.array(s["position"]), tol=1e-9)
        finally:
            adapter.close()


def test_ssc32_controller_stops_answering(client: ArmClient, service: object, adapter_session: zenoh.Session) -> None:
    arm = robots.load("sg5ut")
    with SSC32Emulator() as emu:
        adapter = SSC32Adapter(adapter_session, arm, emu.port, timeout=0.3)
        try:
            wait_for(lambda: service._adapter_count(arm) == 1, what="the adapter's token")  # type: ignore[attr-defined]
            events, sub = collect(client, "armd/sg5ut/events")
            emu.responding = False
            wait_for(lambda: any(e["event"] == "fault" for e in events), timeout=5, what="a fault event")
            wait_for(lambda: service._adapter_count(arm) == 0, timeout=5, what="the token withdrawn")  # type: ignore[attr-defined]
            with pytest.raises(ServiceError) as e:
                client.move("sg5ut", [0.2, 1.2, -0.6, -0.6])
            assert e.value.code == "no_adapter"
            emu.responding = True
            wait_for(lambda: service._adapter_count(arm) == 1, timeout=5, what="recovery")  # type: ignore[attr-defined]
            sub.undeclare()  # type: ignore[attr-defined]
        finally:
            adapter.close()


def test_a_trajectory_with_one_bad_sample_is_rejected_whole(client: ArmClient, service: object,
                                                            adapter_session: zenoh.Session) -> None:
    arm = robots.load("insomniac")
    with SSC32Emulator() as emu:
        adapter = SSC32Adapter(adapter_session, arm, emu.port)
        try:
            wait_for(lambda: service._adapter_count(arm) == 1, what="the adapter's token")  # type: ignore[attr-defined]
            traj = client.plan("insomniac", [0.3, 1.2, -1.0, -0.5, 0.0], start=arm.neutral)
            msg = {"robot": "insomniac", "id": "bad", "kind": "move", "rate_hz": traj.rate_hz,
                   "times": traj.times.tolist(), "position": traj.position.tolist(),
                   "velocity": traj.velocity.tolist(), "acceleration": traj.acceleration.tolist()}
            msg["position"][len(traj.times) // 2][0] = 2.0  # base_yaw past its +pi/2 limit, one sample
            events, sub = collect(client, "armd/insomniac/events")
            before = len(emu.history)
            client.session.put("armd/insomniac/trajectory", json.dumps(msg))
            wait_for(lambda: any(e["event"] == "rejected" for e in events), timeout=5, what="a rejection")
            time.sleep(0.3)
            assert len(emu.history) == before  # nothing of it reached the wire
            rejected = next(e for e in events if e["event"] == "rejected")
            assert "base_yaw" in str(rejected["reason"])
            sub.undeclare()  # type: ignore[attr-defined]
        finally:
            adapter.close()


def test_stop_mid_move_halts(client: ArmClient, service: object, adapter_session: zenoh.Session) -> None:
    arm = robots.load("insomniac")
    with SSC32Emulator() as emu:
        adapter = SSC32Adapter(adapter_session, arm, emu.port)
        try:
            wait_for(lambda: service._adapter_count(arm) == 1, what="the adapter's token")  # type: ignore[attr-defined]
            goal = np.array([1.2, 2.0, -1.8, 1.0, 1.0])
            events, sub = collect(client, "armd/insomniac/events")
            client.move("insomniac", goal.tolist(), speed=0.3)
            time.sleep(0.5)
            asked = time.time()
            stopped = client.stop("insomniac")
            wait_for(lambda: any(e["event"] == "started" and e.get("id") == stopped["id"] for e in events),
                     timeout=2, what="the stop started")
            started = next(e for e in events if e["event"] == "started" and e.get("id") == stopped["id"])
            assert float(started["time"]) - asked < 0.1  # the adapter switched to the stop within a few cycles
            sub.undeclare()  # type: ignore[attr-defined]
            time.sleep(stopped["duration"] + 0.3)
            sent = len(emu.history)
            time.sleep(0.3)
            assert len(emu.history) == sent  # nothing more is sent once stopped
            q = ssc32_joints(arm, emu)
            assert np.max(np.abs(q - goal)) > 0.1  # halted short of the goal
            assert not emu.moving()
        finally:
            adapter.close()


def test_adapter_killed_mid_move_then_no_adapter(client: ArmClient, service: object, router: str) -> None:
    arm = robots.load("sg5ut")
    session = zenoh.open(network_config(connect=[router]))
    with SSC32Emulator() as emu:
        adapter = SSC32Adapter(session, arm, emu.port)
        wait_for(lambda: service._adapter_count(arm) == 1, what="the adapter's token")  # type: ignore[attr-defined]
        client.move("sg5ut", [0.6, 1.0, -0.3, -0.4], speed=0.3)
        time.sleep(0.2)
        session.close()  # the adapter's process goes away: its session (and token) with it
        wait_for(lambda: service._adapter_count(arm) == 0, timeout=5, what="the token gone")  # type: ignore[attr-defined]
        with pytest.raises(ServiceError) as e:
            client.move("sg5ut", [0.2, 1.2, -0.6, -0.6])
        assert e.value.code == "no_adapter"
        adapter._stop.set()  # the thread of the dead process
        adapter.shutdown()




def test_sg5ut_mirrored_shoulder_pair_and_gripper_channel(client: ArmClient, service: object,
                                                          adapter_session: zenoh.Session) -> None:
    arm = robots.load("sg5ut")
    with SSC32Emulator() as emu:
        adapter = SSC32Adapter(adapter_session, arm, emu.port)
        try:
            wait_for(lambda: service._adapter_count(arm) == 1, what="the adapter's token")  # type: ignore[attr-defined]
            goal = np.array([0.3, 1.1, -0.5, -0.4])
            client.move("sg5ut", goal.tolist(), wait=True, wait_timeout=15)
            time.sleep(0.2)
            assert abs(emu.pulse(1) + emu.pulse(2) - 3000) <= 1  # channels 1 and 2 mirrored about 1500
            assert np.allclose(ssc32_joints(arm, emu), goal, atol=2e-3)
            assert all(set(m.pulses) == {0, 1, 2, 3, 4} for m in emu.history[1:])  # every channel of the map
            client.gripper("sg5ut", 1.0)
            wait_for(lambda: emu.target(5) == 2000, timeout=5, what="the gripper channel")
        finally:
            adapter.close()


def test_an_adapter_refuses_an_arm_it_cannot_drive(adapter_session: zenoh.Session) -> None:
    """Servo arms to the GRBL adapter, stepper arms to the SSC-32's: refused before any port
    is opened, naming what the adapter drives."""
    from clients.grbl import GrblAdapter
    from robots import BadRequest

    with pytest.raises(BadRequest) as e:
        SSC32Adapter(adapter_session, robots.load("gupta3"), "/dev/nonexistent-ssc32")
    assert e.value.field == "robot" and "not all servos: the SSC-32 adapter drives servos" in e.value.message
    with pytest.raises(BadRequest) as e:
        GrblAdapter(adapter_session, robots.load("insomniac"), "/dev/nonexistent-grbl")
    assert e.value.field == "robot" and "not all steppers: the GRBL adapter drives steppers" in e.value.message
