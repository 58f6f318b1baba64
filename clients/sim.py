"""The simulator adapter: executes published trajectories on a simulated arm, in real time
(or ``time_scale`` times faster), with an optional first-order servo lag, so that the whole
system runs with no hardware. ``armd adapter sim ROBOT``; ``armd serve --sim`` starts one
per catalogue arm.

Like every adapter it holds a liveliness token ``<prefix>/<robot>/adapter/<id>`` while it
runs, publishes ``<prefix>/<robot>/state`` (position, velocity, acceleration, moving, the
trajectory id, a timestamp) at ``state_hz`` and ``<prefix>/<robot>/events`` (accepted,
started, done, rejected with a reason, aborted when replaced), re-checks every trajectory
against the arm's limits before executing it, and lets a newer trajectory replace the
running one.
"""

from __future__ import annotations

import logging
import math
import threading
import time
import uuid
from typing import Any

import numpy as np
import zenoh

from robots import ArmdError, Robot
from service.protocol import encode

from .trajectory_message import Command, parse

log = logging.getLogger("armd.sim")
JSON = zenoh.Encoding.APPLICATION_JSON


class SimAdapter:
    def __init__(self, session: zenoh.Session, robot: Robot, *, prefix: str = "armd", time_scale: float = 1.0,
                 lag: float = 0.0, state_hz: float = 50.0, start: np.ndarray | None = None) -> None:
        if not (time_scale > 0 and math.isfinite(time_scale)):
            raise ValueError("time_scale must be a positive number")
        self.robot = robot
        self.session = session
        self.prefix = prefix.rstrip("/")
        self.id = uuid.uuid4().hex[:12]
        self.time_scale = time_scale
        self.lag = lag  # first-order servo time constant [s] (0: none)
        self.period = 1.0 / state_hz
        base = f"{self.prefix}/{robot.name}"
        self._lock = threading.Lock()
        self.position = np.array(robot.neutral if start is None else start, dtype=float)
        self.velocity = np.zeros(robot.nq)
        self.acceleration = np.zeros(robot.nq)
        self._cmd: Command | None = None
        self._t0 = 0.0
        self._done_sent = True
        self._state_pub = session.declare_publisher(f"{base}/state", encoding=JSON)
        self._event_pub = session.declare_publisher(f"{base}/events", encoding=JSON,
                                                    congestion_control=zenoh.CongestionControl.BLOCK)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name=f"sim-{robot.name}", daemon=True)
        self._thread.start()
        self._sub = session.declare_subscriber(f"{base}/trajectory", self._on_trajectory)
        self._token = session.liveliness().declare_token(f"{base}/adapter/{self.id}")

    def _event(self, event: str, **fields: Any) -> None:
        self._event_pub.put(encode({"event": event, "adapter": self.id, "time": time.time(), **fields}))

    def _on_trajectory(self, sample: zenoh.Sample) -> None:
        try:
            cmd = parse(self.robot, sample.payload.to_bytes())
        except ArmdError as e:
            log.warning("%s: trajectory rejected: %s", self.robot.name, e.message)
            self._event("rejected", reason=e.message, error=e.to_dict())
            return
        with self._lock:
            if self._cmd is not None and not self._done_sent:
                self._event("aborted", id=self._cmd.id, reason=f"replaced by {cmd.id}")
            self._cmd = cmd
            self._t0 = time.monotonic()
            self._done_sent = False
        self._event("accepted", id=cmd.id, kind=cmd.kind, duration=cmd.duration)
        self._event("started", id=cmd.id)

    def _run(self) -> None:
        last = time.monotonic()
        while not self._stop.is_set():
            now = time.monotonic()
            dt = now - last
            last = now
            done_id = None
            with self._lock:
                cmd = self._cmd
                if cmd is not None:
                    t = (now - self._t0) * self.time_scale
                    p, v, a = cmd.sample_at(t)
                    if self.lag > 0:
                        alpha = 1.0 - math.exp(-dt * self.time_scale / self.lag)
                        self.position = self.position + alpha * (p - self.position)
                    else:
                        self.position = p.copy()
                    self.velocity, self.acceleration = v.copy(), a.copy()
                    if t >= cmd.duration and not self._done_sent and (
                            self.lag == 0 or float(np.max(np.abs(p - self.position))) < 1e-4):
                        self._done_sent = True
                        done_id = cmd.id
                moving = cmd is not None and not self._done_sent
                state = {"robot": self.robot.name, "adapter": self.id, "position": self.position.tolist(),
                         "velocity": (self.velocity if moving else np.zeros(self.robot.nq)).tolist(),
                         "acceleration": (self.acceleration if moving else np.zeros(self.robot.nq)).tolist(),
                         "moving": moving, "trajectory": None if cmd is None else cmd.id, "time": time.time()}
            try:
                self._state_pub.put(encode(state))
                if done_id is not None:
                    self._event("done", id=done_id)
            except Exception:  # the session is closing
                log.debug("state publish failed", exc_info=True)
            self._stop.wait(self.period)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)
        for entity in (self._token, self._sub, self._state_pub, self._event_pub):
            try:
                entity.undeclare()
            except Exception:
                log.debug("undeclare failed", exc_info=True)

