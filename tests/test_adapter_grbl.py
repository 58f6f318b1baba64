"""Service + GRBL adapter + GRBL emulator on a pseudo-terminal: the code path a user's
/dev/ttyACM0 takes, end to end, and an error from the controller."""

from __future__ import annotations

import time

import numpy as np
import pytest
import zenoh

import robots
from clients import ArmClient
from clients.emulators.grbl import GrblEmulator
from clients.grbl import GrblAdapter
from tests.conftest import collect, wait_for


def grbl_joints(arm: robots.Robot, emu: GrblEmulator) -> np.ndarray:
    steps = emu.steps()
    cmds = np.array([steps[a.axis] for a in arm.actuators.actuators])  # type: ignore[union-attr]
    return arm.actuators.joints_from_commands(cmds, tol=np.inf)


def test_grbl_move_end_to_end(client: ArmClient, service: object, adapter_session: zenoh.Session) -> None:
    arm = robots.load("gupta3")
    with GrblEmulator() as emu:
        adapter = GrblAdapter(adapter_session, arm, emu.port)
        try:
            wait_for(lambda: service._adapter_count(arm) == 1, what="the adapter's token")  # type: ignore[attr-defined]
            for i, act in enumerate(arm.actuators.actuators):
                assert emu.settings[100 + i] == pytest.approx(act.steps_per_degree, rel=1e-4)  # type: ignore[union-attr]
            target = [0.15, 0.05, 0.12]
            wait_for(lambda: client.state("gupta3")["source"] == "adapter", what="the adapter's state")
            client.move("gupta3", {"target": target}, wait=True, wait_timeout=20)
            wait_for(lambda: emu.state == "Idle", timeout=5, what="GRBL idle")
            q = grbl_joints(arm, emu)
            step = max(a.step_angle for a in arm.actuators.actuators)  # type: ignore[union-attr]
            assert np.linalg.norm(arm.fk(q) - target) < 0.28 * step * 3  # within the micro-step quantisation
            assert emu.overflows == 0 and emu.max_rx_used <= 128
            assert arm.limits.contains(q, tol=1e-6)
        finally:
            adapter.close()


def test_grbl_error_aborts(client: ArmClient, service: object, adapter_session: zenoh.Session) -> None:
    arm = robots.load("gupta3")
    with GrblEmulator() as emu:
        adapter = GrblAdapter(adapter_session, arm, emu.port)
        try:
            wait_for(lambda: service._adapter_count(arm) == 1, what="the adapter's token")  # type: ignore[attr-defined]
            events, sub = collect(client, "armd/gupta3/events")
            emu.inject_error_on_next_line(20)
            client.move("gupta3", [0.4, 1.2, -1.2])
            wait_for(lambda: any(e["event"] == "aborted" for e in events), timeout=10, what="an aborted event")
            aborted = next(e for e in events if e["event"] == "aborted")
            assert "error:20" in str(aborted["reason"])
            sub.undeclare()  # type: ignore[attr-defined]
        finally:
            adapter.close()


def test_grbl_stop_mid_move_flushes_and_halts(client: ArmClient, service: object,
                                              adapter_session: zenoh.Session) -> None:
    arm = robots.load("gupta3")
    with GrblEmulator() as emu:
        adapter = GrblAdapter(adapter_session, arm, emu.port)
        try:
            wait_for(lambda: service._adapter_count(arm) == 1, what="the adapter's token")  # type: ignore[attr-defined]
            events, sub = collect(client, "armd/gupta3/events")
            goal = np.array([1.2, 1.5, -1.0])
            client.move("gupta3", goal.tolist(), speed=0.5)
            time.sleep(0.8)
            client.stop("gupta3")
            wait_for(lambda: any(e["event"] == "done" for e in events), timeout=10, what="the stop to finish")
            assert any(e["event"] == "aborted" for e in events)  # the move was replaced
            wait_for(lambda: emu.state == "Idle", timeout=10, what="GRBL idle")
            q = grbl_joints(arm, emu)
            assert np.max(np.abs(q - goal)) > 0.1  # halted short of the goal
            assert not any(e["event"] == "fault" for e in events)  # the flush raised no alarm
            assert emu.overflows == 0
            sub.undeclare()  # type: ignore[attr-defined]
        finally:
            adapter.close()


def test_grbl_alarm_and_silence(client: ArmClient, service: object, adapter_session: zenoh.Session) -> None:
    arm = robots.load("gupta3")
    with GrblEmulator() as emu:
        adapter = GrblAdapter(adapter_session, arm, emu.port, check_period=0.2)
        try:
            wait_for(lambda: service._adapter_count(arm) == 1, what="the adapter's token")  # type: ignore[attr-defined]
            events, sub = collect(client, "armd/gupta3/events")
            client.move("gupta3", [0.8, 1.3, -1.1], speed=0.5)
            time.sleep(0.5)
            emu.inject_alarm(1)  # a hard limit: ALARM:1
            wait_for(lambda: any(e["event"] == "aborted" and "ALARM:1" in str(e.get("reason")) for e in events),
                     timeout=5, what="the alarm reported")
            sub.undeclare()  # type: ignore[attr-defined]
        finally:
            adapter.close()
    with GrblEmulator() as emu:
        adapter = GrblAdapter(adapter_session, arm, emu.port, check_period=0.2)
        try:
            wait_for(lambda: service._adapter_count(arm) == 1, what="the adapter's token")  # type: ignore[attr-defined]
            emu.responding = False
            wait_for(lambda: service._adapter_count(arm) == 0, timeout=5, what="the token withdrawn")  # type: ignore[attr-defined]
            assert adapter.fault and "does not answer" in adapter.fault
        finally:
            adapter.close()
