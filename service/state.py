"""What the service knows of each arm's current state: what adapters report, else what it
last commanded (the running trajectory, evaluated now), else the neutral pose."""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass

import numpy as np

from planning import JointState, Trajectory
from robots import Robot

STALE_AFTER = 1.0  # [s] an adapter's state older than this is not trusted


@dataclass(frozen=True)
class Known:
    state: JointState
    source: str  # "adapter", "commanded" or "neutral"
    moving: bool
    homed: bool = True  # False: the adapter says the controller does not know where the arm is


class StateBook:
    """Thread-safe: the Zenoh callbacks write, the request handlers read."""

    def __init__(self, clock: object = time.monotonic) -> None:
        self._lock = threading.Lock()
        self._reported: dict[str, tuple[float, JointState, bool, bool]] = {}
        self._commanded: dict[str, tuple[float, Trajectory]] = {}
        self._clock = clock

    def now(self) -> float:
        return float(self._clock())  # type: ignore[operator]

    def report(self, robot: str, state: JointState, moving: bool, homed: bool = True) -> None:
        with self._lock:
            self._reported[robot] = (self.now(), state, moving, homed)

    def commanded(self, robot: str, traj: Trajectory) -> None:
        with self._lock:
            self._commanded[robot] = (self.now(), traj)

    def current(self, robot: Robot) -> Known:
        now = self.now()
        with self._lock:
            rep = self._reported.get(robot.name)
            cmd = self._commanded.get(robot.name)
        if rep is not None and now - rep[0] <= STALE_AFTER:
            return Known(rep[1], "adapter", rep[2], rep[3])
        if cmd is not None:
            t0, traj = cmd
            elapsed = now - t0
            if elapsed < traj.duration:
                s = traj.at(elapsed)
                return Known(s, "commanded", True)
            return Known(JointState.at_rest(traj.position[-1].copy()), "commanded", False)
        return Known(JointState.at_rest(np.array(robot.neutral)), "neutral", False)
