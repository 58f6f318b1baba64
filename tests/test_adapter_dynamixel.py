"""The Dynamixel adapter on an emulated bus of XM430-W350 servos (a process of its own), through
ROBOTIS's SDK, with the real service over Zenoh: the OpenManipulator-X of examples/arms."""

from __future__ import annotations

import contextlib
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import zenoh
from conftest import adapter_process, cli_move, collect, wait_for

from armd import robots
from armd.adapters.emulators.dynamixel import DynamixelEmulator
from armd.adapters.emulators.process import EmulatorProcess
from armd.clients import ArmClient
from armd.errors import ControllerFault

pytest.importorskip("dynamixel_sdk")
from armd.adapters.dynamixel import DynamixelAdapter, DynamixelBus

ROOT = Path(__file__).resolve().parent.parent
ARMS = ROOT / "examples" / "arms"
NAME = "openmanipulator-x"
IDS = [11, 12, 13, 14, 15]
GOAL = [0.6, 0.4, -0.3, 0.5]
ACCEL_BAR = 1.02  # (as the Feetech adapter's: the servos' own acceleration limit)


@pytest.fixture(scope="module")
def omx() -> robots.Robot:
    return robots.load_folder(ARMS / NAME)


@pytest.fixture(scope="module")
def omx_service(router: str, omx: robots.Robot) -> Iterator[Any]:
    from armd.service.server import Service
    from armd.service.zconfig import network_config

    session = zenoh.open(network_config(connect=[router]))
    svc = Service(session, {NAME: omx})
    yield svc
    svc.close()
    session.close()


@pytest.fixture(scope="module")
def omx_client(router: str, omx_service: Any) -> Iterator[ArmClient]:
    with ArmClient(router, timeout=10.0) as c:
        yield c


def joints_of(arm: robots.Robot, emu: Any) -> np.ndarray:
    at = emu.positions()
    return arm.actuators.joints_from_commands(np.array([at[a.id] for a in arm.actuators.actuators]), tol=np.inf)


@contextlib.contextmanager
def omx_arm(session: zenoh.Session, service: Any, arm: robots.Robot) -> Iterator[tuple[Any, DynamixelAdapter]]:
    with EmulatorProcess(DynamixelEmulator, ids=IDS) as emu:
        adapter = DynamixelAdapter(session, arm, emu.port)
        try:
            wait_for(lambda: service._adapter_count(arm) == 1, what="the adapter's token")
            yield emu, adapter
        finally:
            adapter.close()


def test_a_move_is_measured_and_within_the_limits(
    omx: robots.Robot, omx_client: ArmClient, omx_service: Any, adapter_session: zenoh.Session
) -> None:
    with omx_arm(adapter_session, omx_service, omx) as (emu, _adapter):
        states, sub = collect(omx_client, f"armd/{NAME}/state")
        omx_client.move(NAME, GOAL, wait=True, wait_timeout=15)
        assert np.max(np.abs(joints_of(omx, emu) - GOAL)) < 0.02
        time.sleep(0.2)
        sub.undeclare()  # type: ignore[attr-defined]
        assert states and all(s["source"] == "measured" for s in states)
        assert np.max(np.abs(np.array(states[-1]["position"]) - joints_of(omx, emu))) < 2 * (2 * np.pi / 4096)
        for j, act in enumerate(omx.actuators.actuators):
            trace = np.array(emu.trace(act.id))
            t = np.arange(trace[0, 0], trace[-1, 0], 0.01)
            p = np.interp(t, trace[:, 0], trace[:, 1]) / act.counts_per_rad  # type: ignore[union-attr]
            v = np.diff(p) / 0.01
            assert np.max(np.abs(v)) <= omx.limits.velocity[j] * 1.01
            assert np.max(np.abs(np.diff(v) / 0.01)) <= omx.limits.acceleration[j] * ACCEL_BAR
        omx_client.gripper(NAME, 1.0)
        wait_for(lambda: abs(emu.position(15) - 3186) < 2, timeout=5, what="the gripper open")


def test_a_servo_that_does_not_answer_at_start_is_named(omx: robots.Robot, adapter_session: zenoh.Session) -> None:
    with EmulatorProcess(DynamixelEmulator, ids=[11, 12, 13, 15]) as emu, pytest.raises(ControllerFault) as e:
        DynamixelAdapter(adapter_session, omx, emu.port)
    assert "servo id 14 (joint4)" in e.value.message


def test_an_alarm_is_named_though_the_read_of_its_cause_lost_a_reply() -> None:
    """A low supply: each servo's status says an alarm, and the adapter reads its hardware error
    status to name it. That read's reply lost on the wire: read again, so the alarm is named
    (the fault is said once: with its cause, not as a "hardware error" first)."""
    with EmulatorProcess(DynamixelEmulator, ids=IDS) as emu:
        bus = DynamixelBus(emu.port, 1_000_000)
        try:
            emu.set_voltage(3.0)
            assert bus.read(IDS)[12].alarms == ("input voltage",)
            emu.drop_replies(12, 1, 1)  # (after one: the sync read's status through, the alarm's read lost)
            got = bus.read(IDS)
            assert all(got[i].alarms == ("input voltage",) for i in IDS), {i: got[i].alarms for i in IDS}
        finally:
            bus.close()


def test_an_alarm_is_a_fault_until_an_operator_unlocks(
    omx: robots.Robot, omx_client: ArmClient, omx_service: Any, adapter_session: zenoh.Session
) -> None:
    """Joint2's servo overheats mid-move: its torque off (its shutdown mask), the move aborted,
    a fault naming servo 12 and the alarm, the token withdrawn. The alarm is latched until a
    reboot: the operator, the cause seen to, unlocks; the servo rebooted holds again."""
    with omx_arm(adapter_session, omx_service, omx) as (emu, _):
        events, sub = collect(omx_client, f"armd/{NAME}/events")
        omx_client.move(NAME, GOAL)
        time.sleep(0.2)
        emu.set_temperature(12, 85.0)  # above its 80 C limit
        wait_for(lambda: any(e["event"] == "fault" for e in events), timeout=10, what="the fault")
        assert "servo 12 (joint2): overheating" in str(next(e for e in events if e["event"] == "fault")["reason"])
        assert any(e["event"] == "aborted" for e in events)
        wait_for(lambda: omx_service._adapter_count(omx) == 0, what="the token withdrawn")
        emu.set_temperature(12, 40.0)
        time.sleep(0.5)
        assert not any(e["event"] == "recovered" for e in events)  # latched: not by itself
        assert emu.register(12, 64) == 0  # (its torque off)
        omx_client.unlock(NAME, "assume_rest")
        wait_for(lambda: any(e["event"] == "recovered" for e in events), timeout=10, what="the recovery")
        assert emu.register(12, 64) == 1
        omx_client.move(NAME, [0.0, 0.0, 0.0, 0.0], wait=True, wait_timeout=15)
        sub.undeclare()  # type: ignore[attr-defined]


def test_the_omx_end_to_end_from_the_command_line(
    router: str, omx: robots.Robot, omx_service: Any, tmp_path: Path
) -> None:
    with EmulatorProcess(DynamixelEmulator, ids=IDS) as emu:
        cmd = ["dynamixel", NAME, "--robots-dir", str(ARMS), "--port", emu.port, "--connect", router]
        with adapter_process(cmd, tmp_path):
            wait_for(lambda: omx_service._adapter_count(omx) == 1, timeout=30, what="the adapter's token")
            done = cli_move(NAME, list(GOAL), router)
            assert done.returncode == 0, done.stderr
            assert np.max(np.abs(joints_of(omx, emu) - GOAL)) < 0.02
