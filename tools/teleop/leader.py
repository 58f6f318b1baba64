"""A leader arm: a bus-servo arm in the operator's hands, read with its torque off, whose pose
its follower takes (:mod:`.leader_map`), as a source of the teleoperation loop (:mod:`.stream`).

It opens the bus itself (no adapter may be running on the port), pings every servo, turns
every torque off (:class:`armd.adapters.by_hand.HandGuided`, as ``armd record`` does; the
operator is asked to hold the arm first only if a servo holds it) and reads every servo's
present position in one sync read a tick, as fast as the loop ticks (100 Hz by default).

When it stops answering: a reply lost is a tick with no put (the follower goes on with the
last one: a busy machine's late replies cost nothing); no whole reading for as long as the
follower's deadman (``lost_after``: by then it brakes), the bus failing (the port gone:
unplugged) or the servos named silent (:class:`~armd.errors.ControllerFault`) is
:class:`~.stream.Lost`: the loop puts nothing more and says so once. The bus is then
opened again every ``RETRY`` (the same path: a udev link such as ``/dev/serial/by-id/...``
follows the device) until every servo answers a ping, and the loop follows in a new session:
the follower comes to the leader's pose from where it rested, within its limits, never by a
jump.

The leader's calibration: ``--leader-calibration FILE``, else
:func:`leader_calibration_file` (``<robot>.leader.calibration.toml`` beside the adapters'
state, written by ``armd calibrate ROBOT ... --output`` that path), else the robot.toml's
factory values.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from pathlib import Path

from armd.adapters.base import actuators_of, state_dir_default
from armd.adapters.bus_servo import Bus, Reading
from armd.adapters.by_hand import LIMP, HandGuided
from armd.errors import ControllerFault
from armd.robots import BusServo, Robot
from armd.robots import calibration as robots_calibration
from armd.service.track_message import DEADMAN

from .leader_map import LeaderMap
from .stream import Lost, Step

log = logging.getLogger(__name__)

LOST_AFTER = DEADMAN  # [s] no whole reading for this long (the follower's deadman): the leader is lost
RETRY = 0.5  # [s] a lost leader's bus is opened again this often
START_WAIT = 3.0  # [s] at start, how long the servos may take to answer every ping


def leader_calibration_file(robot: Robot, state_dir: str | Path | None = None) -> Path:
    """Where a leader arm's calibration is looked for by default: beside the adapters' state
    (``state_dir``, else :func:`~armd.adapters.base.state_dir_default`),
    ``<robot>.leader.calibration.toml`` (the follower of the same kind keeps
    ``<robot>.calibration.toml``: two arms, two files)."""
    return Path(state_dir or state_dir_default()) / f"{robot.name}.leader.{robots_calibration.FILE}"


class Leader:
    """``robot`` (the leader's model, its calibration applied) on the bus ``connect()`` opens,
    mapped by ``mapping``; ``ask(prompt)`` returns when the operator has done what it says (the
    first time only, and only if a servo holds the arm)."""

    def __init__(
        self,
        robot: Robot,
        connect: Callable[[], Bus],
        mapping: LeaderMap,
        *,
        ask: Callable[[str], None] | None = None,
        name: str | None = None,
        lost_after: float = LOST_AFTER,
        retry: float = RETRY,
    ) -> None:
        self.robot = robot
        self.mapping = mapping
        self.name = name or f"the leader {robot.name}"
        self.lost_after = lost_after
        self.retry = retry
        self._connect = connect
        servos = actuators_of(robot, BusServo, "bus-servo")
        self._ids = [s.id for s in servos] + ([robot.gripper.channel] if robot.gripper is not None else [])
        self._ask = ask
        self._arm: HandGuided | None = None
        self._why = ""
        self._retry_at = 0.0
        self._whole_at = 0.0  # [s] the last whole reading
        self.readings = 0

    def start(self, wait: float = START_WAIT) -> None:
        """Open the bus the first time: a port that cannot be opened is the error at once; the
        servos must all answer a ping within ``wait`` [s] (powering up; a busy machine's late
        answers), else the error naming those that did not."""
        until = time.monotonic() + wait
        while True:
            bus = self._connect()
            try:
                self._arm = self._hand_guided(bus, first=True)
                break
            except ControllerFault:
                if time.monotonic() >= until:
                    raise
                time.sleep(self.retry / 5)
        self._whole_at = time.monotonic()

    def _open(self) -> HandGuided:
        return self._hand_guided(self._connect(), first=False)

    def _hand_guided(self, bus: Bus, first: bool) -> HandGuided:
        """The arm on ``bus``, every servo answering, its torque off (``bus`` closed if not)."""
        try:
            return HandGuided(self.robot, bus, (lambda: self._hold_first(bus)) if first else (lambda: None))
        except BaseException:
            bus.close()
            raise

    def _hold_first(self, bus: Bus) -> None:
        """Ask the operator to hold the arm if a servo holds it now (its torque on): it falls limp."""
        if self._ask is not None and any(s.torque for s in bus.read_settings(self._ids).values()):
            self._ask(LIMP)

    def poll(self) -> Step:
        """One sync read of every servo: the follower's put, None (a reply lost), or :class:`Lost`."""
        now = time.monotonic()
        if self._arm is None:
            if now < self._retry_at:
                return Lost(self._why)
            try:
                self._arm = self._open()
            except Exception as e:  # (the port not there yet, a servo silent: tried again)
                log.debug("the leader's bus did not open: %s", e)
                self._retry_at = now + self.retry
                return Lost(self._why)
            self._whole_at = now
        try:
            got: dict[int, Reading] | None = self._arm.read()
        except Exception as e:  # the SDK's and pyserial's own on a port that went (OSError, termios.error), or the
            self._drop(e)  # servos named silent (ControllerFault): the bus closed, opened again later
            return Lost(self._why)
        now = time.monotonic()
        if got is None:
            log.debug("a reading of the leader lost (%.0f ms since the last whole one)", 1e3 * (now - self._whole_at))
            if now - self._whole_at > self.lost_after:
                self._why = f"{self.name} stopped answering: replies lost on {self._arm.bus.port}"
                return Lost(self._why)
            return None
        self._whole_at = now
        self.readings += 1
        return self.mapping.put(self._arm.joints(got), self._arm.opening(got))

    def _drop(self, e: Exception) -> None:
        assert self._arm is not None
        message = getattr(e, "message", None) or str(e) or type(e).__name__
        self._why = f"{self.name} stopped answering ({message})"
        self._arm.bus.close()
        self._arm = None
        self._retry_at = time.monotonic() + self.retry

    def close(self) -> None:
        """The bus released (the torque stays off)."""
        if self._arm is not None:
            self._arm.bus.close()
            self._arm = None
