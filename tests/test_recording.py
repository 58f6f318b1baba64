"""Teach and replay: ``armd record`` on the so101's emulated Feetech bus (the arm moved by hand,
torque off), the recording's checks, smoothing and via points (planning/recording.py), and
``armd replay`` through the service to a simulated arm and to the Feetech adapter."""

from __future__ import annotations

import itertools
import json
import math
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import zenoh
from conftest import ROOT, collect, wait_for

from armd import robots
from armd.adapters.emulators.feetech import FeetechEmulator
from armd.adapters.emulators.process import EmulatorProcess
from armd.adapters.sim import SimAdapter
from armd.errors import BadRequest
from armd.planning.recording import TOLERANCE, Recording, check, parts, simplify

ARM = "so101"


def path_at(t: float) -> np.ndarray:
    """A hand's motion of the so101 [rad]: slow swings, inside the limits."""
    return np.array(
        [
            0.8 * math.sin(1.3 * t),
            -0.6 + 0.4 * math.sin(0.9 * t),
            0.7 * math.sin(1.1 * t + 0.3),
            0.5 * math.sin(1.7 * t),
            1.0 * math.sin(0.7 * t),
        ]
    )


def recording(seconds: float = 4.0, rate: float = 300.0, gripper: bool = True) -> Recording:
    rng = np.random.default_rng(7)
    t = np.arange(0.0, seconds, 1.0 / rate)
    q = np.array([path_at(x) for x in t]) + rng.normal(0.0, 0.0008, (len(t), 5))  # (a count's noise)
    g = np.where((t > 1.5) & (t < 3.0), 0.0, 1.0) if gripper else None
    return Recording(ARM, tuple(robots.load(ARM).joint_names), t, q, g)


# -- the file and its checks --------------------------------------------------------------------


def test_the_file_format_round_trips_and_malformed_files_are_refused_by_name(tmp_path: Path) -> None:
    rec = recording()
    rec.save(tmp_path / "r.json")
    back = Recording.load(tmp_path / "r.json")
    assert back.robot == ARM and back.joints == rec.joints
    assert np.allclose(back.position, rec.position, atol=1e-6) and np.array_equal(back.gripper, rec.gripper)
    good = rec.to_json()
    for change, field in [
        ({"format": "something"}, "format"),
        ({"version": 2}, "format"),
        ({"unit": "deg"}, "unit"),
        ({"t": good["t"][:-1]}, "q"),
        ({"q": [row[:4] for row in good["q"]]}, "q"),
        ({"t": [0.0, 0.0, *good["t"][2:]]}, "t"),
        ({"gripper": [2.0] * len(good["t"])}, "gripper"),
        ({"q": [[math.nan] * 5, *good["q"][1:]]}, "q"),
        ({"t": [0.0]}, "q"),
        ({"version": True}, "format"),
        ({"t": ["0.1", *good["t"][1:]]}, "t"),
        ({"q": [[True, 0.0, 0.0, 0.0, 0.0], *good["q"][1:]]}, "q"),
        ({"q": [good["q"][0][:4], *good["q"][1:]]}, "q"),
        ({"gripper": "open"}, "gripper"),
    ]:
        with pytest.raises(BadRequest) as e:
            Recording.from_json({**good, **change})
        assert e.value.field == field, (change, e.value)


def test_a_jump_a_reading_outside_the_limits_and_another_arm_are_refused() -> None:
    arm = robots.load(ARM)
    rec = recording(gripper=False)
    q = rec.position.copy()
    q[400:, 2] += 0.3  # (a servo read half a count-turn off, a lost calibration)
    with pytest.raises(BadRequest) as e:
        check(Recording(ARM, rec.joints, rec.times, q), arm)
    assert "a jump in the recording: elbow_flex" in e.value.message and f"{rec.times[399]:.3f} s" in e.value.message
    q = rec.position.copy()
    q[:, 0] = np.linspace(0.0, arm.limits.upper[0] + 0.1, len(q))  # (turned past its limit, by hand)
    with pytest.raises(BadRequest) as e:
        check(Recording(ARM, rec.joints, rec.times, q), arm)
    assert "outside the limits" in e.value.message and "shoulder_pan" in e.value.message
    q[:, 0] = np.linspace(0.0, arm.limits.upper[0] + 0.01, len(q))  # (a hair outside: brought inside)
    assert np.max(check(Recording(ARM, rec.joints, rec.times, q), arm)[:, 0]) <= arm.limits.upper[0]
    with pytest.raises(BadRequest) as e:
        check(Recording("koch", rec.joints, rec.times, rec.position), arm)
    assert e.value.field == "robot"


def test_the_via_points_stay_within_the_tolerance_of_every_reading() -> None:
    """Checked independently of the simplification's own measure: each reading against the
    polyline through the via points, sampled densely."""
    rec = recording(gripper=False)
    q = rec.position
    for tol in (0.005, 0.01, 0.03):
        keep = simplify(q, tol)
        assert keep[0] == 0 and keep[-1] == len(q) - 1 and len(keep) < len(q) / 10
        for a, b in itertools.pairwise(keep):
            s = np.linspace(0.0, 1.0, 400)[:, None]
            line = q[a] + s * (q[b] - q[a])
            for k in range(a, b + 1):
                assert np.min(np.max(np.abs(line - q[k]), axis=1)) <= tol + 0.003, (tol, k)


def test_a_replay_is_split_where_the_gripper_moves_and_into_moves_of_few_via_points() -> None:
    arm = robots.load(ARM)
    rec = recording()
    todo = parts(rec, arm, max_via=6)
    assert np.allclose(todo[0].goal, rec.position[0], atol=0.003) and todo[0].gripper == 1.0  # first: the start
    assert all(len(p.via) <= 6 for p in todo)
    grips = [(p.end_time, p.gripper) for p in todo if p.gripper is not None]
    # the gripper closes at 1.5 s, opens at 3.0 s: a move ends at each, then the gripper; and at the end
    assert [g for _, g in grips] == [1.0, 0.0, 1.0, 1.0]
    assert abs(grips[1][0] - 1.5) < 0.01 and abs(grips[2][0] - 3.0) < 0.01
    for p, n in itertools.pairwise(todo[1:]):
        assert p.end_time == n.start_time  # (each move goes on from where the last ended)
    for bad in ({"tolerance": -1.0}, {"max_via": -1}, {"max_via": 101}, {"max_via": True}):
        with pytest.raises(BadRequest):
            parts(rec, arm, **bad)  # type: ignore[arg-type]


def test_a_motion_back_over_its_own_way_keeps_its_turns() -> None:
    """base 0 -> 1 -> 0 -> 1 rad: every turn a via point (the nearest point of a segment would
    lose them: the readings all lie on the first segment)."""
    t = np.linspace(0.0, 3.0, 901)
    q = np.zeros((901, 5))
    q[:, 0] = np.interp(t, [0, 1, 2, 3], [0.0, 1.0, 0.0, 1.0])
    assert simplify(q, 0.01) == [0, 300, 600, 900]
    todo = parts(Recording(ARM, tuple(robots.load(ARM).joint_names), t, q), robots.load(ARM))
    turns = [float(v[0]) for p in todo[1:] for v in [*p.via, p.goal]]
    assert np.allclose(turns, [1.0, 0.0, 1.0], atol=0.02), turns  # (smoothed over 50 ms at the turns)


def test_a_slow_close_by_hand_is_one_gripper_action() -> None:
    rec = recording(gripper=False)
    g = np.interp(rec.times, [0.0, 1.0, 1.6, 4.0], [1.0, 1.0, 0.0, 0.0])  # closed over 0.6 s
    todo = parts(Recording(ARM, rec.joints, rec.times, rec.position, g), robots.load(ARM))
    grips = [(p.end_time, p.gripper) for p in todo if p.gripper is not None]
    assert [x for _, x in grips] == [1.0, 0.0, 0.0], grips  # the start, the close, the end
    assert abs(grips[1][0] - 1.06) < 0.005  # (the arm stops where the gripper had moved by 0.1: at 1.06 s)


# -- replay, through the service ------------------------------------------------------------------


def replay(router: str, file: Path, *extra: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "armd.cli", "replay", ARM, str(file), "--connect", router, "--timeout", "10", *extra],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=180,
    )


def test_a_replay_follows_the_recordings_path_within_the_limits(
    router: str, client: Any, service: Any, adapter_session: zenoh.Session, tmp_path: Path
) -> None:
    arm = robots.load(ARM)
    rec = recording(seconds=3.5)
    file = tmp_path / "teach.json"
    rec.save(file)
    sim = SimAdapter(adapter_session, arm, time_scale=4.0)
    try:
        wait_for(lambda: service._adapter_count(arm) == 1, what="the sim's token")
        trajectories, sub = collect(client, f"armd/{ARM}/trajectory")
        events: list[tuple[float, dict[str, Any]]] = []
        timed = client.session.declare_subscriber(
            f"armd/{ARM}/events", lambda s: events.append((time.monotonic(), json.loads(s.payload.to_bytes())))
        )
        done = replay(router, file)
        sub.undeclare()  # type: ignore[attr-defined]
        timed.undeclare()
        assert done.returncode == 0, done.stderr
        assert "replayed" in done.stdout.splitlines()[-1], done.stdout
        # each gripper action, its adapter's word, then half a second before the arm goes on
        kinds = [e["event"] for _, e in events]
        assert kinds.count("gripper") == 4 and kinds.count("accepted") == 4, kinds  # (start, close, open, end)
        for k, (t, e) in enumerate(events):
            later = [u for u, f in events[k + 1 :] if f["event"] == "accepted"]
            if e["event"] == "gripper" and later:
                assert later[0] - t >= 0.5, (later[0] - t, kinds)
        assert np.allclose(sim.measure().position, rec.position[-1], atol=0.005)
        assert sim.gripper_opening == 1.0
        # the path executed: every sample within the limits, every reading of the recording near it
        samples = np.vstack([np.array(t["position"]) for t in trajectories])
        assert np.all(arm.limits.contains_batch(samples, tol=1e-9))
        for t in trajectories:
            v, a = np.abs(np.array(t["velocity"])), np.abs(np.array(t["acceleration"]))
            assert np.all(v <= arm.limits.velocity * (1 + 1e-6)) and np.all(a <= arm.limits.acceleration * (1 + 1e-6))
        s = np.linspace(0.0, 1.0, 10, endpoint=False)[None, :, None]  # (between samples: straight, 10 points each)
        dense = (samples[:-1, None, :] + s * np.diff(samples, axis=0)[:, None, :]).reshape(-1, arm.nq)
        dist = np.array([np.min(np.max(np.abs(dense - q), axis=1)) for q in rec.position[::10]])
        assert np.max(dist) <= TOLERANCE + 0.008, np.max(dist)  # (measured: 0.013; the smoothing's share too)
        # at the hand's pace: the replay of the 3.5 s (after the move to its start) took 4.1 s (4.7 s for
        # its first 1.5 s when waypoints were passed at each joint's own speed, not the path's tangent)
        replayed = sum(t["duration"] for t in trajectories[1:])
        assert replayed <= 1.25 * (rec.times[-1] - rec.times[0]), replayed
    finally:
        sim.close()


def test_a_recording_with_a_jump_moves_nothing(
    router: str, client: Any, service: Any, adapter_session: zenoh.Session, tmp_path: Path
) -> None:
    arm = robots.load(ARM)
    rec = recording(seconds=2.0, gripper=False)
    q = rec.position.copy()
    q[300:, 1] += 0.4
    file = tmp_path / "jump.json"
    Recording(ARM, rec.joints, rec.times, q).save(file)
    sim = SimAdapter(adapter_session, arm, time_scale=4.0)
    try:
        wait_for(lambda: service._adapter_count(arm) == 1, what="the sim's token")
        before = sim.measure().position
        trajectories, sub = collect(client, f"armd/{ARM}/trajectory")
        done = replay(router, file)
        time.sleep(0.2)
        sub.undeclare()  # type: ignore[attr-defined]
        assert done.returncode == 1 and "a jump in the recording: shoulder_lift" in done.stderr, done.stderr
        assert trajectories == [] and np.array_equal(sim.measure().position, before)
    finally:
        sim.close()


# -- record, on the bus ----------------------------------------------------------------------------


def test_record_on_the_bus_then_replay_on_the_same_arm(
    router: str, service: Any, adapter_session: zenoh.Session, tmp_path: Path
) -> None:
    """``armd record so101`` with the arm moved by hand along a known path (and its gripper
    closed and opened), then the Feetech adapter started and ``armd replay``: the arm ends where
    the hand left it."""
    pytest.importorskip("scservo_sdk")
    from armd.adapters.feetech import FeetechAdapter

    arm = robots.load(ARM)
    file = tmp_path / "teach.json"
    per_rad = 4096 / (2 * math.pi)
    with EmulatorProcess(FeetechEmulator, ids=[1, 2, 3, 4, 5, 6]) as emu:
        for k, x in enumerate(path_at(0.0)):  # (the hand holds the arm at the path's start, the gripper open)
            emu.move_by_hand(k + 1, 2048 + x * per_rad)
        emu.move_by_hand(6, 3186)
        from armd.adapters.feetech import FeetechBus

        bus = FeetechBus(emu.port, 1_000_000)  # (servo 2 holding, as an adapter left it)
        bus.write_goals({2: round(emu.position(2))}, {2: 1000})
        bus.set_torque(2, True)
        bus.close()
        proc = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "armd.cli",
                "record",
                ARM,
                "--adapter",
                "feetech",
                "--port",
                emu.port,
                "-o",
                str(file),
                "--seconds",
                "3",
            ],
            cwd=ROOT,
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        assert proc.stdout is not None and proc.stdin is not None
        assert proc.stdout.readline().startswith("> Hold the arm")
        assert emu.register(2, 40) == 1  # (the adapter's torque: still on until the operator holds the arm)
        proc.stdin.write("\n")
        proc.stdin.flush()
        assert "recording" in proc.stdout.readline()
        moved: list[np.ndarray] = []
        t0 = time.monotonic()
        while (t := time.monotonic() - t0) < 2.6:  # the hand: the path, every 5 ms
            q = path_at(t)
            for k, x in enumerate(q):
                emu.move_by_hand(k + 1, 2048 + x * per_rad)
            emu.move_by_hand(6, 2048 if 0.8 < t < 1.8 else 3186)  # the gripper (robot.toml's counts): closed meanwhile
            moved.append(q)
            time.sleep(0.005)
        _, err = proc.communicate(timeout=30)
        assert proc.returncode == 0, err
        assert all(emu.register(i, 40) == 0 for i in range(1, 7))  # torque off throughout
        rec = Recording.load(file)
        rate = (len(rec.times) - 1) / (rec.times[-1] - rec.times[0])
        assert rate >= 200, rate  # (the bus's rate: about 300 sync reads a second at 1 Mbaud)
        path = np.array(moved)
        # every reading on the hand's path: between two of its steps (a servo at a time), to a count (0.0015 rad)
        lo, hi = np.minimum(path[:-1], path[1:]) - 0.002, np.maximum(path[:-1], path[1:]) + 0.002
        assert all(np.any(np.all((lo <= q) & (q <= hi), axis=1)) for q in rec.position)
        assert rec.gripper is not None and set(np.round(rec.gripper, 3)) == {0.0, 1.0}
        closed = rec.times[rec.gripper == 0.0]
        assert 0.7 < closed[0] < 0.9 and 1.7 < closed[-1] < 1.9  # (the recorder's clock starts a little later)
        last = rec.position[-1]
        # the arm moved elsewhere by hand; the adapter holds it there; the replay brings it back along the path
        for k in range(5):
            emu.move_by_hand(k + 1, 2048.0)
        adapter = FeetechAdapter(adapter_session, arm, emu.port)
        try:
            wait_for(lambda: service._adapter_count(arm) == 1, what="the adapter's token")
            done = replay(router, file)
            assert done.returncode == 0, done.stderr
            assert np.max(np.abs(adapter.measure().position - last)) < 0.01
        finally:
            adapter.close()


def test_record_refuses_an_arm_not_on_a_bus(tmp_path: Path) -> None:
    done = subprocess.run(
        [
            sys.executable,
            "-m",
            "armd.cli",
            "record",
            "insomniac",
            "--adapter",
            "feetech",
            "--port",
            "/dev/null",
            "-o",
            str(tmp_path / "x.json"),
            "--seconds",
            "1",
        ],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert done.returncode == 1 and "insomniac" in done.stderr and "Feetech" in done.stderr, done.stderr
    assert not (tmp_path / "x.json").exists()


def test_record_goes_on_through_lost_replies_and_names_a_silent_servo() -> None:
    """Replies lost read after read (20 of servo 3's: every read for a while loses it and the
    replies after it) leave a gap in the recording, not an error (the old recorder gave up after
    4); a servo silent for longer than ``LOST_FOR`` (2 s) ends it, naming that servo alone."""
    pytest.importorskip("scservo_sdk")
    import threading

    from armd.adapters import by_hand
    from armd.adapters.feetech import FeetechBus
    from armd.errors import ControllerFault

    arm = robots.load(ARM)
    with EmulatorProcess(FeetechEmulator, ids=[1, 2, 3, 4, 5, 6]) as emu:
        stop = threading.Event()
        out: list[object] = []
        seconds = 1.5

        def run() -> None:
            try:
                out.append(
                    by_hand.record(
                        arm, FeetechBus(emu.port, 1_000_000), stop, seconds=seconds, say=str, ready=lambda: None
                    )
                )
            except Exception as e:  # (told below)
                out.append(e)

        worker = threading.Thread(target=run)
        worker.start()
        time.sleep(0.5)
        emu.drop_replies(3, 20)
        worker.join(timeout=30)
        assert not worker.is_alive()
        rec = out[0]
        assert isinstance(rec, Recording), rec
        assert rec.times[-1] > 1.2 and len(rec.times) > 150
        seconds = 4.0  # (longer than LOST_FOR after the silence)
        worker = threading.Thread(target=run)
        out.clear()
        worker.start()
        time.sleep(0.3)
        emu.silence(3)
        worker.join(timeout=30)
        assert not worker.is_alive()
        assert isinstance(out[0], ControllerFault), out
        assert out[0].message.startswith("servo id 3 does not answer"), out[0].message
