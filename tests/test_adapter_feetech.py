"""The Feetech adapter on an emulated bus of STS3215 servos (in a process of its own, as a bus
has its own CPUs), through the vendor's SDK, with the real service over Zenoh: the SO-101."""

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
from armd.adapters.emulators.feetech import FeetechEmulator
from armd.adapters.emulators.process import EmulatorProcess
from armd.clients import ArmClient
from armd.errors import ArmdError, BadRequest, ControllerFault

pytest.importorskip("scservo_sdk")
from armd.adapters.feetech import FeetechAdapter

ROOT = Path(__file__).resolve().parent.parent
GOAL = [0.8, 0.9, -0.7, 0.6, 1.2]
# At the servos (the emulator's model, over 10 ms): each servo's own acceleration limit is its
# joint's, rounded down (start-up sets it): 1.00x measured, idle or busy; the rest is the measure's
ACCEL_BAR = 1.02


def joints_of(arm: robots.Robot, emu: Any) -> np.ndarray:
    """The arm's joints as the servos' raw positions put them (no offsets on these servos)."""
    at = emu.positions()
    return arm.actuators.joints_from_commands(np.array([at[a.id] for a in arm.actuators.actuators]), tol=np.inf)


@contextlib.contextmanager
def feetech_arm(session: zenoh.Session, service: Any, **options: Any) -> Iterator[tuple[Any, FeetechAdapter]]:
    arm = robots.load("so101")
    with EmulatorProcess(FeetechEmulator, ids=[1, 2, 3, 4, 5, 6]) as emu:
        adapter = FeetechAdapter(session, arm, emu.port, **options)
        try:
            wait_for(lambda: service._adapter_count(arm) == 1, what="the adapter's token")
            yield emu, adapter
        finally:
            adapter.close()


def _speeds(arm: robots.Robot, emu: Any) -> tuple[np.ndarray, np.ndarray]:
    """Each joint's fastest speed [rad/s] and hardest acceleration [rad/s^2] at the servos,
    from their traces (the emulator's model, every 1 ms step), over 10 ms windows."""
    vmax, amax = np.zeros(arm.nq), np.zeros(arm.nq)
    for j, act in enumerate(arm.actuators.actuators):
        trace = np.array(emu.trace(act.id))
        if len(trace) < 3:
            continue
        t = np.arange(trace[0, 0], trace[-1, 0], 0.01)
        p = np.interp(t, trace[:, 0], trace[:, 1]) / act.counts_per_rad  # type: ignore[union-attr]
        v = np.diff(p) / 0.01
        vmax[j] = np.max(np.abs(v))
        amax[j] = np.max(np.abs(np.diff(v) / 0.01))
    return vmax, amax


def test_a_move_is_measured_tracked_and_within_the_limits(
    client: ArmClient, service: object, adapter_session: zenoh.Session
) -> None:
    arm = robots.load("so101")
    with feetech_arm(adapter_session, service) as (emu, adapter):
        states, sub = collect(client, "armd/so101/state")
        r = client.move("so101", GOAL, wait=True, wait_timeout=15)
        assert np.max(np.abs(joints_of(arm, emu) - GOAL)) < 0.02
        time.sleep(0.2)
        sub.undeclare()  # type: ignore[attr-defined]
        assert states and all(s["source"] == "measured" for s in states)
        last = np.array(states[-1]["position"])
        assert np.max(np.abs(last - joints_of(arm, emu))) < 2 * (2 * np.pi / 4096)  # what the servos say
        vmax, amax = _speeds(arm, emu)
        assert np.all(vmax <= arm.limits.velocity * 1.01), vmax  # the servos' own speed limit, and the plan
        assert np.all(amax <= arm.limits.acceleration * ACCEL_BAR), amax
        assert r.duration > 0.3 and adapter._cycles > 100


def test_a_servo_that_does_not_answer_at_start_is_named(adapter_session: zenoh.Session) -> None:
    arm = robots.load("so101")
    with EmulatorProcess(FeetechEmulator, ids=[1, 2, 4, 5, 6]) as emu, pytest.raises(ControllerFault) as e:
        FeetechAdapter(adapter_session, arm, emu.port)
    assert "servo id 3 (elbow_flex)" in e.value.message


def test_a_bus_another_program_has_open_is_refused_as_busy() -> None:
    """An adapter, or armd calibrate or record, on a port another one drives: refused, not two
    programs turning torques on and off under each other."""
    from armd.adapters.feetech import FeetechBus

    with EmulatorProcess(FeetechEmulator, ids=[1, 2, 3, 4, 5, 6]) as emu:
        first = FeetechBus(emu.port, 1_000_000)
        try:
            with pytest.raises(ControllerFault) as e:
                FeetechBus(emu.port, 1_000_000)
            assert "busy" in e.value.message and emu.port in e.value.message
            assert first.ping(1) is not None  # (the first still has it)
        finally:
            first.close()
        FeetechBus(emu.port, 1_000_000).close()  # (free again)


def test_an_arm_of_other_actuators_is_refused_before_the_port_is_opened(adapter_session: zenoh.Session) -> None:
    with pytest.raises(BadRequest) as e:
        FeetechAdapter(adapter_session, robots.load("insomniac"), "/dev/nonexistent-feetech")
    assert "bus_servos" in e.value.message or "busservos" in e.value.message


def test_start_up_holds_the_arm_where_it_is_found(service: object, adapter_session: zenoh.Session) -> None:
    """Servos found away from their factory middle, with stale goals in their registers: the
    adapter makes each goal where the servo is before the torque goes on: nothing moves."""
    arm = robots.load("so101")
    at = {1: 2300.0, 2: 1900.0, 3: 2200.0, 4: 2000.0, 5: 2500.0, 6: 2048.0}
    with EmulatorProcess(FeetechEmulator, ids=[1, 2, 3, 4, 5, 6], positions=at) as emu:
        for i in (1, 2, 3):
            emu.move_by_hand(i, at[i] + 50)  # (power-up's goal: where it was; moved since)
        before = emu.positions()
        adapter = FeetechAdapter(adapter_session, arm, emu.port)
        try:
            time.sleep(0.3)
            assert all(emu.register(i, 40) == 1 for i in (1, 2, 3, 4, 5))  # torque on
            after = emu.positions()
            assert max(abs(after[i] - before[i]) for i in before) < 1.0
            assert np.allclose(adapter.measure().position, joints_of(arm, emu), atol=2e-3)
        finally:
            adapter.close()


def test_an_arm_found_outside_its_limits_is_refused_and_one_a_count_past_is_moved(
    client: ArmClient, service: object, adapter_session: zenoh.Session
) -> None:
    """shoulder_pan found 0.15 rad past its limit: the adapter does not start (its servos limp:
    nothing moved) and says what to do. Found 0.005 rad past (a servo settled a count or three
    beyond a goal at its limit): the service plans from the limit, and the arm moves."""
    arm = robots.load("so101")
    per = 4096 / (2 * np.pi)
    with EmulatorProcess(FeetechEmulator, ids=[1, 2, 3, 4, 5, 6], positions={1: 2048 + 2.07 * per}) as emu:
        with pytest.raises(ControllerFault) as e:
            FeetechAdapter(adapter_session, arm, emu.port)
        assert "shoulder_pan" in e.value.message and "by hand" in e.value.message
        assert emu.register(1, 40) == 0
    with EmulatorProcess(FeetechEmulator, ids=[1, 2, 3, 4, 5, 6], positions={1: 2048 + 1.925 * per}) as emu:
        adapter = FeetechAdapter(adapter_session, arm, emu.port)
        try:
            wait_for(lambda: service._adapter_count(arm) == 1, what="the adapter's token")  # type: ignore[attr-defined]
            client.move("so101", [0.0, 0.0, 0.0, 0.0, 0.0], wait=True, wait_timeout=15)
            assert np.max(np.abs(joints_of(arm, emu))) < 0.01
        finally:
            adapter.close()


def test_a_blocked_joint_aborts_the_move_and_stops_the_arm(
    client: ArmClient, service: object, adapter_session: zenoh.Session
) -> None:
    """Something in elbow_flex's way: it falls behind the plan by more than its tracking
    tolerance; the move is aborted naming the joint, and the arm stopped from where it is."""
    arm = robots.load("so101")
    with feetech_arm(adapter_session, service) as (emu, _):
        events, sub = collect(client, "armd/so101/events")
        elbow = arm.actuators.actuators[2]
        emu.hold(elbow.id, float(elbow.to_command(np.array(-0.2))))  # type: ignore[union-attr]
        client.move("so101", [0.8, 0.3, -0.7, 0.6, 1.2])  # (a goal whose way, the elbow held, stays clear of the floor)
        wait_for(lambda: any(e["event"] == "aborted" for e in events), timeout=10, what="the abort")
        aborted = next(e for e in events if e["event"] == "aborted")
        assert aborted["joint"] == "elbow_flex" and aborted["check"] == "tracking"
        assert "elbow_flex" in str(aborted["reason"]) and float(aborted["error"]) > 0.1  # type: ignore[arg-type]
        wait_for(lambda: sum(e["event"] == "done" for e in events) >= 1, timeout=5, what="the stop done")
        time.sleep(0.3)
        still = emu.positions()
        time.sleep(0.3)
        assert max(abs(emu.positions()[i] - still[i]) for i in still) < 1.0  # stopped
        assert abs(joints_of(arm, emu)[2] - (-0.2)) < 0.01  # (held where it was blocked)
        emu.hold(elbow.id, None)
        client.move("so101", [0.0, 0.0, 0.0, 0.0, 0.0], wait=True, wait_timeout=15)  # planned from the measured state
        sub.undeclare()  # type: ignore[attr-defined]


def test_an_alarm_aborts_faults_and_names_the_servo(
    client: ArmClient, service: object, adapter_session: zenoh.Session
) -> None:
    """An overheat mid-move: the move aborted, the fault naming the servo; the servo lets go (its
    unloading condition) and stays limp once cool, the fault saying so, until an operator unlocks."""
    arm = robots.load("so101")
    with feetech_arm(adapter_session, service) as (emu, _):
        events, sub = collect(client, "armd/so101/events")
        client.move("so101", GOAL)
        time.sleep(0.2)
        emu.set_temperature(2, 75.0)  # above its 70 C limit
        wait_for(lambda: any(e["event"] == "fault" for e in events), timeout=5, what="the fault")
        fault = next(e for e in events if e["event"] == "fault")
        assert "servo 2 (shoulder_lift): overheat" in str(fault["reason"])
        assert any(e["event"] == "aborted" for e in events)
        wait_for(lambda: service._adapter_count(arm) == 0, what="the token withdrawn")  # type: ignore[attr-defined]
        with pytest.raises(ArmdError) as e:
            client.move("so101", [0.0] * 5)
        assert e.value.code == "no_adapter"
        emu.set_temperature(2, 40.0)  # cool again: the alarm clears, but the servo let go (its unloading condition)
        wait_for(lambda: sum(e["event"] == "fault" for e in events) == 2, timeout=5, what="the second fault")
        limp = [e for e in events if e["event"] == "fault"][1]
        assert "servo id 2 (shoulder_lift) let go" in str(limp["reason"]) and "armd unlock so101" in str(limp["reason"])
        time.sleep(0.5)
        assert not any(e["event"] == "recovered" for e in events)  # (never unlocked by the adapter itself)
        assert emu.register(2, 40) == 0
        answer = client.unlock("so101", "assume_rest", wait=5.0)
        assert answer is not None and answer["event"] == "unlocked", answer
        wait_for(lambda: any(e["event"] == "recovered" for e in events), timeout=5, what="the recovery")
        assert emu.register(2, 40) == 1 and emu.register(2, 41) > 0  # torque on, its acceleration limit set
        sub.undeclare()  # type: ignore[attr-defined]


def test_a_lost_reply_is_skipped_and_a_silent_servo_is_a_fault(
    client: ArmClient, service: object, adapter_session: zenoh.Session
) -> None:
    arm = robots.load("so101")
    with feetech_arm(adapter_session, service) as (emu, _):
        events, sub = collect(client, "armd/so101/events")
        r = client.move("so101", GOAL)
        time.sleep(0.2)
        emu.drop_replies(4, 2)  # two replies lost: skipped, the move goes on
        wait_for(lambda: any(e["event"] == "done" and e["id"] == r.id for e in events), timeout=10, what="done")
        assert not any(e["event"] in ("fault", "aborted") for e in events)
        emu.silence(4)
        wait_for(lambda: any(e["event"] == "fault" for e in events), timeout=5, what="the fault")
        assert "servo id 4" in str(next(e for e in events if e["event"] == "fault")["reason"])
        emu.silence(4, False)
        wait_for(lambda: any(e["event"] == "recovered" for e in events), timeout=5, what="the recovery")
        wait_for(lambda: service._adapter_count(arm) == 1, what="the token back")  # type: ignore[attr-defined]
        sub.undeclare()  # type: ignore[attr-defined]


def test_a_calibration_maps_the_servos_and_one_that_contradicts_the_limits_is_refused(
    client: ArmClient, service: object, adapter_session: zenoh.Session, tmp_path: Path
) -> None:
    """shoulder_pan's servo mounted the other way round, its middle 252 counts off: with the
    arm's calibration (in the state dir, where ``armd calibrate`` keeps it), the adapter reads
    the joint at 0 where the servo is at 2300, and drives it the right way. A calibration whose
    range does not cover the joint limits is refused before anything moves."""
    from armd.adapters.base import calibration_file
    from armd.errors import RobotFileError
    from armd.robots import calibration

    arm = robots.load("so101")
    calibration.write(calibration_file(arm), {"shoulder_pan": (2300.0, -1, (600.0, 4000.0))})
    with EmulatorProcess(FeetechEmulator, ids=[1, 2, 3, 4, 5, 6], positions={1: 2300.0}) as emu:
        adapter = FeetechAdapter(adapter_session, arm, emu.port)
        try:
            wait_for(lambda: service._adapter_count(arm) == 1, what="the adapter's token")  # type: ignore[attr-defined]
            assert abs(adapter.measure().position[0]) < 2e-3
            client.move("so101", [0.5, 0.0, 0.0, 0.0, 0.0], wait=True, wait_timeout=15)
            assert abs(emu.position(1) - (2300 - 0.5 * 4096 / (2 * np.pi))) < 2
        finally:
            adapter.close()
        bad = tmp_path / "narrow.toml"
        calibration.write(bad, {"elbow_flex": (2048.0, 1, (1500.0, 2600.0))})
        with pytest.raises(RobotFileError) as e:
            FeetechAdapter(adapter_session, arm, emu.port, calibration=bad)
        assert e.value.field == "elbow_flex" and "contradicts the joint limits" in e.value.problem


def test_the_so101_end_to_end_from_the_command_line(router: str, service: object, tmp_path: Path) -> None:
    """``armd adapter feetech so101 --port ...`` as a user runs it, then ``armd move``."""
    arm = robots.load("so101")
    with (
        EmulatorProcess(FeetechEmulator, ids=[1, 2, 3, 4, 5, 6]) as emu,
        adapter_process(["feetech", "so101", "--port", emu.port, "--connect", router], tmp_path),
    ):
        wait_for(lambda: service._adapter_count(arm) == 1, timeout=30, what="the adapter's token")  # type: ignore[attr-defined]
        done = cli_move("so101", list(GOAL), router)
        assert done.returncode == 0, done.stderr
        assert np.max(np.abs(joints_of(arm, emu) - GOAL)) < 0.02
