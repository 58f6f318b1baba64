"""The bus-servo adapter: arms of serial bus servos that report where they are (Feetech STS,
Dynamixel X), whatever the vendor; the vendor's protocol is a :class:`Bus` (:mod:`.feetech`,
:mod:`.dynamixel`).

Start-up: every servo of the arm's actuator map (and its gripper) must answer a ping (else
:class:`ControllerFault` naming the ids that did not); each servo's own acceleration limit is
set to its joint's (rounded down: the servo itself, whatever reaches the bus, late or not,
accelerates and brakes no harder, a stop at its goal included); its goal is set to where it
is, then its torque is turned on: the arm holds where it was found, nothing jumps. A servo
that brakes within a limit brakes before each goal it is given: the goals go a ``lead``
ahead on the plan, longer than a servo at full speed takes to brake (0.2 s on the so101), so
that it runs at the speed it is given. If the adapter's process stalls, each servo runs on to
its goal (on the plan) and brakes there within its limit; the next cycle starts it again from
the speed it has.

Execution: every pass of the control loop (``run_tick``, as fast as the bus allows) is one bus
cycle: a sync write of every servo's goal and speed (the plan a ``lead`` ahead, at the plan's
speed now, corrected toward the plan by the measured error over ``CORRECTION``, within the
velocity limit and, since the last cycle, the acceleration limit's change: a servo given a speed
moves at it) and a sync read of every servo's position, speed, load, voltage, temperature and
alarm bits. The state published is that reading (``source: "measured"``), and
the service plans from it. Monitoring, at every cycle (ros2_control's path and goal
tolerances):

- a joint farther from the plan than its ``tracking_tolerance`` (robot.toml), or not at the
  goal within ``settle`` of the trajectory's end: the trajectory is aborted and the arm stopped
  from its measured state (:meth:`Adapter.emergency_stop`: jerk-limited, within every limit),
  the event naming the joint, its error and the tolerance;
- a servo's alarm (overload, overheat, voltage): aborted, stopped, and a fault naming the
  servo and the alarm, until its alarm clears (a servo that latches it, and turns its torque
  off, waits for an operator: ``armd unlock ROBOT --assume-rest``, :meth:`unlock`);
- a read that fails (a reply lost, garbled, late) is skipped: the goals go on; more than
  ``max_lost`` in a row is a fault naming the servos that did not answer (the token withdrawn:
  ``move`` answers ``no_adapter``), recovered when they answer again.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from abc import ABC, abstractmethod
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import zenoh

from armd.errors import ControllerFault
from armd.planning import JointState
from armd.robots import BusServo, Robot

from .base import Adapter, actuators_of, calibrated
from .trajectory_message import Command, FloatArray

log = logging.getLogger(__name__)

LEAD = 0.05  # [s] how far ahead on the plan each goal is, at least (a cycle this late still finds the servo moving)
LEAD_MARGIN = 0.05  # [s] ... and more than the time a servo at full speed takes to brake at its limit
MAX_LEAD = 0.3  # [s] the most the lead grows to on a busy machine
LATENESS_DECAY = 0.5  # per second: how fast the lead forgets a late cycle
CORRECTION = 0.1  # [s] a servo off the plan is brought back to it over about this long
MAX_LOST = 3  # failed reads in a row before the bus is a fault
SETTLE = 0.5  # [s] after a trajectory's end, how long the arm may take to reach its goal
GOAL_TOLERANCE = 0.02  # [rad] how near its goal a joint must be SETTLE after the end (else: aborted); done
# before that when every servo is within a count of its goal
GRIPPER_SPEED = 2000  # [counts/s] the gripper's
READ_WAIT = 0.001  # [s] the longest one read of the port blocks (the SDKs' packet timeouts still apply)
START_SLACK = 0.02  # [rad] how far outside its limits the arm may be found at start (as the SSC-32's)
FRESH = 0.002  # [s] a reading this recent answers measure() without another read


@dataclass(frozen=True)
class Reading:
    """One servo's state, in its own units: ``position`` [counts], ``speed`` [counts/s],
    ``load`` [fraction of full torque, signed], ``voltage`` [V], ``temperature`` [C], and the
    alarm bits of its status (``alarms``: their names)."""

    position: int
    speed: float
    load: float
    voltage: float
    temperature: float
    alarms: tuple[str, ...] = ()


class Bus(ABC):
    """One vendor's bus, through its SDK: what the adapter asks of it."""

    name = "bus"
    port = ""

    @abstractmethod
    def ping(self, ident: int) -> int | None:
        """The servo's model number, or None if it does not answer."""

    @abstractmethod
    def read(self, ids: list[int]) -> dict[int, Reading]:
        """Every servo's reading, in one sync read; a servo whose reply was lost is missing."""

    @abstractmethod
    def write_goals(self, goals: dict[int, int], speeds: dict[int, int]) -> None:
        """Every servo's goal position [counts] and the speed it moves there at [counts/s, >= 1],
        in one sync write (no reply)."""

    @abstractmethod
    def set_limits(self, ident: int, acceleration: float) -> None:
        """The servo's own acceleration limit [counts/s^2], rounded down to its units (at least one)."""

    @abstractmethod
    def set_torque(self, ident: int, on: bool) -> None:
        """Torque on or off (raises :class:`ControllerFault` if the servo does not take it)."""

    @abstractmethod
    def clear_alarm(self, ident: int) -> None:
        """Clear the servo's latched alarm (the torque stays off)."""

    @abstractmethod
    def close(self) -> None:
        """Release the port."""


class SdkBus(Bus):
    """A bus through a vendor's SDK of the ROBOTIS shape (``PortHandler``, ``PacketHandler``:
    Feetech's ``scservo_sdk`` and ROBOTIS's ``dynamixel_sdk``): the port opened, the input reset
    before every exchange, ping, torque, close. A subclass sets ``module`` (the SDK's import
    name), ``protocol`` (the ``PacketHandler``'s argument), ``torque_address`` and the rest."""

    module = ""
    protocol: float = 0
    torque_address = 0
    write_errors = 0  # the status's error bits that say a write was not taken (Feetech's are alarms)

    def __init__(self, port: str, baud: int) -> None:
        import importlib

        try:
            sdk: Any = importlib.import_module(self.module)
        except ImportError as e:
            raise ControllerFault(
                f"the {self.name} adapter needs its vendor's SDK: pip install 'armd[hardware]' ({e})"
            ) from None
        self.sdk = sdk
        self.port = port
        self.handler = sdk.PortHandler(port)
        try:
            opened = self.handler.openPort() and self.handler.setBaudRate(baud)
        except Exception as e:  # (pyserial's SerialException, OSError)
            raise ControllerFault(f"cannot open {port}: {e}") from None
        if not opened:
            raise ControllerFault(f"cannot open {port} at {baud} baud")
        try:  # one program on a bus at a time (an adapter, armd calibrate, armd record): pyserial's lock
            self.handler.ser.exclusive = True
        except Exception as e:  # (pyserial's SerialException: another program holds the lock)
            self.handler.closePort()
            raise ControllerFault(f"{port} is busy (another program has it open: an adapter?): {e}") from None
        # the SDK opens the port non-blocking and spins reading until a reply comes: a read that
        # waits (up to READ_WAIT for the bytes it asks for) leaves the CPU to others meanwhile (the
        # control loop runs at real-time priority: a spinning one starves everything else on its core)
        self.handler.ser.timeout = READ_WAIT
        self.packets = sdk.PacketHandler(self.protocol)

    def _fresh(self) -> None:
        """Stale input dropped (the SDKs' ``clearPort`` waits for the output instead: a reply that
        came after its timeout would be read as the next one's)."""
        self.handler.ser.reset_input_buffer()

    def _ok(self, result: int) -> bool:
        return bool(result == self.sdk.COMM_SUCCESS)

    def ping(self, ident: int) -> int | None:
        self._fresh()
        model, result, _ = self.packets.ping(self.handler, ident)
        return int(model) if self._ok(result) else None

    def _write(self, ident: int, address: int, size: int, value: int) -> None:
        """A write that must be taken (its status: no error), else :class:`ControllerFault`."""
        self._fresh()
        write = {1: self.packets.write1ByteTxRx, 2: self.packets.write2ByteTxRx, 4: self.packets.write4ByteTxRx}[size]
        result, error = write(self.handler, ident, address, value)
        if not self._ok(result) or error & self.write_errors:
            why = self.packets.getTxRxResult(result) if not self._ok(result) else self.packets.getRxPacketError(error)
            raise ControllerFault(f"servo id {ident} on {self.port} did not take a write to address {address}: {why}")

    def set_torque(self, ident: int, on: bool) -> None:
        self._write(ident, self.torque_address, 1, 1 if on else 0)

    def close(self) -> None:
        try:
            self.handler.closePort()
        except Exception:  # (already closed)
            log.debug("close failed", exc_info=True)


def ping_all(bus: Bus, robot: Robot, servos: list[BusServo]) -> None:
    """Every servo of ``servos`` (and ``robot``'s gripper) must answer a ping on ``bus``, else
    :class:`ControllerFault` naming the ids that did not, and their joints."""
    gripper_id = robot.gripper.channel if robot.gripper is not None else None
    wanted = [*(s.id for s in servos), *([gripper_id] if gripper_id is not None else [])]
    models = {i: bus.ping(i) for i in wanted}
    silent = [i for i, m in models.items() if m is None]
    if silent:
        names = {s.id: s.name for s in servos}
        if gripper_id is not None:
            names[gripper_id] = "gripper"
        raise ControllerFault(
            f"no answer from servo id {', '.join(f'{i} ({names[i]})' for i in silent)} on {bus.port}: "
            "check its cable, its power and its id (the arm's robot.toml: [[actuators]] id)"
        )
    log.info(
        "%s: %d servos answer on %s (models %s)",
        robot.name,
        len(wanted),
        bus.port,
        ", ".join(f"{i}: {m}" for i, m in models.items()),
    )


class BusServoAdapter(Adapter):
    """Drives ``robot``'s bus servos on ``bus``."""

    kind = "bus"
    run_tick = 0.001  # [s] (a cycle takes a few ms at 1 Mbaud: the bus sets the rate)

    def __init__(
        self,
        session: zenoh.Session,
        robot: Robot,
        bus: Bus,
        *,
        prefix: str = "armd",
        state_hz: float = 50.0,
        lead: float = LEAD,
        max_lost: int = MAX_LOST,
        settle: float = SETTLE,
    ) -> None:
        self.servos = actuators_of(robot, BusServo, f"{bus.name} bus-servo")
        self.bus = bus
        # a servo brakes before its goal at its own acceleration limit: the goal must be far
        # enough ahead that a servo at full speed need not (its braking distance, and a margin)
        lim = robot.limits
        self.lead = max(lead, float(np.max(lim.velocity / (2.0 * lim.acceleration))) + LEAD_MARGIN)
        self.max_lost = max_lost
        self.settle = settle
        self.ids = [s.id for s in self.servos]
        self.gripper_id = robot.gripper.channel if robot.gripper is not None else None
        self._io = threading.Lock()  # the bus: the control loop, and the gripper's requests
        self._reading: dict[int, Reading] = {}
        self._read_at = -math.inf
        self._lost = 0
        self._missing: list[int] = []
        self._position = np.array(robot.neutral, dtype=float)
        self._velocity = np.zeros(robot.nq)
        self._alarm: str | None = None
        self._cycles = 0  # bus cycles (sync write and read) done
        self.tracking = np.zeros(robot.nq)  # [rad] per joint, the worst error of the running (or last) trajectory
        amap = robot.actuators
        self._per_rad = np.array([s.counts_per_rad for s in self.servos])
        self._vmax, self._amax = robot.limits.velocity, robot.limits.acceleration
        self._v_sent, self._v_sent_at = np.zeros(robot.nq), 0.0  # [rad/s] the speeds last sent, and when
        self._lateness = 0.0  # [s] the longest gap between cycles lately (decaying)
        # [counts/s] each servo's fastest: its joints' velocity limits (a linkage: the sum), rounded down
        self._top = np.floor(amap.rate_bounds(self._vmax, self._amax)[0] * self._per_rad)
        self._direction = np.array([s.direction for s in self.servos])
        super().__init__(session, robot, prefix=prefix, state_hz=state_hz, check_period=0.1)
        self.position_source = "measured"
        try:
            self._start_up(amap)
        except BaseException:
            bus.close()
            raise
        self.activate()

    # -- start-up -------------------------------------------------------------------------

    def _start_up(self, amap: object) -> None:
        ping_all(self.bus, self.robot, self.servos)
        if not self._read():
            raise ControllerFault(f"the servos on {self.bus.port} answer a ping but not a read")
        lim = self.robot.limits
        if not lim.contains(self._position, tol=START_SLACK):  # (its torque still off: nothing moved)
            bad = lim.violations(self._position, tol=START_SLACK)
            raise ControllerFault(
                f"{self.robot.name} is outside its limits ({bad[0].message}): with its servos limp, move "
                "the arm inside them by hand and start again (a servo that reads so where the arm is inside "
                "needs calibrating: armd calibrate)"
            )
        accel = self.robot.actuators.rate_bounds(self.robot.limits.velocity, self._amax)[1]
        for k, s in enumerate(self.servos):  # (a servo moved by several joints: its bound over them all)
            self.bus.set_limits(s.id, float(accel[k]) * s.counts_per_rad)
        here = {i: r.position for i, r in self._reading.items() if i in self.ids}
        self.bus.write_goals(here, self._speeds(np.zeros(self.robot.nq)))  # (enabled, a servo drives to its goal)
        for i in self.ids:
            self.bus.set_torque(i, True)

    # -- the bus ------------------------------------------------------------------------------

    def _read(self) -> bool:
        """One sync read; the joints' state from it. False if a reply was lost."""
        wanted = self.ids
        with self._io:
            got = self.bus.read(wanted)
        now = time.monotonic()
        missing = [i for i in wanted if i not in got]
        if missing:
            self._lost += 1
            self._missing = missing
            if self._lost > self.max_lost:
                raise ControllerFault(
                    f"servo id {', '.join(map(str, missing))} did not answer {self._lost} reads in a row "
                    f"on {self.bus.port}"
                )
            return False
        self._lost = 0
        self._reading = got
        self._read_at = now
        counts = np.array([got[i].position for i in wanted], dtype=float)
        speeds = np.array([got[i].speed for i in wanted], dtype=float)
        amap = self.robot.actuators
        self._position = amap.joints_from_commands(counts, tol=np.inf)
        # [rad/s] of each actuator, then the joints (least squares: rates = J(q) v)
        rates = self._direction * speeds / self._per_rad
        self._velocity = np.linalg.lstsq(amap.jacobian(self._position), rates, rcond=None)[0]
        alarms = [(s, got[s.id].alarms) for s in self.servos if got[s.id].alarms]
        self._alarm = "; ".join(f"servo {s.id} ({s.name}): {', '.join(a)}" for s, a in alarms) if alarms else None
        self._cycles += 1
        return True

    def _speeds(self, v: FloatArray, q: FloatArray | None = None) -> dict[int, int]:
        """Each servo's speed [counts/s] for joint velocities ``v`` [rad/s] at position ``q``
        (else anywhere: the bound over the joints' range), within its joint's velocity limit
        (rounded down), and at least 1 (0 is the servo's top speed)."""
        amap = self.robot.actuators
        rate = (np.abs(amap.jacobian(q) @ v) if q is not None else amap.slopes @ np.abs(v)) * self._per_rad
        return {i: int(c) for i, c in zip(self.ids, np.clip(np.floor(rate), 1, self._top), strict=True)}

    def _send(self, q: FloatArray, v: FloatArray) -> None:
        counts = self.robot.actuators.commands(q)
        speeds = self._speeds(v, q)
        with self._io:
            self.bus.write_goals({i: int(c) for i, c in zip(self.ids, counts, strict=True)}, speeds)

    # -- the Adapter hooks ----------------------------------------------------------------------

    def execute(self, cmd: Command, t: float, first: bool) -> bool:
        # each servo: to the plan a lead ahead, at the plan's speed now, less or more by how far
        # it is ahead of or behind the plan (brought back over CORRECTION), within the velocity
        # limit and the acceleration limit's change since the last cycle; a servo given a speed
        # moves at it, not faster, whatever its loop would do (a smooth speed, not steps)
        now = time.monotonic()
        if first:
            self.tracking = np.zeros(self.robot.nq)
            self._v_sent, self._v_sent_at = self._velocity.copy(), now
        p, v, _ = cmd.sample_at(t)
        v = np.clip(v + (p - self._position) / CORRECTION, -self._vmax, self._vmax)
        # each joint's speed changes by no more than its acceleration limit allows since the last
        # change (a late cycle: a change no larger than the time it took)
        since = max(now - self._v_sent_at, 0.0)
        # the lead grows with how late cycles have come lately (a busy machine), up to MAX_LEAD
        self._lateness = max(self._lateness * LATENESS_DECAY**since, since)
        lead = min(max(self.lead, 2.0 * self._lateness), MAX_LEAD)
        base = self._v_sent
        if since > lead and self._read():  # (held up this long, a servo may have reached its goal
            base = self._velocity  # and stopped: it starts again from how fast it moves now, ramping up)
        budget = self._amax * min(since, lead)
        v = np.clip(v, base - budget, base + budget)
        self._v_sent, self._v_sent_at = v, now
        self._send(cmd.sample_at(t + lead)[0], v)
        if not self._read():
            return False  # (a lost reply: the goals go on; monitoring waits for the next reading)
        if self._alarm is not None:
            raise ControllerFault(f"alarm: {self._alarm}")
        if cmd.kind == "stop":  # a stop is never aborted: it ends when its time is up and the arm is still
            return t >= cmd.duration and bool(np.all(np.abs(self._velocity) < 0.05))
        plan = cmd.sample_at(t)[0]
        error = self._position - plan
        if t < cmd.duration:
            self.tracking = np.maximum(self.tracking, np.abs(error))
        over = np.abs(error) - self.robot.tracking_tolerance
        if t < cmd.duration and np.any(over > 0):
            j = int(np.argmax(over))
            self._abort(cmd, j, error[j], "tracking")
            return False
        if t >= cmd.duration:
            left = np.abs(self._position - cmd.position[-1])
            goal = self.robot.actuators.commands(cmd.position[-1])
            if all(abs(self._reading[i].position - int(c)) <= 1 for i, c in zip(self.ids, goal, strict=True)):
                return True  # (every servo within a count of its goal: there, as far as it can tell)
            if t >= cmd.duration + self.settle:
                if np.all(left <= GOAL_TOLERANCE):
                    return True  # (a servo's dead band may leave it a count or two off: near enough)
                j = int(np.argmax(left))
                self._abort(cmd, j, float(self._position[j] - cmd.position[-1][j]), "goal")
        return False

    def finished(self, cmd: Command) -> None:
        log.info(
            "%s: %s done; the worst tracking error: %s rad",
            self.robot.name,
            cmd.id,
            " ".join(f"{e:.4f}" for e in self.tracking),
        )

    def _abort(self, cmd: Command, j: int, error: float, what: str) -> None:
        name = self.robot.joint_names[j]
        tol = float(self.robot.tracking_tolerance[j]) if what == "tracking" else GOAL_TOLERANCE
        reason = (
            f"{name} is {abs(error):.3f} rad {'off the plan' if what == 'tracking' else 'from its goal'} "
            f"(tolerance {tol:.3f} rad)"
            + ("" if what == "tracking" else f" {self.settle:.1f} s after the trajectory's end")
            + ": stopped where it is"
        )
        log.warning("%s: trajectory %s aborted: %s", self.robot.name, cmd.id, reason)
        self.event("aborted", id=cmd.id, reason=reason, joint=name, error=error, tolerance=tol, check=what)
        with self._lock:
            self._finished = True  # (the stop below replaces it: no second "aborted")
        self.emergency_stop(f"{cmd.id}-{what}", f"{what} error on {name}")

    def hold(self) -> None:
        """Goals where the servos are (each brakes within its own limits, set at start-up)."""
        if self._reading:
            top = self._speeds(self._vmax)
            with self._io:
                self.bus.write_goals({i: self._reading[i].position for i in self.ids if i in self._reading}, top)

    def measure(self) -> JointState:
        if time.monotonic() - self._read_at > FRESH:
            self._read()
        return JointState(self._position.copy(), self._velocity.copy(), np.zeros(self.robot.nq))

    def estimate(self) -> JointState:
        return JointState(self._position.copy(), self._velocity.copy(), np.zeros(self.robot.nq))

    def check(self) -> None:
        """A read if none came lately (an idle arm); an alarm or a silent bus is a fault."""
        if time.monotonic() - self._read_at > self.check_period:
            self._read()
            if self._lost:
                raise ControllerFault(
                    f"servo id {', '.join(map(str, self._missing))} did not answer on {self.bus.port}"
                )
        if self._alarm is not None:
            raise ControllerFault(f"alarm: {self._alarm}")

    def grip(self, opening: float) -> None:
        gripper = self.robot.gripper
        if gripper is None:
            super().grip(opening)
            return
        with self._io:
            self.bus.write_goals({gripper.channel: gripper.pulse(opening)}, {gripper.channel: GRIPPER_SPEED})
            self.bus.set_torque(gripper.channel, True)
        self.gripper_opening = opening

    def unlock(self, how: str) -> None:
        """An operator's word that the servos may hold again (``armd unlock ROBOT --assume-rest``,
        after an alarm: the cause seen to): each servo's alarm cleared (a Dynamixel rebooted),
        its goal where it is, its torque on. The arm holds where it is; nothing moves."""
        with self._io:
            for i in self.ids:
                self.bus.clear_alarm(i)
            got = self.bus.read(self.ids)
            missing = [i for i in self.ids if i not in got]
            if missing:
                raise ControllerFault(f"servo id {', '.join(map(str, missing))} did not answer on {self.bus.port}")
            self.bus.write_goals({i: got[i].position for i in self.ids}, self._speeds(np.zeros(self.robot.nq)))
            for i in self.ids:
                self.bus.set_torque(i, True)
        self._read()

    def shutdown(self) -> None:
        """The port released; the servos keep their torque and hold (turn it off: ``armd record``)."""
        self.bus.close()


class SdkBusAdapter(BusServoAdapter):
    """A bus-servo adapter on its vendor's :class:`SdkBus` (``bus_type``): ``robot``'s servos on
    ``port`` at ``baud`` (default: the arm's ``[controller] baud``, else 1 Mbaud), or on ``bus``,
    opened already (the command line opens the port before it joins Zenoh)."""

    bus_type: type[SdkBus]  # (the subclass's)

    def __init__(
        self,
        session: zenoh.Session,
        robot: Robot,
        port: str,
        *,
        baud: int | None = None,
        bus: SdkBus | None = None,
        prefix: str = "armd",
        state_hz: float = 50.0,
        lead: float = LEAD,
        calibration: str | Path | None = None,
        **options: Any,
    ) -> None:
        actuators_of(robot, BusServo, self.bus_type.name)  # (an arm it cannot drive: refused before the port is opened)
        # the arm's calibration (armd calibrate), if it has one: checked against its limits before the port is opened
        robot = calibrated(robot, calibration)
        if bus is None:
            bus = self.bus_type(port, int(baud or robot.controller.get("baud", 1_000_000)))  # type: ignore[call-overload]
        super().__init__(session, robot, bus, prefix=prefix, state_hz=state_hz, lead=lead, **options)
