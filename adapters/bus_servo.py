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
- a fault (below) aborts the trajectory; the arm is braked to rest as a ``stop`` brakes it,
  from the adapter's :meth:`~BusServoAdapter.estimate` (the last reading carried on to now at
  the faster of the speed measured and the speed sent, never past the goal sent: a stop planned
  from it never asks a joint back), the stop running under the fault; each servo that still
  has its torque brakes within its own acceleration limit.

Faults (:meth:`~BusServoAdapter._diagnose`, at every check, 10 a second, and at once when a
cycle sees an alarm or too many lost replies), each said once (the same reason again is only
counted), the state published on at its rate meanwhile:

- a servo's alarm (overload, overheat, voltage), naming the servo and the alarm;
- a servo that let go (its torque off, as an STS does on an overheat or an overload, a
  Dynamixel on any hardware error): it waits for an operator (``armd unlock ROBOT
  --assume-rest``, :meth:`unlock`), never set going again by the adapter;
- a servo reset (its acceleration register back to 0, its torque off: a power cycle, a cable
  plugged back): a new controller, set up again as at start-up (:meth:`_configure`: written and
  read back) before ``recovered``, at the check after the fault was said; moves are refused
  meanwhile;
- a read that fails (a reply lost, garbled, late) is tried again at once if it failed fast
  (noise), else skipped: the goals go on; more than ``max_lost`` in a row is a fault: each
  servo the reads missed is pinged (a sync read broken off at a silent servo loses the replies
  after it), and those that do not answer are named (``servo id 3 (elbow_flex) does not
  answer``) and left out of the reads until they answer a ping again.

How long a reply may take: the SDKs' timeouts assume an FTDI chip's factory latency (16 ms,
counted twice); here the link's own, its latency timer's where the system shows one, and at
else what the pings at start measure (:attr:`SdkBus.latency`), plus ``LINK_MARGIN``: a silent
servo costs a few milliseconds a read. A latency above ``SLOW_LINK`` is said at start, with how
to lower it.
"""

from __future__ import annotations

import logging
import math
import os
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
CYCLE_WEIGHT = 0.2  # of the last cycle's length in the moving average of a cycle's
CORRECTION = 0.1  # [s] a servo off the plan is brought back to it over about this long
MAX_LOST = 3  # failed reads in a row before the bus is a fault
SETTLE = 0.5  # [s] after a trajectory's end, how long the arm may take to reach its goal
GOAL_TOLERANCE = 0.02  # [rad] how near its goal a joint must be SETTLE after the end (else: aborted); done
# before that when every servo is within a count of its goal
GRIPPER_SPEED = 2000  # [counts/s] the gripper's
READ_WAIT = 0.001  # [s] the longest one read of the port blocks (the SDKs' packet timeouts still apply)
START_SLACK = 0.02  # [rad] how far outside its limits the arm may be found at start (as the SSC-32's)
FRESH = 0.002  # [s] a reading this recent answers measure() without another read
SDK_LATENCY = 0.016  # [s] what the SDKs assume of every link (an FTDI chip's factory latency timer)
USB_FRAME = 0.001  # [s] a USB link's latency where nothing says more (a full-speed frame)
LINK_MARGIN = 0.01  # [s] the slack a reply has beyond its bytes' time and twice the link's latency
MAX_LATENCY = 0.05  # [s] the most the pings' measure of the link's latency is taken to be
SLOW_LINK = 0.004  # [s] a latency above this is said at start, with how to lower it
WRITES = 3  # tries of a write whose status did not come
RETRY_WITHIN = 0.003  # [s] a sync read that lost a reply this fast (noise, not a silent servo) is tried again at once


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


@dataclass(frozen=True)
class Settings:
    """What a servo's RAM holds of the adapter's settings: its ``torque`` on or off, and its
    ``acceleration`` register [its units; 0: none, as at power-up]."""

    torque: bool
    acceleration: int


class Bus(ABC):
    """One vendor's bus, through its SDK: what the adapter asks of it."""

    name = "bus"
    port = ""
    latency = 0.0  # [s] how long the link holds a reply beyond its bytes' time on the wire

    def learn_latency(self) -> None:
        """Take :attr:`latency` from what the pings so far measured (the default: as it is)."""
        return None

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
    def set_limits(self, ident: int, acceleration: float) -> int:
        """The servo's own acceleration limit [counts/s^2], rounded down to its units (at least
        one); the register's value written [its units]."""

    @abstractmethod
    def read_settings(self, ids: list[int]) -> dict[int, Settings]:
        """What each servo's RAM holds of what the adapter set (its torque, its acceleration
        register), in sync reads; a servo whose reply was lost is missing."""

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
    sync_read_extra: tuple[Any, ...] = ()  # (more arguments of the SDK's syncReadTx)
    ping_bytes = 12  # a ping and its answers, both ways [bytes]
    ping_exchanges = 1  # the SDK's ping: how many requests and answers

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
        # how long a reply may take: the SDKs assume an FTDI chip's factory latency (16 ms, twice);
        # here the link's own, its latency timer's where the system has one, else a USB frame's,
        # and what the pings measure (a silent servo then costs a few ms a read, not 34)
        timer = usb_latency_timer(port)
        self.latency = timer if timer is not None else SDK_LATENCY  # [s] (until the pings have measured it)
        self.latency_timer = timer
        self._took: list[float] = []  # [s] each ping's round trip less the wire's time
        self.handler.setPacketTimeout = self._packet_timeout

    def _packet_timeout(self, packet_length: int) -> None:
        """The SDK's ``setPacketTimeout``, with the link's latency (:attr:`latency`) for its 16 ms."""
        h = self.handler
        h.packet_start_time = h.getCurrentTime()
        h.packet_timeout = h.tx_time_per_byte * packet_length + 1000.0 * (2.0 * self.latency + LINK_MARGIN)  # [ms]

    def _fresh(self) -> None:
        """Stale input dropped (the SDKs' ``clearPort`` waits for the output instead: a reply that
        came after its timeout would be read as the next one's)."""
        self.handler.ser.reset_input_buffer()

    def _ok(self, result: int) -> bool:
        return bool(result == self.sdk.COMM_SUCCESS)

    def ping(self, ident: int) -> int | None:
        """The servo's model number, or None (an answer's round trip, less the wire's time, is
        kept for :meth:`learn_latency`)."""
        self._fresh()
        asked = time.monotonic()
        try:
            model, result, _ = self.packets.ping(self.handler, ident)
        except IndexError:  # (Feetech's SDK indexes a model number its garbled reply lacks: no answer)
            return None
        if not self._ok(result):
            return None
        wire = self.handler.tx_time_per_byte * self.ping_bytes / 1000.0
        self._took.append((time.monotonic() - asked - wire) / self.ping_exchanges)
        return int(model)

    def learn_latency(self) -> None:
        """The link's latency from the pings' round trips so far (their median), where the system
        shows no latency timer: at least a USB frame, at most ``MAX_LATENCY``."""
        if self.latency_timer is None and self._took:
            self.latency = min(max(float(np.median(self._took)), USB_FRAME), MAX_LATENCY)

    def _write(self, ident: int, address: int, size: int, value: int) -> None:
        """A write that must be taken (its status: no error), else :class:`ControllerFault`; one
        whose status did not come is written again, up to ``WRITES`` times (the same value: no
        harm; on a busy machine a status may come too late)."""
        write = {1: self.packets.write1ByteTxRx, 2: self.packets.write2ByteTxRx, 4: self.packets.write4ByteTxRx}[size]
        for _ in range(WRITES):
            self._fresh()
            result, error = write(self.handler, ident, address, value)
            if self._ok(result):
                break
        if not self._ok(result) or error & self.write_errors:
            why = self.packets.getTxRxResult(result) if not self._ok(result) else self.packets.getRxPacketError(error)
            raise ControllerFault(f"servo id {ident} on {self.port} did not take a write to address {address}: {why}")

    def _sync_read(self, address: int, size: int, ids: list[int]) -> dict[int, tuple[list[int], int]]:
        """One sync read of ``size`` bytes at ``address``: each servo's data and status error
        byte, read reply by reply in the order asked (the SDK's ``readRx``, which skips another
        servo's reply: one lost loses those after it too)."""
        self._fresh()
        result = self.packets.syncReadTx(self.handler, address, size, list(ids), len(ids), *self.sync_read_extra)
        out: dict[int, tuple[list[int], int]] = {}
        if not self._ok(result):
            return out
        for i in ids:
            data, result, error = self.packets.readRx(self.handler, i, size)
            if not self._ok(result) or len(data) < size:
                break
            out[i] = (list(data), int(error))
        return out

    def set_torque(self, ident: int, on: bool) -> None:
        self._write(ident, self.torque_address, 1, 1 if on else 0)

    def close(self) -> None:
        try:
            self.handler.closePort()
        except Exception:  # (already closed)
            log.debug("close failed", exc_info=True)


def sync_read(bus: Bus, ids: list[int]) -> tuple[dict[int, Reading], float]:
    """One sync read of ``ids`` on ``bus``; if it lost a reply fast (garbled: noise on the wire,
    not a silent servo, whose reply is waited for), once more at once. A servo whose reply was
    still lost is missing. And when the reading was taken [s, monotonic]: when the read that
    got it was asked (the servos answer what they measure as the request arrives; the reply
    may come a USB latency later)."""
    asked = time.monotonic()
    got = bus.read(ids)
    if len(got) < len(ids) and time.monotonic() - asked < RETRY_WITHIN:
        asked = time.monotonic()
        got = bus.read(ids)
    return got, asked


def silent_servos(bus: Bus, ids: list[int], pings: int = 3) -> list[int]:
    """Those of ``ids`` that answer none of ``pings`` pings: a sync read broken off at a silent
    servo loses the replies of the servos after it too, which are well (and a busy machine may
    miss one answer)."""
    return [i for i in ids if all(bus.ping(i) is None for _ in range(pings))]


def usb_latency_timer(port: str) -> float | None:
    """[s] the latency timer of the USB-serial chip behind ``port`` (an FTDI's, which holds what
    the servos send until it fills or the timer runs out), where the system shows one; else None."""
    name = os.path.basename(os.path.realpath(port))
    try:
        return int((Path("/sys/class/tty") / name / "device" / "latency_timer").read_text()) / 1000.0
    except (OSError, ValueError):
        return None


def ping_all(bus: Bus, robot: Robot, servos: list[BusServo]) -> None:
    """Every servo of ``servos`` (and ``robot``'s gripper) must answer a ping on ``bus``, else
    :class:`ControllerFault` naming the ids that did not, and their joints."""
    gripper_id = robot.gripper.channel if robot.gripper is not None else None
    wanted = [*(s.id for s in servos), *([gripper_id] if gripper_id is not None else [])]
    models = {i: bus.ping(i) for i in wanted}
    quiet = [i for i, m in models.items() if m is None]
    if quiet:  # (asked again: on a busy machine an answer may come too late)
        still = silent_servos(bus, quiet)
        models.update({i: bus.ping(i) for i in quiet if i not in still})
    bus.learn_latency()
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
        "%s: %d servos answer on %s (models %s; replies within %.1f ms)",
        robot.name,
        len(wanted),
        bus.port,
        ", ".join(f"{i}: {m}" for i, m in models.items()),
        1000.0 * bus.latency,
    )
    if bus.latency > SLOW_LINK:
        name = os.path.basename(os.path.realpath(bus.port))
        how = (
            f"set it to 1 ms: echo 1 | sudo tee /sys/bus/usb-serial/devices/{name}/latency_timer (for good: a "
            "udev rule, docs/adapters.md)"
            if name.startswith("ttyUSB")
            else "a USB-serial adapter whose latency can be set lower is worth it (docs/adapters.md)"
        )
        log.warning(
            "%s: replies take %.0f ms to come back from %s (a USB-serial chip's latency timer? an FTDI's is "
            "16 ms from the factory): every bus cycle waits for it, the arm is followed less closely; %s",
            robot.name,
            1000.0 * bus.latency,
            bus.port,
            how,
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
        self._names = {s.id: s.name for s in self.servos}
        self._io = threading.RLock()  # the bus: the control loop, and the gripper's requests
        self._reading: dict[int, Reading] = {}
        self._read_at = self._sampled_at = -math.inf  # [s] when the last reading came, when it was taken
        self._lost = 0
        self._missing: list[int] = []  # the servos the last failed read missed
        self._silent: list[int] = []  # servos that answer no ping (a cable off): not read until they do
        self._accel_units: dict[int, int] = {}  # each servo's acceleration register, as the adapter set it
        self._position = np.array(robot.neutral, dtype=float)
        self._velocity = np.zeros(robot.nq)
        self._goal = self._position.copy()  # [rad] the goals last sent
        self._alarm: str | None = None
        self._cycles = 0  # bus cycles (sync write and read) done
        self.tracking = np.zeros(robot.nq)  # [rad] per joint, the worst error of the running (or last) trajectory
        amap = robot.actuators
        self._per_rad = np.array([s.counts_per_rad for s in self.servos])
        self._vmax, self._amax = robot.limits.velocity, robot.limits.acceleration
        self._v_sent, self._v_sent_at = np.zeros(robot.nq), 0.0  # [rad/s] the speeds last sent, and when
        self._lateness = 0.0  # [s] the longest gap between cycles lately (decaying)
        self._cycle = self.run_tick  # [s] how long a bus cycle takes lately (a moving average)
        # [counts/s] each servo's fastest: its joints' velocity limits (a linkage: the sum), rounded down
        self._top = np.floor(amap.rate_bounds(self._vmax, self._amax)[0] * self._per_rad)
        self._direction = np.array([s.direction for s in self.servos])
        super().__init__(session, robot, prefix=prefix, state_hz=state_hz, check_period=0.1)
        self.position_source = "measured"
        try:
            self._start_up()
        except BaseException:
            bus.close()
            raise
        self.activate()

    # -- start-up, and a power cycle ----------------------------------------------------------

    def _start_up(self) -> None:
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
        self._configure()

    def _configure(self) -> None:
        """Every servo set up as the adapter relies on, and read back (else :class:`ControllerFault`
        naming the servo): its acceleration limit its joint's (rounded down), its goal where it is,
        then its torque on. Nothing moves. At start-up, after an unlock, and after a power cycle
        (a servo that lost its RAM is a new controller)."""
        accel = self.robot.actuators.rate_bounds(self._vmax, self._amax)[1]
        with self._io:
            for k, s in enumerate(self.servos):  # (a servo moved by several joints: its bound over them all)
                self._accel_units[s.id] = self.bus.set_limits(s.id, float(accel[k]) * s.counts_per_rad)
            got = self.bus.read(self.ids)
            missing = [i for i in self.ids if i not in got]
            if missing:
                raise ControllerFault(f"servo id {self._named(missing)} did not answer a read on {self.bus.port}")
            # (enabled, a servo drives to its goal: first where it is)
            self.bus.write_goals({i: got[i].position for i in self.ids}, self._speeds(np.zeros(self.robot.nq)))
            for i in self.ids:
                self.bus.set_torque(i, True)
        settings = self._settings()
        unset = [
            f"{self._named([i])}: " + ("no answer" if st is None else "torque off" if not st.torque else "acceleration")
            for i in self.ids
            for st in [settings.get(i)]
            if st is None or not st.torque or st.acceleration != self._accel_units[i]
        ]
        if unset:
            raise ControllerFault(f"servo id {'; '.join(unset)} not as set on {self.bus.port}")
        self._silent, self._lost = [], 0
        self._read()
        self._goal = self._position.copy()
        self._v_sent = np.zeros(self.robot.nq)

    def _set_up_again(self) -> None:
        """After a power cycle (said as a fault already): whatever ran ends (the servos let go,
        a stop planned before means nothing now), every servo set up again where it is."""
        with self._lock:
            if self._cmd is not None and not self._finished:
                self.event("aborted", id=self._cmd.id, reason="the servos were reset: set up again where they are")
            self._finished = True
        self._configure()
        self.homed = True
        self.new_epoch()  # (limp meanwhile, the arm may have sagged: its state may jump)
        log.info("%s: the servos on %s are set up again (read back)", self.robot.name, self.bus.port)

    # -- the bus ------------------------------------------------------------------------------

    def _named(self, ids: list[int]) -> str:
        return ", ".join(f"{i} ({self._names.get(i, 'gripper')})" for i in ids)

    def _read(self) -> bool:
        """One sync read of every servo that answers (a reply lost: read again at once, if the
        first took less than ``RETRY_WITHIN``); the joints' state from it. False if a reply was
        lost. Never raises: what a run of lost reads means is :meth:`_diagnose`'s to say."""
        wanted = [i for i in self.ids if i not in self._silent]
        with self._io:
            got, sampled = sync_read(self.bus, wanted)
        now = time.monotonic()
        missing = [i for i in wanted if i not in got]
        if missing:
            self._lost += 1
            self._missing = missing
            return False
        self._lost = 0
        self._reading.update(got)
        self._read_at, self._sampled_at = now, sampled
        counts = np.array([self._reading[i].position for i in self.ids], dtype=float)
        # (a silent servo: where it was last read, still)
        speeds = np.array([0.0 if i in self._silent else self._reading[i].speed for i in self.ids])
        amap = self.robot.actuators
        self._position = amap.joints_from_commands(counts, tol=np.inf)
        # [rad/s] of each actuator, then the joints (least squares: rates = J(q) v)
        rates = self._direction * speeds / self._per_rad
        self._velocity = np.linalg.lstsq(amap.jacobian(self._position), rates, rcond=None)[0]
        alarms = [(s, got[s.id].alarms) for s in self.servos if s.id in got and got[s.id].alarms]
        self._alarm = "; ".join(f"servo {s.id} ({s.name}): {', '.join(a)}" for s, a in alarms) if alarms else None
        self._cycles += 1
        return True

    def _find_silent(self) -> None:
        """The servos that answer no ping, of those the failed reads missed and those silent
        already: a sync read broken off at a silent servo loses the replies after it too."""
        with self._io:  # (a servo named silent already: a ping each check, until it answers)
            new = sorted(set(self._missing) - set(self._silent))
            self._silent = sorted(silent_servos(self.bus, new) + silent_servos(self.bus, self._silent, pings=1))

    def _diagnose(self) -> str | None:
        """Why the arm cannot be driven now, else None: servos that do not answer (named by a
        ping each), replies lost read after read, alarms, servos reset (a power cycle: their
        torque off, their settings lost) or let go (their torque off after an alarm). Servos
        reset while a fault is said already are set up again here (:meth:`_set_up_again`)."""
        if self._lost > self.max_lost or self._silent:
            self._find_silent()
        port = self.bus.port
        if self._silent or self._lost > self.max_lost:  # (one reason, whether a ping got through or not)
            quiet = self._silent or self._missing[:1]  # (else the servo where the reads broke off)
            return f"servo id {self._named(quiet)} does not answer on {port}: check its cable and its power"
        settings = self._settings()
        reset = [i for i, st in settings.items() if st.acceleration != self._accel_units.get(i)]
        if reset:
            if self.fault is None:
                self.homed = False  # (the arm's servos are not as the adapter set them: no move until they are)
                return (
                    f"servo id {self._named(reset)} was reset (a power cycle? its torque off, its acceleration "
                    f"limit gone) on {port}: set up again as soon as it answers"
                )
            self._set_up_again()
            settings = self._settings()
        limp = [i for i, st in settings.items() if not st.torque]
        if limp and self._alarm is None:
            # (the torque went off since the last read, an alarm with it maybe: read again, so that
            # the fault is said once with its cause, not once without and again with it)
            self._read()
        parts = [f"alarm: {self._alarm}"] if self._alarm is not None else []
        if limp:
            parts.append(
                f"servo id {self._named(limp)} let go (its torque off): see to the cause, then "
                f"armd unlock {self.robot.name} --assume-rest"
            )
        return "; ".join(parts) or None

    def _settings(self) -> dict[int, Settings]:
        """What each servo holds of the adapter's settings; a servo that reads otherwise than as
        set is read again at once, and the second reading is the one believed (a reply that came
        late, after its timeout, on a busy machine, is read as the next one's: a whole state's
        bytes taken for a torque and an acceleration)."""
        with self._io:
            first = self.bus.read_settings(self.ids)
            odd = [i for i, st in first.items() if not st.torque or st.acceleration != self._accel_units.get(i)]
            again = self.bus.read_settings(odd) if odd else {}
        return {i: again.get(i, st) for i, st in first.items()}

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
        self._goal = np.array(q, dtype=float)

    # -- the Adapter hooks ----------------------------------------------------------------------

    def execute(self, cmd: Command, t: float, first: bool) -> bool:
        # each servo: to the plan a lead ahead, at the plan's speed now, less or more by how far
        # it is ahead of or behind the plan (brought back over CORRECTION), within the velocity
        # limit and the acceleration limit's change since the last cycle; a servo given a speed
        # moves at it, not faster, whatever its loop would do (a smooth speed, not steps)
        now = time.monotonic()
        stop = cmd.kind == "stop"
        if first:
            self.tracking = np.zeros(self.robot.nq)
            # (a stop: from the state it was planned from, which under a fault is carried on past the last reading)
            self._v_sent, self._v_sent_at = (cmd.velocity[0] if stop else self._velocity).copy(), now
        since = max(now - self._v_sent_at, 0.0)
        if not first:
            self._cycle += (since - self._cycle) * CYCLE_WEIGHT
        # the lead grows with how late cycles have come lately (a busy machine), up to MAX_LEAD
        self._lateness = max(self._lateness * LATENESS_DECAY**since, since)
        lead = min(max(self.lead, 2.0 * self._lateness), MAX_LEAD)
        # the plan's speed as the next cycle comes: a servo given it ramps to it meanwhile (within its
        # own limit), where the speed now would leave it a cycle behind the plan (20 ms at 3 rad/s on a
        # link with an FTDI's latency: 0.06 rad)
        v = cmd.sample_at(t + min(self._cycle, lead))[1]
        if self._lost == 0:  # (off the plan as of the last reading, taken a cycle and a link's latency ago)
            v = v + (cmd.sample_at(t - (now - self._sampled_at))[0] - self._position) / CORRECTION
        v = np.clip(v, -self._vmax, self._vmax)
        # each joint's speed changes by no more than its acceleration limit allows since the last
        # change (a late cycle: a change no larger than the time it took)
        base = self._v_sent
        if since > lead and self._read():  # (held up this long, a servo may have reached its goal
            base = self._velocity  # and stopped: it starts again from how fast it moves now, ramping up)
        budget = self._amax * min(since, lead)
        v = np.clip(v, base - budget, base + budget)
        self._v_sent, self._v_sent_at = v, now
        self._send(cmd.sample_at(t + lead)[0], v)
        read = self._read()
        if stop:  # a stop is never aborted, a fault or not: it ends when its time is up and the arm is still
            still = read and bool(np.all(np.abs(self._velocity) < 0.05))
            return t >= cmd.duration and (still or t >= cmd.duration + self.settle)
        if not read:
            if self._lost > self.max_lost:
                raise ControllerFault(self._diagnose() or f"replies lost on {self.bus.port}")
            return False  # (a lost reply: the goals go on; monitoring waits for the next reading)
        if self._alarm is not None:
            raise ControllerFault(self._diagnose() or f"alarm: {self._alarm}")
        plan = cmd.sample_at(t - (now - self._sampled_at))[0]  # (where the plan was when the reading was taken)
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
        """Each servo's goal where it comes to rest braking at its joint's acceleration limit
        from how it moves (:meth:`estimate`), at the speed it has: it brakes there by its own
        limit, never back (a goal behind a servo at speed would send it back)."""
        s = self.estimate()
        rest = self.robot.limits.clip(s.position + s.velocity * np.abs(s.velocity) / (2.0 * self._amax))
        self._send(rest, np.abs(s.velocity))

    def measure(self) -> JointState:
        if time.monotonic() - self._read_at > FRESH:
            self._read()
        return JointState(self._position.copy(), self._velocity.copy(), np.zeros(self.robot.nq))

    def estimate(self) -> JointState:
        """The arm's state now, from the last reading carried on to now: each joint on at the
        faster of its measured speed and the speed last sent, for as long as since the reading
        (at most the lead), never past its goal last sent. Where a joint not read lately may be
        by now, at the farthest: a stop planned from it never asks a joint back."""
        dt = min(max(time.monotonic() - self._sampled_at, 0.0), self.lead)
        v, sent = self._velocity, self._v_sent
        fast = np.where(np.sign(sent) == np.sign(v), np.sign(v) * np.maximum(np.abs(v), np.abs(sent)), v)
        p = np.clip(
            self._position + fast * dt,
            np.minimum(self._position, self._goal),
            np.maximum(self._position, self._goal),
        )
        return JointState(p, fast, np.zeros(self.robot.nq))

    def check(self) -> None:
        """A read if none came lately (an idle arm), then :meth:`_diagnose`: a reason is a fault."""
        if time.monotonic() - self._read_at > self.check_period:
            self._read()
        why = self._diagnose()
        if why is not None:
            raise ControllerFault(why)

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
        then set up as at start-up (:meth:`_configure`: its acceleration limit, its goal where it
        is, its torque on, read back). The arm holds where it is; nothing moves."""
        with self._io:
            for i in self.ids:
                self.bus.clear_alarm(i)
        self._configure()
        self.homed = True

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
