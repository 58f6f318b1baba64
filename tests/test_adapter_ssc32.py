"""Service + adapters + controller emulators on pseudo-terminals: the code path a user's
/dev/ttyUSB0 takes, end to end, and the faults."""

from __future__ import annotations

import contextlib
import json
import logging
import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import zenoh

from armd import robots
from armd.adapters.emulators.measure import Motion, peaks, ssc32_motion, ssc32_speed_noise
from armd.adapters.emulators.measure import ratios as _ratios
from armd.adapters.emulators.process import EmulatorProcess
from armd.adapters.emulators.ssc32 import SSC32Emulator
from armd.adapters.ssc32 import SSC32Adapter
from armd.clients import ArmClient
from armd.errors import ControllerFault, ServiceError
from armd.service.zconfig import network_config
from tests.conftest import collect, wait_for

pytestmark = pytest.mark.slow  # (seconds: processes, routers, emulated boards; `pytest -m "not slow"` skips it)


def arm_moves(arm: robots.Robot, emu: SSC32Emulator) -> list[Any]:
    """The group moves the emulator received for the arm's servos (not its scanners')."""
    channels = {a.channel for a in arm.actuators.actuators}  # type: ignore[union-attr]
    return [m for m in emu.history if set(m.pulses) & channels]


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


def test_a_trajectory_with_one_bad_sample_is_rejected_whole(
    client: ArmClient, service: object, adapter_session: zenoh.Session
) -> None:
    arm = robots.load("insomniac")
    with SSC32Emulator() as emu:
        adapter = SSC32Adapter(adapter_session, arm, emu.port)
        try:
            wait_for(lambda: service._adapter_count(arm) == 1, what="the adapter's token")  # type: ignore[attr-defined]
            traj = client.plan("insomniac", [0.3, 1.2, -1.0, -0.5, 0.0], start=arm.neutral)
            msg = {
                "robot": "insomniac",
                "id": "bad",
                "kind": "move",
                "rate_hz": traj.rate_hz,
                "times": traj.times.tolist(),
                "position": traj.position.tolist(),
                "velocity": traj.velocity.tolist(),
                "acceleration": traj.acceleration.tolist(),
            }
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
            wait_for(
                lambda: any(e["event"] == "started" and e.get("id") == stopped["id"] for e in events),
                timeout=2,
                what="the stop started",
            )
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
        try:
            wait_for(lambda: service._adapter_count(arm) == 1, what="the adapter's token")  # type: ignore[attr-defined]
            client.move("sg5ut", [0.6, 1.0, -0.3, -0.4], speed=0.3)
            time.sleep(0.2)
            session.close()  # the adapter's process goes away: its session (and token) with it
            wait_for(lambda: service._adapter_count(arm) == 0, timeout=5, what="the token gone")  # type: ignore[attr-defined]
            with pytest.raises(ServiceError) as e:
                client.move("sg5ut", [0.2, 1.2, -0.6, -0.6])
            assert e.value.code == "no_adapter"
        finally:  # (failed or not: the thread of the dead process, and its session, go)
            adapter._stop.set()
            adapter.shutdown()
            session.close()


def test_sg5ut_mirrored_shoulder_pair_and_gripper_channel(
    client: ArmClient, service: object, adapter_session: zenoh.Session
) -> None:
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
            streamed = [set(m.pulses) for m in emu.history[1:]]  # (the first: the start-up's jump)
            assert set().union(*streamed) == {0, 1, 2, 3, 4}  # every channel of the map
            assert all(ch in ({0}, {1, 2}, {3}, {4}) for ch in streamed)  # the mirrored pair: one command
            client.gripper("sg5ut", 1.0)
            wait_for(lambda: emu.target(5) == 2000, timeout=5, what="the gripper channel")
        finally:
            adapter.close()


def test_desk4_linkage_moves_in_one_timed_command(
    router: str, client: ArmClient, service: object, tmp_path: Path
) -> None:
    """desk4's third servo moves two joints (through its four-bar: its angle a nonlinear function
    of theirs): the two servos of that linkage go in one command timed by T (their speeds are in
    no one ratio, and a board's group ends together), the others with a speed S each; every
    joint, read back from the board's pulses through the linkage's inverse, within its limits at
    every moment, and at each goal (two moves across most of the minor arm's range)."""
    arm = robots.load("desk4")
    # (the board and the adapter in processes of their own, as for every limit measured here: in
    # this busy interpreter a line is written, and stamped, when it gets to run, milliseconds late)
    with EmulatorProcess(SSC32Emulator) as emu:
        adapter = adapter_process(emu.port, router, tmp_path, robot="desk4")
        try:
            wait_for(lambda: service._adapter_count(arm) == 1, timeout=30, what="the adapter's token")  # type: ignore[attr-defined]
            since = emu.clock()
            for goal in ([0.8, 0.5, -0.3], [-0.5, 1.8, -2.4]):
                client.move("desk4", goal, wait=True, wait_timeout=15)
                time.sleep(0.3)
                assert np.allclose(ssc32_joints(arm, emu), goal, atol=3e-3)  # type: ignore[arg-type]
            streamed = [m for m in emu.history if m.time >= since]
            chs = [a.channel for a in arm.actuators.actuators]
            assert all(set(m.pulses) in ({chs[0]}, {chs[1], chs[2]}) for m in streamed)
            assert all(
                (m.duration_ms is not None) == (len(m.pulses) == 2) and bool(m.speeds) == (len(m.pulses) == 1)
                for m in streamed
            )
            m = _moved(arm, emu, since)  # type: ignore[arg-type]
            r = ratios(arm, m, 0.02)
            assert m.jumps == 0 and r.velocity <= SPEED_BAR and r.acceleration <= ACCEL_BAR and r.outside <= 1e-9, r
            # the minor arm moves along curves between the board's breakpoints: sampled every 0.5 ms,
            # its fastest and its change of speed over a period (the stream's) within the limits too
            fastest, change = peaks(arm, ssc32_motion(arm, emu, since=since, dense=5e-4), 0.02)  # type: ignore[arg-type]
            noise = ssc32_speed_noise(arm, emu, since)  # type: ignore[arg-type]  # (whole microseconds: each piece's speed off)
            assert np.all(fastest <= arm.limits.velocity * SPEED_BAR), fastest / arm.limits.velocity
            assert np.all(change <= arm.limits.acceleration * ACCEL_BAR + 2 * noise / 0.02), (
                change / arm.limits.acceleration
            )
        finally:
            adapter.terminate()
            adapter.wait(10)


def test_an_adapter_refuses_an_arm_it_cannot_drive(adapter_session: zenoh.Session) -> None:
    """Servo arms to the GRBL adapter, stepper arms to the SSC-32's: refused before any port
    is opened, naming what the adapter drives."""
    from armd.adapters.grbl import GrblAdapter
    from armd.errors import BadRequest

    with pytest.raises(BadRequest) as e:
        SSC32Adapter(adapter_session, robots.load("gupta3"), "/dev/nonexistent-ssc32")
    assert e.value.field == "robot" and "not all servos: the SSC-32 adapter drives servos" in e.value.message
    with pytest.raises(BadRequest) as e:
        GrblAdapter(adapter_session, robots.load("insomniac"), "/dev/nonexistent-grbl")
    assert e.value.field == "robot" and "not all steppers: the GRBL adapter drives steppers" in e.value.message


# -- the promise, at the board: every joint within its limits, at every moment ----------------------

ROOT = Path(__file__).resolve().parent.parent
GOAL = [1.2, 2.0, -1.8, 1.0, 1.0]  # insomniac, far from neutral: every joint near its velocity limit
# The board's pulses and speeds are whole microseconds: the measure allows each piece's speed
# that rounding (adapters/emulators/measure.py). A line the host held on its way (the kernel
# thread that carries a pseudo-terminal's bytes, a few ms now and then) reaches the board late
# and the next one on time: that change is counted over the period the adapter aimed for, and
# such lines are counted (HELD_MAX a move; an adapter that sends lines too close together would
# show it at every line). What is left is the host's timing of the writes (the loop's 1 ms
# tick); the adapter's own model keeps every change within the limit
# (test_the_adapters_own_model_keeps_the_limits).
ACCEL_BAR = 1.05
SPEED_BAR = 1.01  # (the same rounding on a speed)
BUSY_ACCEL_BAR = 1.05  # beside two busy processes on two cores (the loop runs at real-time priority)
HELD_MAX = 10  # lines of a move (of about 45) held on their way by the host: a busy host holds a few
# insomniac's base, wrist and roll across most of their range: each at its velocity limit, 3 rad/s
# (1910 us/s: a frame of it is 38 us), for most of the 1.5 s
SWEEP = ([-1.45, 1.8, -1.6, 1.3, -1.45], [1.45, 1.8, -1.6, -1.3, 1.45])


def ratios(arm: robots.Robot, m: Motion, period: float, exact: bool = False) -> Any:
    """The worst speed and acceleration against the limits: of the board's output (the rounding
    of its targets to whole microseconds allowed for), or of an exact path (``exact``: the
    adapter's own model)."""
    if exact:
        return _ratios(arm, m, period)
    return _ratios(arm, m, period, ssc32_speed_noise(arm, EMULATORS[-1], m.times[0]), held=True)


EMULATORS: list[SSC32Emulator] = []  # the test's emulator, for its rounding (set by _moved)


def commanded(adapter: SSC32Adapter) -> Motion:
    """The lines as the adapter sent and timed them (each servo from where it had the board, at
    the time the link delivers its command): what a board that keeps time does, before the
    pulses' rounding."""
    pieces = list(adapter._pieces)[1:]
    times = sorted({float(t) for _, t0, _, t1 in pieces for t in (*t0, *t1)})
    return Motion(np.array(times), np.array([adapter._was_at(t) for t in times]), 0)


def adapter_process(
    port: str, router: str, tmp_path: Path, *extra: str, robot: str = "insomniac"
) -> subprocess.Popen[str]:
    """``armd adapter ssc32 insomniac`` as a user runs it: a process of its own, its log in
    ``tmp_path`` (a pipe nobody reads would stall it once full), its kept pose there too."""
    env = {**os.environ, "ARMD_STATE_DIR": str(tmp_path)}
    return subprocess.Popen(
        [
            sys.executable,
            "-m",
            "armd.cli",
            "adapter",
            "ssc32",
            robot,
            "--port",
            port,
            "--connect",
            router,
            *extra,
        ],
        cwd=ROOT,
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=(tmp_path / "adapter.log").open("w"),
        text=True,
    )


@contextlib.contextmanager
def running_adapter(
    router: str, service: Any, tmp_path: Path, *extra: str, **emulator: Any
) -> Iterator[tuple[EmulatorProcess, subprocess.Popen[str]]]:
    """An emulated SSC-32 in a process of its own (a board has its own CPU, not this busy
    interpreter's) and ``armd adapter ssc32 insomniac`` on it as a user runs it (``extra``: its
    options), ready: its token seen, its start-up's jump to neutral on the board."""
    arm = robots.load("insomniac")
    with EmulatorProcess(SSC32Emulator, **emulator) as emu:
        proc = adapter_process(emu.port, router, tmp_path, *extra)
        try:
            wait_for(lambda: service._adapter_count(arm) == 1, timeout=30, what="the adapter's token")
            time.sleep(0.1)
            yield emu, proc
        finally:
            proc.terminate()
            proc.wait(10)


def _moved(arm: robots.Robot, emu: SSC32Emulator, since: float) -> Motion:
    EMULATORS.append(emu)
    m = ssc32_motion(arm, emu, since=since)
    assert len(m.times) > 10, "the board did not move"
    return m


def _check_promise(
    arm: robots.Robot, m: Motion, period: float, planned: float, goal: list[float], slack: float = 0.15
) -> None:
    r = ratios(arm, m, period)
    assert m.jumps == 0
    assert r.outside <= 1e-9, r
    assert r.velocity <= SPEED_BAR, r
    assert r.acceleration <= ACCEL_BAR and r.held <= HELD_MAX, r
    start, end = m.moving()
    assert end - start <= 1.15 * planned + slack, (end - start, planned)  # re-timed at most a little slower
    assert np.max(np.abs(m.position[-1] - np.array(goal))) < 3e-3  # at the goal (within the pulses' rounding)


@pytest.mark.parametrize(
    ("baud", "query_delay"),
    [(115200, 1e-4), (115200, 0.15), (9600, 1e-4)],
    ids=["quiet", "slow board", "factory 9600 baud"],
)
def test_a_move_keeps_every_limit_at_the_board(
    router: str, client: ArmClient, service: object, tmp_path: Path, baud: int, query_delay: float
) -> None:
    """What the board outputs (its own interpolation, exactly) moves every joint within its
    limits, and arrives: at 9600 baud the stream is thinned to what the link carries, and a
    board that answers QP in 150 ms neither slows the stream nor faults. The adapter runs as a
    user runs it, a process of its own (in this interpreter, beside the service and the router,
    a thread switch can hold a write after it was timed)."""
    arm = robots.load("insomniac")
    board = running_adapter(router, service, tmp_path, "--baud", str(baud), baud=baud, query_delay=query_delay)
    with board as (emu, _):
        events, sub = collect(client, "armd/insomniac/events")
        since = emu.clock()
        r = client.move("insomniac", GOAL, wait=True, wait_timeout=15)
        time.sleep(0.3)
        sub.undeclare()  # type: ignore[attr-defined]
        assert not [e for e in events if e["event"] in ("fault", "aborted", "rejected")], events
        first = arm.actuators.actuators[0].channel  # (each line: a command per servo, this one's first)
        moves = [m.time for m in emu.history if m.time >= since and first in m.pulses]
        # the stream's own period (a whole number of the plan's 50 Hz samples: the move asks the service's
        # default rate), from its cadence as the board received it (a little longer: the loop runs late)
        period = round(float(np.median(np.diff(moves))) * 50.0) / 50.0
        _check_promise(arm, _moved(arm, emu, since), period, r.duration, GOAL)
        if baud == 9600:
            assert period > 1.5 / 50.0  # thinned: 50 lines a second do not fit 960 bytes a second


def test_the_adapters_own_model_keeps_the_limits(
    client: ArmClient, service: object, adapter_session: zenoh.Session
) -> None:
    """The lines as the adapter aimed and timed them (before the pulses' rounding): every change
    of speed within the acceleration limits, every speed within the velocity limits."""
    arm = robots.load("insomniac")
    with SSC32Emulator() as emu:
        adapter = SSC32Adapter(adapter_session, arm, emu.port)
        try:
            wait_for(lambda: service._adapter_count(arm) == 1, what="the adapter's token")  # type: ignore[attr-defined]
            client.move("insomniac", GOAL, wait=True, wait_timeout=15)
            r = ratios(arm, commanded(adapter), 0.02, exact=True)
            assert r.velocity <= 1.0 + 1e-6 and r.acceleration <= 1.0 + 1e-3, r
        finally:
            adapter.close()


def test_a_board_running_on_to_its_target_can_still_stop_inside_the_limits(
    client: ArmClient, service: object, adapter_session: zenoh.Session
) -> None:
    """A long lead (a busy machine's: 0.25 s) toward a goal near a limit: each line's target is
    where the board stops if the adapter stalls, and a stall shorter than the lead leaves the
    board running toward it at the line's speed. From every target, at that speed, braking by
    the acceleration limit must end inside the position limits (else the adapter, running
    again, must brake harder than the limit: the 6x seen in a stall stress run). Before the
    mend, targets were only kept inside the limits themselves, reached at full speed."""
    arm = robots.load("insomniac")
    goal = [1.45, 2.0, -1.8, 1.0, 1.0]  # base_yaw 0.12 rad from its upper limit
    with SSC32Emulator() as emu:
        adapter = SSC32Adapter(adapter_session, arm, emu.port, lead=0.25)
        try:
            wait_for(lambda: service._adapter_count(arm) == 1, what="the adapter's token")  # type: ignore[attr-defined]
            client.move("insomniac", goal, wait=True, wait_timeout=15)
            amax = arm.limits.acceleration
            checked = 0
            for p0, t0, p1, t1 in list(adapter._pieces)[1:]:
                v = (p1 - p0) / np.maximum(t1 - t0, 1e-9)
                stop = p1 + v * np.abs(v) / (2.0 * amax)
                assert arm.limits.contains(stop, tol=1e-6), (p1, v, stop)
                checked += 1
            assert checked > 10
            assert np.allclose(ssc32_joints(arm, emu), goal, atol=3e-3)
        finally:
            adapter.close()


def test_busy_processes_do_not_break_the_promise(
    router: str, client: ArmClient, service: object, tmp_path: Path
) -> None:
    """Two processes spinning beside the adapter (on a 2-core machine): late ticks re-time the
    stream, never speed it up. The adapter runs as users run it, a process of its own (in this
    interpreter, beside the service and the router, its loop would wait for their turns at the
    interpreter as well); the board is an emulator in a process of its own (a board has its own
    CPU)."""
    arm = robots.load("insomniac")
    burn = [
        subprocess.Popen([sys.executable, "-c", "import time\nt=time.time()+30\nwhile time.time()<t: pass"])
        for _ in range(2)
    ]
    try:
        with running_adapter(router, service, tmp_path) as (emu, _):
            since = emu.clock()
            r = client.move("insomniac", GOAL, wait=True, wait_timeout=20)
            time.sleep(0.3)
            m = ssc32_motion(arm, emu, since=since)  # type: ignore[arg-type]
            rr = _ratios(arm, m, 0.02, ssc32_speed_noise(arm, emu, since), held=True)  # type: ignore[arg-type]
            assert m.jumps == 0 and rr.velocity <= SPEED_BAR and rr.outside <= 1e-9, rr
            assert rr.acceleration <= BUSY_ACCEL_BAR and rr.held <= HELD_MAX, rr
            assert np.max(np.abs(m.position[-1] - np.array(GOAL))) < 3e-3
            assert m.moving()[1] - m.moving()[0] <= 2.0 * r.duration + 0.5
    finally:
        for p in burn:
            p.kill()
            p.wait()


def test_a_line_held_on_its_way_changes_the_speeds_late_not_by_more(
    router: str, client: ArmClient, service: object, tmp_path: Path
) -> None:
    """The host holds a line 8 ms after the adapter wrote it, three times in a move (as a USB-serial
    link or the kernel's terminal thread may now and then): the servos change speed late, by
    what was aimed (a move timed by T would cover the rest of its way in T instead: faster or
    slower by the distance lost, here a change of speed twice the limit). The change after a held
    line comes early and is counted over the period the adapter aimed for; every joint within
    its limits; the held lines seen as held."""
    arm = robots.load("insomniac")
    with running_adapter(router, service, tmp_path) as (emu, _):
        since = emu.clock()
        r = client.move("insomniac", GOAL)
        for _ in range(3):
            time.sleep(0.2 * r.duration)
            emu.delay_input(0.008)
        wait_for(lambda: np.max(np.abs(ssc32_joints(arm, emu) - GOAL)) < 3e-3, timeout=15, what="the goal")
        time.sleep(0.3)
        m = _moved(arm, emu, since)
        rr = ratios(arm, m, 0.02)
        assert m.jumps == 0 and rr.velocity <= SPEED_BAR and rr.outside <= 1e-9, rr
        assert rr.acceleration <= ACCEL_BAR, rr
        assert 1 <= rr.held <= 3 + HELD_MAX, rr


def test_a_stalled_adapter_never_catches_up_by_jumping(
    router: str, client: ArmClient, service: object, tmp_path: Path
) -> None:
    """The adapter's process stopped (SIGSTOP) for 1.5 s mid-move: the board finishes the move in
    hand and holds; when the adapter runs again it ramps up from rest within the limits and
    finishes the trajectory later: never faster than the limits."""
    arm = robots.load("insomniac")
    with running_adapter(router, service, tmp_path) as (emu, proc):
        since = emu.clock()
        r = client.move("insomniac", GOAL)
        time.sleep(0.3 * r.duration)
        proc.send_signal(signal.SIGSTOP)
        stalled = emu.clock()
        time.sleep(1.5)
        proc.send_signal(signal.SIGCONT)
        wait_for(lambda: np.max(np.abs(ssc32_joints(arm, emu) - GOAL)) < 3e-3, timeout=15, what="the goal")
        time.sleep(0.3)
        m = _moved(arm, emu, since)
        before = Motion(m.times[m.times <= stalled], m.position[m.times <= stalled], 0)
        after = m.times >= stalled + 1.0
        resumed = Motion(m.times[after], m.position[after], 0)
        for label, part in (("before the stall", before), ("after it", resumed)):
            rr = ratios(arm, part, 0.02)
            said = (label, rr, (tmp_path / "adapter.log").read_text()[-3000:])  # (what the adapter said, if it fails)
            assert rr.velocity <= SPEED_BAR and rr.acceleration <= ACCEL_BAR and rr.outside <= 1e-9, said
            assert rr.held <= HELD_MAX, said
        assert m.jumps == 0
        # the stall: the board finished its move in hand (within the lead and a period) and held there:
        # the one stop at speed an SSC-32 move cannot soften (docs/adapters.md)
        at = [
            np.array([np.interp(t, m.times, m.position[:, j]) for j in range(arm.nq)])
            for t in (stalled + 0.15, stalled + 1.0)
        ]
        assert np.allclose(at[0], at[1], atol=1e-9)  # held, while the adapter was stopped
        v = np.diff(m.position, axis=0) / np.maximum(np.diff(m.times), 1e-9)[:, None]
        assert np.all(
            np.abs(v[(m.times[:-1] >= stalled) & (m.times[1:] <= stalled + 1.5)]) <= arm.limits.velocity * SPEED_BAR
        )


def test_a_restarted_adapter_adopts_the_board_and_a_powered_board_gets_the_last_pose(
    client: ArmClient, service: object, adapter_session: zenoh.Session
) -> None:
    arm = robots.load("insomniac")
    q1 = np.array([0.4, 1.3, -1.2, -0.3, 0.2])
    with SSC32Emulator() as emu:
        adapter = SSC32Adapter(adapter_session, arm, emu.port)
        try:
            wait_for(lambda: service._adapter_count(arm) == 1, what="the adapter's token")  # type: ignore[attr-defined]
            client.move("insomniac", q1.tolist(), wait=True, wait_timeout=15)
        finally:
            adapter.close()  # (it keeps the last pose in ARMD_STATE_DIR)
        wait_for(lambda: service._adapter_count(arm) == 0, what="the token gone")  # type: ignore[attr-defined]
        sent = len(arm_moves(arm, emu))
        adapter = SSC32Adapter(adapter_session, arm, emu.port)  # the board kept its pulses: adopted, nothing sent
        try:
            time.sleep(0.1)
            assert len(arm_moves(arm, emu)) == sent  # (its scanners' servos start their sweeps: not the arm's)
            assert np.allclose(adapter.measure().position, q1, atol=0.02)
        finally:
            adapter.close()
        emu.power_cycle()  # a board just powered: no pulses; the first command is a jump, to the pose kept
        adapter = SSC32Adapter(adapter_session, arm, emu.port)
        try:
            wait_for(lambda: len(arm_moves(arm, emu)) > sent, timeout=2, what="the first command")
            first = arm_moves(arm, emu)[sent]
            assert first.duration_ms is None
            assert [first.pulses[a.channel] for a in arm.actuators.actuators] == arm.actuators.commands(q1).tolist()  # type: ignore[union-attr]
        finally:
            adapter.close()


def test_a_board_that_disagrees_with_the_adapter_is_a_fault(
    client: ArmClient, service: object, adapter_session: zenoh.Session
) -> None:
    """A board reset behind the adapter's back answers QP with no pulse: a fault that says so
    and stays; nothing is sent to it after, not even the stops an operator asks (the first line
    to a channel without a pulse jumps its servo at full speed; before, each stop did)."""
    arm = robots.load("sg5ut")
    with SSC32Emulator() as emu:
        adapter = SSC32Adapter(adapter_session, arm, emu.port, query_period=0.1)
        try:
            wait_for(lambda: service._adapter_count(arm) == 1, what="the adapter's token")  # type: ignore[attr-defined]
            events, sub = collect(client, "armd/sg5ut/events")
            emu.power_cycle()  # reset behind the adapter's back: QP answers 0 (one in flight may be lost: no answer)
            said = lambda: [str(e["reason"]) for e in events if e["event"] == "fault"]  # noqa: E731
            wait_for(lambda: any("outputs 0 us" in r and "reset" in r for r in said()), timeout=5, what="the fault")
            sent = len(emu.history)
            for _ in range(3):  # (an operator's estops: a line would jump a limp servo, so none is sent)
                client.session.put("armd/sg5ut/estop", json.dumps({"by": "test"}))  # type: ignore[attr-defined]
                time.sleep(0.15)
            assert len(emu.history) == sent, emu.history[sent:]
            assert emu.pulses() == {}
            assert service._adapter_count(arm) == 0  # type: ignore[attr-defined]  # (and it stays faulted: no recovery)
            sub.undeclare()  # type: ignore[attr-defined]
        finally:
            adapter.close()


def test_a_link_too_slow_for_the_trajectory_is_refused_before_any_pulse(
    client: ArmClient, service: object, adapter_session: zenoh.Session
) -> None:
    arm = robots.load("insomniac")
    with SSC32Emulator(baud=1200) as emu:
        adapter = SSC32Adapter(adapter_session, arm, emu.port, baud=1200, timeout=1.0)
        try:
            wait_for(lambda: service._adapter_count(arm) == 1, what="the adapter's token")  # type: ignore[attr-defined]
            events, sub = collect(client, "armd/insomniac/events")
            sent = len(arm_moves(arm, emu))
            with pytest.raises(ServiceError) as e:  # the move's reply says so: the adapter refused it
                client.move("insomniac", GOAL)
            assert e.value.code == "rejected" and "1200 baud" in e.value.message
            wait_for(lambda: any(e["event"] == "rejected" for e in events), timeout=5, what="a rejection")
            time.sleep(0.2)
            assert len(arm_moves(arm, emu)) == sent
            assert "1200 baud" in str(next(e for e in events if e["event"] == "rejected")["reason"])
            sub.undeclare()  # type: ignore[attr-defined]
        finally:
            adapter.close()


@pytest.mark.parametrize("held", [0.015, 0.019], ids=["15 ms", "19 ms"])
def test_lines_a_busy_host_holds_up_to_a_frame_are_no_fault(
    router: str, client: ArmClient, service: object, tmp_path: Path, held: float
) -> None:
    """A busy host holds every line 15 (19) ms on its way to the board (the kernel thread that
    carries the terminal's bytes runs late, and what was written meanwhile goes with it: a QP
    written soon after a line is held less than the line), and the board answers QP with its
    frame's pulse (up to 20 ms behind its interpolation) in 10 us. Sweeps at 3 rad/s (1910
    us/s): a QP answer up to 39 ms of the motion (74 us) behind the model when it was asked, and
    no fault: every sweep ends at its goal within its velocity and position limits, with no
    halt, no stop, no re-timing. Before the checks knew the board (an answer 25 us from the
    model was a fault, at once), these sweeps faulted in the first or second sweep, each fault
    a halt from full speed within a frame (20-86x the acceleration limit counted) and a
    recovery from an answer the board had moved on from, faults and recoveries alternating
    every 45-60 ms.

    The board changes speed when each line arrives: the host's timing, more so on a busy
    machine, where a line is held longer than the rest and the next less (the adapter's own
    timing is checked exactly in test_the_adapters_own_model_keeps_the_limits). So the changes
    of speed are not held to the limits here (beside two busy processes a line held 19 ms and
    the next less counted 20x): that no fault halted a sweep is what the events say. (At a
    move's end the last lines aim past the goal, and a board a little ahead of the model
    reaches such a target and is sent back: up to 0.03 rad, with the committed adapter as
    well; the stream's, not a check's doing.)"""
    arm = robots.load("insomniac")
    with running_adapter(router, service, tmp_path) as (emu, _):
        emu.hold_input(held)  # (less than the stream's period: two lines never go together)
        events, sub = collect(client, "armd/insomniac/events")
        for goal in (*SWEEP, *SWEEP):
            since = emu.clock()
            client.move("insomniac", goal, wait=True, wait_timeout=15)
            time.sleep(0.2)
            m = _moved(arm, emu, since)
            rr = ratios(arm, m, 0.02)
            said = (goal, rr, events)
            assert m.jumps == 0 and rr.velocity <= SPEED_BAR and rr.outside <= 1e-9, said
            assert np.max(np.abs(m.position[-1] - np.array(goal))) < 3e-3, said
        sub.undeclare()  # type: ignore[attr-defined]
        assert not [e for e in events if e["event"] in ("fault", "aborted", "late", "recovered")], events


def _reversal(m: Motion) -> np.ndarray:
    """Per joint, the farthest it went back against its way [rad] (its way: from where it
    starts to where it ends)."""
    out = np.zeros(m.position.shape[1])
    for j in range(m.position.shape[1]):
        x = np.sign(m.position[-1, j] - m.position[0, j] or 1.0) * m.position[:, j]
        out[j] = float(np.max(np.maximum.accumulate(x) - x))
    return out


def test_a_servo_someone_else_moves_is_a_fault_and_no_stop_moves_it_back(
    router: str, client: ArmClient, service: object, tmp_path: Path
) -> None:
    """Another program on the same port turns the resting arm's base back (564 us at 400 us/s,
    1.4 s), and an operator's estops come from 0.4 s on (every 0.1 s). The QP that sees it
    off the model is asked again, and the second answer is the fault (channel 0, twice in a
    row); the adapter recovers once the servo stands still, from where it is then (its state
    the board's). Meanwhile and after, nothing the adapter sends moves the servo back: its
    output never reverses by more than 0.005 rad, and the other program's move ends where it
    sent it. Before: each recovery took an answer the servo had since moved on from, and each
    estop planned from there sent the servo to it at 1 us/s (its move ended 400 us short, held
    at such an answer; a stop at rest now sends nothing)."""
    arm = robots.load("insomniac")
    with running_adapter(router, service, tmp_path) as (emu, _):
        client.move("insomniac", GOAL, wait=True, wait_timeout=15)
        time.sleep(0.3)
        events, sub = collect(client, "armd/insomniac/events")
        states, states_sub = collect(client, "armd/insomniac/state")
        since = emu.clock()
        other = os.open(emu.port, os.O_WRONLY | os.O_NOCTTY)  # (a raw write: no flush of the adapter's input)
        try:
            os.write(other, b"#0P1700S400\r")
        finally:
            os.close(other)
        time.sleep(0.4)  # (the servo 160 us on)
        end = time.monotonic() + 3.0  # (the other move ends in 1.4 s; then the servo is still, and recovered)
        while time.monotonic() < end or (
            time.monotonic() < end + 5.0 and not any(e["event"] == "recovered" for e in events)
        ):
            client.session.put("armd/insomniac/estop", json.dumps({"by": "test"}))
            time.sleep(0.1)
        time.sleep(2.0)  # (a line that creeps at 1 us/s: 3 us, 0.005 rad, in 3 s)
        sub.undeclare()  # type: ignore[attr-defined]
        states_sub.undeclare()  # type: ignore[attr-defined]
        m = ssc32_motion(arm, emu, since=since)  # type: ignore[arg-type]
        back = _reversal(m)
        assert np.all(back <= 0.005), (back, events)
        assert emu.pulse(0) == 1700  # (the other program's move ended where it was sent)
        faults = [str(e["reason"]) for e in events if e["event"] == "fault"]
        assert faults and "channel 0 outputs" in faults[0] and "twice in a row" in faults[0], faults
        assert "asked again" in (tmp_path / "adapter.log").read_text()
        assert service._adapter_count(arm) == 1  # type: ignore[attr-defined]
        here = np.array(states[-1]["position"])
        assert np.allclose(here, ssc32_joints(arm, emu), atol=0.01), (here, ssc32_joints(arm, emu))  # type: ignore[arg-type]


# -- the port vanishes ----------------------------------------------------------------------------


def test_a_vanished_port_is_one_line_and_opened_again_with_a_back_off(
    adapter_session: zenoh.Session, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """The cable pulled for good: the port fails under the adapter (EIO from every call, a
    termios.error from its flush). One ERROR line says so, with no traceback, and the adapter
    opens the port again after 0.25, 0.5, 1, 2 s: not at every 20 ms check. Before: a
    traceback every 20 ms (termios.error is no SerialException), without end."""
    arm = robots.load("sg5ut")
    link = tmp_path / "ttyUSB0"  # (the path a user gave: a udev name that vanishes with the device)
    with SSC32Emulator() as emu:
        link.symlink_to(emu.port)
        adapter = SSC32Adapter(adapter_session, arm, str(link), state_dir=tmp_path)
        try:
            time.sleep(0.3)
            caplog.clear()
            with caplog.at_level(logging.DEBUG):
                emu.unplug()
                time.sleep(3.0)
            records = [r for r in caplog.records if r.name.startswith("armd")]
            errors = [r for r in records if r.levelno >= logging.ERROR]
            assert len(errors) == 1 and "is gone" in errors[0].getMessage(), [r.getMessage() for r in errors]
            assert all(r.exc_info is None for r in records)  # (no traceback)
            attempts = [r for r in records if "cannot open" in r.getMessage()]
            assert 3 <= len(attempts) <= 5, [r.getMessage() for r in attempts]  # 0.25 + 0.5 + 1 + 2 s: 4
            assert adapter.fault is not None and "is gone" in adapter.fault
        finally:
            adapter.close()


@pytest.mark.parametrize("version", ["\x00\x7f\x13garbage", "Grbl 1.1h ['$' for help]", "ok"])
def test_what_does_not_answer_ver_like_an_ssc32_gets_nothing(
    adapter_session: zenoh.Session, tmp_path: Path, version: str
) -> None:
    arm = robots.load("sg5ut")
    with SSC32Emulator(version=version) as emu:
        with pytest.raises(ControllerFault, match="is not an SSC-32"):
            SSC32Adapter(adapter_session, arm, emu.port, state_dir=tmp_path)
        time.sleep(0.1)
        assert emu.history == [] and emu.errors == []  # (asked who it is; nothing else)


def test_a_port_back_with_its_board_powered_recovers_within_the_limits(
    router: str, client: ArmClient, service: object, tmp_path: Path
) -> None:
    """The cable pulled mid-move for 1.5 s, the board powered: it finishes the move in hand
    and holds; the adapter says the port is gone once, opens it again (a new terminal behind
    the same name), finds an SSC-32 there (VER) where its model has the board, and recovers.
    The board's output, through all of it, keeps the limits, never jumps nor goes back."""
    arm = robots.load("insomniac")
    link = tmp_path / "ttyUSB0"
    with EmulatorProcess(SSC32Emulator) as emu:
        link.symlink_to(emu.port)
        proc = adapter_process(str(link), router, tmp_path)
        try:
            wait_for(lambda: service._adapter_count(arm) == 1, timeout=30, what="the adapter's token")  # type: ignore[attr-defined]
            time.sleep(0.1)
            events, sub = collect(client, "armd/insomniac/events")
            since = emu.clock()
            r = client.move("insomniac", GOAL)
            time.sleep(0.3 * r.duration)
            unplugged = emu.clock()
            emu.unplug()
            link.unlink()
            time.sleep(1.5)
            plugged = emu.clock()
            link.symlink_to(emu.plug())
            wait_for(lambda: any(e["event"] == "recovered" for e in events), timeout=15, what="recovered")
            wait_for(lambda: service._adapter_count(arm) == 1, timeout=5, what="the token again")  # type: ignore[attr-defined]
            client.move("insomniac", arm.neutral, wait=True, wait_timeout=20)
            time.sleep(0.3)
            sub.undeclare()  # type: ignore[attr-defined]
            m = _moved(arm, emu, since)  # type: ignore[arg-type]
            log_text = (tmp_path / "adapter.log").read_text()
            # the board finished the move in hand and held (the one stop at speed an SSC-32 move
            # cannot soften: docs/adapters.md); before the cable was pulled and after it was back,
            # every limit held
            for label, part in (("before", m.times <= unplugged), ("after", m.times >= plugged)):
                rr = ratios(arm, Motion(m.times[part], m.position[part], 0), 0.02)
                said = (label, rr, log_text[-3000:])
                assert rr.velocity <= SPEED_BAR and rr.acceleration <= ACCEL_BAR and rr.outside <= 1e-9, said
            assert m.jumps == 0
            held = (m.times >= unplugged + 0.35) & (m.times <= plugged)  # (the lead and a period after)
            assert np.ptp(m.position[held], axis=0).max() < 1e-9 if held.any() else True
            faults = [str(e["reason"]) for e in events if e["event"] == "fault"]
            assert len(faults) == 1 and "is gone" in faults[0], faults
            assert log_text.count("is gone") == 1 and "Traceback" not in log_text, log_text[-3000:]
            assert len(log_text.splitlines()) < 30, log_text[-3000:]  # (no line at every pass while it was gone)
            assert np.max(np.abs(ssc32_joints(arm, emu) - arm.neutral)) < 3e-3  # type: ignore[arg-type]
        finally:
            proc.terminate()
            proc.wait(10)
