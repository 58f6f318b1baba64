"""Service + GRBL adapter + GRBL emulator on a pseudo-terminal: the code path a user's
/dev/ttyACM0 takes, end to end: an unknown position until an operator says where the arm is,
machine coordinates, GRBL's settings, errors and alarms, stops by feed hold (announced with the
time they take), and (on the emulator with GRBL's planner) the executed timing and acceleration
of moves, where GRBL turns from one streamed line to the next too."""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

import numpy as np
import pytest
import zenoh

from armd import robots
from armd.adapters.emulators.grbl import GrblEmulator
from armd.adapters.emulators.measure import actuator_limits_deg, fitted_peaks, grbl_exact_motion, grbl_motion, span
from armd.adapters.grbl import GrblAdapter
from armd.clients import ArmClient
from armd.errors import ControllerFault, ServiceError
from tests.conftest import collect, wait_for

pytestmark = pytest.mark.slow  # (seconds: processes, routers, emulated boards; `pytest -m "not slow"` skips it)

ARM = "gupta3"


def actuator_steps(arm: robots.Robot, q: object) -> np.ndarray:
    return np.asarray(arm.actuators.commands(np.asarray(q, dtype=float)), dtype=np.int64)


def grbl_steps(arm: robots.Robot, emu: GrblEmulator) -> np.ndarray:
    steps = emu.steps()
    return np.array([steps[a.axis] for a in arm.actuators.actuators], dtype=np.int64)  # type: ignore[union-attr]


class Writes:
    """Every byte the adapter writes to GRBL, recorded (real-time bytes are not in the emulator's
    ``lines``), and when each write was made (``time.monotonic``, the emulator's clock)."""

    def __init__(self, adapter: GrblAdapter) -> None:
        self.data = bytearray()
        self.times: list[tuple[float, bytes]] = []
        original = adapter._write

        def write(data: bytes) -> None:
            self.data += data
            self.times.append((time.monotonic(), data))
            original(data)

        adapter._write = write  # type: ignore[method-assign]


@contextmanager
def running(
    service: object, session: zenoh.Session, emu: GrblEmulator, arm: robots.Robot | None = None, **kwargs: Any
) -> Iterator[GrblAdapter]:
    adapter = GrblAdapter(session, arm or robots.load(ARM), emu.port, **kwargs)
    try:
        wait_for(lambda: service._adapter_count(adapter.robot) == 1, what="the adapter's token")  # type: ignore[attr-defined]
        yield adapter
    finally:
        adapter.close()


def wait_state(client: ArmClient, **want: object) -> None:
    wait_for(lambda: all(client.state(ARM).get(k) == v for k, v in want.items()), what=f"the state {want}")


def test_move_refused_until_an_operator_says_where_the_arm_is(
    client: ArmClient, service: object, adapter_session: zenoh.Session
) -> None:
    arm = robots.load(ARM)
    with GrblEmulator() as emu, running(service, adapter_session, emu) as adapter:
        writes = Writes(adapter)
        assert not adapter.homed
        for i, act in enumerate(arm.actuators.actuators):
            assert emu.settings[100 + i] == pytest.approx(act.steps_per_degree, rel=1e-4)  # type: ignore[union-attr]
        wait_state(client, source="adapter", homed=False)
        with pytest.raises(ServiceError) as refused:
            client.move(ARM, [0.2, 1.4, -1.4])
        assert refused.value.code == "position_unknown"
        assert not any(ln.startswith(("G1", "G53")) for ln in emu.lines)  # nothing of it reached GRBL
        assert b"!" not in writes.data
        events, sub = collect(client, f"armd/{ARM}/events")
        client.estop(ARM)  # the position unknown: an estop still holds GRBL
        wait_for(lambda: any(e["event"] == "done" for e in events), timeout=5, what="the estop done")
        assert b"!" in writes.data and emu.state == "Idle"
        sub.undeclare()  # type: ignore[attr-defined]
        answer = client.unlock(ARM, "assume_rest", wait=10)
        assert answer is not None and answer["event"] == "unlocked", answer
        wait_state(client, homed=True)
        rest = np.array(arm.neutral)
        assert np.allclose(client.state(ARM)["position"], rest, atol=arm.actuators.actuators[0].resolution)
        goal = np.array([0.31, 1.23, -1.07])
        client.move(ARM, goal.tolist(), wait=True, wait_timeout=20)
        wait_for(lambda: emu.state == "Idle", timeout=5, what="GRBL idle")
        # GRBL started at 0 at the rest pose: its machine position is the goal's whole steps less the rest's
        assert np.array_equal(grbl_steps(arm, emu), actuator_steps(arm, goal) - actuator_steps(arm, rest))
        assert emu.overflows == 0 and emu.max_rx_used <= 128
        moves = [ln for ln in emu.lines if "G1" in ln]
        assert moves and all(ln.startswith("G53G1") for ln in moves)  # machine coordinates, every line


def test_assume_rest_at_start_and_a_rest_pose_of_its_own(
    client: ArmClient, service: object, arm_copy: Any, adapter_session: zenoh.Session
) -> None:
    folder = arm_copy(ARM, toml_edits=[("baud = 115200", 'baud = 115200\nrest_pose = [0.1, "pi/2", -1.0]')])
    with GrblEmulator() as emu:
        adapter = GrblAdapter(adapter_session, robots.load_folder(folder), emu.port, assume_rest=True)
        try:
            assert adapter.homed
            assert np.allclose(adapter.measure().position, [0.1, np.pi / 2, -1.0], atol=1e-3)
        finally:
            adapter.close()
    arm = robots.load(ARM)
    with GrblEmulator() as emu, running(service, adapter_session, emu, assume_rest=True) as adapter:
        assert adapter.homed
        wait_state(client, source="adapter", homed=True)
        goal = np.array([-0.4, 1.0, -1.3])
        client.move(ARM, goal.tolist(), wait=True, wait_timeout=20)
        wait_for(lambda: emu.state == "Idle", timeout=5, what="GRBL idle")
        assert np.array_equal(grbl_steps(arm, emu), actuator_steps(arm, goal) - actuator_steps(arm, arm.neutral))


def test_a_stored_work_offset_does_not_shift_the_arm(
    client: ArmClient, service: object, adapter_session: zenoh.Session
) -> None:
    arm = robots.load(ARM)
    kwargs: dict[str, Any] = {"offsets": {"G54": {"X": 10.0, "Y": -20.0, "Z": 5.0}}}
    with GrblEmulator(**kwargs) as emu, running(service, adapter_session, emu, assume_rest=True):
        emu_any: Any = emu
        assert any(emu_any.work_offset().values())  # G54 is active: a work offset GRBL would apply
        goal = np.array([0.25, 1.3, -1.2])
        client.move(ARM, goal.tolist(), wait=True, wait_timeout=20)
        wait_for(lambda: emu.state == "Idle", timeout=5, what="GRBL idle")
        assert np.array_equal(grbl_steps(arm, emu), actuator_steps(arm, goal) - actuator_steps(arm, arm.neutral))
        physical = emu_any.physical()
        want = (actuator_steps(arm, goal) - actuator_steps(arm, arm.neutral)) / [
            a.steps_per_degree  # type: ignore[union-attr]
            for a in arm.actuators.actuators
        ]
        assert np.allclose([physical[a.axis] for a in arm.actuators.actuators], want, atol=1e-6)  # type: ignore[union-attr]


def test_status_mask_is_set_and_a_board_that_refuses_it_is_not_driven(
    client: ArmClient, service: object, adapter_session: zenoh.Session
) -> None:
    with GrblEmulator() as emu:
        emu.settings[10] = 0  # reports WPos, as a board configured by someone else may
        emu.settings[11] = 0.5
        with running(service, adapter_session, emu) as adapter:
            assert emu.settings[10] == 1
            assert emu.settings[11] == pytest.approx(adapter.wanted_settings()[11], abs=1e-3)
            arm = adapter.robot
            for i in range(len(arm.actuators)):  # each axis' limits, in degrees of its actuator
                assert emu.settings[110 + i] == pytest.approx(np.degrees(arm.limits.velocity[i]) * 60, abs=1e-3)
                assert emu.settings[120 + i] == pytest.approx(np.degrees(arm.limits.acceleration[i]), abs=1e-3)
            for n, v in adapter.wanted_settings().items():
                assert emu.settings[n] == pytest.approx(v, rel=1e-4, abs=1e-3), n

    class Stubborn(GrblEmulator):
        def _store_setting(self, n: int, value: float) -> int:
            return 0 if n == 10 else super()._store_setting(n, value)  # answers ok, keeps $10=0

    with Stubborn() as emu:
        emu.settings[10] = 0
        with pytest.raises(ControllerFault, match=r"will not take \$10=1.*refusing to start"):
            GrblAdapter(adapter_session, robots.load(ARM), emu.port)


def test_a_board_that_does_not_answer_names_the_port(adapter_session: zenoh.Session) -> None:
    with GrblEmulator() as emu:
        emu.responding = False
        with pytest.raises(ControllerFault, match=f"no GRBL answers on {emu.port}"):
            GrblAdapter(adapter_session, robots.load(ARM), emu.port)


def test_error_aborts_with_its_meaning_and_keeps_the_position(
    client: ArmClient, service: object, adapter_session: zenoh.Session
) -> None:
    with GrblEmulator() as emu, running(service, adapter_session, emu, assume_rest=True) as adapter:
        events, sub = collect(client, f"armd/{ARM}/events")
        emu.inject_error_on_next_line(20)
        client.move(ARM, [0.4, 1.2, -1.2])
        wait_for(lambda: any(e["event"] == "aborted" for e in events), timeout=10, what="an aborted event")
        aborted = next(e for e in events if e["event"] == "aborted")
        assert "error:20 (Unsupported command" in str(aborted["reason"])
        wait_for(lambda: adapter.fault is None, timeout=5, what="the adapter recovered")
        assert adapter.homed  # a feed hold and a reset in Hold:0 keep the position
        wait_for(lambda: emu.state == "Idle", timeout=5, what="GRBL idle")
        sub.undeclare()  # type: ignore[attr-defined]


def test_alarm_mid_move_faults_and_waits_for_an_operator(
    client: ArmClient, service: object, adapter_session: zenoh.Session
) -> None:
    arm = robots.load(ARM)
    with GrblEmulator() as emu, running(service, adapter_session, emu, assume_rest=True, check_period=0.2) as adapter:
        writes = Writes(adapter)
        events, sub = collect(client, f"armd/{ARM}/events")
        client.move(ARM, [0.8, 1.3, -1.1], speed=0.5)
        time.sleep(0.5)
        emu.inject_alarm(1)  # a hard limit: ALARM:1
        wait_for(
            lambda: any(e["event"] == "fault" and "ALARM:1 (Hard limit" in str(e.get("reason")) for e in events),
            timeout=5,
            what="the alarm reported with its meaning",
        )
        assert any(e["event"] == "aborted" and "ALARM:1" in str(e.get("reason")) for e in events)
        wait_state(client, homed=False)
        time.sleep(0.5)  # some check periods: the adapter must not clear the alarm by itself
        assert b"\x18" not in writes.data and "$X" not in emu.lines and "$H" not in emu.lines
        assert emu.state == "Alarm"
        holds = writes.data.count(b"!")
        client.estop(ARM)  # in an alarm: still a feed hold, and still no reset
        wait_for(lambda: writes.data.count(b"!") > holds, timeout=5, what="a feed hold")
        time.sleep(0.3)
        assert b"\x18" not in writes.data and emu.state == "Alarm"
        with pytest.raises(ServiceError) as refused:  # (GRBL answers no '?' in a limit alarm: the adapter
            client.move(ARM, arm.neutral)  # must not take that for a controller gone)
        assert refused.value.code == "position_unknown"
        faults = [e for e in events if e["event"] == "fault"]
        assert [e["reason"] for e in faults] == [faults[0]["reason"]], faults  # the alarm alone: no "does not answer"
        answer = client.unlock(ARM, "assume_rest", wait=10)  # the operator: the arm is at rest (say)
        assert answer is not None and answer["event"] == "unlocked", answer
        assert "$X" in emu.lines and b"\x18" in writes.data  # because the operator said so
        wait_state(client, homed=True)
        client.move(ARM, [0.1, 1.5, -1.5], wait=True, wait_timeout=20)
        assert adapter.homed and adapter.fault is None
        sub.undeclare()  # type: ignore[attr-defined]


def test_unlock_home_needs_switches(client: ArmClient, service: object, adapter_session: zenoh.Session) -> None:
    with GrblEmulator() as emu, running(service, adapter_session, emu):
        answer = client.unlock(ARM, "home", wait=10)
        assert answer is not None and answer["event"] == "rejected"
        assert "no homing switches" in str(answer["reason"]) and "$H" not in emu.lines


class Poller:
    """The emulator's GRBL steps, polled every 2 ms in a thread: (time, steps) samples."""

    def __init__(self, arm: robots.Robot, emu: GrblEmulator) -> None:
        self.samples: list[tuple[float, np.ndarray]] = []
        self._go = True
        self._thread = threading.Thread(target=self._run, args=(arm, emu), daemon=True)
        self._thread.start()

    def _run(self, arm: robots.Robot, emu: GrblEmulator) -> None:
        while self._go:
            self.samples.append((time.time(), grbl_steps(arm, emu)))
            time.sleep(0.002)

    def stop(self) -> tuple[np.ndarray, np.ndarray]:
        self._go = False
        self._thread.join()
        return np.array([t for t, _ in self.samples]), np.array([s for _, s in self.samples])


def test_stop_mid_move_decelerates_along_the_path_in_time(
    client: ArmClient, service: object, adapter_session: zenoh.Session
) -> None:
    arm = robots.load(ARM)
    with GrblEmulator() as emu, running(service, adapter_session, emu, assume_rest=True) as adapter:
        writes = Writes(adapter)
        events, sub = collect(client, f"armd/{ARM}/events")
        goal = np.array([1.2, 0.6, -2.2])
        poller = Poller(arm, emu)
        client.move(ARM, goal.tolist())
        time.sleep(1.0)
        asked = time.time()
        client.stop(ARM)
        wait_for(lambda: any(e["event"] == "done" for e in events), timeout=10, what="the stop to finish")
        time.sleep(0.2)
        t, steps = poller.stop()
        accepted = [e for e in events if e["event"] == "accepted" and e.get("trajectory") == "stop"]
        assert len(accepted) == 1
        planned = float(accepted[0]["duration"])
        done = next(e for e in events if e["event"] == "done" and e["id"] == accepted[0]["id"])
        assert any(e["event"] == "aborted" for e in events)  # the move was replaced
        assert not any(e["event"] == "fault" for e in events)  # the flush raised no alarm
        assert planned > 0.2  # it was moving fast: a real stop
        took = float(done["time"]) - asked
        print(f"\nstop: planned {planned:.3f} s, done {took:.3f} s after the request ({took / planned:.3f}x planned)")
        assert took <= 1.25 * planned + 0.1, (took, planned)
        # the arm's own motion, exactly: no axis ever reverses during the stop
        tt, pp = grbl_motion(arm, emu)
        now = time.monotonic() - (time.time() - asked)  # the request on the emulator's clock
        seg = pp[tt >= now - 0.1]
        d = np.sign(seg[min(len(seg) - 1, 20)] - seg[0])
        assert not (np.diff(pp[tt >= now], axis=0) * d < 0).any(), "a joint reversed during the stop"
        t_end = span(tt[tt >= now - 1.0], pp[tt >= now - 1.0])[1]
        print(f"stop: the arm at rest {t_end - now:.3f} s after the request (trace)")
        assert t_end - now <= 1.25 * planned + 0.1
        before = (t > asked - 0.1) & (t <= asked)
        direction = np.sign(steps[before][-1] - steps[before][0])
        assert np.count_nonzero(direction) >= 2  # the joints were moving
        during = steps[t >= asked]
        backwards = np.diff(during, axis=0) * direction < 0
        assert not backwards.any(), "a joint moved against its direction during the stop"
        assert np.array_equal(during[-1], during[-30])  # at rest at the end
        moved = np.abs(during[-1] - during[0])
        assert np.any(moved > 0)  # it decelerated (a stop is not a jump to a halt)
        assert (
            np.max(np.abs(arm.actuators.joints_from_commands(during[-1] + actuator_steps(arm, arm.neutral)) - goal))
            > 0.1
        )  # halted short of the goal
        assert b"!" in writes.data and emu.overflows == 0
        wait_for(lambda: emu.state == "Idle", timeout=5, what="GRBL idle (its hold flushed)")
        sub.undeclare()  # type: ignore[attr-defined]


def test_a_new_move_while_moving_stops_first(
    client: ArmClient, service: object, adapter_session: zenoh.Session
) -> None:
    arm = robots.load(ARM)
    with GrblEmulator() as emu, running(service, adapter_session, emu, assume_rest=True):
        events, sub = collect(client, f"armd/{ARM}/events")
        client.move(ARM, [1.2, 0.6, -2.2])
        time.sleep(1.0)
        second = client.move(ARM, [0.0, 1.5, -1.5])  # planned from the moving state: the arm is held elsewhere
        wait_for(
            lambda: any(e["event"] in ("rejected", "done") and e.get("id") == second.id for e in events),
            timeout=10,
            what="the second move's outcome",
        )
        outcome = next(e for e in events if e["event"] in ("rejected", "done") and e.get("id") == second.id)
        assert outcome["event"] == "rejected" and "plan it again" in str(outcome["reason"])
        wait_state(client, moving=False)
        third = client.move(ARM, [0.0, 1.5, -1.5], wait=True, wait_timeout=20)  # from rest: runs
        wait_for(lambda: any(e["event"] == "done" and e.get("id") == third.id for e in events), what="done")
        wait_for(lambda: emu.state == "Idle", timeout=5, what="GRBL idle")
        assert np.array_equal(
            grbl_steps(arm, emu), actuator_steps(arm, [0.0, 1.5, -1.5]) - actuator_steps(arm, arm.neutral)
        )
        # slowly: held within START_TOL of where the new move starts, so it runs once GRBL is held
        client.move(ARM, [0.3, 1.3, -1.3], speed=0.05)
        time.sleep(1.0)
        fourth = client.move(ARM, [-0.2, 1.6, -1.6])
        wait_for(
            lambda: any(e["event"] in ("rejected", "done") and e.get("id") == fourth.id for e in events),
            timeout=20,
            what="the fourth move's outcome",
        )
        assert any(e["event"] == "done" and e.get("id") == fourth.id for e in events), events[-3:]
        wait_for(lambda: emu.state == "Idle", timeout=5, what="GRBL idle")
        assert np.array_equal(
            grbl_steps(arm, emu), actuator_steps(arm, [-0.2, 1.6, -1.6]) - actuator_steps(arm, arm.neutral)
        )
        sub.undeclare()  # type: ignore[attr-defined]


def test_a_restart_forgets_the_position(client: ArmClient, service: object, adapter_session: zenoh.Session) -> None:
    """The adapter restarts (the port is opened again: the Arduino resets, GRBL's position is 0
    wherever the arm stands): homed false again, moves refused, until an operator says."""
    with GrblEmulator() as emu:
        with running(service, adapter_session, emu, assume_rest=True):
            client.move(ARM, [0.3, 1.2, -1.3], wait=True, wait_timeout=20)
        time.sleep(0.05)  # the port closed: the emulator sees the hang-up (it polls every 2 ms)
        with running(service, adapter_session, emu) as adapter:
            assert not adapter.homed  # whether the board reset (DTR) or not: GRBL's position is not trusted
            wait_state(client, source="adapter", homed=False)
            with pytest.raises(ServiceError) as refused:
                client.move(ARM, [0.0, 1.5, -1.5])
            assert refused.value.code == "position_unknown"


def test_silence_withdraws_the_token(service: object, adapter_session: zenoh.Session) -> None:
    with GrblEmulator() as emu, running(service, adapter_session, emu, check_period=0.2) as adapter:
        emu.responding = False
        wait_for(lambda: service._adapter_count(adapter.robot) == 0, timeout=5, what="the token withdrawn")  # type: ignore[attr-defined]
        assert adapter.fault and "does not answer" in adapter.fault


@pytest.mark.parametrize("rate_hz", [50.0, 200.0])
def test_grbl_executes_the_plan_in_time_within_the_limits(
    client: ArmClient, service: object, arm_copy: Any, adapter_session: zenoh.Session, rate_hz: float
) -> None:
    """A 2 s move: GRBL's own planner (junctions, trapezoids, 15 blocks) takes at most 1.10 x the
    planned time + 0.05 s and accelerates no axis beyond 1.25 x its limit. The arm here has 256
    micro-steps (gupta3's limits, 16 x finer steps), so that a 40 ms fit of the trace measures the
    motion, not its steps (a step over a 40 ms window is 0.4 x the limit at 16 micro-steps)."""
    folder = arm_copy(
        ARM, toml_edits=[("microsteps = 16 ", "microsteps = 256 ")] + [("microsteps = 16\n", "microsteps = 256\n")] * 2
    )
    arm = robots.load_folder(folder)
    with GrblEmulator() as emu, running(service, adapter_session, emu, arm, assume_rest=True):
        wait_state(client, source="adapter", homed=True)
        emu.clear_trace()  # type: ignore[attr-defined]
        goal = np.array([1.5, 1.0, -2.3])
        reply = client.move(ARM, goal.tolist(), rate_hz=rate_hz, wait=True, wait_timeout=20)
        wait_for(lambda: emu.state == "Idle", timeout=5, what="GRBL idle")
        t, p = grbl_motion(arm, emu)
        t0, t1 = span(t, p)
        executed = t1 - t0
        _, amax = actuator_limits_deg(arm)
        peaks = {w: fitted_peaks(t, p, w)[1] / amax for w in (0.04, 0.1)}
        # the same measure of the plan itself, followed exactly by a stepper (whole steps at their times)
        plan = client.plan(ARM, goal.tolist(), start=list(arm.neutral), rate_hz=rate_hz)
        fine = np.arange(0.0, plan.duration + 1e-9, 0.002)
        angles = np.degrees(arm.actuators.angles(plan.position))
        ideal = np.column_stack([np.interp(fine, plan.times, c) for c in angles.T])
        spd = np.array([a.steps_per_degree for a in arm.actuators.actuators])  # type: ignore[union-attr]
        floor = {w: fitted_peaks(fine, np.rint(ideal * spd) / spd, w)[1] / amax for w in peaks}
        print(
            f"\n{rate_hz:g} Hz: planned {reply.duration:.3f} s, executed {executed:.3f} s "
            f"({executed / reply.duration:.3f}x); peak acceleration / limit per axis, fitted over "
            + "; ".join(
                f"{w * 1000:g} ms: {np.round(r, 3).tolist()} (the plan, stepped: {np.round(floor[w], 3).tolist()})"
                for w, r in peaks.items()
            )
        )
        assert 1.5 <= reply.duration <= 2.5
        assert executed <= 1.10 * reply.duration + 0.05
        assert np.all(peaks[0.04] <= 1.25)
        assert np.array_equal(grbl_steps(arm, emu), actuator_steps(arm, goal) - actuator_steps(arm, arm.neutral))


def test_homing_sets_the_position_from_home_pose(
    client: ArmClient, adapter_session: zenoh.Session, arm_copy: Any, monkeypatch: pytest.MonkeyPatch
) -> None:
    """An arm with switches ([controller] homing = true, home_pose): ``$H``, then exact moves. GRBL
    homes toward + (``$23=0``) and sets its position to ``-$27`` (the pull-off) there."""
    base = robots.load(ARM)
    switches = {"X": 20.0, "Y": 15.0, "Z": 25.0}  # [deg] from where the arm stands at power-up (its neutral)
    home = np.array(base.neutral) + np.radians([switches[a] - 1.0 for a in "XYZ"])
    folder = arm_copy(
        ARM,
        toml_edits=[
            (
                "baud = 115200",
                "baud = 115200\nhoming = true\nhome_pose = [" + ", ".join(f"{v!r}" for v in home.tolist()) + "]",
            )
        ],
    )
    arm = robots.load_folder(folder)
    with GrblEmulator(home_switches=switches, settings={24: 300.0, 25: 1500.0, 27: 1.0}) as emu:  # type: ignore[call-arg]
        adapter = GrblAdapter(adapter_session, arm, emu.port, home=True)
        try:
            assert adapter.homed and emu.settings[22] == 1 and "$H" in emu.lines
            physical: Any = emu.physical()  # type: ignore[attr-defined]
            assert np.allclose([physical[a] for a in "XYZ"], [switches[a] - 1.0 for a in "XYZ"], atol=0.12)
            q = adapter.measure().position
            assert np.allclose(q, home, atol=arm.actuators.actuators[0].resolution)
        finally:
            adapter.close()


def executed_acceleration(arm: robots.Robot, emu: GrblEmulator, h: float = 0.01, dt: float = 0.0005) -> np.ndarray:
    """Per actuator, the largest acceleration of the executed motion over finite differences of
    +-``h`` [s] (every ``dt`` [s]), as a fraction of its limit: where GRBL turns from one line to
    the next, each axis' speed steps at once, and a step of ``dv`` reads ``dv / h`` here."""
    pieces = emu.pieces
    t = np.arange(pieces[0][0] - h, pieces[-1][0] + pieces[-1][1] + h, dt)
    p = grbl_exact_motion(arm, emu, t)
    k = round(h / dt)
    acc = (p[2 * k :] - 2.0 * p[k:-k] + p[: -2 * k]) / h**2
    return np.max(np.abs(acc), axis=0) / actuator_limits_deg(arm)[1]


TURNS: dict[str, tuple[object, dict[str, Any]]] = {
    "line": ({"target": [0.16, 0.10, 0.02]}, {"path": "line"}),  # a straight tool line: curved in joint space
    "via": ([-0.4, 1.3, -1.9], {"via": [[0.6, 1.2, -1.2], [0.9, 1.7, -2.0]]}),  # every joint reverses
}


@pytest.mark.parametrize("kind", sorted(TURNS))
def test_grbl_turns_between_lines_within_every_axis_acceleration(
    client: ArmClient, service: object, adapter_session: zenoh.Session, kind: str
) -> None:
    """Moves whose joints change direction (a Cartesian line, a path through waypoints where
    every joint reverses): where GRBL turns from one streamed line to the next, each axis' speed
    steps at once (GRBL's junction deviation). Measured on the executed motion by +-10 ms finite
    differences, no axis accelerates beyond 1.10 x its limit (at most a tenth of a limit's
    10 ms at a junction, ``$11``); GRBL slows down at the corners of the curves for it, and the
    arm ends exactly at the goal."""
    arm = robots.load(ARM)
    goal, options = TURNS[kind]
    with GrblEmulator() as emu, running(service, adapter_session, emu, assume_rest=True):
        wait_state(client, source="adapter", homed=True)
        emu.clear_trace()
        reply = client.move(ARM, goal, wait=True, wait_timeout=30, **options)
        wait_for(lambda: emu.state == "Idle", timeout=5, what="GRBL idle")
        pieces = emu.pieces
        executed = pieces[-1][0] + pieces[-1][1] - pieces[0][0]
        peaks = executed_acceleration(arm, emu)
        slow = executed_acceleration(arm, emu, h=0.1)  # over +-100 ms
        print(
            f"\n{kind}: planned {reply.duration:.3f} s, executed {executed:.3f} s ({executed / reply.duration:.3f}x); "
            f"peak acceleration / limit per axis over +-10 ms: {np.round(peaks, 3).tolist()}"
        )
        assert np.all(peaks <= 1.10), peaks
        assert np.max(slow) >= 0.2  # the arm does accelerate (a measure that read 0 would prove nothing)
        assert executed <= 2.5 * reply.duration  # (slower: GRBL turns each corner of a curve slowly)
        assert np.array_equal(grbl_steps(arm, emu), actuator_steps(arm, reply.goal) - actuator_steps(arm, arm.neutral))


def test_a_stop_is_announced_with_the_time_grbl_takes_to_hold(
    client: ArmClient, service: object, adapter_session: zenoh.Session
) -> None:
    """GRBL runs behind the plan (it slows at the corners of a curve): a stop after the plan's
    time is over, GRBL still moving, is announced with the feed hold's time (GRBL's speed over
    its deceleration along the path), which is about the time the arm takes to come to rest."""
    arm = robots.load(ARM)
    with GrblEmulator() as emu, running(service, adapter_session, emu, assume_rest=True) as adapter:
        wait_state(client, source="adapter", homed=True)
        writes = Writes(adapter)
        events, sub = collect(client, f"armd/{ARM}/events")
        try:
            goal, options = TURNS["line"]
            emu.clear_trace()
            began = time.monotonic()
            reply = client.move(ARM, goal, **options)
            wait_for(lambda: emu.state == "Run", timeout=5, what="GRBL running")

            def speed() -> float:  # [deg/s] GRBL's along its path, at its last piece's start
                pieces = emu.pieces
                return float(np.linalg.norm(pieces[-1][3])) if pieces else 0.0

            wait_for(
                lambda: (time.monotonic() - began > reply.duration + 0.1 and speed() > 25.0) or emu.state == "Idle",
                timeout=20,
                what="GRBL moving fast after the plan's time",
            )
            assert emu.state != "Idle", "GRBL finished within the plan's time: nothing to check"
            client.stop(ARM)

            def stop() -> dict[str, Any] | None:
                return next((e for e in events if e["event"] == "accepted" and e.get("trajectory") == "stop"), None)

            wait_for(lambda: stop() is not None, what="the stop accepted")
            accepted = stop()
            assert accepted is not None
            wait_for(lambda: any(e["event"] == "done" and e["id"] == accepted["id"] for e in events), what="its end")
        finally:
            sub.undeclare()  # type: ignore[attr-defined]
        bang = next(t for t, data in writes.times if b"!" in data)
        pieces = emu.pieces
        rest = pieces[-1][0] + pieces[-1][1]
        took, announced = rest - bang, float(accepted["duration"])
        print(f"\nstop: announced {announced:.3f} s, the arm at rest {took:.3f} s after the hold")
        assert announced > 0.05  # (a stop planned from the plan's state there, at rest, would say 0.02)
        assert 0.4 * took - 0.05 <= announced <= 2.0 * took + 0.1  # (GRBL's speed changes while the stop is sent)
        goal_steps = actuator_steps(arm, reply.goal) - actuator_steps(arm, arm.neutral)
        assert np.any(grbl_steps(arm, emu) != goal_steps)  # held short of the goal
