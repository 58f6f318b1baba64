"""``armd view``: a live 3-D view of one arm in the browser, drawn with meshcat.

:class:`ArmView` draws an arm from its URDF's visual geometry (Pinocchio's
``MeshcatVisualizer``) in a meshcat scene served by this process on 127.0.0.1 only.
meshcat bundles its three.js viewer, so the page needs no network. The view moves the arm
to each joint state it is shown and draws a trajectory's tool path (a tube through the
forward kinematics of its samples) and its target (a sphere at the tool point where it
ends, or at the Cartesian target it carries).

:class:`ZenohFeed` feeds a view from Zenoh: ``<prefix>/<robot>/state`` (what adapters
publish, at 50 Hz or more) and ``<prefix>/<robot>/trajectory`` (what ``move`` and ``stop``
publish). Drawing is throttled: only the newest state is drawn, at most ``max_rate_hz``
times a second, by a thread of the view; callers never wait for the browser.

``armd view ROBOT`` (:mod:`armd.cli.tools`) wires the two together and prints the viewer's URL.
"""

from __future__ import annotations

import json
import logging
import math
import sys
import threading
import warnings
from collections.abc import Sequence
from types import TracebackType
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from armd.errors import ArmdError, BadRequest, ViewerError
from armd.robots import Robot
from armd.robots.types import FloatArray

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

if TYPE_CHECKING:
    import zenoh

log = logging.getLogger(__name__)
HOST = "127.0.0.1"
DEFAULT_PORT = 7000  # meshcat's own default; without an explicit port the next free one is taken
PORT_TRIES = 100
CAMERA_FOV = 75.0  # [deg] meshcat's default camera: vertical field of view
CAMERA_DIRECTION = (0.55, -1.0, 0.5)  # from the scene centre towards the camera, in the arm's base frame
PATH_COLOR = 0xFF00FF  # the tool path: flat (unlit) magenta, distinct from every arm's colours
TARGET_COLOR = 0x00C853  # the target: flat green
OBSTACLE_COLOR = 0xFF6D00  # the world's obstacles: flat orange
OBJECT_COLOR = 0x00B8D4  # what the range sensors see (detect): flat cyan
WORLD_POLL = 1.0  # [s] how often the feed asks the service's info for the arm's world
PATH_RADIUS = 0.003  # [m]
TARGET_RADIUS = 0.015  # [m]: shows round the tool of an arm that reached it
GRID_STEP = 0.1  # [m] the floor grid's squares
MAX_PATH_POINTS = 400  # a long trajectory's tool path is drawn through at most this many samples
ZMQ_TIMEOUT_MS = 5000


# -- the meshcat server, in a thread of this process ---------------------------------------------


def _bind(port: int | None) -> tuple[list[Any], int]:
    """Listening sockets on 127.0.0.1: ``port`` exactly (0: any free one), or the first free
    one from :data:`DEFAULT_PORT` when ``port`` is None."""
    from tornado.netutil import bind_sockets

    candidates = range(DEFAULT_PORT, DEFAULT_PORT + PORT_TRIES) if port is None else [port]
    for p in candidates:
        try:
            socks = bind_sockets(p, address=HOST)
        except OSError as e:
            if port is not None:
                raise ViewerError(
                    f"cannot listen on {HOST}:{port}: {e.strerror}; choose another port (--port)", port=port
                ) from None
            continue
        return socks, int(socks[0].getsockname()[1])
    raise ViewerError(f"no free port on {HOST} in {DEFAULT_PORT}..{DEFAULT_PORT + PORT_TRIES - 1}; choose one (--port)")


class _MeshcatServer:
    """meshcat's bridge (ZMQ commands in, websocket messages out) and its static three.js viewer,
    served by a thread with its own event loop. meshcat's own ``meshcat-server`` listens on
    every interface and cannot be told a port; this reuses its bridge, bound to 127.0.0.1."""

    def __init__(self, port: int | None) -> None:
        try:
            with warnings.catch_warnings():  # it imports zmq.eventloop.ioloop, deprecated since pyzmq 17
                warnings.simplefilter("ignore", DeprecationWarning)
                import meshcat.servers.zmqserver  # noqa: F401
        except ImportError as e:
            raise ViewerError(f"the viewer needs meshcat: pip install meshcat ({e})") from None
        self._ready = threading.Event()
        self._error: BaseException | None = None
        self._bridge: Any = None
        self._http: Any = None
        self.zmq_url = ""
        self.port = 0
        self._thread = threading.Thread(target=self._run, args=(port,), name="meshcat-server", daemon=True)
        self._thread.start()
        if not self._ready.wait(30.0):
            raise ViewerError("the meshcat server did not start within 30 s")
        if self._error is not None:
            raise self._error

    @property
    def url(self) -> str:
        return f"http://{HOST}:{self.port}/static/"

    def _run(self, port: int | None) -> None:
        import asyncio

        import zmq
        from meshcat.servers.tree import SceneTree
        from meshcat.servers.zmqserver import (
            VIEWER_HTML,
            VIEWER_ROOT,
            StaticFileHandlerNoCache,
            WebSocketHandler,
            ZMQWebSocketBridge,
        )
        from tornado.httpserver import HTTPServer
        from tornado.ioloop import IOLoop
        from tornado.web import Application

        class QuietWebSocket(WebSocketHandler):  # meshcat's prints every page that opens or closes
            def open(self) -> None:
                self.bridge.websocket_pool.add(self)
                self.bridge.send_scene(self)

            def on_close(self) -> None:
                self.bridge.websocket_pool.discard(self)

        loop = asyncio.new_event_loop()
        asyncio.set_event_loop(loop)
        ioloop = IOLoop.current()
        socks: list[Any] = []
        try:
            socks, self.port = _bind(port)
            # The bridge's constructor would listen on every interface: build it by hand instead.
            bridge = ZMQWebSocketBridge.__new__(ZMQWebSocketBridge)
            bridge.host = HOST
            bridge.websocket_pool = set()
            bridge.app = Application(
                [
                    (r"/static/(.*)", StaticFileHandlerNoCache, {"path": VIEWER_ROOT, "default_filename": VIEWER_HTML}),
                    (r"/", QuietWebSocket, {"bridge": bridge}),
                ],
                log_function=lambda handler: None,
            )  # no access log line per file
            bridge.ioloop = ioloop
            bridge.zmq_socket, bridge.zmq_stream, _ = bridge.setup_zmq(f"tcp://{HOST}:*")
            bridge.zmq_url = self.zmq_url = bridge.zmq_socket.getsockopt(zmq.LAST_ENDPOINT).decode()
            bridge.fileserver_port = self.port
            bridge.web_url = self.url
            bridge.tree = SceneTree()
            self._http = HTTPServer(bridge.app)
            self._http.add_sockets(socks)
            self._bridge = bridge
        except BaseException as e:
            self._error = e if isinstance(e, ArmdError) else ViewerError(f"the meshcat server cannot start: {e}")
            for sock in socks:
                sock.close()
            self._ready.set()
            ioloop.close(all_fds=True)
            return
        self._ready.set()
        try:
            ioloop.start()
        finally:
            ioloop.close(all_fds=True)

    def _shutdown(self) -> None:  # on the server's loop
        for ws in list(self._bridge.websocket_pool):
            ws.close()
        self._http.stop()
        self._bridge.zmq_stream.close()
        self._bridge.ioloop.stop()

    def close(self) -> None:
        if self._bridge is not None and self._thread.is_alive():
            self._bridge.ioloop.add_callback(self._shutdown)
            self._thread.join(timeout=5.0)


class _Window:
    """The client end of the bridge, as meshcat's ``Visualizer`` wants it (``send``), with a
    timeout: meshcat's own window waits forever for a server that is gone."""

    def __init__(self, zmq_url: str, web_url: str) -> None:
        import zmq

        self.web_url = web_url
        self._socket: zmq.Socket[bytes] = zmq.Context.instance().socket(zmq.REQ)
        self._socket.setsockopt(zmq.RCVTIMEO, ZMQ_TIMEOUT_MS)
        self._socket.setsockopt(zmq.SNDTIMEO, ZMQ_TIMEOUT_MS)
        self._socket.setsockopt(zmq.LINGER, 0)
        self._socket.connect(zmq_url)

    def send(self, command: Any) -> None:
        import umsgpack
        import zmq

        data = command.lower()
        try:
            self._socket.send_multipart([data["type"].encode(), data["path"].encode(), umsgpack.packb(data)])
            self._socket.recv()
        except zmq.ZMQError as e:
            raise ViewerError(f"the meshcat server does not answer: {e}") from None

    def close(self) -> None:
        self._socket.close(linger=0)


# -- the view --------------------------------------------------------------------------------------


def _visual_model(robot: Robot) -> Any:
    """The URDF's ``<visual>`` geometry, placed on ``robot.model``'s joints."""
    import pinocchio as pin

    urdf = "robot.urdf"
    toml = robot.folder / "robot.toml"
    if toml.is_file():  # it may name another URDF file ([robot] urdf)
        with open(toml, "rb") as f:
            urdf = str(tomllib.load(f).get("robot", {}).get("urdf", urdf))
    try:
        return pin.buildGeomFromUrdf(
            robot.model, str(robot.folder / urdf), pin.GeometryType.VISUAL, package_dirs=[str(robot.folder)]
        )
    except Exception as e:  # Pinocchio raises ValueError/RuntimeError from C++
        raise ViewerError(f"cannot read the visual geometry of {robot.folder / urdf}: {e}") from None


def _floor(visual_model: Any) -> float:
    """The height [m] in ``base`` of the floor: under the base's own visuals, and at most 0."""
    import itertools

    lowest = 0.0
    for go in visual_model.geometryObjects:
        if go.parentJoint != 0:  # moves with the arm
            continue
        go.geometry.computeLocalAABB()
        box = go.geometry.aabb_local
        for corner in itertools.product(*zip(np.array(box.min_), np.array(box.max_), strict=True)):
            lowest = min(lowest, float(go.placement.act(np.array(corner))[2]))
    return lowest


def _tube(points: FloatArray, radius: float, sides: int = 8) -> tuple[FloatArray, NDArray[np.uint32]] | None:
    """A closed tube of ``radius`` [m] through ``points`` (k, 3): vertices and triangles;
    None if the points do not leave a ``radius`` of the first one."""
    keep = [points[0]]
    for p in points[1:]:
        if np.linalg.norm(p - keep[-1]) > radius / 2:
            keep.append(p)
    if len(keep) < 2:
        return None
    P = np.array(keep)
    T = np.gradient(P, axis=0)
    T /= np.linalg.norm(T, axis=1, keepdims=True)
    normals = []
    n = np.cross(T[0], np.eye(3)[int(np.argmin(np.abs(T[0])))])
    for t in T:  # parallel transport: the rings do not twist along the path
        n = n - (n @ t) * t
        if np.linalg.norm(n) < 1e-9:
            n = np.cross(t, np.eye(3)[int(np.argmin(np.abs(t)))])
        n = n / np.linalg.norm(n)
        normals.append(n)
    N = np.array(normals)
    B = np.cross(T, N)
    a = 2 * np.pi * np.arange(sides) / sides
    V = P[:, None, :] + radius * (np.cos(a)[None, :, None] * N[:, None, :] + np.sin(a)[None, :, None] * B[:, None, :])
    i = np.arange(len(P) - 1)[:, None] * sides
    j = np.arange(sides)[None, :]
    a0, a1 = i + j, i + (j + 1) % sides
    b0, b1 = a0 + sides, a1 + sides
    faces = np.concatenate([np.stack([a0, a1, b1], -1).reshape(-1, 3), np.stack([a0, b1, b0], -1).reshape(-1, 3)])
    return V.reshape(-1, 3), faces.astype(np.uint32)


def _translation(p: ArrayLike) -> FloatArray:
    m = np.eye(4)
    m[:3, 3] = np.asarray(p, dtype=float)
    return m


class ArmView:
    """A live 3-D view of ``robot`` in the browser (open :attr:`url`).

    Show it joint states (:meth:`show_state`) and trajectories (:meth:`show_trajectory`)
    from any thread: they return at once, and a drawing thread draws the newest of them at
    most ``max_rate_hz`` times a second. ``port``: the HTTP port on 127.0.0.1 (0: any free
    one; None: 7000 or the next free one). Close it (or use it as a context manager).
    """

    def __init__(self, robot: Robot, *, port: int | None = None, max_rate_hz: float = 30.0) -> None:
        if not (math.isfinite(max_rate_hz) and max_rate_hz > 0):
            raise BadRequest(f"max_rate_hz must be positive, got {max_rate_hz}", field="max_rate_hz")
        if port is not None and not 0 <= port <= 65535:
            raise BadRequest(f"port must be in 0..65535, got {port}", field="port")
        self.robot = robot
        self.period = 1.0 / max_rate_hz
        visual_model = _visual_model(robot)
        self._server = _MeshcatServer(port)
        self._window: _Window | None = None
        try:
            self._window = _Window(self._server.zmq_url, self._server.url)
            self._setup(visual_model)
        except BaseException:
            self._close_server()
            raise
        self._lock = threading.Lock()  # guards the pending work and the counters below
        self._draw_lock = threading.Lock()  # one meshcat command at a time
        self._done = threading.Condition(self._lock)
        self._wake = threading.Event()
        self._stop = threading.Event()
        self._pending_q: FloatArray | None = None
        self._pending_path: tuple[FloatArray, FloatArray] | None = None
        self._pending_clear = False
        self._asked = 0  # requests made so far; _drawn: requests drawn so far
        self._drawn = 0
        self._shown: FloatArray = robot.neutral.copy()
        self.frames = 0  # frames drawn (each: the newest state and trajectory shown since the last)
        self._thread = threading.Thread(target=self._run, name=f"view-{robot.name}", daemon=True)
        self._thread.start()

    # -- the scene ------------------------------------------------------------------------------

    def _setup(self, visual_model: Any) -> None:
        import meshcat
        import meshcat.geometry as g
        from pinocchio.visualize import MeshcatVisualizer

        self._vis = meshcat.Visualizer(window=self._window)
        self.floor = _floor(visual_model)
        self.centre, self.camera, self.reach = self._framing()
        root = self._vis["armd"]
        root.delete()
        # meshcat's camera orbits the scene's origin: put the arm's workspace centre there.
        root.set_transform(_translation(-self.centre))
        self._vis["/Grid"].set_property("visible", False)  # 0.5 m squares: too coarse for these arms
        self._vis["/Axes"].set_property("visible", False)
        root["floor"].set_object(self._grid(), None)
        root["axes"].set_object(g.triad(GRID_STEP))
        # the default camera sits in a frame where y is up: (x, y, z) of the arm is (x, z, -y) there
        c = self.camera - self.centre
        self._vis["/Cameras/default/rotated/<object>"].set_property("position", [c[0], c[2], -c[1]])
        self._pin = MeshcatVisualizer(self.robot.model, None, visual_model)
        self._pin.initViewer(viewer=self._vis)
        self._pin.loadViewerModel(rootNodeName="armd/arm")
        self._pin.display(self.robot.neutral)
        world = self.robot.collision
        self.obstacles: list[dict[str, Any]] = []
        self.objects: list[dict[str, Any]] = []  # what the range sensors see, drawn
        world = self.robot.collision
        self._floor_z = float(world.ground) if world is not None and world.ground is not None else 0.0
        self._draw_world([] if world is None else world.describe()["obstacles"])  # type: ignore[arg-type]

    def show_world(self, obstacles: Sequence[dict[str, Any]]) -> None:
        """Draw these obstacles (``{"name", "shape", "size", "position", "rpy"}``, as the
        protocol's ``world`` and ``info`` give them) in place of those drawn."""
        with self._draw_lock:
            self._draw_world(obstacles)

    def _draw_world(self, obstacles: Sequence[dict[str, Any]]) -> None:
        import meshcat.geometry as g
        import pinocchio as pin

        self._vis["armd/world"].delete()
        material = g.MeshBasicMaterial(color=OBSTACLE_COLOR)
        for k, o in enumerate(obstacles):
            size = [float(x) for x in o["size"]]
            shape = o["shape"]
            turn = np.eye(4)
            if shape == "box":
                geometry = g.Box(size)
            elif shape == "sphere":
                geometry = g.Sphere(size[0])
            elif shape == "cylinder":
                geometry = g.Cylinder(size[1], size[0])
                turn[:3, :3] = pin.rpy.rpyToMatrix(math.pi / 2, 0.0, 0.0)  # (meshcat's cylinders stand on y)
            else:
                raise BadRequest(f"obstacles[{k}].shape: no drawing for {shape!r}", field=f"obstacles[{k}].shape")
            placed = np.eye(4)
            placed[:3, :3] = pin.rpy.rpyToMatrix(*[float(x) for x in o.get("rpy", (0.0, 0.0, 0.0))])
            placed[:3, 3] = [float(x) for x in o["position"]]
            node = self._vis[f"armd/world/{k}"]
            node.set_object(geometry, material)
            node.set_transform(placed @ turn)
        self.obstacles = [dict(o) for o in obstacles]

    def show_objects(self, objects: Sequence[dict[str, Any]]) -> None:
        """Draw the objects the arm's range sensors see (``detect``'s: ``position``, ``width``),
        each an upright cylinder as wide as it was seen, from the floor to the beams' height, in
        place of those drawn."""
        import meshcat.geometry as g
        import pinocchio as pin

        with self._draw_lock:
            self._vis["armd/objects"].delete()
            material = g.MeshBasicMaterial(color=OBJECT_COLOR)
            floor = self._floor_z
            for k, o in enumerate(objects):
                x, y, z = (float(v) for v in o["position"])
                height = max(z - floor, 0.01)
                node = self._vis[f"armd/objects/{k}"]
                node.set_object(g.Cylinder(height, max(float(o["width"]) / 2, 0.005)), material)
                placed = np.eye(4)
                placed[:3, :3] = pin.rpy.rpyToMatrix(math.pi / 2, 0.0, 0.0)  # (meshcat's cylinders stand on y)
                placed[:3, 3] = [x, y, floor + height / 2]
                node.set_transform(placed)
            self.objects = [dict(o) for o in objects]

    def _framing(self) -> tuple[FloatArray, FloatArray, float]:
        """The scene centre and a camera position [m] in ``base``, and the arm's reach [m].

        The centre is the middle of the arm at rest; the camera is far enough back that every
        joint and the tool stay in the picture wherever the arm goes above the floor (over 200
        random joint vectors within the limits): meshcat's camera orbits the centre, and a
        camera inside the workspace would see the arm come at it.
        """
        import pinocchio as pin

        model = self.robot.model
        data = model.createData()
        lim = self.robot.limits
        qs = np.random.default_rng(0).uniform(lim.lower, lim.upper, size=(200, self.robot.nq))
        points = []
        for q in [self.robot.neutral, *qs]:
            pin.forwardKinematics(model, data, q)
            tool = np.array(pin.updateFramePlacement(model, data, self.robot.tool_frame_id).translation)
            points.append([np.zeros(3), *(np.array(data.oMi[i].translation) for i in range(1, model.njoints)), tool])
        rest = np.array(points[0])
        centre = (rest.min(axis=0) + rest.max(axis=0)) / 2
        everywhere = np.concatenate(points)
        everywhere = everywhere[everywhere[:, 2] >= self.floor]  # the arm does not go through the floor
        radius = max(float(np.max(np.linalg.norm(everywhere - centre, axis=1))), 0.05)
        reach = float(np.max(np.linalg.norm(everywhere, axis=1)))
        distance = radius / math.tan(math.radians(CAMERA_FOV) / 2)
        direction = np.array(CAMERA_DIRECTION) / np.linalg.norm(CAMERA_DIRECTION)
        return centre, centre + distance * direction, reach

    def _grid(self) -> Any:
        import meshcat.geometry as g

        half = GRID_STEP * math.ceil(self.reach / GRID_STEP)
        ticks = np.arange(-half, half + GRID_STEP / 2, GRID_STEP)
        z = self.floor
        segments = []
        for t in ticks:
            segments += [[t, -half, z], [t, half, z], [-half, t, z], [half, t, z]]
        vertices = np.array(segments, dtype=np.float32).T
        return g.LineSegments(g.PointsGeometry(vertices), g.LineBasicMaterial(color=0x9AA4B0))

    @property
    def url(self) -> str:
        """The viewer's page, e.g. ``http://127.0.0.1:7000/static/``."""
        return self._server.url

    # -- what callers show ---------------------------------------------------------------------

    def show_state(self, q: Sequence[float] | FloatArray) -> None:
        """Move the drawn arm to joint vector ``q`` [rad] (drawn within one period; a newer
        state replaces one not drawn yet)."""
        qa = self.robot.joint_vector(q).copy()
        with self._lock:
            self._pending_q = qa
            self._asked += 1
        self._wake.set()

    def show_trajectory(self, position: ArrayLike, target: ArrayLike | None = None) -> None:
        """Draw the tool path of joint samples ``position`` (k, nq) [rad] and ``target`` [m]
        (in ``base``; default: the tool point of the last sample)."""
        pos = np.asarray(position, dtype=float)
        n = self.robot.nq
        if pos.ndim != 2 or pos.shape[1] != n or len(pos) == 0 or not np.all(np.isfinite(pos)):
            raise BadRequest(
                f"trajectory position must be (k, {n}) finite joint samples [rad], got shape {list(pos.shape)}",
                field="position",
            )
        if target is None:
            tgt = self.robot.fk(pos[-1])
        else:
            tgt = np.asarray(target, dtype=float)
            if tgt.shape != (3,) or not np.all(np.isfinite(tgt)):
                raise BadRequest(f"target must be 3 finite numbers [x, y, z] in metres, got {target!r}", field="target")
        with self._lock:
            self._pending_path = (pos.copy(), tgt.copy())
            self._pending_clear = False
            self._asked += 1
        self._wake.set()

    def clear_trajectory(self) -> None:
        """Remove the drawn tool path and target."""
        with self._lock:
            self._pending_path = None
            self._pending_clear = True
            self._asked += 1
        self._wake.set()

    def show_arm(self, visible: bool = True) -> None:
        """Show or hide the arm (the path and the target stay)."""
        with self._draw_lock:
            self._vis["armd/arm"].set_property("visible", bool(visible))

    def flush(self, timeout: float = 5.0) -> bool:
        """Wait until everything shown so far is drawn; False on timeout."""
        with self._done:
            asked = self._asked
            return self._done.wait_for(lambda: self._drawn >= asked or self._stop.is_set(), timeout)

    @property
    def shown(self) -> FloatArray:
        """The joint vector [rad] the arm is drawn at."""
        with self._lock:
            return self._shown.copy()

    # -- the drawing thread ----------------------------------------------------------------------

    def _run(self) -> None:
        while not self._stop.is_set():
            self._wake.wait()
            if self._stop.is_set():
                break
            self._wake.clear()
            with self._lock:
                q, path, clear, asked = self._pending_q, self._pending_path, self._pending_clear, self._asked
                self._pending_q, self._pending_path, self._pending_clear = None, None, False
            drawn = None
            try:
                with self._draw_lock:
                    if clear:
                        self._vis["armd/path"].delete()
                        self._vis["armd/target"].delete()
                    if path is not None:
                        self._draw_path(*path)
                    if q is not None:
                        self._pin.display(q)
                        drawn = q
            except ViewerError as e:
                log.error("%s: %s", self.robot.name, e.message)
            except Exception:
                log.exception("%s: drawing failed", self.robot.name)
            with self._lock:
                if drawn is not None:
                    self._shown = drawn
                self.frames += 1
                self._drawn = asked
                self._done.notify_all()
            self._stop.wait(self.period)  # the throttle: at most one frame a period

    def _draw_path(self, position: FloatArray, target: FloatArray) -> None:
        import meshcat.geometry as g

        stride = max(1, math.ceil(len(position) / MAX_PATH_POINTS))
        samples = [*position[::stride], position[-1]]
        points = np.array([self.robot.fk(q) for q in samples])
        tube = _tube(points, PATH_RADIUS)
        if tube is None:
            self._vis["armd/path"].delete()
        else:
            self._vis["armd/path"].set_object(g.TriangularMeshGeometry(*tube), g.MeshBasicMaterial(color=PATH_COLOR))
        self._vis["armd/target"].set_object(g.Sphere(TARGET_RADIUS), g.MeshBasicMaterial(color=TARGET_COLOR))
        self._vis["armd/target"].set_transform(_translation(target))

    # -- closing ----------------------------------------------------------------------------------

    def _close_server(self) -> None:
        if self._window is not None:
            self._window.close()
        self._server.close()

    def close(self) -> None:
        """Stop drawing and stop the server (open pages lose their connection)."""
        if self._stop.is_set():
            return
        self._stop.set()
        self._wake.set()
        self._thread.join(timeout=5.0)
        with self._done:
            self._done.notify_all()
        self._close_server()

    def __enter__(self) -> ArmView:
        return self

    def __exit__(self, et: type[BaseException] | None, e: BaseException | None, tb: TracebackType | None) -> None:
        self.close()


# -- fed from Zenoh ------------------------------------------------------------------------------


def _target_of(msg: dict[str, Any]) -> Any:
    """A trajectory message's explicit Cartesian target, if it carries one."""
    if msg.get("target") is not None:
        return msg["target"]
    goal = msg.get("goal")
    if isinstance(goal, dict) and goal.get("target") is not None:
        return goal["target"]
    return None


class ZenohFeed:
    """Shows ``view`` what the network says about its arm: every state on
    ``<prefix>/<robot>/state``, every trajectory on ``<prefix>/<robot>/trajectory``, the arm's
    world as the service's ``info`` gives it, and (an arm with scanning range sensors) the
    objects they see as the service's ``detect`` gives them (both polled every WORLD_POLL s)."""

    def __init__(self, view: ArmView, session: zenoh.Session, *, prefix: str = "armd") -> None:
        self.view = view
        self.base = f"{prefix.rstrip('/')}/{view.robot.name}"
        self.states = 0  # messages received
        self.trajectories = 0
        self._warned_state = False
        self._subs = [
            session.declare_subscriber(f"{self.base}/state", self._on_state),
            session.declare_subscriber(f"{self.base}/trajectory", self._on_trajectory),
        ]
        self.session = session
        self.worlds = 0  # changes of the arm's world drawn
        self.seen = 0  # changes of what its range sensors see, drawn
        self._closed = threading.Event()
        self._poller = threading.Thread(target=self._poll_world, name=f"world-{view.robot.name}", daemon=True)
        self._poller.start()

    def _poll_world(self) -> None:
        """The arm's world as the service has it (obstacles added at run time: the ``world``
        verb), from ``info`` every WORLD_POLL seconds (a guest may ask it), redrawn on a change."""
        while not self._closed.wait(WORLD_POLL):
            try:
                replies = list(self.session.get(f"{self.base}/info", timeout=WORLD_POLL))
                ok = [r.ok for r in replies if r.ok is not None]
                if not ok:
                    continue
                world = json.loads(ok[0].payload.to_bytes()).get("world") or {}
                obstacles = world.get("obstacles", [])
                if obstacles != self.view.obstacles:
                    self.view.show_world(obstacles)
                    self.worlds += 1
                    log.info("%s: world drawn (%d obstacles)", self.base, len(obstacles))
            except Exception:  # (the service gone, the session closing, a bad reply: try again later)
                log.debug("world poll failed", exc_info=True)
            if any(s.mount == "scanner" for s in self.view.robot.sensors.values()):
                self._poll_objects()

    def _poll_objects(self) -> None:
        """What the arm's scanners see (``detect``, one sweep), redrawn on a change (rounded to
        a centimetre: the noise of one sweep to the next is not a change)."""
        try:
            replies = list(self.session.get(f"{self.base}/detect", payload=b'{"sweeps": 1}', timeout=WORLD_POLL))
            ok = [r.ok for r in replies if r.ok is not None]
            if not ok:
                return
            objects = json.loads(ok[0].payload.to_bytes()).get("objects", [])

            def rounded(objs: list[dict[str, Any]]) -> list[tuple[float, ...]]:
                return [tuple(round(float(v), 2) for v in (*o["position"], o["width"])) for o in objs]

            if rounded(objects) != rounded(self.view.objects):
                self.view.show_objects(objects)
                self.seen += 1
        except Exception:  # (no service, no adapter yet, a bad reply: try again later)
            log.debug("objects poll failed", exc_info=True)

    def _on_state(self, sample: zenoh.Sample) -> None:
        self.states += 1
        try:
            msg = json.loads(sample.payload.to_bytes())
            self.view.show_state(msg["position"])
        except (ValueError, KeyError, TypeError, ArmdError) as e:
            if not self._warned_state:  # states come at 50 Hz: say it once
                self._warned_state = True
                log.warning(
                    "%s/state: message ignored (%s); further bad states are ignored silently",
                    self.base,
                    getattr(e, "message", e),
                )

    def _on_trajectory(self, sample: zenoh.Sample) -> None:
        self.trajectories += 1
        try:
            msg = json.loads(sample.payload.to_bytes())
            self.view.show_trajectory(msg["position"], _target_of(msg))
        except (ValueError, KeyError, TypeError, ArmdError) as e:
            log.warning("%s/trajectory: message ignored (%s)", self.base, getattr(e, "message", e))
            return
        log.info(
            "%s: trajectory %s (%s, %.2f s) drawn",
            self.base,
            msg.get("id", "?"),
            msg.get("kind", "move"),
            float(msg.get("duration") or 0.0),
        )

    def close(self) -> None:
        self._closed.set()
        if self._poller.is_alive() and self._poller is not threading.current_thread():
            self._poller.join(timeout=2 * WORLD_POLL + 1.0)
        for sub in self._subs:
            try:
                sub.undeclare()
            except Exception:  # the session may be closed already
                log.debug("undeclare failed", exc_info=True)
        self._subs = []

    def __enter__(self) -> ZenohFeed:
        return self

    def __exit__(self, et: type[BaseException] | None, e: BaseException | None, tb: TracebackType | None) -> None:
        self.close()


__all__ = ["DEFAULT_PORT", "HOST", "OBJECT_COLOR", "OBSTACLE_COLOR", "ArmView", "ViewerError", "ZenohFeed"]
