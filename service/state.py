"""What the service knows of each arm's current state: what its live adapters report (the
freshest of them), else what it last commanded (the running trajectory, evaluated now), else
the neutral pose. Which reports are trusted is the service's decision (service.server); the
book keeps one state per adapter and forgets an adapter when it goes."""

from __future__ import annotations

import threading
import time
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from armd.errors import StartMismatch
from armd.planning import JointState, Trajectory
from armd.robots import Robot

STALE_AFTER = 1.0  # [s] an adapter's state older than this is not trusted
REPORT_POSITION_SLACK = 0.05  # [rad] a reported position may be this far outside the limits (quantisation, noise)
REPORT_SPEED_SLACK = 1.25  # a reported speed may be this many times the limit (finite differences of a measure)


def reported_state(robot: Robot, report: Mapping[str, Any]) -> JointState:
    """The state an adapter reports (``position``, and ``velocity`` and ``acceleration``, zero
    if absent): ValueError unless each is ``robot.nq`` finite numbers."""
    zeros = np.zeros(robot.nq)
    try:
        q, v, a = (
            np.asarray(report[k] if k == "position" else report.get(k, zeros), dtype=float)
            for k in ("position", "velocity", "acceleration")
        )
    except (KeyError, TypeError, AttributeError) as e:
        raise ValueError(f"not a state: {e}") from None
    if any(x.shape != (robot.nq,) or not np.all(np.isfinite(x)) for x in (q, v, a)):
        raise ValueError("bad shape or not finite")
    return JointState(q, v, a)


def implausible(robot: Robot, state: JointState) -> str | None:
    """Why a reported state cannot be so (outside the limits, or faster than them, beyond the
    slack a measure has), or None."""
    lim = robot.limits
    if not lim.contains(state.position, tol=REPORT_POSITION_SLACK):
        return "outside the limits"
    if np.any(np.abs(state.velocity) > lim.velocity * REPORT_SPEED_SLACK):
        return "faster than the limits"
    return None


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
        self._reported: dict[str, dict[str, tuple[float, JointState, bool, bool]]] = {}  # robot: adapter: report
        self._commanded: dict[str, tuple[float, Trajectory]] = {}
        self._clock = clock

    def now(self) -> float:
        return float(self._clock())  # type: ignore[operator]

    def report(self, robot: str, state: JointState, moving: bool, homed: bool = True, adapter: str = "") -> None:
        with self._lock:
            self._reported.setdefault(robot, {})[adapter] = (self.now(), state, moving, homed)

    def forget(self, robot: str, adapter: str) -> None:
        """An adapter gone: its last report no longer says where the arm is."""
        with self._lock:
            self._reported.get(robot, {}).pop(adapter, None)

    def last(self, robot: str, adapter: str) -> tuple[float, JointState] | None:
        """When ``adapter``'s last report of ``robot`` came, and what it said."""
        with self._lock:
            rep = self._reported.get(robot, {}).get(adapter)
        return None if rep is None else (rep[0], rep[1])

    def commanded(self, robot: str, traj: Trajectory) -> None:
        with self._lock:
            self._commanded[robot] = (self.now(), traj)

    def current(self, robot: Robot) -> Known:
        now = self.now()
        with self._lock:
            reports = self._reported.get(robot.name, {})
            rep = max(reports.values(), key=lambda r: r[0]) if reports else None
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


def where_the_adapter_is(arm: Robot, error: object) -> JointState | None:
    """The state an adapter gave with its ``start_mismatch`` refusal, if it is one and
    believable as a report is (:func:`reported_state`, :func:`implausible`);
    else None."""
    if not isinstance(error, Mapping) or error.get("code") != StartMismatch.code:
        return None
    state = error.get("state")
    if not isinstance(state, Mapping):
        return None
    try:
        there = reported_state(arm, state)
    except ValueError:
        return None
    return None if implausible(arm, there) else there
