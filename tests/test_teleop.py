"""``armd teleop`` (issue 35): an arm driven by hand through its tracking stream, end to end.

The follower is the service and a simulated arm on an in-process router, as in
tests/test_tracking.py. The leaders are the Feetech and Dynamixel packet-level emulators on
pseudo-terminals (in processes of their own), read through the vendors' SDKs by ``armd
teleop`` run as a user runs it, their servos turned by hand over time (their torque off). The
keyboard is ``armd teleop --keyboard`` in a pseudo-terminal, sent the bytes a terminal sends.
The gamepad is driven at its mapping's seam, evdev's events in and puts out (this machine has
no /dev/uinput to make a virtual pad with)."""

from __future__ import annotations

import contextlib
import fcntl
import math
import os
import queue
import signal
import struct
import subprocess
import sys
import termios
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import orjson
import pytest
import zenoh
from conftest import wait_for

from armd import robots
from armd.adapters.emulators.feetech import FeetechEmulator
from armd.adapters.emulators.process import EmulatorProcess
from armd.adapters.sim import SimAdapter
from armd.clients import ArmClient
from armd.robots import calibration as robots_calibration
from armd.service.server import Service
from armd.service.zconfig import network_config
from armd.tools.teleop.frames import heading, turned

pytestmark = pytest.mark.slow  # (processes, emulated buses, a router)

ROOT = Path(__file__).resolve().parent.parent
ARMS_DIR = ROOT / "examples" / "arms"
PREFIX = "tp"
CPR = 4096
TOUCH = 3e-3  # [rad] a follower at rest where the leader is: a count and a half of the leader's servo


# -- the follower: the service and a simulated arm -------------------------------------------------


@pytest.fixture
def served(router: str) -> Iterator[tuple[str, Service]]:
    """The service, a new one for each test (its streams' state their own: a stream's gripper,
    its sessions)."""
    session = zenoh.open(network_config(connect=[router]))
    arms = {n: robots.load(n) for n in ("so101", "insomniac")}
    arms["openmanipulator-x"] = robots.load_folder(ARMS_DIR / "openmanipulator-x")
    service = Service(session, arms, prefix=PREFIX)
    yield router, service
    service.close()
    session.close()


class Follower:
    """A simulated arm of the service's, and what is said and put on its keys."""

    def __init__(self, served: tuple[str, Service], name: str) -> None:
        router, self.service = served
        self.arm = self.service.arms[name]
        self.session = zenoh.open(network_config(connect=[router]))
        self.sim = SimAdapter(self.session, self.arm, prefix=PREFIX)
        self.events: list[dict[str, Any]] = []
        self.puts: list[tuple[float, dict[str, Any]]] = []  # (when it came, the put)
        self.lock = threading.Lock()
        base = f"{PREFIX}/{name}"
        self._subs = [
            self.session.declare_subscriber(f"{base}/events", self._on_event),
            self.session.declare_subscriber(f"{base}/track", self._on_put),
        ]
        wait_for(lambda: self.service.book.current(self.arm).source == "adapter", 10, "the adapter's state")

    def _on_event(self, sample: zenoh.Sample) -> None:
        with self.lock:
            self.events.append(orjson.loads(sample.payload.to_bytes()))

    def _on_put(self, sample: zenoh.Sample) -> None:
        with self.lock:
            self.puts.append((time.monotonic(), orjson.loads(sample.payload.to_bytes())))

    def track_events(self, status: str) -> list[dict[str, Any]]:
        with self.lock:
            return [e for e in self.events if e.get("event") == "track" and e.get("status") == status]

    def puts_since(self, t: float) -> list[dict[str, Any]]:
        """The puts sent at ``t`` [s, monotonic: every process's clock] or after (their own ``time``)."""
        with self.lock:
            return [p for _, p in self.puts if p["time"] >= t]

    def quiet(self, seconds: float = 0.5, timeout: float = 10.0) -> None:
        """Waits until no put has come for ``seconds``."""

        def still() -> bool:
            with self.lock:
                return not self.puts or time.monotonic() - self.puts[-1][0] >= seconds

        wait_for(still, timeout, "the puts to stop")

    def no_more_puts(self, seconds: float = 0.3) -> None:
        """No put comes for ``seconds``."""
        with self.lock:
            before = len(self.puts)
        time.sleep(seconds)
        with self.lock:
            assert len(self.puts) == before, self.puts[before:]

    @property
    def position(self) -> np.ndarray:
        return np.array(self.sim.position, dtype=float)

    def rests_at(self, q: np.ndarray, tolerance: float = TOUCH, timeout: float = 20.0, what: str = "") -> None:
        """Waits until the arm rests within ``tolerance`` [rad] of ``q``."""

        def there() -> bool:
            return bool(np.max(np.abs(self.position - q)) <= tolerance) and not np.any(self.sim.velocity)

        wait_for(there, timeout, what or f"{self.arm.name} at {np.round(q, 3)} (at {np.round(self.position, 3)})")

    def still(self, settle: float = 0.3, timeout: float = 10.0) -> np.ndarray:
        """Where the arm comes to rest (unchanged for ``settle`` s)."""
        last = [self.position, time.monotonic()]

        def rested() -> bool:
            now = self.position
            if np.any(now != last[0]):
                last[0], last[1] = now, time.monotonic()
            return time.monotonic() - last[1] >= settle

        wait_for(rested, timeout, f"{self.arm.name} to rest")
        return self.position

    def close(self) -> None:
        for sub in self._subs:
            sub.undeclare()
        self.sim.close()
        self.session.close()
        wait_for(lambda: self.service._adapter_count(self.arm) == 0, 10, "the adapter gone")


@pytest.fixture
def follower(served: tuple[str, Service]) -> Iterator[Callable[[str], Follower]]:
    made: list[Follower] = []

    def make(name: str) -> Follower:
        made.append(Follower(served, name))
        return made[-1]

    yield make
    for f in made:
        f.close()


# -- the leader: a bus arm in the hand, on its emulator --------------------------------------------


class Hand:
    """A leader arm as it really is (each servo's zero and direction), moved by hand on its
    emulator: a joint vector is each servo's count by the arm's map (a = M q + b)."""

    def __init__(self, emu: Any, arm: robots.Robot, zero: dict[int, float], direction: dict[int, int]) -> None:
        self.emu, self.arm, self.zero, self.direction = emu, arm, zero, direction
        self.servos = list(arm.actuators.actuators)

    def counts(self, q: np.ndarray) -> dict[int, float]:
        amap = self.arm.actuators
        a = amap.M @ np.asarray(q, dtype=float) + amap.b
        return {
            s.id: self.zero[s.id] + self.direction[s.id] * float(x) * CPR / (2 * math.pi)  # type: ignore[attr-defined]
            for s, x in zip(self.servos, a, strict=True)
        }

    def pose(self, q: np.ndarray) -> None:
        for i, c in self.counts(q).items():
            self.emu.move_by_hand(i, c)

    def glide(
        self, start: np.ndarray, end: np.ndarray, seconds: float, watch: Callable[[], np.ndarray], hz: float = 25.0
    ) -> list[tuple[np.ndarray, np.ndarray]]:
        """The arm turned from ``start`` to ``end`` over ``seconds`` (a hand's pace), step by
        step; at each step, the leader's joints and ``watch()`` (where the follower is)."""
        out = []
        n = max(int(seconds * hz), 1)
        t0 = time.monotonic()
        for k in range(1, n + 1):
            s = 0.5 - 0.5 * math.cos(math.pi * k / n)  # (from rest to rest)
            q = start + s * (end - start)
            self.pose(q)
            out.append((q, watch()))
            time.sleep(max(0.0, t0 + k / hz - time.monotonic()))
        return out


class Teleop:
    """``armd teleop ARGS`` as its own process, on the test's router: every line it prints."""

    def __init__(self, args: list[str], router: str, tmp_path: Path) -> None:
        self.lines: list[str] = []
        self._cv = threading.Condition(threading.RLock())
        self._err = (tmp_path / "teleop.err").open("w")
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "armd.cli", "teleop", *args, "--connect", router, "--prefix", PREFIX],
            cwd=ROOT,
            stdin=subprocess.DEVNULL,
            stdout=subprocess.PIPE,
            stderr=self._err,
            text=True,
        )
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()
        self.err_path = tmp_path / "teleop.err"

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            with self._cv:
                self.lines.append(line.rstrip("\n"))
                self._cv.notify_all()

    def said(self, text: str) -> list[str]:
        with self._cv:  # (a re-entrant lock: also under wait_for_line's)
            return [line for line in self.lines if text in line]

    def wait_for_line(self, text: str, count: int = 1, timeout: float = 60.0) -> str:
        """The ``count``-th line with ``text``, once it is printed."""
        with self._cv:
            self._cv.wait_for(lambda: len(self.said(text)) >= count or self.proc.poll() is not None, timeout)
        lines = self.said(text)
        assert len(lines) >= count, f"not {count} lines with {text!r}: {self.lines}\n{self.err_path.read_text()}"
        return lines[count - 1]

    def stop(self) -> int:
        """SIGINT (Ctrl-C): its exit code."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
        try:
            code = self.proc.wait(timeout=20)
        finally:
            self.close()
        return code

    def close(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait(timeout=10)
        self._reader.join(timeout=10)
        self._err.close()


@contextlib.contextmanager
def teleop(args: list[str], router: str, tmp_path: Path) -> Iterator[Teleop]:
    t = Teleop(args, router, tmp_path)
    try:
        yield t
    finally:
        t.close()


def relink(link: Path, target: str) -> None:
    """``link`` to ``target``, at once (as udev's /dev/serial/by-id links follow a device)."""
    new = link.with_suffix(".new")
    with contextlib.suppress(FileNotFoundError):
        new.unlink()
    new.symlink_to(target)
    os.replace(new, link)


SO101_ZERO = {1: 2100.0, 2: 1990.0, 3: 2048.0, 4: 2200.0, 5: 1900.0}  # the leader's own servos, as mounted
SO101_DIRECTION = {1: 1, 2: -1, 3: 1, 4: -1, 5: 1}
GRIPPER = (1500.0, 2900.0)  # its gripper's counts closed and open


def write_calibration(path: Path, arm: robots.Robot, zero: dict[int, float], direction: dict[int, int]) -> None:
    """The leader's calibration.toml as ``armd calibrate`` writes it: each servo's zero,
    direction and the counts its joint's limits reach (and a margin)."""
    hand = Hand(None, arm, zero, direction)
    values = {}
    for k, s in enumerate(hand.servos):
        ends = []
        for x in s.angle_range:  # type: ignore[attr-defined]
            q = np.zeros(arm.nq)
            q[int(np.argmax(np.abs(arm.actuators.M[k])))] = x
            ends.append(hand.counts(q)[s.id])  # type: ignore[attr-defined]
        values[s.name] = (zero[s.id], direction[s.id], (min(ends) - 60.0, max(ends) + 60.0))  # type: ignore[attr-defined]
    robots_calibration.write(path, values, GRIPPER)


def followed(path: list[tuple[np.ndarray, np.ndarray]], q0: np.ndarray, q1: np.ndarray) -> None:
    """The follower moved with the leader, not only once it stopped: before the leader's last
    step it had come a quarter of the way (how closely it follows, idle or busy, is a
    benchmark's to say)."""
    way = q1 - q0
    progress = [float((follow - q0) @ way / (way @ way)) for _, follow in path[:-1]]
    assert max(progress) > 0.25, progress


def test_a_leader_of_the_same_kind_leads_joint_to_joint_and_its_gripper(
    served: tuple[str, Service], follower: Callable[[str], Follower], tmp_path: Path
) -> None:
    """The so101 leading the so101: the leader's counts through its own calibration (zeros off
    the factory's, two servos turned round) are the follower's joints; a joint past the
    follower's limit is taken to it, and said; the gripper follows."""
    pytest.importorskip("scservo_sdk")
    arm = robots.load("so101")
    cal = tmp_path / "leader.toml"
    write_calibration(cal, arm, SO101_ZERO, SO101_DIRECTION)
    q0 = np.array([0.2, -0.3, 0.4, 0.1, 0.0])
    hand = Hand(None, arm, SO101_ZERO, SO101_DIRECTION)
    at = {**hand.counts(q0), 6: GRIPPER[0]}
    f = follower("so101")
    with EmulatorProcess(FeetechEmulator, ids=[1, 2, 3, 4, 5, 6], positions=at) as emu:
        hand.emu = emu
        args = ["so101", "--leader", "feetech", "--leader-port", emu.port, "--leader-calibration", str(cal)]
        with teleop(args, served[0], tmp_path) as t:
            t.wait_for_line("follows joint to joint")
            assert all(emu.register(i, 40) == 0 for i in range(1, 7))  # the leader's torque off
            f.rests_at(q0, what="the follower at the leader's pose")
            q1 = np.array([-0.3, 0.3, -0.2, -0.4, 0.6])
            path = hand.glide(q0, q1, 1.5, lambda: f.position)
            f.rests_at(q1, what="the follower where the leader stopped")
            followed(path, q0, q1)
            # the gripper: the leader's opening
            for opening in (1.0, 0.4):
                emu.move_by_hand(6, GRIPPER[0] + opening * (GRIPPER[1] - GRIPPER[0]))
                wait_for(
                    lambda o=opening: f.sim.gripper_opening is not None and abs(f.sim.gripper_opening - o) < 0.01,
                    10,
                    f"the follower's gripper at {opening}",
                )
            # a joint past the follower's limit: taken to the limit, and said
            past = q1.copy()
            past[0] = arm.limits.upper[0] + 0.05
            hand.pose(past)
            limit = past.copy()
            limit[0] = arm.limits.upper[0]
            f.rests_at(limit, what="the follower at shoulder_pan's limit")
            line = t.wait_for_line("beyond its limits")
            assert "shoulder_pan" in line
            assert t.stop() == 0
        assert t.wait_for_line("ended:")


def test_a_leader_that_stops_answering_stops_the_puts_and_is_followed_again_when_it_is_back(
    served: tuple[str, Service], follower: Callable[[str], Follower], tmp_path: Path
) -> None:
    """Its servos silent (a cable off), then its port gone (unplugged): each time the puts stop
    at once (the follower brakes at its deadman), it is said once, and when the leader answers
    again the follower comes to its pose in a new session (no calibration here: the factory's
    zeros, and said)."""
    pytest.importorskip("scservo_sdk")
    arm = robots.load("so101")
    hand = Hand(None, arm, dict.fromkeys(range(1, 6), 2048.0), dict.fromkeys(range(1, 6), 1))
    q0 = np.array([0.3, -0.2, 0.3, 0.2, -0.5])
    f = follower("so101")
    link = tmp_path / "leader-port"
    with EmulatorProcess(FeetechEmulator, ids=[1, 2, 3, 4, 5, 6], positions=hand.counts(q0)) as emu:
        hand.emu = emu
        link.symlink_to(emu.port)
        with teleop(["so101", "--leader", "feetech", "--leader-port", str(link)], served[0], tmp_path) as t:
            assert "no calibration of the leader so101" in t.wait_for_line("no calibration")
            t.wait_for_line("follows joint to joint")
            f.rests_at(q0)
            sessions = {p["session"] for p in f.puts_since(0.0)}
            for outage in ("silent", "unplugged"):
                deadmen = len(f.track_events("deadman"))
                wait_for(lambda: f.puts_since(time.monotonic() - 0.05), 10, "the teleop putting")
                if outage == "silent":
                    for i in range(1, 7):
                        emu.silence(i)
                else:
                    emu.unplug()
                gone = time.monotonic()
                f.quiet()
                assert len(f.puts_since(gone)) <= 1  # (the reading under way, at most; then none)
                # (a busy machine may have stalled the leader's replies a moment before: that is said too)
                back = len(t.said("answers again"))
                t.wait_for_line("stopped answering", back + 1)
                wait_for(lambda n=deadmen: len(f.track_events("deadman")) > n, 10, "the follower's deadman")
                rest = f.still()
                q = q0 + (0.2 if outage == "silent" else -0.2)  # moved meanwhile
                hand.pose(q)
                time.sleep(0.3)
                assert np.array_equal(f.position, rest)  # (nothing followed while it was gone)
                if outage == "silent":
                    for i in range(1, 7):
                        emu.silence(i, False)
                else:
                    relink(link, emu.plug())
                t.wait_for_line("answers again", back + 1)
                assert len(t.said("stopped answering")) == back + 1  # said once, however long it was gone
                f.rests_at(q, what=f"the follower at the leader's pose once it is back ({outage})")
                new = {p["session"] for p in f.puts_since(0.0)} - sessions
                assert new  # a new session
                sessions |= new
            assert t.stop() == 0


def test_a_leader_of_another_kind_leads_by_its_tool_point(
    served: tuple[str, Service], follower: Callable[[str], Follower], tmp_path: Path
) -> None:
    """The so101 leading the insomniac: the insomniac's tool goes where the so101's is, each
    seen from its own base and facing its own forward, at the so101's tool pitch."""
    pytest.importorskip("scservo_sdk")
    leader = robots.load("so101")
    hand = Hand(None, leader, dict.fromkeys(range(1, 6), 2048.0), dict.fromkeys(range(1, 6), 1))
    q0 = np.array([0.3, -0.3, 0.3, 0.2, 0.0])
    f = follower("insomniac")
    ins = f.arm
    turn = heading(ins) - heading(leader)
    assert abs(turn - math.pi / 2) < 1e-9  # (the insomniac faces +x, the so101 -y: from their models)

    def target(q: np.ndarray) -> tuple[np.ndarray, float]:
        """Where the leader's tool is (as its servos' whole counts say), in the insomniac's frame."""
        counts = np.array([round(c) for c in hand.counts(q).values()], dtype=float)
        read = leader.actuators.joints_from_commands(counts, tol=np.inf)
        pose = leader.pose(read)
        return turned(pose.position, turn), pose.pitch

    def there(q: np.ndarray) -> Callable[[], bool]:
        p, pitch = target(q)
        return lambda: (
            bool(np.linalg.norm(ins.fk(f.position) - p) < 1e-3)
            and abs(ins.tool_pitch(f.position) - pitch) < 1e-3
            and not np.any(f.sim.velocity)
        )

    with EmulatorProcess(FeetechEmulator, ids=[1, 2, 3, 4, 5, 6], positions=hand.counts(q0)) as emu:
        hand.emu = emu
        args = ["insomniac", "--leader", "feetech", "--leader-port", emu.port, "--leader-robot", "so101"]
        with teleop(args, served[0], tmp_path) as t:
            t.wait_for_line("insomniac follows by its tool point")
            wait_for(there(q0), 20, "the insomniac's tool at the so101's")
            q1 = np.array([-0.4, -0.2, 0.6, -0.2, 0.0])
            hand.glide(q0, q1, 1.0, lambda: f.position)
            wait_for(there(q1), 20, "the insomniac's tool where the so101's stopped")
            assert t.stop() == 0
    assert {p["session"] for p in f.puts_since(0.0)} and all("target" in p for p in f.puts_since(0.0))


def test_a_dynamixel_leader_leads_its_kind_with_the_calibration_in_the_state_dir(
    served: tuple[str, Service], follower: Callable[[str], Follower], tmp_path: Path
) -> None:
    """The OpenManipulator-X leading its kind on ROBOTIS's SDK: the leader's calibration found
    where ``armd calibrate ... --output`` put it by default (``<robot>.leader.calibration.toml``
    in the adapters' state dir), the gripper too."""
    pytest.importorskip("dynamixel_sdk")
    from armd.adapters.emulators.dynamixel import DynamixelEmulator

    arm = robots.load_folder(ARMS_DIR / "openmanipulator-x")
    zero = {11: 2048.0, 12: 2000.0, 13: 2100.0, 14: 2048.0}
    direction = {11: 1, 12: 1, 13: -1, 14: 1}
    state = Path(os.environ["ARMD_STATE_DIR"])
    write_calibration(state / "openmanipulator-x.leader.calibration.toml", arm, zero, direction)
    hand = Hand(None, arm, zero, direction)
    q0 = np.array([0.5, -0.3, 0.4, 0.2])
    f = follower("openmanipulator-x")
    at = {**hand.counts(q0), 15: GRIPPER[1]}
    with EmulatorProcess(DynamixelEmulator, ids=[11, 12, 13, 14, 15], positions=at) as emu:
        hand.emu = emu
        args = ["openmanipulator-x", "--robots-dir", str(ARMS_DIR), "--leader", "dynamixel", "--leader-port", emu.port]
        with teleop(args, served[0], tmp_path) as t:
            assert str(state / "openmanipulator-x.leader.calibration.toml") in t.wait_for_line("calibration:")
            t.wait_for_line("follows joint to joint")
            f.rests_at(q0)
            wait_for(lambda: f.sim.gripper_opening == 1.0, 10, "the follower's gripper open")
            q1 = np.array([-0.6, 0.4, -0.3, -0.5])
            path = hand.glide(q0, q1, 1.5, lambda: f.position)
            f.rests_at(q1)
            followed(path, q0, q1)
            assert t.stop() == 0


# -- the keyboard: armd teleop --keyboard in a pseudo-terminal -------------------------------------


class Terminal:
    """``armd teleop ARGS`` in a pseudo-terminal (``TERM=xterm``, 40 x 120), as it runs in a
    user's: the bytes typed, and everything it draws."""

    def __init__(self, args: list[str], router: str) -> None:
        master, slave = os.openpty()
        fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", 40, 120, 0, 0))
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "armd.cli", "teleop", *args, "--connect", router, "--prefix", PREFIX],
            cwd=ROOT,
            stdin=slave,
            stdout=slave,
            stderr=slave,
            env={**os.environ, "TERM": "xterm"},
            start_new_session=True,  # (its own session: the test's terminal's signals are not its)
        )
        os.close(slave)
        self.master = master
        self._output = bytearray()
        self._lock = threading.Lock()
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        while True:
            try:
                chunk = os.read(self.master, 4096)
            except OSError:  # (EIO: the other end closed)
                return
            if not chunk:
                return
            with self._lock:
                self._output += chunk

    @property
    def output(self) -> bytes:
        with self._lock:
            return bytes(self._output)

    def type(self, keys: bytes) -> float:
        """The keys typed; when [s, monotonic]."""
        at = time.monotonic()
        os.write(self.master, keys)
        return at

    def hold(
        self,
        key: bytes,
        seconds: float,
        until: Callable[[], bool] = lambda: True,
        first: float = 0.45,
        every: float = 0.03,
        timeout: float = 30.0,
    ) -> tuple[float, float]:
        """``key`` held for ``seconds``, and on until ``until()`` (the arm has got somewhere: on a
        busy machine it goes less far in a second), as a terminal sends it: once, then after
        ``first`` [s] again every ``every`` [s]. When it was pressed and when it was sent last."""
        pressed = self.type(key)
        last = pressed
        time.sleep(first)
        while time.monotonic() - pressed < seconds or not until():
            assert time.monotonic() - pressed < timeout, f"{key!r} held for {timeout} s"
            last = self.type(key)
            time.sleep(every)
        return pressed, last

    def shows(self, text: str, timeout: float = 20.0) -> None:
        wait_for(lambda: text.encode() in self.output, timeout, f"{text!r} on the screen")

    def close(self) -> int | None:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(timeout=10)
        self._reader.join(timeout=10)
        os.close(self.master)
        return self.proc.returncode


def moving(put: dict[str, Any]) -> bool:
    return any(put.get("velocity", [0.0])) or bool(put.get("pitch_rate")) or bool(put.get("roll_rate"))


def test_the_keyboard_jogs_the_tool_holds_it_and_space_stops_it(
    served: tuple[str, Service], follower: Callable[[str], Follower]
) -> None:
    f = follower("insomniac")
    ins = f.arm
    # (its longest deadman: the arm held while the keys are let go, on a machine whose CPUs are busy)
    term = Terminal(["insomniac", "--keyboard", "--deadman", "1"], served[0])
    try:
        term.shows("armd teleop insomniac: the keyboard")
        term.shows("x +0.287")  # where the tool is (the insomniac at its neutral pose)
        start = ins.fk(f.position)
        # forward (w), held: the tool moves from the press on, not stopping before the terminal's first repeat
        pressed, last = term.hold(b"w", 1.2, lambda: ins.fk(f.position)[0] - start[0] > 0.03)
        wait_for(lambda: f.puts_since(last + 0.4), 10, "puts after the key was let go")
        first = [p for p in f.puts_since(pressed + 0.15) if p["time"] < pressed + 0.45]  # (before the first repeat)
        assert first and all(moving(p) for p in first), first
        assert all(p["velocity"][0] > 0 and p["velocity"][1:] == [0.0, 0.0] for p in first)
        rest = f.still()
        moved = ins.fk(rest) - start
        assert moved[0] > 0.005 and np.max(np.abs(moved[1:])) < 1e-3, moved  # forward: the insomniac's +x
        # let go: puts go on, still (the arm held: no deadman)
        time.sleep(0.5)
        held = f.puts_since(last + 0.5)
        assert len(held) > 10 and not any(moving(p) for p in held)
        assert not f.track_events("deadman")
        # left (the left arrow, as an xterm sends it in the keypad mode curses sets): the insomniac's +y
        here = ins.fk(rest)
        term.hold(b"\x1bOD", 0.6, lambda: ins.fk(f.position)[1] - here[1] > 0.01)
        moved = ins.fk(f.still()) - here
        assert moved[1] > 0.002 and abs(moved[0]) < 1e-3 and abs(moved[2]) < 1e-3, moved
        # the gripper
        term.type(b"c")
        wait_for(lambda: f.sim.gripper_opening == 0.0, 10, "the gripper closed")
        term.type(b"o")
        wait_for(lambda: f.sim.gripper_opening == 1.0, 10, "the gripper open")
        # faster, and forward beyond reach: the screen says why the tool does not go on
        term.type(b"++")
        term.shows("0.2 m/s")
        term.hold(b"w", 1.5, lambda: b"unreachable: the target is out of reach" in term.output)
        # space stops: the stop verb, the session ended, no more puts until the next key
        term.hold(b"s", 0.6)
        term.type(b" ")
        wait_for(lambda: f.track_events("ended"), 10, "the session ended by the stop")
        term.shows("stopped (space)")
        f.still()
        f.no_more_puts()
        sessions = {p["session"] for p in f.puts_since(0.0)}
        low = ins.fk(f.position)
        term.hold(b"r", 0.6, lambda: ins.fk(f.position)[2] - low[2] > 0.01)  # up: in a new session
        up = ins.fk(f.still())
        assert len({p["session"] for p in f.puts_since(0.0)} - sessions) == 1
        assert up[2] - low[2] > 0.002
        term.type(b"q")
        assert term.proc.wait(timeout=20) == 0
        assert b"ended:" in term.output
    finally:
        term.close()


# -- the gamepad: at its mapping's seam (evdev's events in, puts out) --------------------------------


class Pad:
    """A gamepad as python-evdev's ``InputDevice`` shows one (its axes' ``AbsInfo``, its events
    as ``InputEvent``), moved by the test: no /dev/uinput here to make a virtual one."""

    def __init__(self) -> None:
        self.ev = pytest.importorskip("evdev", reason="python-evdev (the gamepad extra) is not installed")
        c = self.ev.ecodes
        self.name, self.path = "Test Pad", "/dev/input/event-test"
        stick = {"min": -32768, "max": 32767, "fuzz": 16, "flat": 128, "resolution": 0}
        trigger = {"min": 0, "max": 1023, "fuzz": 0, "flat": 0, "resolution": 0}
        hat = {"min": -1, "max": 1, "fuzz": 0, "flat": 0, "resolution": 0}
        self.info = {
            **{code: stick for code in (c.ABS_X, c.ABS_Y, c.ABS_RX, c.ABS_RY)},
            **{code: trigger for code in (c.ABS_Z, c.ABS_RZ)},
            c.ABS_HAT0X: hat,
            c.ABS_HAT0Y: hat,
        }
        self.at = dict.fromkeys(self.info, 0)
        self.queue: queue.Queue[Any] = queue.Queue()
        self.gone = False

    def capabilities(self) -> dict[int, list[Any]]:
        c = self.ev.ecodes
        return {
            c.EV_ABS: [(code, self.ev.AbsInfo(value=self.at[code], **i)) for code, i in self.info.items()],
            c.EV_KEY: [c.BTN_SOUTH, c.BTN_EAST, c.BTN_TL, c.BTN_TR],
        }

    def read(self) -> Iterator[Any]:
        if self.gone:
            raise OSError(19, "No such device")
        if self.queue.empty():
            raise BlockingIOError(11, "Resource temporarily unavailable")
        while not self.queue.empty():
            yield self.queue.get()

    def close(self) -> None:
        pass

    def push(self, name: str, value: int) -> None:
        """The axis or button ``name`` (evdev's) to ``value``, and a sync report."""
        c = self.ev.ecodes
        code = c.ecodes[name]
        kind = c.EV_ABS if name.startswith("ABS_") else c.EV_KEY
        if kind == c.EV_ABS:
            self.at[code] = value
        now = time.time()
        sec, usec = int(now), int((now % 1) * 1e6)
        self.queue.put(self.ev.InputEvent(sec, usec, kind, code, value))
        self.queue.put(self.ev.InputEvent(sec, usec, c.EV_SYN, c.SYN_REPORT, 0))

    def press(self, name: str) -> None:
        self.push(name, 1)
        self.push(name, 0)


def test_the_gamepads_sticks_triggers_and_buttons_jog_the_tool(
    served: tuple[str, Service], follower: Callable[[str], Follower]
) -> None:
    pad = Pad()
    from armd.tools.teleop.gamepad import EvdevPad, Gamepad
    from armd.tools.teleop.jog import Jog
    from armd.tools.teleop.stream import Stream

    f = follower("insomniac")
    ins = f.arm
    said: list[str] = []
    until = threading.Event()
    with ArmClient(served[0], prefix=PREFIX, timeout=10.0) as client:
        gamepad = Gamepad(Jog(ins), lambda: EvdevPad(device=pad))
        gamepad.start()
        stream = Stream(client, "insomniac", rate_hz=50, say=said.append)
        loop = threading.Thread(target=stream.run, args=(gamepad, until))
        loop.start()
        try:
            start = ins.fk(f.position)
            # within the dead zone: nothing put
            pad.push("ABS_X", 3000)  # (9% of its half travel)
            time.sleep(0.5)
            assert stream.puts == 0
            # the left stick forward (its Y up: negative), then back in the middle
            pad.push("ABS_Y", -32768)
            wait_for(lambda: ins.fk(f.position)[0] - start[0] > 0.03, 30, "the tool forward")
            pad.push("ABS_Y", 0)
            wait_for(lambda: f.puts_since(0.0) and not moving(f.puts_since(0.0)[-1]), 10, "the stick back at rest")
            assert all(p["velocity"][1] == 0.0 for p in f.puts_since(0.0))  # (X within its dead zone throughout)
            rest = f.still()
            moved = ins.fk(rest) - start
            # (where it rests: the point the service moved on, on a busy machine a little behind the arm then)
            assert moved[0] > 0.005 and np.max(np.abs(moved[1:])) < 1e-3, moved
            # the right trigger: up; the right stick up: the tool's tip up
            pad.push("ABS_RZ", 1023)
            wait_for(lambda: ins.fk(f.position)[2] - ins.fk(rest)[2] > 0.01, 30, "the tool up")
            pad.push("ABS_RZ", 0)
            pad.push("ABS_RY", -32768)
            wait_for(lambda: ins.tool_pitch(f.position) - ins.tool_pitch(rest) > 0.1, 30, "the tool's tip up")
            pad.push("ABS_RY", 0)
            up = f.still()
            assert ins.fk(up)[2] - ins.fk(rest)[2] > 0.002 and ins.tool_pitch(up) - ins.tool_pitch(rest) > 0.02
            # the bumpers: the gripper; the D-pad up: faster
            pad.press("BTN_TL")
            wait_for(lambda: f.sim.gripper_opening == 0.0, 10, "the gripper closed")
            pad.press("BTN_TR")
            wait_for(lambda: f.sim.gripper_opening == 1.0, 10, "the gripper open")
            linear = gamepad.jog.linear
            pad.push("ABS_HAT0Y", -1)
            pad.push("ABS_HAT0Y", 0)
            wait_for(lambda: gamepad.jog.linear > linear, 5, "faster")
            # the pad gone: no more puts, said once; back: followed again in a new session
            sessions = {p["session"] for p in f.puts_since(0.0)}
            deadmen = len(f.track_events("deadman"))
            pad.gone = True
            wait_for(lambda: any("is gone" in x for x in said), 10, "the pad said gone")
            f.no_more_puts(0.6)
            wait_for(lambda: len(f.track_events("deadman")) > deadmen, 10, "the deadman")
            pad.gone = False
            pad.push("ABS_Y", 32767)  # (back, with the stick pulled: back)
            wait_for(lambda: any("answers again" in x for x in said), 10, "the pad back")
            wait_for(lambda: {p["session"] for p in f.puts_since(0.0)} - sessions, 10, "a put of a new session")
            assert len({p["session"] for p in f.puts_since(0.0)} - sessions) == 1
            assert sum("is gone" in x for x in said) == 1
            # the east button: stop (the stick still pulled moves nothing until it is let go)
            pad.press("BTN_EAST")
            wait_for(lambda: f.track_events("ended"), 10, "the session ended by the stop")
            stopped = f.still()
            f.no_more_puts()
            pad.push("ABS_Y", 0)
            f.no_more_puts()
            pad.push("ABS_Y", 32767)  # (pulled again: back, in a new session)
            wait_for(lambda: ins.fk(f.position)[0] < ins.fk(stopped)[0] - 0.005, 30, "the tool back")
            pad.push("ABS_Y", 0)
            assert len({p["session"] for p in f.puts_since(0.0)} - sessions) == 2
        finally:
            until.set()
            loop.join(timeout=10)
            gamepad.close()
    assert not loop.is_alive()


def test_a_sticks_dead_zone_and_travel() -> None:
    pytest.importorskip("evdev", reason="python-evdev (the gamepad extra) is not installed")
    from armd.tools.teleop.gamepad import PadMap, Travel

    codes = __import__("evdev").ecodes
    m = PadMap({codes.ABS_X: Travel(0, 255, 0), codes.ABS_RZ: Travel(0, 1023, 0)})
    for x, left in ((128, 0.0), (140, 0.0), (255, -1.0), (0, 1.0)):
        m.feed(3, codes.ABS_X, x)
        assert abs(m.axes().left - left) < 1e-9, (x, m.axes())
    m.feed(3, codes.ABS_X, 128 + 64)  # half way right: beyond the dead zone, scaled from its edge
    assert -0.5 < m.axes().left < -0.3
    m.feed(3, codes.ABS_RZ, 1023)
    assert m.axes().up == 1.0
    assert m.feed(1, codes.BTN_EAST, 1) == "stop" and m.feed(1, codes.BTN_EAST, 2) is None  # (2: a held repeat)


# -- what it refuses: one line each ---------------------------------------------------------------


def test_what_teleop_cannot_do_it_says_in_one_line(served: tuple[str, Service]) -> None:
    def teleop_run(*args: str) -> subprocess.CompletedProcess[str]:
        return subprocess.run(
            [sys.executable, "-m", "armd.cli", "teleop", *args, "--connect", served[0], "--prefix", PREFIX],
            cwd=ROOT,
            stdin=subprocess.DEVNULL,
            capture_output=True,
            text=True,
            timeout=120,
        )

    out = teleop_run("so101")  # no source
    assert out.returncode == 2 and "one of the arguments --leader --keyboard --gamepad is required" in out.stderr
    for args, said in (
        (["so101", "--leader", "feetech"], "--leader needs --leader-port"),
        (["so101", "--leader", "feetech", "--leader-port", "/dev/ttyNOSUCHPORT"], "cannot open /dev/ttyNOSUCHPORT"),
        (["so101", "--keyboard"], "runs in a terminal"),
        (["so101", "--keyboard", "--leader-port", "/dev/ttyUSB0"], "go with --leader"),
        (["nosucharm", "--leader", "feetech", "--leader-port", "/dev/ttyUSB0"], "nosucharm"),
    ):
        out = teleop_run(*args)
        assert out.returncode == 1, (args, out.stdout, out.stderr)
        lines = out.stderr.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("armd: error:") and said in lines[0], (args, out.stderr)
    if __import__("importlib").util.find_spec("evdev") is not None:  # (no /dev/input/event* here)
        out = teleop_run("insomniac", "--gamepad")
        assert out.returncode == 1 and "no gamepad among the input devices" in out.stderr, out.stderr
