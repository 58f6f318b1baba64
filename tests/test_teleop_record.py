"""``armd record --teleop`` and ``armd replay`` of a teleoperated session (issue 35): a circle of
targets streamed by the Python client to the service and a simulated arm on an in-process
router, heard by ``armd record`` run as a user runs it (its own process); then replayed by
``armd replay``, as a path of moves and, ``--stream``, as the same puts again at their pace.
Every sample the arm was sent is checked against its limits (as tests/test_tracking.py does)."""

from __future__ import annotations

import contextlib
import itertools
import math
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import orjson
import pytest
import zenoh
from conftest import ROOT, collect, free_port, wait_for

from armd import robots
from armd.clients import ArmClient
from armd.errors import BadRequest
from armd.planning.recording import Command, Recording
from armd.service.server import Service
from armd.service.zconfig import network_config
from tests.test_tracking import Recorder, within_limits

pytestmark = pytest.mark.slow  # (processes, a router, seconds of motion)

ARM = "insomniac"
IDLE = "so101"  # served, with no adapter
PREFIX = "rt"
CENTRE_OFFSET = np.array([0.0, -0.05, -0.05])  # [m] the circle's centre from the tool at the neutral pose
RADIUS = 0.05  # [m]
SPEED = 0.2  # [m/s] along the circle
CIRCLE_S = 2.0  # [s]
DEADMAN = 1.0  # [s] the session's: long enough to come to its last target on a busy machine, where cycles come late


# -- the service, a simulated arm that keeps what it ran, and armd's commands as their own processes --


@pytest.fixture(scope="module")
def served(router: str) -> Iterator[Service]:
    session = zenoh.open(network_config(connect=[router]))
    service = Service(session, {ARM: robots.load(ARM), IDLE: robots.load(IDLE)}, prefix=PREFIX)
    yield service
    service.close()
    session.close()


@pytest.fixture(scope="module")
def arm_sim(router: str, served: Service) -> Iterator[Recorder]:
    session = zenoh.open(network_config(connect=[router]))
    rec = Recorder(session, robots.load(ARM), PREFIX)
    wait_for(lambda: served.book.current(served.arms[ARM]).source == "adapter", 10, "the adapter's state")
    yield rec
    rec.adapter.close()
    session.close()
    wait_for(lambda: served._adapter_count(served.arms[ARM]) == 0, 10, "the adapter gone")


class Armd:
    """``armd ARGS`` as its own process: every line it prints, its stderr, Enter and Ctrl-C."""

    def __init__(self, args: list[str]) -> None:
        self.lines: list[str] = []
        self._cv = threading.Condition()
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "armd.cli", *args],
            cwd=ROOT,
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        self.err = ""
        self._reader = threading.Thread(target=self._read, name="test-armd-stdout")
        self._reader.start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            with self._cv:
                self.lines.append(line.rstrip("\n"))
                self._cv.notify_all()

    def wait_for_line(self, text: str, timeout: float = 60.0) -> str:
        with self._cv:
            self._cv.wait_for(lambda: any(text in x for x in self.lines) or self.proc.poll() is not None, timeout)
            found = [x for x in self.lines if text in x]
        assert found, f"no line with {text!r}: {self.lines} {self.proc.poll()}"
        return found[0]

    def enter(self) -> None:
        assert self.proc.stdin is not None
        self.proc.stdin.write("\n")
        self.proc.stdin.flush()

    def wait(self, timeout: float = 120.0) -> int:
        """Its exit code, once it ends (its stderr in ``err``)."""
        assert self.proc.stdin is not None and self.proc.stderr is not None
        with contextlib.suppress(BrokenPipeError):
            self.proc.stdin.close()
        code = self.proc.wait(timeout=timeout)
        self.err = self.proc.stderr.read()
        return code

    def close(self) -> None:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(timeout=10)
        self._reader.join(timeout=10)
        for pipe in (self.proc.stdin, self.proc.stdout, self.proc.stderr):
            if pipe is not None:
                with contextlib.suppress(BrokenPipeError):
                    pipe.close()


@contextlib.contextmanager
def armd(*args: str) -> Iterator[Armd]:
    cmd = Armd(list(args))
    try:
        yield cmd
    finally:
        cmd.close()


def run(*args: str, timeout: float = 120.0) -> tuple[int, str, str]:
    """``armd ARGS`` to its end: its exit code, what it printed, its stderr."""
    with armd(*args) as cmd:
        code = cmd.wait(timeout)
        cmd.close()
        return code, "\n".join(cmd.lines), cmd.err


def network(router: str) -> list[str]:
    return ["--connect", router, "--prefix", PREFIX, "--timeout", "10"]


def resting(arm_sim: Recorder, settle: float = 0.3, timeout: float = 20.0) -> np.ndarray:
    """Where the arm comes to rest (its position unchanged for ``settle`` s)."""
    last = [arm_sim.adapter.position.copy(), time.monotonic()]

    def still() -> bool:
        now = arm_sim.adapter.position.copy()
        if np.any(now != last[0]):
            last[0], last[1] = now, time.monotonic()
        return time.monotonic() - last[1] >= settle

    wait_for(still, timeout, "the arm to rest")
    return arm_sim.adapter.position.copy()


def forget(arm_sim: Recorder) -> None:
    """What the arm ran so far forgotten: it is at rest, the next trajectory starts anew."""
    with arm_sim.lock:
        arm_sim.ran.clear()
        arm_sim.times.clear()


def joined(ran: list[Any]) -> np.ndarray:
    """The positions a run of trajectories sent, sample by sample, each up to where the next
    took over (as :meth:`Recorder.commanded`)."""
    parts = []
    for cmd, nxt in zip(ran, [*ran[1:], None], strict=True):
        spliced = nxt is not None and nxt.after == cmd.id
        parts.append(cmd.position[: round(nxt.at * cmd.rate_hz)] if spliced else cmd.position)
    return np.vstack(parts)


def ran_within_limits(arm: robots.Robot, arm_sim: Recorder) -> int:
    """Every sample the arm was sent since :func:`forget` within every limit (finite
    differences, the splices joined; each run of one rate on its own: moves and streams start and
    end at rest): the samples checked."""
    with arm_sim.lock:
        ran = list(arm_sim.ran)
    assert ran, "nothing ran"
    n = 0
    for _, run_ in itertools.groupby(ran, key=lambda cmd: cmd.rate_hz):
        part = list(run_)
        samples = joined(part)
        within_limits(arm, samples, 1.0 / part[0].rate_hz)
        n += len(samples)
    return n


# -- a session, recorded ---------------------------------------------------------------------------


@dataclass
class Session:
    file: Path
    printed: str
    puts: list[dict[str, Any]]  # as the stream sent them (heard on the key)
    sent: int  # puts sent
    end: np.ndarray  # [rad] where the arm rested when the session ended
    targets: np.ndarray  # [m] the circle's targets


@pytest.fixture(scope="module")
def recorded(router: str, served: Service, arm_sim: Recorder, tmp_path_factory: pytest.TempPathFactory) -> Session:
    """``armd record insomniac --teleop`` while a client streams: the gripper opened and the
    tool held at the circle's start for a second, then once round most of the circle at 0.2
    m/s, the gripper closed halfway; ended with Enter once the arm rests."""
    arm = served.arms[ARM]
    file = tmp_path_factory.mktemp("session") / "session.json"
    centre = arm.fk(arm.neutral) + CENTRE_OFFSET
    w = SPEED / RADIUS
    n = int(CIRCLE_S * 100)
    targets = np.array(
        [centre + RADIUS * np.array([0.0, math.cos(w * k / 100), math.sin(w * k / 100)]) for k in range(n)]
    )
    resting(arm_sim)
    with (
        armd("record", ARM, "--teleop", "-o", str(file), *network(router)) as rec,
        ArmClient(router, prefix=PREFIX, timeout=10.0) as client,
    ):
        rec.wait_for_line("recording insomniac")
        time.sleep(0.3)  # (the arm at rest, heard before the stream begins)
        heard, sub = collect(client, f"{PREFIX}/{ARM}/track")
        try:
            with client.track(ARM, deadman=DEADMAN) as t:
                t0 = time.monotonic()
                for k in range(100):  # held at the start for a second, the gripper open
                    t.send(target=targets[0].tolist(), gripper=1.0)
                    time.sleep(max(0.0, t0 + (k + 1) / 100 - time.monotonic()))
                t0 = time.monotonic()
                for k, p in enumerate(targets):
                    t.send(target=p.tolist(), gripper=1.0 if k < n // 2 else 0.0)
                    time.sleep(max(0.0, t0 + (k + 1) / 100 - time.monotonic()))
                end = resting(arm_sim)
                sent = t.seq
            time.sleep(0.3)
            rec.enter()
            assert rec.wait() == 0, rec.err
        finally:
            sub.undeclare()  # type: ignore[attr-defined]
        rec.close()
        printed = "\n".join(rec.lines)
    return Session(file, printed, list(heard), sent, end, targets)


def test_a_streamed_session_is_recorded_with_the_arms_state_and_the_commands_in_time_order(
    recorded: Session, arm_sim: Recorder
) -> None:
    arm = robots.load(ARM)
    raw = orjson.loads(recorded.file.read_bytes())
    assert raw["version"] == 2 and raw["state"] == {"adapter": arm_sim.adapter.id, "source": "commanded"}
    rec = Recording.load(recorded.file)
    assert rec.robot == ARM and rec.joints == tuple(arm.joint_names)
    # the state: in time order, at the adapter's pace (50 a second), where the arm was
    t = rec.times
    assert np.all(np.diff(t) > 0.0)
    assert 20.0 <= (len(t) - 1) / (t[-1] - t[0]) <= 60.0, (len(t) - 1) / (t[-1] - t[0])
    assert np.allclose(
        rec.position[-1], recorded.end, atol=1e-6
    )  # the arm at rest where the session ended (to the file's 6 digits)
    assert all(arm.limits.contains(q, tol=1e-9) for q in rec.position)
    # the commands: every put, as it was sent, in order; on the clock of the state, at its client's pace
    # (a stream's puts are sent to be dropped where they queue, the latest being what matters: on
    # a busy machine some are. Measured: none idle nor with two busy processes, and none heard on
    # the router's side then; once 107 of 300 missing from the recording, others' tests running too)
    assert rec.commands is not None
    assert f"{len(rec.commands)} puts in 1 session(s)" in recorded.printed, recorded.printed
    seqs = [c.put["seq"] for c in rec.commands]
    assert seqs == sorted(set(seqs)) and set(seqs) <= set(range(recorded.sent)), seqs
    assert len(seqs) >= 0.5 * recorded.sent, (len(seqs), recorded.sent)
    heard = {p["seq"]: p for p in recorded.puts}
    assert all(c.put == heard[c.put["seq"]] for c in rec.commands if c.put["seq"] in heard)
    ct = np.array([c.t for c in rec.commands])
    assert np.all(np.diff(ct) >= 0.0)
    assert np.allclose(np.diff(ct), np.diff([c.put["time"] for c in rec.commands]), atol=1e-5)
    assert t[0] <= ct[0] and ct[-1] < t[-1]  # (heard from before the first put to after the last)
    moved = int(np.argmax(np.any(np.abs(rec.position - rec.position[0]) > 1e-4, axis=1)))
    assert moved > 0 and t[moved] >= ct[0] - 0.01, (t[moved], ct[0])  # the arm moved after the first put, not before
    # the gripper: open, then closed (the adapter's word on what it commanded)
    assert rec.gripper is not None and rec.gripper[0] == 1.0 and rec.gripper[-1] == 0.0


def test_the_path_replay_ends_where_the_session_ended_within_every_limit(
    router: str, recorded: Session, arm_sim: Recorder
) -> None:
    arm = robots.load(ARM)
    with ArmClient(router, prefix=PREFIX, timeout=10.0) as client:
        client.move(ARM, np.array(arm.neutral) + np.array([0.4, 0.0, 0.0, 0.0, 0.0]), wait=True)
    resting(arm_sim)
    forget(arm_sim)
    code, printed, err = run("replay", ARM, str(recorded.file), *network(router))
    assert code == 0, err
    assert "replayed" in printed.splitlines()[-1], printed
    assert np.allclose(resting(arm_sim), recorded.end, atol=1e-3)
    assert arm_sim.adapter.gripper_opening == 0.0
    assert ran_within_limits(arm, arm_sim) > 100


def test_the_stream_replay_puts_the_session_again_at_its_pace_within_every_limit(
    router: str, recorded: Session, arm_sim: Recorder
) -> None:
    arm = robots.load(ARM)
    rec = Recording.load(recorded.file)
    assert rec.commands is not None
    with ArmClient(router, prefix=PREFIX, timeout=10.0) as client:
        client.move(ARM, np.array(arm.neutral) + np.array([-0.4, 0.0, 0.0, 0.0, 0.0]), wait=True)
        resting(arm_sim)
        forget(arm_sim)
        came: list[tuple[float, dict[str, Any]]] = []
        sub = client.session.declare_subscriber(
            f"{PREFIX}/{ARM}/track", lambda s: came.append((time.monotonic(), orjson.loads(s.payload.to_bytes())))
        )
        events, said = collect(client, f"{PREFIX}/{ARM}/events")
        try:
            code, printed, err = run("replay", ARM, str(recorded.file), "--stream", *network(router))
        finally:
            sub.undeclare()
            said.undeclare()  # type: ignore[attr-defined]
    assert code == 0, err
    assert f"replayed {recorded.file} on {ARM}: {len(rec.commands)} puts in 1 session(s)" in printed, printed
    # the arm ends where the session ended, its tool at the last target: idle, to a micrometre; on
    # a busy machine a cycle's trajectory that came late is refused and the arm may end a mm short,
    # in the session as in its replay (measured: 1.1 mm). Its joints are those the IK takes for
    # that point, its pitch free, from where the way there led. Every sample within every limit.
    end = resting(arm_sim)
    assert np.linalg.norm(arm.fk(end) - arm.fk(recorded.end)) < 0.005, (end, recorded.end)
    assert np.linalg.norm(arm.fk(end) - recorded.targets[-1]) < 0.005
    assert arm_sim.adapter.gripper_opening == 0.0
    assert ran_within_limits(arm, arm_sim) > 100
    # the same puts, in a new session numbered from 1, the deadman kept; at the recording's pace
    # (as in the recording, a put the network dropped on a busy machine is missing from those heard)
    puts = [p for _, p in came]
    session = puts[0]["session"]
    assert {p["session"] for p in puts} == {session} and session not in {c.put["session"] for c in rec.commands}
    seqs = [p["seq"] for p in puts]
    assert seqs == sorted(set(seqs)) and set(seqs) <= set(range(1, len(rec.commands) + 1)), seqs
    assert len(seqs) >= 0.5 * len(rec.commands), (len(seqs), len(rec.commands))

    def said_alike(put: dict[str, Any]) -> dict[str, Any]:
        return {k: v for k, v in put.items() if k not in ("session", "seq", "time")}

    assert all(said_alike(p) == said_alike(rec.commands[p["seq"] - 1].put) for p in puts)
    started = [e for e in events if e.get("status") == "started" and e.get("session") == session]
    assert [e["deadman"] for e in started] == [DEADMAN]
    # from rest at the stream's start: its first put not kept waiting for the move there to end
    assert not [e for e in events if e.get("status") == "waiting"], events
    ct = np.array([rec.commands[s - 1].t for s in seqs])
    assert np.allclose([p["time"] - puts[0]["time"] for p in puts], ct - ct[0], atol=1e-6)  # (when each was due)
    span = came[-1][0] - came[0][0]
    assert abs(span - (ct[-1] - ct[0])) < 0.1 * (ct[-1] - ct[0]) + 0.2, (span, ct[-1] - ct[0])
    # the tool went round the circle again: each target near the way the arm was sent
    tool = np.array([arm.fk(q) for q in arm_sim.commanded()[::2]])
    near = [float(np.min(np.linalg.norm(tool - p, axis=1))) for p in recorded.targets]
    assert np.median(near) < 0.02, np.median(near)


# -- what it refuses -------------------------------------------------------------------------------


def good_json() -> dict[str, Any]:
    arm = robots.load(ARM)
    t = np.linspace(0.0, 1.0, 11)
    q = np.array([np.array(arm.neutral) + 0.1 * x for x in t])
    puts = [{"session": "s", "seq": k, "joints": q[k].tolist(), "time": 100.0 + float(x)} for k, x in enumerate(t)]
    return Recording(
        ARM, tuple(arm.joint_names), t, q, None, tuple(Command(float(x), p) for x, p in zip(t, puts, strict=True))
    ).to_json()


def test_a_malformed_file_is_refused_naming_what_and_an_old_one_still_loads(tmp_path: Path) -> None:
    good = good_json()
    assert good["version"] == 2 and Recording.from_json(good).commands is not None
    old = {k: v for k, v in good.items() if k not in ("commands", "state")} | {"version": 1}
    assert Recording.from_json(old).commands is None  # (version 1: an arm recorded by hand)
    assert Recording.from_json({**old, "commands": "ignored in version 1"}).commands is None
    c = good["commands"]
    for change, field in [
        ({"version": 3}, "format"),
        ({"commands": None}, "commands"),
        ({"commands": "puts"}, "commands"),
        ({"commands": [{"t": 0.0}]}, "commands"),
        ({"commands": [{"t": 0.0, "put": c[0]["put"], "more": 1}]}, "commands"),
        ({"commands": [{"t": "0.1", "put": c[0]["put"]}]}, "commands"),
        ({"commands": [{"t": True, "put": c[0]["put"]}]}, "commands"),
        ({"commands": [{"t": math.nan, "put": c[0]["put"]}]}, "commands"),
        ({"commands": [{"t": 0.0, "put": "{}"}]}, "commands"),
        ({"commands": [c[1], c[0]]}, "commands"),
        ({"state": {"adapter": 5}}, "state"),
        ({"state": {"who": "x"}}, "state"),
        ({"state": ["sim"]}, "state"),
    ]:
        with pytest.raises(BadRequest) as e:
            Recording.from_json({**good, **change})
        assert e.value.field == field, (change, e.value)
    no_commands = {k: v for k, v in good.items() if k != "commands"}
    with pytest.raises(BadRequest) as e:
        Recording.from_json(no_commands)
    assert e.value.field == "format" and "no commands" in e.value.message
    # from the command line, before anything is asked of any service
    (tmp_path / "old.json").write_text(orjson.dumps(old).decode())
    (tmp_path / "bad.json").write_text(orjson.dumps({**good, "commands": [c[1], c[0]]}).decode())
    (tmp_path / "new.json").write_text(orjson.dumps({**good, "version": 3}).decode())
    nobody = ["--connect", f"tcp/127.0.0.1:{free_port()}", "--timeout", "1"]
    for name, said in [
        (
            "old",
            "has no tracking stream to replay (an arm recorded by hand, version 1): replay its path, without --stream",
        ),
        ("bad", "commands must be in time order: commands[1] at 0 s after 0.1 s"),
        ("new", "not an armd recording: format 'armd-recording' version 3 (expected 'armd-recording' version 1 or 2)"),
    ]:
        code, _, err = run("replay", ARM, str(tmp_path / f"{name}.json"), "--stream", *nobody)
        assert code == 1 and said in err, (name, err)


def test_recording_with_no_service_or_no_adapter_says_so(router: str, served: Service, tmp_path: Path) -> None:
    out = tmp_path / "never.json"
    cases = [
        (["--connect", f"tcp/127.0.0.1:{free_port()}"], "cannot reach an armd network at tcp/127.0.0.1:"),
        (["--connect", router, "--prefix", "nobody"], "no armd service answered nobody/insomniac/info"),
        (network(router), "no adapter of so101 is running"),
    ]
    with contextlib.ExitStack() as stack:
        cmds = [
            stack.enter_context(
                armd("record", IDLE if "so101" in said else ARM, "--teleop", "-o", str(out), "--seconds", "1", *where)
            )
            for where, said in cases
        ]
        for cmd, (_, said) in zip(cmds, cases, strict=True):
            assert cmd.wait() == 1 and said in cmd.err, cmd.err
            assert "armd: error:" in cmd.err and "Traceback" not in cmd.err
    assert not out.exists()
