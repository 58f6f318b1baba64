"""A tracking stream on the catalogue's stepper arm (gupta3): put by the Python client
(``ArmClient.track``), planned by the service, spliced by the GRBL adapter into the lines GRBL
holds, on the GRBL emulator on a pseudo-terminal (GRBL's planner, junctions and feed hold), all
through a real router. What is checked is what the emulator executed, its own motion: within
every position, velocity and acceleration limit of gupta3 (every piece of GRBL's motion; the
speed steps at its junctions within the adapter's ``$11``), on the stream's way, wherever the
stream goes, when its puts stop, when it is stopped, when its trajectories come late or are
refused, and when the adapter stalls. (How closely and how late GRBL follows is a figure:
docs/benchmarks.md.) Run beside two busy processes too: the emulator has a process of its own."""

from __future__ import annotations

import json
import math
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
from armd.adapters.emulators.measure import actuator_limits_deg, grbl_exact_motion
from armd.adapters.emulators.process import EmulatorProcess
from armd.adapters.grbl import JUNCTION_SHARE, STEP_WINDOW, GrblAdapter
from armd.adapters.trajectory_message import Command
from armd.clients import ArmClient
from armd.service.server import Service
from armd.service.zconfig import network_config
from tests.conftest import wait_for

pytestmark = pytest.mark.slow  # (seconds: routers, the service, an emulated board)

ARM = "gupta3"
PREFIX = "gs"
SLACK = 1e-6  # (rounding of the emulator's exact motion)


class Served(GrblEmulator):
    """The GRBL emulator, its exact motion and state as calls too: served from a process of its
    own (:class:`EmulatorProcess` forwards calls), it reads each line as it is written, as an
    Arduino does, however busy the machine (a thread of the test's, starved, answered a status
    request half a second late: a fault)."""

    def exact(self) -> list[Any]:
        return self.pieces

    def now(self) -> str:
        return self.state

    def speed(self) -> float:
        """[units/s] how fast it moves now, along its path (its exact motion, run to now)."""
        if self.state == "Idle" or not self.pieces:
            return 0.0
        _, dt, _, v, a = self.pieces[-1]
        return math.hypot(*(vi + ai * dt for vi, ai in zip(v, a, strict=True)))


class Board:
    """:class:`Served` in a process of its own, read as the measures read an emulator; what it
    did is kept when its process ends (:meth:`keep`)."""

    axes = "XYZ"

    def __init__(self, process: EmulatorProcess) -> None:
        self.process: EmulatorProcess | None = process
        self.port = process.port
        self._kept: tuple[list[Any], str, dict[str, int]] | None = None

    def keep(self) -> None:
        """Keep its motion, state and steps, as they are now (its process is about to end)."""
        assert self.process is not None
        self._kept = (list(self.process.exact()), str(self.process.now()), dict(self.process.steps()))
        self.process = None

    @property
    def pieces(self) -> list[Any]:
        return self._kept[0] if self._kept is not None else list(self._live().exact())

    @property
    def state(self) -> str:
        return self._kept[1] if self._kept is not None else str(self._live().now())

    def steps(self) -> dict[str, int]:
        return self._kept[2] if self._kept is not None else dict(self._live().steps())

    def clear_trace(self) -> None:
        self._live().clear_trace()

    def speed(self) -> float:
        """[deg/s] how fast GRBL moves now, along its path."""
        return float(self._live().speed())

    def _live(self) -> EmulatorProcess:
        assert self.process is not None
        return self.process


class Recording(GrblAdapter):
    """The GRBL adapter, keeping the trajectories it ran, each once, in order (a stream's each up
    to where the next took over), and what it said."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        self.ran: list[Command] = []
        self.said: list[dict[str, Any]] = []
        self.record = threading.Lock()
        super().__init__(*args, **kwargs)

    def execute(self, cmd: Command, t: float, first: bool) -> bool:
        with self.record:
            if not self.ran or self.ran[-1] is not cmd:
                self.ran.append(cmd)
        return super().execute(cmd, t, first)

    def spliced(self, before: Command, cmd: Command) -> None:
        with self.record:  # (two may take over in one pass of a late loop: each is kept)
            if not self.ran or self.ran[-1] is not before:
                self.ran.append(before)
            self.ran.append(cmd)
        super().spliced(before, cmd)

    def event(self, event: str, **fields: Any) -> None:
        with self.record:
            self.said.append({"event": event, **fields})
        super().event(event, **fields)

    def events(self, event: str) -> list[dict[str, Any]]:
        with self.record:
            return [e for e in self.said if e["event"] == event]

    def last(self) -> Command:
        """The last trajectory of the stream it ran (said so if a fault stopped it)."""
        assert not self.events("fault"), self.events("fault")
        with self.record:
            return [c for c in self.ran if c.kind == "move"][-1]

    def planned(self) -> np.ndarray:
        """The joint positions [rad] of every trajectory of the stream it ran, whole (GRBL runs
        what it holds of one beyond where the next takes over: that is on this one's way)."""
        with self.record:
            return np.vstack([c.position for c in self.ran if c.kind == "move"])


class Late(Recording):
    """Every ``every``-th trajectory message is held ``hold`` [s] before it is read (a busy
    machine, a congested link): it comes after its time."""

    def __init__(self, *args: Any, every: int = 15, hold: float = 0.15, **kwargs: Any) -> None:
        self.every, self.hold, self.count = every, hold, 0
        super().__init__(*args, **kwargs)

    def _on_trajectory(self, sample: zenoh.Sample) -> None:
        self.count += 1
        if self.count % self.every == 0:
            time.sleep(self.hold)
        super()._on_trajectory(sample)


class Stalling(Recording):
    """Its control loop stalls once, ``stall`` [s], ``after`` [s] into the stream (a process the
    machine did not run): nothing is sent to GRBL meanwhile."""

    def __init__(self, *args: Any, after: float = 0.6, stall: float = 2.0, **kwargs: Any) -> None:
        self.after, self.stall = after, stall
        self.began: float | None = None
        self.stalled: tuple[float, float] | None = None  # [s] when it stalled, from and to
        super().__init__(*args, **kwargs)

    def execute(self, cmd: Command, t: float, first: bool) -> bool:
        now = time.monotonic()
        if cmd.track is not None and self.began is None:
            self.began = now
        if self.stalled is None and self.began is not None and now - self.began > self.after:
            time.sleep(self.stall)
            self.stalled = (now, time.monotonic())
        return super().execute(cmd, t, first)


@pytest.fixture(scope="module")
def served(router: str) -> Iterator[Service]:
    with zenoh.open(network_config(connect=[router])) as session:
        service = Service(session, {ARM: robots.load(ARM)}, prefix=PREFIX)
        try:
            yield service
        finally:
            service.close()


@pytest.fixture
def armd(router: str, served: Service) -> Iterator[ArmClient]:
    with ArmClient(router, prefix=PREFIX, timeout=10.0) as client:
        yield client


@contextmanager
def stepper_arm(router: str, served: Service, kind: type[Recording] = Recording) -> Iterator[tuple[Board, Any]]:
    """The emulator (in a process of its own), and the GRBL adapter on it (the arm at its rest
    pose, as an operator said), with the service's state from it; both closed at the end, and
    the service seeing it gone."""
    arm = served.arms[ARM]
    with (
        EmulatorProcess(Served, axes=Board.axes) as process,
        zenoh.open(network_config(connect=[router])) as session,
    ):
        emu = Board(process)
        # (its loop shares the test's interpreter with the service and the router: on a busy machine it
        # may wait for Python's lock longer than for a board's answer; a board that stops answering
        # is tests/test_adapter_grbl.py's)
        adapter = kind(session, robots.load(ARM), emu.port, prefix=PREFIX, assume_rest=True, timeout=2.0)
        try:
            wait_for(lambda: served._adapter_count(arm) == 1, 10, "the adapter's token")
            wait_for(lambda: served.book.current(arm).source == "adapter", 10, "the adapter's state")
            time.sleep(0.3)  # (the last test's session's deadman: run out, so that this test's begins at once)
            emu.clear_trace()
            yield emu, adapter
        finally:
            adapter.close()
            emu.keep()
    wait_for(lambda: served._adapter_count(arm) == 0, 10, "the adapter gone")


def joints(arm: robots.Robot, emu: Board, times: np.ndarray) -> np.ndarray:
    """The arm's joints [rad] at ``times`` [s], from the emulator's exact motion (GRBL's planner
    and stepper profiles before their whole steps; the arm at its rest pose when GRBL started)."""
    spd = np.array([a.steps_per_degree for a in arm.actuators.actuators])  # type: ignore[attr-defined]
    rest = np.asarray(arm.actuators.commands(np.array(arm.neutral, dtype=float)), dtype=float)
    return arm.actuators.joints_from_commands(grbl_exact_motion(arm, emu, times) * spd + rest, tol=np.inf)


def within_limits(arm: robots.Robot, emu: Board) -> dict[str, float]:
    """What the emulator executed against gupta3's limits (ratios; asserted):

    - ``velocity``, ``acceleration``: the largest of every piece of GRBL's motion (constant
      acceleration each: its acceleration, and its speed at both ends), per axis, over the limit;
    - ``junction``: where GRBL turns from one block to the next, each axis' speed steps at once
      (no acceleration lasts); the largest step, over what the axis' limit gives in GRBL's 10 ms
      step segment: within ``JUNCTION_SHARE`` by the adapter's ``$11``;
    - ``window``: the largest acceleration over +-10 ms finite differences of the motion (a step
      and the accelerations about it): within 1 + ``JUNCTION_SHARE`` by construction;
    - every joint within its position limits, sampled every 2 ms."""
    pieces = emu.pieces
    assert pieces, "nothing moved"
    vmax, amax = actuator_limits_deg(arm)
    cols = [emu.axes.index(a.axis) for a in arm.actuators.actuators]  # type: ignore[attr-defined]
    dt = np.array([p[1] for p in pieces])[:, None]
    v0 = np.array([[p[3][c] for c in cols] for p in pieces])
    a0 = np.array([[p[4][c] for c in cols] for p in pieces])
    v1 = v0 + a0 * dt
    out = {
        "velocity": float(np.max(np.maximum(np.abs(v0), np.abs(v1)) / vmax)),
        "acceleration": float(np.max(np.abs(a0) / amax)),
        "junction": float(np.max(np.abs(v0[1:] - v1[:-1]) / (amax * STEP_WINDOW), initial=0.0)),
    }
    h, step = STEP_WINDOW, 0.0005
    t = np.arange(pieces[0][0] - h, pieces[-1][0] + pieces[-1][1] + h, step)
    p = grbl_exact_motion(arm, emu, t)
    k = round(h / step)
    out["window"] = float(np.max(np.abs(p[2 * k :] - 2.0 * p[k:-k] + p[: -2 * k]) / h**2 / amax))
    assert out["velocity"] <= 1 + SLACK and out["acceleration"] <= 1 + SLACK, out
    assert out["junction"] <= JUNCTION_SHARE * (1 + SLACK), out
    assert out["window"] <= 1 + JUNCTION_SHARE + SLACK, out
    q = joints(arm, emu, t[::4])
    assert arm.limits.contains_batch(q, tol=1e-9).all()
    return out


def at_rest(adapter: Recording, emu: Board, timeout: float = 30.0) -> None:
    """Wait for the adapter to finish what it runs and GRBL to be idle (else say where they are)."""
    deadline = time.monotonic() + timeout
    while True:
        with adapter._lock:
            cmd, running = adapter._cmd, adapter._cmd is not None and not adapter._finished
        state = emu.state
        if not running and state == "Idle":
            return
        if time.monotonic() > deadline:
            held = adapter._held
            raise AssertionError(
                f"the arm not at rest in {timeout:g} s: GRBL {state} at {adapter._steps.tolist()} steps, the "
                f"adapter runs {cmd and (cmd.id, cmd.kind)} (lines to send {bool(adapter._queue)}, unanswered "
                f"{list(adapter._pending)}, fault {adapter.fault}, "
                f"held {held and (held.at, held.end, len(held.lines))})"
            )
        time.sleep(0.02)


def resting_at(arm: robots.Robot, adapter: Recording, emu: Board, target: np.ndarray) -> bool:
    """The adapter runs nothing, GRBL is idle, and the tool is on ``target`` [m] (to a step's 0.3 mm)."""
    with adapter._lock:
        running = adapter._cmd is not None and not adapter._finished
    if running or emu.state != "Idle":
        return False
    rest = np.asarray(arm.actuators.commands(np.array(arm.neutral, dtype=float)))
    q = arm.actuators.joints_from_commands(grbl_steps(arm, emu) + rest, tol=np.inf)
    return bool(np.linalg.norm(arm.fk(q) - target) < 0.001)


def grbl_steps(arm: robots.Robot, emu: Board) -> np.ndarray:
    steps = emu.steps()
    return np.array([steps[a.axis] for a in arm.actuators.actuators])  # type: ignore[attr-defined]


def ends_where(arm: robots.Robot, emu: Board, cmd: Command) -> None:
    """GRBL at rest at ``cmd``'s last sample, to the step (the rest pose was GRBL's 0)."""
    rest = np.asarray(arm.actuators.commands(np.array(arm.neutral, dtype=float)))
    assert np.array_equal(grbl_steps(arm, emu), cmd.commands[-1] - rest)


def on_the_path(arm: robots.Robot, emu: Board, path: np.ndarray, tol: float) -> float:
    """How far [rad] the executed motion went from the trajectories' way (each point of it
    against the nearest of their samples; off it: the lines that join what GRBL held of one to
    the next); asserted within ``tol``."""
    pieces = emu.pieces
    t = np.arange(pieces[0][0], pieces[-1][0] + pieces[-1][1], 0.005)
    q = joints(arm, emu, t)
    far = max(float(np.min(np.max(np.abs(path - x), axis=1))) for x in q)
    assert far <= tol, far
    return far


def stream(track: Any, points: np.ndarray, hz: float = 100.0) -> None:
    """Put each target in turn at ``hz`` on the test's clock."""
    t0 = time.monotonic()
    for k, p in enumerate(points):
        track.send(target=p.tolist())
        time.sleep(max(0.0, t0 + (k + 1) / hz - time.monotonic()))


def keep(track: Any, seconds: float, hz: float = 100.0, **put: Any) -> None:
    """Put the same target at ``hz`` for ``seconds``."""
    t0 = time.monotonic()
    k = 0
    while time.monotonic() - t0 < seconds:
        track.send(**put)
        k += 1
        time.sleep(max(0.0, t0 + k / hz - time.monotonic()))


def test_a_stream_of_targets_is_followed_within_every_limit(router: str, served: Service, armd: ArmClient) -> None:
    """Targets along a line and back, 100 a second: the arm follows the stream's path (GRBL
    slower where it turns, never off it by more than what GRBL held when a splice came; more
    than half a second behind, the stream waits for it at rest), within every limit, and ends on
    the last target."""
    arm = robots.load(ARM)
    home = arm.fk(np.array(arm.neutral))
    a, b = home + np.array([0.0, 0.05, -0.02]), home + np.array([-0.03, -0.04, 0.03])
    way = np.linspace(0.0, 1.0, 120)[:, None]
    points = np.vstack([a + (b - a) * way, b + (a - b) * way[:60]])  # 1.8 s, at ~0.1 m/s, and half back
    with stepper_arm(router, served) as (emu, adapter), armd.track(ARM, deadman=1.0) as t:
        stream(t, points)
        deadline = time.monotonic() + 30.0
        while not resting_at(arm, adapter, emu, points[-1]):  # (held there: GRBL runs behind the stream)
            assert time.monotonic() < deadline, "the arm never rested on the last target"
            keep(t, 0.2, target=points[-1].tolist())
        statuses = {e.status for e in t.events}
    ratios = within_limits(arm, emu)
    ends_where(arm, emu, adapter.last())
    path = adapter.planned()
    far = on_the_path(arm, emu, path, 0.05)
    q = joints(arm, emu, np.array([emu.pieces[-1][0] + emu.pieces[-1][1]]))[0]
    print(f"\nfollowed: {ratios}; off the trajectories' way by {far:.4f} rad at most")
    assert np.linalg.norm(arm.fk(q) - points[-1]) < 0.001  # on the last target (to a step's 0.3 mm)
    assert len(adapter.events("started")) >= 1 and not adapter.events("aborted")
    assert statuses <= {"started", "deadman", "rejected"}, [e.message for e in t.events]


def test_a_stream_whose_puts_stop_comes_to_rest_where_its_last_trajectory_brakes(
    router: str, served: Service, armd: ArmClient
) -> None:
    """The puts stop while the arm goes a long way: no splice comes, and GRBL, which holds only the
    path's next lines, runs the last trajectory to its end, braked to rest where its deadman said,
    short of the goal, to the step."""
    arm = robots.load(ARM)
    goal = np.array(arm.neutral) + np.array([1.2, 0.6, -0.9])  # seconds away at a third of the limits
    with stepper_arm(router, served) as (emu, adapter), armd.track(ARM, deadman=0.1) as t:
        keep(t, 0.5, joints=goal.tolist(), speed=0.3)
        at_rest(adapter, emu)
        assert t.wait_for("deadman") is not None
    within_limits(arm, emu)
    last = adapter.last()
    ends_where(arm, emu, last)
    assert last.track is not None and last.kind == "move"
    assert np.max(np.abs(last.position[-1] - goal)) > 0.3  # braked short of the goal
    assert [e["id"] for e in adapter.events("done")] == [last.id]  # the stream's end, said once
    on_the_path(arm, emu, adapter.planned(), 0.05)


def test_an_estop_mid_stream_brakes_the_arm_along_its_way_never_back(
    router: str, served: Service, armd: ArmClient
) -> None:
    """An estop while the stream moves the arm: GRBL's feed hold brakes it along the lines it
    holds, within every limit, no joint going back; the stream's later puts move nothing, and
    GRBL, held and reset at rest, keeps its position (no alarm)."""
    arm = robots.load(ARM)
    goal = np.array(arm.neutral) + np.array([1.2, 0.6, -0.9])
    with stepper_arm(router, served) as (emu, adapter), armd.track(ARM, deadman=0.5) as t:
        keep(t, 0.5, joints=goal.tolist())
        deadline = time.monotonic() + 10.0
        while emu.speed() <= 20.0:  # [deg/s] (GRBL slows down at each corner of its lines: stopped there
            assert time.monotonic() < deadline, "GRBL never moved fast"  # it would prove nothing)
            t.send(joints=goal.tolist())
            time.sleep(0.01)
        asked = time.monotonic()
        armd.estop(ARM)
        keep(t, 0.3, joints=goal.tolist())  # after the estop: the session is over
        at_rest(adapter, emu)
        assert t.wait_for("ended") is not None
        held = grbl_steps(arm, emu)
        keep(t, 0.2, joints=goal.tolist())
        time.sleep(0.3)
        assert np.array_equal(grbl_steps(arm, emu), held)  # nothing moved after it
    stops = [e for e in adapter.events("accepted") if e.get("trajectory") == "stop"]
    assert len(stops) == 1 and any(e["id"] == stops[0]["id"] for e in adapter.events("done"))
    assert not adapter.events("fault")  # (the reset came in Hold:0: no alarm)
    within_limits(arm, emu)
    end = emu.pieces[-1][0] + emu.pieces[-1][1]
    q = joints(arm, emu, np.arange(asked - 0.002, end + 0.01, 0.002))
    moving = (q[2] - q[0]) / 0.004  # [rad/s] when the estop was asked
    assert np.max(np.abs(moving)) > 0.1  # it was moving, fast
    way = np.where(moving != 0.0, np.sign(moving), np.sign(q[-1] - q[0]))
    back = -np.diff(q, axis=0) * way
    assert np.max(back) <= 1e-9, np.max(back)  # no joint ever went back
    assert np.max(np.abs(q[-1] - goal)) > 0.2  # stopped short of the goal


def test_late_and_refused_splices_never_make_the_arm_jump(router: str, served: Service, armd: ArmClient) -> None:
    """Every 15th trajectory of the stream read 150 ms late (refused: the arm goes on with the one it
    has, and the service takes over again from it), and two splices put by someone else, one
    naming a trajectory the adapter does not run, one that would jump: refused. The arm goes on
    along what it runs, within every limit, and ends where the last one it took ends."""
    arm = robots.load(ARM)
    home = arm.fk(np.array(arm.neutral))
    a, b = home + np.array([0.0, 0.04, -0.02]), home + np.array([-0.03, -0.05, 0.02])
    points = a + (b - a) * np.linspace(0.0, 1.0, 150)[:, None]
    with stepper_arm(router, served, Late) as (emu, adapter), armd.track(ARM, deadman=1.0) as t:
        stream(t, points[:75])
        running = adapter.last()  # (a splice of it that would jump 0.01 rad, and one of nobody's)
        k = min(len(running.times) - 1, 40)
        msg = {"kind": "move", "track": t.session_id, "rate_hz": running.rate_hz, "times": running.times[: -k or None]}
        for ident, after, off in (("stray", "nobody", 0.0), ("jump", running.id, 0.01)):
            put = {**msg, "id": ident, "position": running.position[k:] + off}
            put["splice"] = {"after": after, "at": running.times[k]}
            armd.session.put(f"{PREFIX}/{ARM}/trajectory", json.dumps(put, default=lambda a: a.tolist()))
        stream(t, points[75:])
        at_rest(adapter, emu)
    refused = {e.get("id"): e["reason"] for e in adapter.events("rejected")}
    late = [r for r in refused.values() if "after its time" in r]
    assert "takes over from nobody" in refused["stray"] and "jump" in refused  # (the jump: off by 0.01 rad, or
    # naming one that was no longer the last by the time it came)
    assert late, refused  # (some came late: the test's point)
    assert not adapter.events("aborted") and not adapter.events("fault")
    ratios = within_limits(arm, emu)
    ends_where(arm, emu, adapter.last())
    far = on_the_path(arm, emu, adapter.planned(), 0.05)
    print(f"\n{len(late)} late, {len(refused)} refused in all: {ratios}; off the path by {far:.4f} rad at most")


def test_a_stalled_adapter_leaves_grbl_to_rest_at_the_end_of_what_it_holds(
    router: str, served: Service, armd: ArmClient
) -> None:
    """The adapter's loop stalls 2 s mid-stream (nothing sent): GRBL runs what it holds and
    comes to rest at its end, as its planner always planned, within every limit; then the
    stream's lines come again, and GRBL goes on from rest along the path (no jump to catch up)."""
    arm = robots.load(ARM)
    goal = np.array(arm.neutral) + np.array([1.2, 0.6, -0.9])
    with stepper_arm(router, served, Stalling) as (emu, adapter), armd.track(ARM, deadman=0.5) as t:
        keep(t, 3.0, joints=goal.tolist())
        at_rest(adapter, emu)
    ratios = within_limits(arm, emu)
    assert adapter.stalled is not None
    began, ended = adapter.stalled
    q = joints(arm, emu, np.arange(began, ended, 0.002))
    still = np.max(np.abs(np.diff(q, axis=0)), axis=1) == 0.0
    assert still.any() and not still.all()  # it ran on after the stall began, and was at rest before it ended
    ends_where(arm, emu, adapter.last())
    on_the_path(arm, emu, adapter.planned(), 0.05)
    print(f"\nstalled {ended - began:.2f} s: {ratios}")
