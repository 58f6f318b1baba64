"""armd view: a real meshcat server on 127.0.0.1, a real Zenoh router, and the page rendered by a
real headless Chromium (WebGL on SwiftShader), whose screenshots are checked against the
forward kinematics: the arm is drawn where FK puts it, it moves with the published state,
and a published trajectory's tool path and target are drawn where they are."""

from __future__ import annotations

import math
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
import urllib.request
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest
import zenoh
from conftest import free_port, wait_for
from matplotlib.image import imread
from numpy.typing import NDArray

from armd import planning, robots
from armd.adapters.sim import SimAdapter
from armd.errors import BadRequest, ViewerError
from armd.service.protocol import encode
from armd.service.zconfig import client_config
from armd.tools.view import CAMERA_FOV, OBJECT_COLOR, OBSTACLE_COLOR, PATH_COLOR, TARGET_COLOR, ArmView, ZenohFeed

pytestmark = pytest.mark.slow  # (seconds: processes, routers, emulated boards; `pytest -m "not slow"` skips it)

ROOT = Path(__file__).resolve().parent.parent
W, H = 800, 600
CHROMIUM = next((p for p in map(shutil.which, ("chromium", "chromium-browser", "google-chrome")) if p), None)
needs_chromium = pytest.mark.skipif(
    CHROMIUM is None, reason="no Chromium to render the viewer page: apt-get install chromium (Debian/Ubuntu)"
)
# Headless, offline (without the networking flags it hangs on a closed network), WebGL on the CPU.
CHROMIUM_FLAGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--use-angle=swiftshader",
    "--enable-unsafe-swiftshader",
    f"--window-size={W},{H}",
    "--virtual-time-budget=3000",
]

Image = NDArray[np.int64]


def screenshot(url: str, out: Path) -> Image:
    """The page at ``url`` as Chromium draws it: (H, W, 3) RGB in 0..255."""
    assert CHROMIUM is not None
    with tempfile.TemporaryDirectory() as profile:
        run = subprocess.run(
            [CHROMIUM, *CHROMIUM_FLAGS, f"--user-data-dir={profile}", f"--screenshot={out}", url],
            capture_output=True,
            text=True,
            timeout=60,
        )
    assert out.is_file(), f"chromium wrote no screenshot (exit {run.returncode}): {run.stderr[-2000:]}"
    return np.asarray(np.round(imread(out)[..., :3] * 255), dtype=np.int64)


def project(view: ArmView, p: object) -> tuple[float, float]:
    """Pixel (x, y) of point ``p`` [m] in the arm's base frame, through the view's camera (meshcat's
    perspective camera: 75 degree vertical field of view, z up, looking at the scene centre)."""
    eye = view.camera
    f = view.centre - eye
    f /= np.linalg.norm(f)
    r = np.cross(f, [0.0, 0.0, 1.0])
    r /= np.linalg.norm(r)
    u = np.cross(r, f)
    d = np.asarray(p, dtype=float) - eye
    t = math.tan(math.radians(CAMERA_FOV) / 2)
    return (1 + (d @ r) / ((d @ f) * t * W / H)) / 2 * W, (1 - (d @ u) / ((d @ f) * t)) / 2 * H


def colored(img: Image, color: int, tol: int = 30) -> NDArray[np.bool_]:
    rgb = np.array([(color >> 16) & 255, (color >> 8) & 255, color & 255])
    return np.all(np.abs(img - rgb) <= tol, axis=-1)


def distance_to(mask: NDArray[np.bool_], xy: tuple[float, float]) -> float:
    """Pixels from ``xy`` to the nearest pixel centre of ``mask`` (inf if the mask is empty)."""
    ys, xs = np.nonzero(mask)
    return float(np.min(np.hypot(xs + 0.5 - xy[0], ys + 0.5 - xy[1]))) if len(xs) else math.inf


def arm_points(arm: robots.Robot, q: object) -> list[NDArray[np.float64]]:
    """Every joint origin and the tool point [m] at ``q``."""
    data = arm.model.createData()
    pin.forwardKinematics(arm.model, data, np.asarray(q, dtype=float))
    return [np.array(data.oMi[i].translation) for i in range(1, arm.model.njoints)] + [arm.fk(q)]


def state_message(arm: robots.Robot, q: object) -> bytes:
    """A state exactly as an adapter publishes it (adapters/base.py, Adapter._publish_state)."""
    zeros = [0.0] * arm.nq
    return encode(
        {
            "robot": arm.name,
            "adapter": "test0000",
            "kind": "sim",
            "position": list(map(float, q)),
            "velocity": zeros,
            "acceleration": zeros,
            "moving": False,
            "trajectory": None,
            "fault": None,
            "time": time.time(),
        }
    )


@pytest.fixture
def view_session(router: str) -> Iterator[zenoh.Session]:
    """The viewer's Zenoh session: a client of the router, as ``armd view`` opens it."""
    session = zenoh.open(client_config([router]))
    yield session
    session.close()


@pytest.fixture
def insomniac_view(view_session: zenoh.Session) -> Iterator[tuple[ArmView, ZenohFeed]]:
    with ArmView(robots.load("insomniac"), port=0) as view, ZenohFeed(view, view_session) as feed:
        yield view, feed


@needs_chromium
def test_the_arm_is_drawn_where_fk_puts_it_and_follows_the_state(
    insomniac_view: tuple[ArmView, ZenohFeed], adapter_session: zenoh.Session, tmp_path: Path
) -> None:
    view, _ = insomniac_view
    arm = view.robot
    pub = adapter_session.declare_publisher("armd/insomniac/state", encoding=zenoh.Encoding.APPLICATION_JSON)
    a = np.array([0.8, 1.9, -1.2, -0.6, 0.0])  # turned left, forearm reaching forward and up
    b = np.array([-1.2, 1.0, -0.4, -0.9, 0.5])  # turned right, leaning far forward

    def shown(q: NDArray[np.float64]) -> bool:
        pub.put(state_message(arm, q))  # as an adapter does, again and again
        return bool(np.allclose(view.shown, q))

    shots = {}
    for name, q in (("a", a), ("b", b)):
        wait_for(lambda q=q: shown(q), 10.0, f"the view to show state {name}")
        shots[name] = screenshot(view.url, tmp_path / f"{name}.png")
    view.show_arm(False)
    background = screenshot(view.url, tmp_path / "hidden.png")
    pub.undeclare()

    masks = {k: np.any(np.abs(img - background) > 24, axis=-1) for k, img in shots.items()}
    for name, q in (("a", a), ("b", b)):
        fraction = float(masks[name].mean())
        # the arm covers a real part of the picture, not a speck and not the whole page
        assert 0.01 < fraction < 0.5, f"pose {name}: {fraction:.4f} of the pixels are the arm's"
        for p in arm_points(arm, q):
            d = distance_to(masks[name], project(view, p))
            assert d <= 3.0, f"pose {name}: nothing drawn within {d:.1f} px of the point {p.round(3)}"
    # the state moved the arm: each pose's wrist and tool are drawn where the other pose has background
    for name, other, q in (("a", "b", a), ("b", "a", b)):
        points = arm_points(arm, q)
        for p in (points[3], points[-1]):
            xy = project(view, p)
            assert distance_to(masks[name], xy) <= 1.0 and distance_to(masks[other], xy) > 3.0, (
                f"pose {name}: the point {p.round(3)} is not drawn in {name} only"
            )
    changed = float(np.any(np.abs(shots["a"] - shots["b"]) > 24, axis=-1).mean())
    assert changed > 0.005, f"only {changed:.4f} of the picture changed between the poses"
    # no trajectory yet: nothing of the path's or the target's colour
    for img in (*shots.values(), background):
        assert colored(img, PATH_COLOR).sum() == 0 and colored(img, TARGET_COLOR).sum() == 0


@needs_chromium
def test_obstacles_added_on_the_service_are_drawn_where_they_are(
    insomniac_view: tuple[ArmView, ZenohFeed], client: object, tmp_path: Path
) -> None:
    """An obstacle added over the ``world`` verb is drawn (the feed polls the service's info),
    centred where it is; cleared, it is gone."""
    view, feed = insomniac_view
    centre = [0.05, -0.25, 0.1]
    try:
        client.world(  # type: ignore[attr-defined]
            "insomniac", add=[{"name": "crate", "shape": "box", "size": [0.08, 0.08, 0.08], "position": centre}]
        )
        wait_for(lambda: [o["name"] for o in view.obstacles] == ["crate"], 10.0, "the crate to be drawn")
        orange = colored(screenshot(view.url, tmp_path / "crate.png"), OBSTACLE_COLOR)
        ys, xs = np.nonzero(orange)
        assert orange.sum() > 200, f"only {orange.sum()} pixels of the crate"
        cx, cy = project(view, np.array(centre))
        assert math.hypot(xs.mean() + 0.5 - cx, ys.mean() + 0.5 - cy) < 12.0, "the crate is not drawn where it is"
    finally:
        client.world("insomniac", clear=True)  # type: ignore[attr-defined]
    wait_for(lambda: view.obstacles == [], 10.0, "the crate to go")
    assert colored(screenshot(view.url, tmp_path / "cleared.png"), OBSTACLE_COLOR).sum() == 0
    assert feed.worlds == 2


@needs_chromium
def test_what_the_range_sensors_see_is_drawn_where_it_is(
    insomniac_view: tuple[ArmView, ZenohFeed], service: object, adapter_session: zenoh.Session, tmp_path: Path
) -> None:
    """A can on the simulated insomniac's floor: its scanners see it, ``detect`` places it, and
    the viewer draws it there (seed 000's scenario in the viewer); taken away, it is gone."""
    from armd.adapters.sim_sensors import objects_of

    view, feed = insomniac_view
    arm = robots.load("insomniac")
    can = {"name": "can", "shape": "cylinder", "size": [0.03, 0.12], "position": [0.30, -0.15]}
    sim = SimAdapter(adapter_session, arm, time_scale=10.0, objects=objects_of([can]))
    try:
        wait_for(lambda: len(view.objects) == 1, 15.0, "the can to be drawn")
        cyan = colored(screenshot(view.url, tmp_path / "can.png"), OBJECT_COLOR)
        ys, xs = np.nonzero(cyan)
        assert cyan.sum() > 100, f"only {cyan.sum()} pixels of the can"
        cx, cy = project(view, np.array([0.30, -0.15, 0.05]))
        assert math.hypot(xs.mean() + 0.5 - cx, ys.mean() + 0.5 - cy) < 15.0, "the can is not drawn where it is"
        sim.sensors.set_objects([])
        wait_for(lambda: view.objects == [], 15.0, "the can to go")
        assert feed.seen >= 2
    finally:
        sim.close()


@needs_chromium
def test_a_move_draws_its_tool_path_and_target(
    insomniac_view: tuple[ArmView, ZenohFeed], client: object, adapter_session: zenoh.Session, tmp_path: Path
) -> None:
    view, feed = insomniac_view
    arm = view.robot
    sim = SimAdapter(adapter_session, arm, time_scale=10.0)
    try:
        wait_for(lambda: feed.states > 0, 10.0, "the simulated arm's state")
        target = [0.2, 0.15, 0.1]
        reply = client.move(
            "insomniac",
            {"target": target, "approach": "perpendicular"},  # type: ignore[attr-defined]
            wait=True,
        )
        wait_for(
            lambda: feed.trajectories == 1 and np.allclose(view.shown, reply.goal, atol=2e-3),
            10.0,
            "the view to draw the trajectory and the arm at its goal",
        )
    finally:
        sim.close()
    with_arm = screenshot(view.url, tmp_path / "moved.png")
    view.show_arm(False)
    path_only = screenshot(view.url, tmp_path / "path.png")

    magenta, green = colored(path_only, PATH_COLOR), colored(path_only, TARGET_COLOR)
    start, end = arm.fk(arm.neutral), arm.fk(reply.goal)
    assert np.linalg.norm(end - target) < 1e-3
    # the tool path runs from where the tool was to the target, through the trajectory's tool points
    assert magenta.sum() > 100, f"only {magenta.sum()} pixels of the tool path"
    assert distance_to(magenta, project(view, start)) <= 3.0
    ys, xs = np.nonzero(green)
    assert green.sum() > 50, f"only {green.sum()} pixels of the target"
    tx, ty = project(view, end)
    assert math.hypot(xs.mean() + 0.5 - tx, ys.mean() + 0.5 - ty) < 3.0, "the target is not drawn at the target"
    # with the arm drawn, the arm's gripper covers part of the target, not all of it
    assert 0 < colored(with_arm, TARGET_COLOR).sum() < green.sum()

    # a trajectory that carries its Cartesian target has it drawn there, not at its last sample's tool point
    traj = planning.plan(arm, reply.goal, arm.neutral)
    explicit = arm.fk(arm.neutral) + np.array([0.0, 0.0, 0.08])
    adapter_session.put(
        "armd/insomniac/trajectory", encode({**traj.to_dict(), "id": "t1", "kind": "move", "target": explicit.tolist()})
    )
    wait_for(lambda: feed.trajectories == 2 and view.flush(1.0), 10.0, "the second trajectory")
    green = colored(screenshot(view.url, tmp_path / "explicit.png"), TARGET_COLOR)
    ys, xs = np.nonzero(green)
    tx, ty = project(view, explicit)
    assert green.sum() > 50 and math.hypot(xs.mean() + 0.5 - tx, ys.mean() + 0.5 - ty) < 3.0


def test_states_are_drawn_at_most_at_the_rate_and_bad_ones_ignored(
    insomniac_view: tuple[ArmView, ZenohFeed], adapter_session: zenoh.Session
) -> None:
    view, feed = insomniac_view
    arm = view.robot
    pub = adapter_session.declare_publisher("armd/insomniac/state", encoding=zenoh.Encoding.APPLICATION_JSON)
    try:
        pub.put(state_message(arm, arm.neutral))
        wait_for(lambda: feed.states >= 1 and view.flush(1.0), 10.0, "the first state")
        frames, t0 = view.frames, time.monotonic()
        qs = [arm.neutral + np.array([0.5, 0.0, 0.0, 0.0, 0.0]) * math.sin(k / 10) for k in range(200)]
        for q in qs:  # 200 states at ~400 Hz
            pub.put(state_message(arm, q))
            time.sleep(0.0025)
        wait_for(lambda: feed.states >= 201 and view.flush(1.0), 10.0, "every state")
        elapsed = time.monotonic() - t0
        drawn = view.frames - frames
        assert drawn <= elapsed / view.period + 2, f"{drawn} frames in {elapsed:.2f} s at most {1 / view.period} Hz"
        assert drawn >= 2
        assert np.allclose(view.shown, qs[-1])  # the newest state wins
        # a malformed state (wrong length, not JSON) is ignored; the next good one is drawn
        pub.put(encode({"position": [0.1, 0.2]}))
        pub.put(b"not json")
        wait_for(lambda: feed.states >= 203, 10.0, "the bad states")
        assert view.flush(2.0) and np.allclose(view.shown, qs[-1])
        pub.put(state_message(arm, arm.neutral))
        wait_for(lambda: view.flush(1.0) and np.allclose(view.shown, arm.neutral), 10.0, "the good state")
    finally:
        pub.undeclare()


def test_a_taken_port_is_a_clear_error() -> None:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        port = s.getsockname()[1]
        with pytest.raises(ViewerError, match=f"cannot listen on 127.0.0.1:{port}"):
            ArmView(robots.load("gupta3"), port=port)


def test_bad_input_is_refused(insomniac_view: tuple[ArmView, ZenohFeed]) -> None:
    view, _ = insomniac_view
    with pytest.raises(BadRequest, match="must have 5 values"):
        view.show_state([0.0, 1.0])
    with pytest.raises(BadRequest, match=r"must be \(k, 5\)"):
        view.show_trajectory([[0.0, 1.0, 2.0]])
    with pytest.raises(BadRequest, match="target must be 3 finite numbers"):
        view.show_trajectory([view.robot.neutral], target=[0.1, float("nan"), 0.2])


def armd_view(*args: str) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [sys.executable, "-m", "armd.cli", "view", *args],
        cwd=ROOT,
        text=True,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )


def test_armd_view_serves_the_page_and_stops_on_ctrl_c(router: str) -> None:
    port = free_port()
    proc = armd_view("insomniac", "--connect", router, "--port", str(port))
    try:
        assert proc.stdout is not None
        first = proc.stdout.readline()
        url = f"http://127.0.0.1:{port}/static/"
        assert f"open {url}" in first, first + proc.stderr.read() if proc.poll() is not None else first
        with urllib.request.urlopen(url, timeout=10) as page:
            assert page.status == 200 and "main.min.js" in page.read().decode()
        with urllib.request.urlopen(url + "main.min.js", timeout=10) as js:  # three.js, served offline
            assert len(js.read()) > 100_000
    finally:
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=20)
    assert proc.returncode == 0, err
    assert "Traceback" not in err


def test_armd_view_unknown_robot_is_the_typed_error() -> None:
    proc = armd_view("nosuch", "--port", "0")
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 1
    assert "armd: error: unknown robot 'nosuch'; the catalogue has: desk4, gupta3, insomniac, sg5ut" in err
