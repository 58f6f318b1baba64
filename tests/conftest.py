"""Shared test helpers: a copy of a catalogue arm folder to break in a test."""

from __future__ import annotations

import os

# Every call into the native build is checked against its signature (armd.solvers.jit), in this
# process and the ones it starts: a caller passing the wrong arrays fails a test, not silently.
os.environ.setdefault("ARMD_NATIVE_CHECK", "1")

import shutil
from collections.abc import Callable
from pathlib import Path

import pytest

from armd import robots


@pytest.fixture
def arm_copy(tmp_path: Path) -> Callable[..., Path]:
    """Copy catalogue arm ``name`` into tmp_path, applying (old, new) text edits to its files."""

    def make(
        name: str,
        toml_edits: list[tuple[str, str]] = (),
        urdf_edits: list[tuple[str, str]] = (),
        as_name: str | None = None,
    ) -> Path:
        dst = tmp_path / (as_name or name)
        shutil.copytree(robots.CATALOGUE_DIR / name, dst)
        for fname, edits in (("robot.toml", toml_edits), ("robot.urdf", urdf_edits)):
            text = (dst / fname).read_text()
            for old, new in edits:
                assert old in text, f"test edit not applicable: {old!r} not in {fname}"
                text = text.replace(old, new, 1)
            (dst / fname).write_text(text)
        return dst

    return make


# -- Zenoh: a real router on 127.0.0.1, opened in-process ---------------------------------------

from collections.abc import Iterator  # noqa: E402

import zenoh  # noqa: E402

from armd.service.zconfig import free_port  # noqa: E402 (the tests import it from here too)


@pytest.fixture(scope="module")
def router() -> Iterator[str]:
    """A Zenoh router in this process, listening on a free loopback port: its endpoint."""
    from armd.service.zconfig import network_config

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    session = zenoh.open(network_config(listen=[endpoint], mode="router"))
    yield endpoint
    session.close()


@pytest.fixture(scope="module")
def service(router: str) -> Iterator[object]:
    """The armd service, on its own peer session joined to the router, serving the catalogue."""
    from armd.service.server import Service
    from armd.service.zconfig import network_config

    session = zenoh.open(network_config(connect=[router]))
    svc = Service(session, {n: robots.load(n) for n in robots.names()})
    yield svc
    svc.close()
    session.close()


@pytest.fixture(scope="module")
def client(router: str, service: object) -> Iterator[object]:
    from armd.clients import ArmClient

    with ArmClient(router, timeout=10.0) as c:
        yield c


# -- adapters: a session of their own on the router, and waiting for what they do ----------------

import json  # noqa: E402
import threading  # noqa: E402
import time  # noqa: E402


@pytest.fixture
def adapter_session(router: str) -> Iterator[zenoh.Session]:
    from armd.service.zconfig import network_config

    session = zenoh.open(network_config(connect=[router]))
    yield session
    session.close()


_PLAIN: dict[str, robots.Robot] = {}


def plain(name: str) -> robots.Robot:
    """Catalogue arm ``name`` without its world (no collision checks: the floor, its own links):
    for the tests of IK and planning arithmetic, which hold for every configuration within the
    limits. What the world changes is tested with the world (tests/test_collision.py)."""
    arm = _PLAIN.get(name)
    if arm is None:
        arm = robots.load_folder(robots.CATALOGUE_DIR / name)
        arm.collision = None
        _PLAIN[name] = arm
    return arm


def clear_configs(arm: robots.Robot, rng: object, n: int) -> list[object]:
    """``n`` random configurations of ``arm`` within every limit and clear of collisions (with
    itself, its floor and its obstacles), the tool point above the floor: truths whose tool points
    IK must reach ``ok`` (a colliding one's answer is ``collision``: tests/test_collision.py)."""
    out: list[object] = []
    world = arm.collision
    for _ in range(200_000):
        if len(out) == n:
            break
        q = rng.uniform(arm.limits.lower, arm.limits.upper)  # type: ignore[attr-defined]
        if not arm.limits.contains(q):
            continue
        if world is not None and (
            world.first_contact(q) is not None or (world.ground is not None and arm.fk(q)[2] < world.ground)
        ):
            continue
        out.append(q)
    assert len(out) == n, f"{arm.name}: no clear configuration in 200,000 draws"
    return out


def wait_for(predicate: object, timeout: float = 10.0, what: str = "") -> None:
    deadline = time.monotonic() + timeout
    while not predicate():  # type: ignore[operator]
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        time.sleep(0.02)


def collect(client: object, key: str) -> tuple[list[dict[str, object]], object]:
    got: list[dict[str, object]] = []
    lock = threading.Lock()

    def on(sample: zenoh.Sample) -> None:
        with lock:
            got.append(json.loads(sample.payload.to_bytes()))

    return got, client.session.declare_subscriber(key, on)  # type: ignore[attr-defined]


@pytest.fixture(autouse=True)
def _adapter_state_dir(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Adapters keep what must outlive them (the SSC-32's last pose) in a test's own folder."""
    monkeypatch.setenv("ARMD_STATE_DIR", str(tmp_path / "armd-state"))


@pytest.fixture(autouse=True)
def _no_adapter_left(monkeypatch: pytest.MonkeyPatch) -> Iterator[None]:
    """Every adapter a test made is closed when it ends, failed or not: one left running (its
    thread, its port, its Zenoh entities) once held pytest at exit after a failing test."""
    from armd.adapters.base import Adapter

    made: list[Adapter] = []
    init = Adapter.__init__

    def recorded(self: Adapter, *args: object, **kwargs: object) -> None:
        made.append(self)
        init(self, *args, **kwargs)  # type: ignore[arg-type]

    monkeypatch.setattr(Adapter, "__init__", recorded)
    yield
    for adapter in made:
        stop = getattr(adapter, "_stop", None)
        if stop is not None and not stop.is_set() and hasattr(adapter, "_thread"):
            with contextlib.suppress(Exception):
                adapter.close()


# -- TLS: a certificate authority made at test time -------------------------------------------------

import subprocess  # noqa: E402

DOCS = Path(__file__).resolve().parent.parent / "docs" / "security"


@pytest.fixture
def certs(tmp_path: Path) -> Path:
    """A throwaway CA and router certificate, made by docs/security/make-certs.sh."""
    if shutil.which("openssl") is None:
        pytest.skip("openssl is not installed: the TLS tests make a throwaway certificate authority with it")
    out = tmp_path / "certs"
    subprocess.run(["sh", str(DOCS / "make-certs.sh"), str(out)], check=True, capture_output=True, timeout=60)
    return out


# -- a command line that asks: answered line by line --------------------------------------------

import queue  # noqa: E402
import sys  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent


def converse(
    args: list[str], answer: Callable[[str], str], *, env: dict[str, str] | None = None, timeout: float = 120.0
) -> tuple[int, list[str], str]:
    """``armd ARGS`` run as a user runs it, each prompt it prints (a line starting ``> ``)
    answered by ``answer(prompt)`` (after doing what the prompt asks): its exit code, every line
    it printed and its stderr."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "armd.cli", *args],
        cwd=ROOT,
        env={**os.environ, **(env or {})},
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    assert proc.stdin is not None and proc.stdout is not None and proc.stderr is not None
    lines: queue.Queue[str | None] = queue.Queue()
    err: list[str] = []
    threading.Thread(target=lambda: [lines.put(x) for x in proc.stdout] + [lines.put(None)], daemon=True).start()  # type: ignore[union-attr]
    threading.Thread(target=lambda: err.append(proc.stderr.read()), daemon=True).start()  # type: ignore[union-attr]
    said: list[str] = []
    deadline = time.monotonic() + timeout
    try:
        while True:
            line = lines.get(timeout=max(deadline - time.monotonic(), 0.01))
            if line is None:
                break
            said.append(line.rstrip("\n"))
            if line.startswith("> "):
                reply = answer(line[2:].strip())
                try:
                    proc.stdin.write(reply + "\n")
                    proc.stdin.flush()
                except BrokenPipeError:
                    pass
        code = proc.wait(timeout=max(deadline - time.monotonic(), 1.0))
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    time.sleep(0.05)
    return code, said, "".join(err)


# -- an adapter as a user runs it, then `armd move` ---------------------------------------------

import contextlib  # noqa: E402


@contextlib.contextmanager
def adapter_process(args: list[str], tmp_path: Path) -> Iterator[subprocess.Popen[bytes]]:
    """``armd adapter <args>`` as its own process (its state in ``tmp_path``, its log in
    ``tmp_path/adapter.log``), terminated at the end."""
    env = {**os.environ, "ARMD_STATE_DIR": str(tmp_path)}
    with (tmp_path / "adapter.log").open("w") as log:
        proc = subprocess.Popen(
            [sys.executable, "-m", "armd.cli", "adapter", *args],
            cwd=ROOT,
            env=env,
            stdout=subprocess.DEVNULL,
            stderr=log,
        )
        try:
            yield proc
        finally:
            proc.terminate()
            try:
                proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(timeout=10)


def cli_move(robot: str, goal: list[float], router: str, *more: str) -> subprocess.CompletedProcess[str]:
    """``armd move ROBOT --goal ... --wait`` as a user runs it."""
    return subprocess.run(
        [
            sys.executable,
            "-m",
            "armd.cli",
            "move",
            robot,
            "--goal",
            *map(str, goal),
            "--wait",
            *more,
            "--connect",
            router,
        ],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=60,
    )
