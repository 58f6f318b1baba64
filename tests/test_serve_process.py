"""`armd serve` as a separate process (as a user runs it), called from the client and the CLI."""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from armd import robots
from armd.clients import ArmClient
from armd.errors import ServiceError
from tests.conftest import free_port

pytestmark = pytest.mark.slow  # (seconds: processes, routers, emulated boards; `pytest -m "not slow"` skips it)

ROOT = Path(__file__).resolve().parent.parent
LIMITS = [
    "--max-batch",
    "50",
    "--max-payload",
    "200000",
    "--max-samples",
    "5000",
    "--max-waypoints",
    "10",
    "--deadline",
    "3",
    "--workers",
    "2",
]  # the operator's flags, other than the defaults


CAN = {"name": "can", "shape": "cylinder", "size": [0.03, 0.12], "position": [0.40, 0.10]}


@pytest.fixture(scope="module")
def served(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    objects = tmp_path_factory.mktemp("world") / "objects.json"
    objects.write_text(json.dumps({"insomniac": [CAN]}))
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "armd.cli",
            "serve",
            "--listen",
            endpoint,
            "--sim",
            "--time-scale",
            "5",
            "--objects",
            str(objects),
            *LIMITS,
        ],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    assert proc.stdout is not None
    deadline = time.monotonic() + 120
    line = ""
    while time.monotonic() < deadline:
        line = proc.stdout.readline()
        if "armd serving" in line or proc.poll() is not None:
            break
    assert "armd serving" in line, (line, proc.stderr.read() if proc.poll() is not None else "")
    yield endpoint
    proc.send_signal(signal.SIGTERM)
    assert proc.wait(timeout=20) == 0


def cli(endpoint: str, *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "armd.cli", *args, "--connect", endpoint],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
    )


def test_client_against_the_process(served: str) -> None:
    with ArmClient(served) as c:
        assert [r["name"] for r in c.robots()] == robots.names()
        level = robots.load("sg5ut").fk([0.2, 1.2, -0.6, -0.6])  # a point the tool reaches level
        r = c.ik("sg5ut", level.tolist(), approach="parallel")
        assert r.status == "ok" and abs(r.pitch) < 1e-9
        with pytest.raises(ServiceError) as e:
            c.ik("sg5ut", [0.2, 0.05, float("nan")])
        assert e.value.code == "bad_request"
        goal = np.array([0.3, 1.2, -0.5, -0.4])
        c.move("sg5ut", goal, wait=True, wait_timeout=15)
        assert np.allclose(c.state("sg5ut")["position"], goal, atol=1e-6)


def test_cli_against_the_process(served: str) -> None:
    r = cli(served, "robots")
    assert r.returncode == 0 and "insomniac" in r.stdout
    r = cli(served, "ik", "gupta3", "0.2", "0.0", "0.1")
    assert r.returncode == 0 and "ok" in r.stdout, r.stderr
    r = cli(served, "fk", "gupta3", "0", "1", "-1", "--json")
    assert r.returncode == 0 and '"within_limits": true' in r.stdout
    r = cli(served, "move", "desk4", "--target", "0.25", "0.05", "0.15", "--wait")
    assert r.returncode == 0, r.stderr
    r = cli(served, "stop", "desk4")
    assert r.returncode == 0 and "adapters" in r.stdout
    r = cli(served, "ik", "gupta3", "0.2", "0.0", "nan")
    assert r.returncode == 1 and "armd: error:" in r.stderr and "Traceback" not in r.stderr
    r = cli(served, "ik", "gupta9", "0.2", "0.0", "0.1")
    assert r.returncode == 1 and "unknown robot" in r.stderr


def test_cli_sensor_targets_and_the_gripper(served: str) -> None:
    """``armd ik ROBOT --sensor NAME RANGE [BEARING]`` (seed 000's readings), the gripper's sensor
    read where the simulated arm is, and ``armd gripper ROBOT open|close|0..1``."""
    arm = robots.load("insomniac")
    r = cli(served, "ik", "insomniac", "--sensor", "et_left", "0.25", "-0.3", "--approach", "parallel", "--json")
    assert r.returncode == 0, r.stderr
    expected = [0.12 + 0.25 * math.cos(-0.3), 0.10 + 0.25 * math.sin(-0.3), 0.10]
    assert np.allclose(json.loads(r.stdout)["target"], expected, atol=1e-12)
    with ArmClient(served) as c:
        here = np.array(c.state("insomniac")["position"])
    r = cli(served, "ik", "insomniac", "--sensor", "gripper_et", "0.08", "--json")
    assert np.allclose(json.loads(r.stdout)["target"], arm.sensor_point("gripper_et", 0.08, q=here), atol=1e-9)
    for bad in (["0.2", "0.0", "0.1", "--sensor", "et_left", "0.2"], [], ["--sensor", "et_left"]):
        r = cli(served, "ik", "insomniac", *bad)
        assert r.returncode == 1 and r.stderr.startswith("armd: error:"), (bad, r.stderr)
    r = cli(served, "gripper", "insomniac", "close")
    assert r.returncode == 0 and "opening" in r.stdout, r.stderr
    r = cli(served, "gripper", "insomniac", "0.5", "--json")
    assert r.returncode == 0 and json.loads(r.stdout)["opening"] == 0.5
    r = cli(served, "gripper", "insomniac", "1.5")
    assert r.returncode == 1 and "opening" in r.stderr
    r = cli(served, "pick", "insomniac", "0.25", "0.05", "0.06")
    assert r.returncode == 0 and "lift: line to" in r.stdout and "STOPPED" not in r.stdout, (r.stdout, r.stderr)
    r = cli(served, "place", "insomniac", "0.25", "0.05", "0.06", "--json")
    assert r.returncode == 0 and json.loads(r.stdout)["done"]
    r = cli(served, "pick", "insomniac", "0.9", "0.0", "0.1")
    assert r.returncode == 1 and r.stderr.startswith("armd: error: above:"), r.stderr


def test_the_simulated_sensors_see_the_objects_the_operator_put_down(served: str) -> None:
    """``armd serve --sim --objects FILE``: the insomniac's left scanner sees the can 0.25 m ahead
    between its edges, and ``armd detect`` finds it where it is; a malformed file is refused
    before anything starts."""
    import threading

    import zenoh

    got: list[dict[str, object]] = []
    lock = threading.Lock()

    def on(sample: zenoh.Sample) -> None:
        with lock:
            got.append(json.loads(sample.payload.to_bytes()))

    with ArmClient(served) as c:
        sub = c.session.declare_subscriber("armd/insomniac/sensors/et_left", on)
        deadline = time.monotonic() + 20
        while time.monotonic() < deadline:
            with lock:
                if len({r["sweep"] for r in got}) >= 3:
                    break
            time.sleep(0.05)
        sub.undeclare()
    edge = math.asin(0.03 / 0.28)
    seen = [r for r in got if r["range"] is not None]
    assert seen and all(abs(float(r["bearing"])) <= edge + 1e-6 for r in seen)  # type: ignore[arg-type]
    assert min(float(r["range"]) for r in seen) < 0.26  # type: ignore[arg-type]
    r = cli(served, "detect", "insomniac", "--json")
    assert r.returncode == 0, r.stderr
    (can,) = json.loads(r.stdout)["objects"]
    assert can["stable"] and math.dist(can["position"][:2], CAN["position"]) <= 3 * can["uncertainty"]
    r = cli(served, "detect", "insomniac")
    assert r.returncode == 0 and "1 object(s) seen by et_left, et_right" in r.stdout, r.stdout
    r = cli(served, "detect", "insomniac", "--sensor", "gripper_et")
    assert r.returncode == 1 and "not a scanning sensor" in r.stderr
    bad = subprocess.run(
        [
            sys.executable,
            "-m",
            "armd.cli",
            "serve",
            "--sim",
            "--objects",
            "/nonexistent.json",
            "--listen",
            "tcp/127.0.0.1:1",
        ],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert bad.returncode == 1 and "--objects /nonexistent.json" in bad.stderr


def test_cli_without_a_service() -> None:
    r = subprocess.run(
        [sys.executable, "-m", "armd.cli", "robots", "--connect", f"tcp/127.0.0.1:{free_port()}", "--timeout", "1"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert r.returncode == 1 and "armd: error:" in r.stderr and "Traceback" not in r.stderr


def test_operator_limits_from_the_command_line(served: str) -> None:
    arm = robots.load("gupta3")
    points = [arm.fk([0.01 * k, 1.0, -1.0]).tolist() for k in range(51)]
    with ArmClient(served) as c:
        assert len(c.ik_batch("gupta3", points[:50])["status"]) == 50
        with pytest.raises(ServiceError) as e:
            c.ik_batch("gupta3", points)
        assert e.value.code == "too_large" and e.value.fields["limit"] == 50
        with pytest.raises(ServiceError) as e:
            c.call("gupta3/fk", {"q": [0, 1, -1], "pad": "x" * 200_000})
        assert e.value.code == "too_large" and e.value.fields["limit"] == 200_000
        with pytest.raises(ServiceError) as e:
            c.plan("gupta3", [0.5, 1.2, -1.2], start=[0.0, 1.0, -1.0], rate_hz=1000, speed=0.1)
        assert e.value.code == "too_large" and e.value.fields["limit"] == 5000
        with pytest.raises(ServiceError) as e:
            c.plan("gupta3", [0.5, 1.2, -1.2], via=[[0.0, 1.0, -1.0]] * 11)
        assert e.value.code == "bad_request" and e.value.field == "via"
        assert c.call("robots")["limits"] == {
            "max_payload_bytes": 200_000,
            "max_batch": 50,
            "max_depth": 8,
            "max_waypoints": 10,
            "max_samples": 5000,
            "deadline": 3.0,
        }


def test_serve_refuses_a_nonsense_limit() -> None:
    r = subprocess.run(
        [sys.executable, "-m", "armd.cli", "serve", "--listen", f"tcp/127.0.0.1:{free_port()}", "--deadline", "0"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert r.returncode == 1 and "deadline must be" in r.stderr and "Traceback" not in r.stderr


def _ball_stl(path: Path, n: int) -> int:
    """A unit sphere as a binary STL of 2 n^2 triangles (a latitude-longitude grid)."""
    theta, phi = np.meshgrid(np.linspace(0, np.pi, n + 1), np.linspace(0, 2 * np.pi, n + 1), indexing="ij")
    v = np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], -1)
    a, b, c, d = v[:-1, :-1], v[1:, :-1], v[1:, 1:], v[:-1, 1:]
    tris = np.concatenate([np.stack([a, b, c], -2).reshape(-1, 3, 3), np.stack([a, c, d], -2).reshape(-1, 3, 3)])
    rows = np.zeros(len(tris), dtype=[("normal", "<f4", 3), ("vertices", "<f4", (3, 3)), ("attribute", "<u2")])
    rows["vertices"] = tris
    path.write_bytes(b"\0" * 80 + len(tris).to_bytes(4, "little") + rows.tobytes())
    return len(tris)


def _heavy_arm(folder: Path) -> None:
    """Six joints (the numerical IK's arm), each link a sphere of 238,050 triangles: coal checks it
    in milliseconds, and the service's warm-up of it takes seconds (7.6 s on an idle 2-core
    machine), as a vendor's arm with its detailed meshes does (the PiPER's: a minute)."""
    (folder / "meshes").mkdir(parents=True)
    assert _ball_stl(folder / "meshes" / "ball.stl", 345) == 238_050
    axes = ["0 0 1", "0 1 0", "0 1 0", "1 0 0", "0 1 0", "1 0 0"]
    mesh = '<mesh filename="meshes/ball.stl" scale="0.03 0.03 0.03"/>'
    links = ['<link name="base"/>'] + [
        f'<link name="l{i}"><collision><origin xyz="0 0 0.05"/><geometry>{mesh}</geometry></collision></link>'
        for i in range(1, 7)
    ]
    joints = [
        f'<joint name="j{i}" type="revolute"><parent link="{"base" if i == 1 else f"l{i - 1}"}"/><child link="l{i}"/>'
        f'<origin xyz="0 0 {0.05 if i == 1 else 0.1}"/><axis xyz="{axes[i - 1]}"/>'
        '<limit lower="-2" upper="2" velocity="2" effort="1"/></joint>'
        for i in range(1, 7)
    ]
    tool = '<link name="tool"/><joint name="tool_fixed" type="fixed"><parent link="l6"/><child link="tool"/></joint>'
    (folder / "robot.urdf").write_text(f'<robot name="heavy">{"".join(links)}{"".join(joints)}{tool}</robot>')
    (folder / "robot.toml").write_text(
        '[robot]\njoints = ["j1", "j2", "j3", "j4", "j5", "j6"]\nneutral = [0.0, 0.3, 0.6, 0.0, 0.3, 0.0]\n'
    )


def test_a_sigterm_during_the_warm_up_ends_the_service_at_once(tmp_path: Path) -> None:
    """A warm-up that takes long (here the compiler's: no native build, an empty cache, about
    35 s): a SIGTERM while it runs ends the service within 2 s, not after it."""
    env = {**os.environ, "ARMD_NATIVE": "0", "ARMD_CACHE_DIR": str(tmp_path / "cache")}
    proc = subprocess.Popen(
        [sys.executable, "-m", "armd.cli", "serve", "--listen", f"tcp/127.0.0.1:{free_port()}"],
        cwd=ROOT,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert proc.stderr is not None
        said = []
        while not any("warming up" in line for line in said) and proc.poll() is None:
            said.append(proc.stderr.readline())
        assert proc.poll() is None, said
        time.sleep(1.0)  # (into the compiler's work)
        sent = time.monotonic()
        proc.send_signal(signal.SIGTERM)
        code = proc.wait(timeout=120)
        took = time.monotonic() - sent
        out, err = proc.communicate(timeout=10)
        assert code == 0 and took < 2.0, (code, took, err[-2000:])
        assert "armd serving" not in out and "stopped during the warm-up" in err and "Traceback" not in err, err
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def test_a_slow_arm_warms_up_behind_the_service_and_delays_no_other(tmp_path: Path) -> None:
    """With the heavy arm in --robots-dir, the service is declared once the catalogue's arms are
    warm (their paths compile the code), and answers every arm at once, the heavy one included,
    while the heavy arm warms up on a thread of its own (it held the whole service: a PiPER with
    its vendor's meshes, 58 s before anything answered); a SIGTERM meanwhile still ends it."""
    _heavy_arm(tmp_path / "arms" / "heavy")
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    proc = subprocess.Popen(
        [sys.executable, "-m", "armd.cli", "serve", "--listen", endpoint, "--robots-dir", str(tmp_path / "arms")],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    said: list[str] = []
    reader = threading.Thread(target=lambda: said.extend(iter(proc.stderr.readline, "")), daemon=True)  # type: ignore[union-attr]
    try:
        assert proc.stdout is not None
        line = proc.stdout.readline()
        assert "armd serving" in line and "heavy" in line, (line, said)
        reader.start()
        with ArmClient(endpoint, timeout=10.0) as client:
            for name, target in (("insomniac", [0.25, 0.05, 0.12]), ("heavy", [0.1, 0.0, 0.3])):
                asked = time.monotonic()
                answer = client.ik(name, target)
                assert time.monotonic() - asked < 2.0 and answer.status in ("ok", "unreachable", "collision"), answer
        assert not any("heavy warmed up" in s for s in said), said  # (all of that while it warmed up) ...
        deadline = time.monotonic() + 120
        while not any("heavy warmed up" in s for s in said) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert any("heavy warmed up" in s and "in the background" in s for s in said), said  # (... behind the service)
        sent = time.monotonic()
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=60) == 0 and time.monotonic() - sent < 2.0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
