"""The simulator adapter: executes published trajectories on a simulated arm, in real time
(or ``time_scale`` times faster), with an optional first-order servo lag, so that the whole
system runs with no hardware. ``armd adapter sim ROBOT``; ``armd serve --sim`` starts one
per catalogue arm. Everything on the Zenoh side is :class:`clients.adapter.Adapter`'s.

Its range sensors (those whose model has a curve: the Sharp GP2D12 and GP2D120) read a world
of ``objects`` on the floor and publish on ``<prefix>/<robot>/sensors/<name>``
(:mod:`.sim_sensors`).
"""

from __future__ import annotations

import contextlib
import math
import threading
import time
from collections.abc import Sequence
from dataclasses import replace

import numpy as np
import zenoh

from armd.planning import JointState
from armd.robots import Robot

from .base import Adapter
from .sim_sensors import FloorObject, SimulatedSensors
from .trajectory_message import Command

HOLDS_BELOW = 0.5  # a gripper closed below this opening holds what its tool point is in


class SimAdapter(Adapter):
    kind = "sim"

    def __init__(
        self,
        session: zenoh.Session,
        robot: Robot,
        *,
        prefix: str = "armd",
        time_scale: float = 1.0,
        lag: float = 0.0,
        state_hz: float = 50.0,
        start: np.ndarray | None = None,
        objects: Sequence[FloorObject] = (),
        sensor_seed: int | None = None,
    ) -> None:
        if not (time_scale > 0 and math.isfinite(time_scale)):
            raise ValueError("time_scale must be a positive number")
        super().__init__(session, robot, prefix=prefix, state_hz=state_hz)
        self.time_scale = time_scale
        self.lag = lag  # first-order servo time constant [s] (0: none)
        self.position = np.array(robot.neutral if start is None else start, dtype=float)
        self.velocity = np.zeros(robot.nq)
        self.acceleration = np.zeros(robot.nq)
        self._last = time.monotonic()
        base = f"{prefix}/{robot.name}/sensors"
        self._sensor_pubs = {name: session.declare_publisher(f"{base}/{name}") for name in robot.sensors}
        self.sensors = SimulatedSensors(
            robot,
            objects,
            lambda name, payload: self._sensor_pubs[name].put(payload),
            lambda: self.position.copy(),
            adapter=self.id,
            time_scale=time_scale,
            seed=sensor_seed,
        )
        self.held: tuple[str, np.ndarray] | None = None  # the object the gripper holds, its offset from the tool
        self._sensing = threading.Thread(
            target=self.sensors.run, args=(self._stop,), name=f"sim-sensors-{robot.name}", daemon=True
        )
        self.activate()
        self._sensing.start()

    def execute(self, cmd: Command, t: float, first: bool) -> bool:
        now = time.monotonic()
        dt = 0.0 if first else now - self._last
        self._last = now
        ts = t * self.time_scale
        p, v, a = cmd.sample_at(ts)
        if self.lag > 0:
            alpha = 1.0 - math.exp(-dt * self.time_scale / self.lag)
            self.position = self.position + alpha * (p - self.position)
        else:
            self.position = p.copy()
        self.velocity, self.acceleration = v.copy(), a.copy()
        self._carry()
        return ts >= cmd.duration and (self.lag == 0 or float(np.max(np.abs(p - self.position))) < 1e-4)

    def grip(self, opening: float) -> None:
        super().grip(opening)
        objects = list(self.sensors.objects)
        tool = self.robot.fk(self.position)
        if opening < HOLDS_BELOW and self.held is None:
            for o in objects:
                if o.holds(tool, self.sensors.ground):
                    self.held = (o.name, np.array([*o.position, self.sensors.ground + o.z]) - tool)
                    break
        elif opening >= HOLDS_BELOW and self.held is not None:
            name, _ = self.held
            self.held = None
            self.sensors.set_objects([replace(o, z=0.0) if o.name == name else o for o in objects])  # (dropped)

    def _carry(self) -> None:
        """The object held, where the tool point has taken it."""
        if self.held is None:
            return
        name, offset = self.held
        at = self.robot.fk(self.position) + offset
        z = max(float(at[2]) - self.sensors.ground, 0.0)
        self.sensors.set_objects(
            [
                replace(o, position=(float(at[0]), float(at[1])), z=z) if o.name == name else o
                for o in self.sensors.objects
            ]
        )

    def hold(self) -> None:
        self.velocity = np.zeros(self.robot.nq)
        self.acceleration = np.zeros(self.robot.nq)

    def measure(self) -> JointState:
        return JointState(self.position.copy(), self.velocity.copy(), self.acceleration.copy())

    def shutdown(self) -> None:
        if self._sensing.is_alive():
            self._sensing.join(timeout=2.0)
        for pub in self._sensor_pubs.values():
            with contextlib.suppress(zenoh.ZError):
                pub.undeclare()
