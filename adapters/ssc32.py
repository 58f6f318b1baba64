"""The SSC-32 adapter: servo arms on a Lynxmotion SSC-32 / SSC-32U (seeds 000 and 003).

``armd adapter ssc32 ROBOT --port /dev/ttyUSB0 [--baud B] [--state-dir DIR]``. The port may be
any pyserial URL (``/dev/ttyUSB0``, a pseudo-terminal, ``socket://host:port``); the baud rate
defaults to the arm's ``[controller] baud`` (the SSC-32U leaves the factory at 9600).

The board moves a servo linearly from where it is toward a command's pulse, at the command's
speed ``S`` [us/s] (or so as to take ``T`` ms), then holds; a new command replaces the running
one from where the servo is, and the servos of one command start and end together. The
adapter keeps a model of that motion (per joint: where the board is heading, from where, until
when, as the board interpolates it) and streams a trajectory one line a period, a command per
group of servos that share a joint (a mirrored pair is one command), each padded with spaces to
a fixed width so that every command reaches the board at the same point of every line. A
linkage's servos (a group that moves more than one joint, desk4's) go in one command timed by
``T``: their speeds are in no one ratio, and the board ends a command's servos together:

- Each servo gets a speed and a target a span ahead (``lead`` and a period), and the next line
  replaces it a period in: the board is never idle while the adapter is on time, and a late
  adapter (up to ``lead``) only lengthens the move in hand. A speed, not a time: a command
  that reaches the board late (the host's USB or terminal holding it a few milliseconds)
  changes the servo's speed late, not by more; a move timed by ``T`` would cover what is left
  of its way in ``T``, faster or slower by the distance lost. The speed, per joint, is the
  plan's average over the move ahead, from where the board is (a board off the plan converges
  on it), within one period's change of speed of the move in hand (every acceleration limit,
  over the time since the previous change) and within every velocity limit, whole
  microseconds allowed for; its target is where that speed leads, but no farther than the
  board could run on to and still brake inside every position limit (a board whose adapter
  stalls for less than the lead runs on to it), and a speed that could not stop inside them
  from a period on is slowed, within that period's change. The plan's clock advances with
  the board's, by at most ``MAX_SLIP`` periods a line:
  a late adapter, a stalled process or a slow link re-time the rest of the trajectory,
  slower, from where the board is, ramping up from rest when the board had stopped; nothing
  catches up by jumping. The last line ends at the trajectory's end, once the board may stop
  there within the limits; a stop never reverses a joint.
- Bandwidth: each line's bytes, times the lines per second, against the link (10 bits a byte
  at the baud rate). A trajectory sampled faster than the link carries is streamed every
  ``stride``-th sample (at most 60% of the link: the rest is for the checks); one that would
  need moves further apart than ``MAX_PERIOD`` is refused before any pulse is sent, naming the
  baud rate.
- Checks never block the stream: every ``query_period`` a ``QP`` of every channel is written,
  and its answer read by later passes of the control loop; no answer within ``timeout`` is a
  fault. The board answers the pulse of its frame in progress (it outputs one every 20 ms) in
  10 us, and a line that reached it up to a frame late leaves it where the model was a frame
  before: an answer is compared with the model from two frames before it was asked until it
  was answered, give or take the 10 us and ``MODEL_TOL`` (at rest 15 us; a servo at 3 rad/s,
  91 us behind where the model was when asked). One off that is asked again at once; a second
  in a row with a servo off the same way is a fault (someone else moved the servo, the board
  was reset). The model of that servo is then put where the
  board's answers say it is, narrower with each (``FAULT_QUERY_PERIOD``) while the model
  moves: the stop that brakes the arm (it streams through :meth:`SSC32Adapter.execute`,
  fault or not) brakes from there. Faulted, an answer that agrees with the model recovers the
  adapter as it is; else it recovers once the board stands still (the same answer for
  ``STILL``, after the adapter's own moves have ended), from where the board is then: never
  from an answer the board has since moved on from. A stop that finds the board at rest where
  it would end sends nothing (a line there would creep a board that is not at 1 us/s). A board
  found without a pulse (reset, powered off and on) is sent nothing more, not even a stop: its
  servos are limp, and the first line to a channel would jump its servo at full speed; the
  fault says to restart the adapter.

- Deliveries: a ``Q`` follows every line (two bytes; the board answers ``+`` or ``.``, in
  order with any other answer): its answer says the line has reached the board, and by when at
  the latest (its bytes' time on the link and the board's own latency, the least of the last
  ``LATENCY_WINDOW``, taken off). An answer later than those by ``ANSWER_TOL`` says the host
  held the bytes on their way (a busy host's kernel thread that carries a pseudo-terminal's
  bytes, a USB link that waits to fill its packets), and lets what it held go together: the
  lines then reach the board as fast as the link carries them (6 ms apart at 115200 baud),
  their changes of speed closer than they were aimed. A move's lines go on as aimed (the
  answers only confirm them, and an answer overdue makes the lead grow). A tracking stream
  (``splices``: its trajectories spliced one into the next, one a cycle) is followed within
  every limit through it: its lines (and its stop's) aim ``MAX_LEAD`` ahead, so a line held on
  its way still finds the board moving along the plan, not stopped dead at a target; a line
  after one whose answer came late, or has not come when it was due, changes each speed by no
  more than the acceleration limit gives the link's time of one line (the board may have both
  back to back); a line found held moves the model (its piece starts when it came, and the
  pieces after it are off by the speeds kept meanwhile: the board is where the model says,
  for the aims and the checks); and each target lies beyond where the board may be, off the
  model by the lines still on their way (near a joint's turn, where targets are near, a
  target behind the board sends it back).

Start-up: ``VER`` must answer. Then ``QP``: a board already outputting pulses on every channel
(the adapter restarted, the board stayed powered) is adopted as it is, with no pulse change. A
board just powered outputs none, and a hobby servo's position is unknown until its first
pulse: its first command is a jump, at the servo's own speed, whatever ``S`` or ``T`` say. The adapter
says so in its log and commands the pose the arm was left at (the last commanded pose, kept
per arm in ``state_dir`` when a trajectory ends and when the adapter stops), else neutral;
the state it reports says ``source: "commanded"`` (hobby servos report no position).

The gripper, a separate channel, opens and closes on ``<prefix>/<robot>/gripper``.

Range sensors wired to the board (robot.toml ``[[sensors]] pin``, a scanner's ``channel``) are
read on its analog inputs between the stream's lines, each read after the arm's ``QP`` and the
scanners', their scanners stepped through their sweeps, and each reading published on
``<prefix>/<robot>/sensors/<name>`` (:mod:`.ssc32_sensors`) only if the board is as the adapter
has it (never while faulted), in at most ``SENSOR_SHARE`` of the link (a slow link scans slower).
"""

from __future__ import annotations

import collections
import contextlib
import json
import logging
import math
import re
import time
from pathlib import Path
from typing import NamedTuple

import numpy as np
import serial
import zenoh

from armd.errors import ActuatorMapError, BadRequest, ControllerFault
from armd.planning import JointState
from armd.robots import Robot, Servo

from .base import actuators_of, calibrated, state_dir_default
from .serial_port import PORT_ERRORS, SerialAdapter
from .ssc32_sensors import SCAN_SPEED, WiredSensors
from .trajectory_message import Command, FloatArray

log = logging.getLogger(__name__)

LINK_SHARE = 0.6  # of the link's bytes per second the stream may use
QUIET = 0.1  # [s] the link from the board quiet this long after an overdue answer, before asking again
SENSOR_SHARE = 0.2  # of the link's bytes per second the wired sensors' reads and steps may use (QP: the rest)
MAX_PERIOD = 0.25  # [s] the longest step between streamed samples (farther: refused, the link is too slow)
LEAD = 0.05  # [s] at least this long before the board reaches a move, the next one is sent
MAX_LEAD = 0.25  # [s] the most the lead grows to on a busy machine; a tracking stream's, always
LATENESS_DECAY = 0.5  # per second: how fast the lead forgets a late pass of the control loop
QP_RESOLUTION = 10.0  # [us] QP answers a pulse / 10 (the SSC-32U guide: "a resolution of 10uS")
FRAME = 0.02  # [s] the board outputs a servo's pulse every 20 ms (the guide); QP answers the frame in progress
MODEL_TOL = 5.0  # [us] how far the model may be from the board at rest: a board adopted from a QP (its middle)
STILL = 0.1  # [s] a board whose QP answers stay the same this long (after the adapter's moves end) stands still
FAULT_QUERY_PERIOD = 0.05  # [s] how often the board is asked while faulted or followed (its answers: the way back)
LINE_GAP_SMOOTHING = 0.2  # how much of each new spacing of lines the adapter's estimate takes
CHORD_MIN = 1e-3  # [s] a timed group's speed on a piece just begun: its chord over this long
ARRIVAL_TOL = 2e-4  # [s] how far from when a move is aimed for the board may have it (else it is aimed again)
MAX_SLIP = 1.5  # periods: the most the plan's clock advances between two moves (later: the plan waits)
RUN_TICK = 0.001  # [s] the control loop's period while streaming (sends on time: regular changes of speed)
MAX_ASKED = 32  # questions awaiting their answers at most (a Q after each line: the board answers in order)
LATENCY_WINDOW = 10.0  # [s] the board's latency in answering: the least over this long
ANSWER_TOL = 0.003  # [s] an answer later than the board's latency and the link by more: the host held the bytes


SPEED_MAX = 65535  # [us/s] the largest S the adapter writes (the board's default speed: no limit)
# What VER answers on an SSC-32 (firmware-dependent: SSC32-V2.50USB, SSC32-1.06XE, SSC32-2.01GP):
# anything else on the port is not one, and nothing is sent to it
VERSION = re.compile(r"SSC-?32[-\w. ]{0,32}")


class _Query(NamedTuple):
    """A question written to the board whose answer is not read yet."""

    asked: float  # [s] when it was written (taken before the write)
    request: int  # [bytes] written
    size: int  # [bytes] of its answer
    sense: bool  # with the sensors' request after the QP
    lines: int  # the lines written before it: its answer says they all reached the board
    pulses: bool  # a QP of every channel (else a Q: asked only for that)


def _on_piece(
    p0: FloatArray, t0: FloatArray, p1: FloatArray, t1: FloatArray, t: FloatArray | float
) -> tuple[FloatArray, FloatArray]:
    """Per joint, on the linear piece from ``p0`` at ``t0`` to ``p1`` at ``t1``, held after:
    position and speed at ``t`` (each joint's times its own)."""
    span = t1 - t0
    on = (span > 0.0) & (t < t1)
    v = np.where(on, (p1 - p0) / np.where(span > 0.0, span, 1.0), 0.0)
    return np.where(on, p0 + v * np.maximum(t - t0, 0.0), p1), v


def _groups(M: FloatArray) -> list[list[int]]:
    """The actuators that must move as one group move (those that share a joint: a mirrored
    pair, a linkage), as lists of rows of ``M``, in order."""
    rows = list(range(M.shape[0]))
    group = rows[:]
    for j in range(M.shape[1]):
        linked = [r for r in rows if M[r, j]]
        for r in linked[1:]:
            old, new = group[r], group[linked[0]]
            group = [new if g == old else g for g in group]
    return [[r for r in rows if group[r] == g] for g in sorted(set(group), key=group.index)]


class SSC32Adapter(SerialAdapter):
    kind = "ssc32"
    splices = True  # a stream is followed through lines held on their way to the board: see "Deliveries"
    run_tick = RUN_TICK

    def __init__(
        self,
        session: zenoh.Session,
        robot: Robot,
        port: str,
        *,
        baud: int | None = None,
        prefix: str = "armd",
        state_hz: float = 50.0,
        timeout: float = 0.5,
        query_period: float = 0.5,
        state_dir: str | Path | None = None,
        lead: float = LEAD,
        serial_port: serial.SerialBase | None = None,
        calibration: str | Path | None = None,
    ) -> None:
        actuators_of(robot, Servo, "SSC-32")  # (an arm it cannot drive: refused before its calibration is read)
        robot = calibrated(robot, calibration, state_dir)  # (armd calibrate's centre pulses and directions)
        self.channels = [a.channel for a in actuators_of(robot, Servo, "SSC-32")]
        self.baud = int(baud or robot.controller.get("baud", 9600))  # type: ignore[call-overload]
        if self.baud <= 0:
            raise BadRequest(f"baud must be a positive number, got {self.baud}", field="baud")
        self.timeout = timeout  # [s] how long an answer may take
        self.query_period = query_period
        self.lead = lead
        self.state_file = Path(state_dir or state_dir_default()) / f"{robot.name}.ssc32.json"
        super().__init__(
            session,
            robot,
            port,
            baud=self.baud,
            timeout=timeout,
            write_timeout=timeout,
            prefix=prefix,
            state_hz=state_hz,
            check_period=0.02,
            serial_port=serial_port,
        )
        lim = robot.limits
        self._vlim, self._alim = lim.velocity, lim.acceleration
        self._vmax, self._amax = self._limits_for(self.lead + 0.02), lim.acceleration
        amap = robot.actuators  # [rad] per joint, half a microsecond of a servo that moves it (the most of any)
        self._half_pulse = np.array(
            [
                0.5 * max(a.resolution / m for a, m in zip(amap.actuators, amap.gentlest[:, j], strict=True) if m)
                for j in range(robot.nq)
            ]
        )
        # one command a group of servos (those that share a joint), each padded to a fixed width:
        # every group's carriage return reaches the board at the same point of every line
        self._groups = _groups(amap.M)
        # a group whose servos move more than one joint (a linkage) moves in a time T: its servos'
        # speeds are not in one ratio, and the board ends them together (a speed each would not be kept)
        self._timed = [len({int(j) for r in g for j in np.flatnonzero(amap.M[r])}) > 1 for g in self._groups]
        self._widths = [
            sum(len(f"#{self.channels[r]}P2500") for r in g)
            + (len("T65535") if timed else len(g) * len(f"S{SPEED_MAX}"))
            + 1
            for g, timed in zip(self._groups, self._timed, strict=True)
        ]
        self._cr_at = np.cumsum(self._widths)  # [bytes] where each group's command ends in a line
        group_of = {r: k for k, g in enumerate(self._groups) for r in g}
        self._joint_group = np.array([group_of[int(np.flatnonzero(amap.M[:, j])[0])] for j in range(robot.nq)])
        self._timed_joint = np.array(self._timed)[self._joint_group]
        self._timed_servo = np.array([self._timed[group_of[r]] for r in range(len(self.channels))])
        self._servo_joint = np.array([int(np.flatnonzero(amap.M[r])[0]) for r in range(len(self.channels))])
        # the board's motion, as the model has it: per joint, linear from _p0 at _since to _p1 at _until, then held
        now = time.monotonic()
        self._p0 = self._p1 = np.array(robot.neutral, dtype=float)
        self._since = self._until = np.full(robot.nq, now)
        self._t_line = now  # [s] when the last line's last command reached the board
        self._t_end = now  # [s] when the move in hand ends, as it was aimed (a span after _t_line)
        self._link_free = now  # [s] when the link has carried everything written so far
        self._pieces: collections.deque[tuple[FloatArray, FloatArray, FloatArray, FloatArray]] = collections.deque(
            maxlen=256
        )
        self._tau = 0.0  # [s] the plan's time the running move was aimed from
        self._rhythm = now  # [s] the earliest the next move of a trajectory should reach the board
        self._line_gap = 0.0  # [s] how far apart the lines of a trajectory have reached the board lately
        self._settled = True  # the board heads for the trajectory's end slowly enough to stop there
        self._tracking = False  # the lines are a tracking stream's (or its stop's)
        self._lateness = 0.0  # [s] how late the control loop has written moves lately (decaying)
        self._seen_at = now
        self._stride = 1
        self._queries: collections.deque[_Query] = collections.deque()  # written, their answers awaited in order
        self._polled = now  # [s] when the board's answers were last looked for
        self._lines = 0  # lines of the stream written so far
        # (lines, by when [s] at the latest, whether later than the link and the board's latency account for)
        self._delivered = (0, now, False)  # the lines the board's answers say have reached it
        self._latencies: collections.deque[tuple[float, float]] = collections.deque()  # [s] (answered, latency)
        # the latest lines: when each was aimed to reach the board [s], and the speeds before and after [rad/s]
        self._sent_lines: collections.OrderedDict[int, tuple[float, FloatArray, FloatArray, FloatArray]] = (
            collections.OrderedDict()
        )  # (and each line's piece's start [s], per joint: the piece it is in the model)
        self._held_lines: collections.deque[tuple[float, float]] = collections.deque()  # [s] (arrived, how late)
        self._quiet_since: float | None = None  # [s] an answer was overdue: the last byte that came late since
        self._fault_noted = False
        self._reply = b""
        self._next_query = now
        self._answered = self._faulted_at = -math.inf  # [s] the last QP answer; the last fault
        self._answer: FloatArray | None = None  # [us] the last QP answer
        self._asked = -math.inf  # [s] when the last answer was asked for
        self._suspect: FloatArray | None = None  # per servo, the side (+1, -1; 0: agreed) the last answer was off
        self._suspect_bounds: tuple[FloatArray, FloatArray] | None = None  # [us] its _offsets
        self._followed: np.ndarray | None = None  # the servos found off the model, followed by every answer
        self._bounds: tuple[FloatArray, FloatArray] | None = None  # [us] the board from the model, so far
        self._still: FloatArray | None = None  # [us] faulted: the answer the board has given since _same_since
        self._same_since = math.inf  # [s] faulted: when the first of the same answers was asked for
        self._dark = False  # a channel found without a pulse (a reset, a power cycle): nothing is sent until a restart
        try:
            self.version = self._identify()
        except ControllerFault:
            self.serial.close()
            raise
        log.info("%s on %s at %d baud: %s", robot.name, port, self.baud, self.version)
        self._sensor_pubs = {
            s.name: session.declare_publisher(f"{self._base}/sensors/{s.name}")
            for s in robot.sensors.values()
            if s.pin is not None and s.curve is not None
        }
        self.sensors = WiredSensors(robot, self.id, lambda name, payload: self._sensor_pubs[name].put(payload))
        self._start_up()
        self._start_sensors()
        self.activate()

    # -- start-up -------------------------------------------------------------------------

    def _identify(self) -> str:
        """What ``VER`` answers, if it is an SSC-32's (:data:`VERSION`); :class:`ControllerFault` if not."""
        raw = self._ask(b"VER\r", until=b"\r", size=64)
        if not raw.strip():
            raise ControllerFault(f"no SSC-32 answers on {self.port} at {self.baud} baud (VER got no reply)")
        version = raw.decode("ascii", errors="replace").strip()
        if not VERSION.fullmatch(version):
            raise ControllerFault(
                f"what answers on {self.port} is not an SSC-32: VER got {raw[:64]!r} (an SSC-32 answers like "
                "'SSC32-V2.50USB'); nothing was sent to it"
            )
        return version

    def _start_up(self) -> None:
        """Adopt a board that outputs pulses; else command the pose the arm was left at (a jump)."""
        deadline = time.monotonic() + 5.0
        while self._ask(b"Q\r") == b"+" and time.monotonic() < deadline:  # a move in progress: let it end
            time.sleep(0.02)
        pulses = self._query_pulses()
        amap = self.robot.actuators
        if all(pulses > 0):
            # QP answers in 10 us (the pulse / 10, truncated): the pose kept at the last stop, if
            # the board still outputs it, is exact; else the middle of what QP allows
            kept, _ = self._left_at()
            exact = amap.command_values(kept)
            try:
                q = (
                    kept
                    if np.all((exact >= pulses - 0.5) & (exact < pulses + 10.5))
                    else amap.joints_from_commands(pulses + 5.0, tol=np.inf)
                )
            except ActuatorMapError as e:  # (a linkage's servo where the linkage cannot be)
                self.serial.close()
                raise ControllerFault(
                    f"the SSC-32 on {self.port} holds {self.robot.name} where no joint vector is ({e.message}): "
                    "move the arm inside its limits by hand (power off) first"
                ) from None
            lim = self.robot.limits
            if not lim.contains(q, tol=0.02):
                bad = lim.violations(q, tol=0.02)
                self.serial.close()
                raise ControllerFault(
                    f"the SSC-32 on {self.port} holds {self.robot.name} outside its limits "
                    f"({bad[0].message}): move the arm inside them by hand (power off) first"
                )
            q = lim.clip(q)
            log.info(
                "%s: the board outputs pulses already (%s us): adopted as it is",
                self.robot.name,
                " ".join(str(int(p)) for p in pulses),
            )
            self._hold_at(q)
            return
        q, where = self._left_at()
        log.warning(
            "%s: the SSC-32 outputs no pulses (just powered): a hobby servo's position is unknown until "
            "its first pulse, so the arm JUMPS to %s at the servos' own speed now",
            self.robot.name,
            where,
        )
        self._jump(amap.commands(q))
        if not np.all(self._query_pulses() > 0):  # (asked after the move: answered once the board has it)
            self.serial.close()
            raise ControllerFault(f"the SSC-32 on {self.port} did not take its first command")
        self._hold_at(q)

    def _start_sensors(self) -> None:
        """The wired pins made analog (their first read is not valid: discarded), the scanners
        sent to their sweeps' start, the first read due once they can have got there."""
        if not self.sensors:
            return
        request, n = self.sensors.request, self.sensors.reply_size
        if len(self._ask(request, size=n)) != n:
            self.serial.close()
            raise ControllerFault(f"the SSC-32 on {self.port} does not answer {request.decode().strip()}")
        line = self.sensors.aim()
        if line:
            self._write(line)
        spans = [s.servo.us_per_rad * (s.sweep[1] - s.sweep[0]) for s in self.sensors.sensors if s.servo and s.sweep]
        travel = max(spans, default=0.0) / SCAN_SPEED  # [s] from anywhere in a sweep to its start
        self.sensors.ready_at = max(time.monotonic(), self._link_free) + travel + self.sensors.settle_time()

    def _left_at(self) -> tuple[FloatArray, str]:
        """The pose the arm was last commanded to (kept in ``state_file``), else neutral."""
        try:
            saved = json.loads(self.state_file.read_text())
            q = self.robot.joint_vector(saved["position"])
            if self.robot.limits.contains(q):
                return q, f"the pose it was left at ({self.state_file})"
            log.warning("%s: %s is outside the limits: ignored", self.robot.name, self.state_file)
        except FileNotFoundError:
            pass
        except (ValueError, KeyError, TypeError, OSError) as e:
            log.warning("%s: cannot read %s (%s): ignored", self.robot.name, self.state_file, e)
        return np.array(self.robot.neutral, dtype=float), "the neutral pose"

    def _save_pose(self) -> None:
        q = self._p1
        try:
            self.state_file.parent.mkdir(parents=True, exist_ok=True)
            tmp = self.state_file.with_suffix(".tmp")
            tmp.write_text(
                json.dumps(
                    {
                        "robot": self.robot.name,
                        "position": q.tolist(),
                        "pulses": self.robot.actuators.commands(q).tolist(),
                        "time": time.time(),
                    }
                )
            )
            tmp.replace(self.state_file)
        except OSError as e:
            log.warning("%s: cannot keep the pose in %s: %s", self.robot.name, self.state_file, e)

    # -- the wire ------------------------------------------------------------------------

    def _write(self, data: bytes) -> None:
        if self.gone is not None:
            raise ControllerFault(self.gone)
        try:
            with self._io:
                self.serial.write(data)
        except serial.SerialTimeoutException as e:
            # pyserial starts the write's clock when called and looks at it after writing: a process
            # stopped meanwhile (SIGSTOP, a suspended VM) gets a timeout for a write that went out.
            # Nothing left in the output queue: written, not a stuck link
            if not self._sent_all():
                raise ControllerFault(f"SSC-32 on {self.port}: write failed: {e}") from None
            log.info("%s: a write said it timed out with nothing left to send (this process was held)", self.robot.name)
        except PORT_ERRORS as e:
            raise self.port_gone(e) from None
        now = time.monotonic()
        self._link_free = max(self._link_free, now) + len(data) * 10.0 / self.baud

    def _sent_all(self) -> bool:
        """Whether the port's output queue is empty (False if the port cannot say)."""
        try:
            return int(self.serial.out_waiting) == 0
        except (serial.SerialException, OSError, AttributeError, NotImplementedError, TypeError):
            return False

    def _ask(self, request: bytes, *, until: bytes | None = None, size: int = 1) -> bytes:
        """A blocking question (start-up, and a port found again: the control loop never waits
        for the board otherwise); with ``until``, at most ``size`` bytes up to it."""
        if self.gone is not None:
            raise ControllerFault(self.gone)
        try:
            with self._io:
                self.serial.reset_input_buffer()
                asked = time.monotonic()
                self.serial.write(request)
                got = bytes(self.serial.read_until(until, size) if until is not None else self.serial.read(size))
            if len(got) == size or (until is not None and got.endswith(until)):  # (the board's latency, measured)
                self._latency(time.monotonic(), asked, len(request), len(got))
            return got
        except serial.SerialTimeoutException as e:
            raise ControllerFault(f"SSC-32 on {self.port}: {e}") from None
        except PORT_ERRORS as e:
            raise self.port_gone(e) from None

    def _qp_request(self) -> bytes:
        return ("".join(f"QP{ch}" for ch in self.channels) + "\r").encode()

    def _query_pulses(self) -> FloatArray:
        reply = self._ask(self._qp_request(), size=len(self.channels))
        if len(reply) != len(self.channels):
            raise ControllerFault(f"SSC-32 on {self.port} does not answer QP ({reply!r})")
        return np.array([10.0 * b for b in reply])

    def _jump(self, pulses: np.ndarray) -> None:
        """A group move of every channel with no speed and no time: ``#<ch>P<pw>...\\r``, a jump
        (the start-up's first command: the servos' positions are unknown until then)."""
        line = "".join(f"#{ch}P{int(pw)}" for ch, pw in zip(self.channels, pulses.tolist(), strict=True))
        self._write((line + "\r").encode())

    def _speed_line(self, pulses: np.ndarray, speeds: np.ndarray, ms: int) -> bytes:
        """The stream's line: per group of servos, ``#<ch>P<pw>S<spd>...\\r`` (a linkage's:
        ``#<ch>P<pw>...T<ms>\\r``), each padded in front with spaces (which the board ignores) to
        its fixed width."""
        out = []
        for g, width, timed in zip(self._groups, self._widths, self._timed, strict=True):
            if timed:
                text = "".join(f"#{self.channels[r]}P{int(pulses[r])}" for r in g) + f"T{ms}\r"
            else:
                text = "".join(f"#{self.channels[r]}P{int(pulses[r])}S{int(speeds[r])}" for r in g) + "\r"
            out.append(text.rjust(width))
        return "".join(out).encode()

    def _line_bytes(self) -> int:
        """The bytes of one line of the stream (every group of servos, at its fixed width)."""
        return int(self._cr_at[-1])

    # -- the model of the board ------------------------------------------------------------

    def _hold_at(self, q: FloatArray) -> None:
        """The model: the board holds ``q`` from now on (what came before is forgotten)."""
        now = time.monotonic()
        self._followed = self._bounds = None
        self._p0, self._p1 = q.copy(), q.copy()
        self._since, self._until = np.full(self.robot.nq, now), np.full(self.robot.nq, now)
        self._t_line = self._t_end = now
        self._pieces.clear()
        self._pieces.append((self._p0, self._since, self._p1, self._until))

    def _at(self, t: float | FloatArray) -> tuple[FloatArray, FloatArray]:
        """Where the board is at time ``t`` [s] (per joint, if an array), and how fast it moves
        [rad/s]: each joint on the last piece it had started by then (:meth:`_on`)."""
        p, v = self._on(self._p0, self._since, self._p1, self._until, t)
        early = t < self._since  # (a joint whose command of the last line has not arrived by then)
        if np.any(early) and len(self._pieces) > 1:
            p0, t0, p1, t1 = self._pieces[-2]
            pe, ve = self._on(p0, t0, p1, t1, t)
            p, v = np.where(early, pe, p), np.where(early, ve, v)
        return p, v

    def _on(
        self, p0: FloatArray, t0: FloatArray, p1: FloatArray, t1: FloatArray, t: float | FloatArray
    ) -> tuple[FloatArray, FloatArray]:
        """Per joint, where the board has it at ``t`` on the piece from ``p0`` at ``t0`` to ``p1``
        at ``t1`` (held after), and its speed. The board moves each servo linearly in pulses: a
        joint behind a linkage (a timed group's: desk4's minor) then moves along a curve, and
        its speed is its chord since the piece began (what the board's motion shows between
        two lines; its speed at the start, for a piece just begun), not the piece's average."""
        p, v = _on_piece(p0, t0, p1, t1, t)
        if not self._timed_joint.any():
            return p, v
        amap = self.robot.actuators
        tt = np.broadcast_to(np.asarray(t, dtype=float), p0.shape)
        span = t1 - t0

        def board(at: FloatArray) -> FloatArray:
            s = np.where(span > 0.0, np.clip((at - t0) / np.where(span > 0.0, span, 1.0), 0.0, 1.0), 1.0)
            c0, c1 = amap.command_values(p0), amap.command_values(p1)
            return amap.joints_from_commands(c0 + s[self._servo_joint] * (c1 - c0), tol=np.inf)

        h = np.maximum(np.minimum(tt, t1) - t0, CHORD_MIN)
        exact = board(tt)
        chord = (board(t0 + h) - p0) / h
        moving = (span > 0.0) & (tt < t1)
        timed = self._timed_joint
        return np.where(timed, exact, p), np.where(timed, np.where(moving, chord, 0.0), v)

    def _was_at(self, t: float) -> FloatArray:
        """Where the board was at time ``t`` [s], which may be a few pieces ago."""
        out = np.full(self.robot.nq, np.nan)
        for p0, t0, p1, t1 in reversed(self._pieces):
            here = np.isnan(out) & (t >= t0)
            if np.any(here):
                out = np.where(here, _on_piece(p0, t0, p1, t1, t)[0], out)
            if not np.any(np.isnan(out)):
                return out
        first = self._pieces[0][0] if self._pieces else self._p0
        return np.where(np.isnan(out), first, out)

    def _limits_for(self, span: float) -> FloatArray:
        """The joints' velocity limits a line of ``span`` [s] aims within.

        The board moves a servo linearly in pulses; a joint behind a linkage (desk4's minor) then
        moves along a curve, its speed changing along the piece (``q'' = -(a''/a') q'^2`` along
        the driven joint): its average is kept to ``vmax / (1 + k vmax span / 2)`` (``k``: the
        linkage's largest ``|a''| / |a'|``) so that the piece's fastest is within ``vmax``. Other
        joints: their limits."""
        v = self._vlim.copy()
        for link in self.robot.actuators.linkages.values():
            j = link.driven
            k = float(link.curvature[j, j]) / float(link.gentlest[j])
            v[j] = self._vlim[j] / (1.0 + k * self._vlim[j] * span / 2.0)
        return v

    def _stream(self, cmd: Command, first: bool, period: float, lead: float) -> None:
        """Send the next line of ``cmd`` (:meth:`_aim`), timed for when the board will have each
        of its commands: if this thread was held up meanwhile, aimed again.

        Each servo gets a speed ``S`` and a target a span ahead: the board moves it at that
        speed from wherever it is when the command arrives, so that a command that reaches it a
        little late changes its speed a little late, by no more than was aimed (a move timed by
        ``T`` would instead cover what is left of its way in ``T``: faster or slower by the
        distance lost)."""
        ms = max(1, round((lead + period) * 1000.0))  # [ms] a timed group's T
        span = ms / 1000.0  # [s] the next line replaces this one a period in: a lead to spare
        if self.robot.actuators.linkages:
            self._vmax = self._limits_for(span)
        byte = 10.0 / self.baud
        amap = self.robot.actuators
        start = max(time.monotonic(), self._link_free)
        for _ in range(3):  # everything computed before the line's time is checked, then written at once
            arrivals = start + self._cr_at * byte  # [s] per group: when its carriage return arrives
            t0 = arrivals[self._joint_group]
            x, v, tau, final = self._aim(cmd, t0, float(arrivals[-1]), first, period, span)
            p0 = self._at(t0)[0]
            here = amap.command_values(p0)  # [us] each servo where its command finds it
            want = amap.command_values(x)  # [us] where its speed leads in the span
            rate = np.abs(amap.command_rates(x, v))  # [us/s] as aimed
            speeds = np.clip(np.rint(rate), 1, SPEED_MAX)  # (S0 would be no limit: a jump)
            pulses = amap.commands(x)
            if not final:  # a target rounded away from the servo: not reached before the span is over
                away = np.where(want > here, np.ceil(want - 1e-9), np.floor(want + 1e-9)).astype(np.int64)
                away = np.where(self._timed_servo, pulses, away)  # (a timed group's: as near as may be)
                if self._within(amap.joints_from_commands(away, tol=np.inf)):
                    pulses = away
            line = self._speed_line(pulses, speeds, ms)
            actual = max(time.monotonic(), self._link_free)
            if abs(actual - start) <= ARRIVAL_TOL:
                break
            start = actual + ARRIVAL_TOL  # (the time to aim again)
        self._write(line)
        self._lines += 1
        # held up between the check and the write (preempted, stopped): the board has the line
        # later, no sooner than the write returned (as _write counts it); the model says so, and
        # the next line keeps a period from then
        sent = self._link_free - len(line) * byte
        if sent > start + ARRIVAL_TOL:
            log.debug("%s: a line went out %.1f ms later than aimed", self.robot.name, (sent - start) * 1e3)
            arrivals = sent + self._cr_at * byte
            t0 = arrivals[self._joint_group]
            p0 = self._at(t0)[0]
            here = amap.command_values(p0)
        way = np.abs(pulses - here)
        # the board: each group starts and ends together, taking as long as its slowest servo needs
        lasts = np.array(
            [
                ms / 1000.0 if timed else max(float(way[r] / speeds[r]) for r in g)
                for g, timed in zip(self._groups, self._timed, strict=True)
            ]
        )
        target = amap.joints_from_commands(pulses, tol=np.inf)
        before = self._at(t0)[1]  # [rad/s] the speed this line changes
        self._p0, self._since, self._p1, self._until = p0, t0, target, t0 + lasts[self._joint_group]
        self._pieces.append((self._p0, self._since, self._p1, self._until))
        self._sent_lines[self._lines] = (float(arrivals[-1]), before, self._at(t0)[1], t0)
        while len(self._sent_lines) > MAX_ASKED:
            self._sent_lines.popitem(last=False)
        self._tau = tau
        if not first and float(arrivals[-1]) - self._t_line < 4 * period:  # (a trajectory's lines, not a pause)
            gap = float(arrivals[-1]) - self._t_line
            self._line_gap += LINE_GAP_SMOOTHING * (gap - self._line_gap)
        self._t_line, self._t_end = float(arrivals[-1]), float(arrivals[-1]) + span
        self._rhythm = self._t_line + period  # the next line arrives no sooner: no piece shorter than a period
        self._settled = final

    def _aim(
        self, cmd: Command, arrival: FloatArray, line: float, first: bool, period: float, span: float
    ) -> tuple[FloatArray, FloatArray, float, bool]:
        """The targets [rad] of a line whose commands reach the board at ``arrival`` [s, per
        joint] (the line's last one at ``line``), each a speed [rad/s] held for ``span`` [s];
        the speeds; the plan's time it was aimed from [s]; and whether it is the last one (it
        ends at the trajectory's end, slowly enough to stop there).

        Each joint's speed is the plan's average over the move ahead, from where the board is
        (so a board ahead of or behind the plan converges on it), within one period's change
        of speed of the move in hand (the acceleration limit, over the time since the
        previous change) and within the velocity limit, slowed where it could not stop inside
        the position limits (:meth:`_brakeable`); the target is where that speed leads in
        ``span``, or nearer, where the board could still stop (:meth:`_target`). The plan's
        clock advances with
        the board's, by at most ``MAX_SLIP`` periods a line: a late line re-times the rest
        of the trajectory, slower, from where the board is.
        """
        p0, v0 = self._at(arrival)
        tau = 0.0 if first else self._tau + min(line - self._t_line, MAX_SLIP * period)
        # [rad/s] how far a speed may come out from what is aimed: a whole microsecond a second; in a
        # timed group, a whole-microsecond target over the span and a start up to ARRIVAL_TOL from
        # when it is aimed for (the board a little farther on, or not as far)
        rounding = np.where(self._timed_joint, (self._half_pulse + np.abs(v0) * ARRIVAL_TOL) / span, self._half_pulse)
        # each joint's last change of speed: its last command's arrival, or its target reached (a stop);
        # the time since, less ARRIVAL_TOL (a line may reach the board that much sooner than aimed:
        # once 1.0014x the limit by the adapter's own model, in a busy CI run)
        changed = np.where(self._until <= arrival, self._until, self._since)
        since = np.maximum(arrival - changed - ARRIVAL_TOL, 1e-3)
        # the last line held on its way (a busy host holds bytes and lets them go together): this one may
        # follow it as soon as the link carries it, or soon after when the board has answered since
        held = self._last_line_held(time.monotonic()) if self._tracking else False
        if held or held is None:
            lines, by, _ = self._delivered
            line_time = self._line_bytes() * 10.0 / self.baud
            gap = np.maximum(arrival - by - ARRIVAL_TOL, line_time) if lines >= self._lines else line_time
            since = np.minimum(since, gap)
        c = np.maximum(self._amax * np.minimum(period, since) - rounding, 0.0)
        goal = self.robot.actuators.joints_from_commands(cmd.commands[-1], tol=np.inf)  # (as the board has it)
        if cmd.kind == "stop":  # a joint already past the stop's end stays where it is: a stop never reverses
            way = cmd.position[-1] - cmd.position[0]
            goal = np.where((goal - p0) * way < 0.0, p0, goal)
        if tau + span >= cmd.duration:  # the plan ends within this move: the goal, once the board may stop there
            d = goal - p0
            if np.all(np.abs(d) <= self._amax * period * span * (1 + 1e-9)) and np.all(
                np.abs(d / span - v0) <= c * (1 + 1e-9)
            ):
                return goal.copy(), d / span, tau, True
        # each joint aims where the plan is a span after its own command arrives
        shift = arrival - line
        ahead = np.empty(self.robot.nq)
        for s in np.unique(shift):
            at = shift == s
            ahead[at] = cmd.sample_at(tau + float(s) + span)[0][at]
        v = np.clip(self._stops_at_end(cmd, tau, p0, (ahead - p0) / span, goal, c, period), v0 - c, v0 + c)
        if cmd.kind == "stop":  # a stop never reverses a joint
            v = np.where(v * v0 < 0.0, 0.0, v)
        v = np.clip(v, rounding - self._vmax, self._vmax - rounding)
        v = self._brakeable(p0, v, v0, c, period)
        x = self._inside(p0, self._beyond(p0, v, v0, self._target(p0, v, span, period)))
        # a timed group's speed is its way over T; a servo with its own speed S keeps it, whatever its target
        return x, np.where(self._timed_joint, (x - p0) / span, v), tau, False

    def _stops_at_end(
        self, cmd: Command, tau: float, p0: FloatArray, v: FloatArray, goal: FloatArray, c: FloatArray, period: float
    ) -> FloatArray:
        """``v``, or slower where a joint heading for the trajectory's end (its plan from
        ``tau`` on goes only that way) would not stop there: at that speed until the next line,
        then slower by ``c`` [rad/s] a line (the most a line may change it), the lines as far
        apart as they have come lately. A board behind the plan (a joint behind a linkage aims
        within a lower speed than its limit, :meth:`_limits_for`) catches up only as far as it
        can still stop at the end; without this it came in at speed as the plan slowed, and ran
        0.2 rad past desk4's goal, onto the minor arm's limit, braking there at twice its
        acceleration limit."""
        d = goal - p0
        k = min(int(tau * cmd.rate_hz), len(cmd.times) - 1)
        rest = np.diff(cmd.position[k:], axis=0) * np.sign(d)
        one_way = np.all(rest >= -1e-12, axis=0) if len(rest) else np.ones(len(d), dtype=bool)
        g = max(period, self._line_gap)
        a = np.maximum(c, 1e-9) / g  # [rad/s^2] the braking the lines can give
        # the way from speed u: u g (this line), then u g (u/c + 1)/2 over the lines that brake it
        reach = a * (np.sqrt((1.5 * g) ** 2 + 2.0 * np.abs(d) / a) - 1.5 * g)
        return np.where(one_way & (v * d > 0.0), np.sign(v) * np.minimum(np.abs(v), reach), v)

    def _stop_point(self, x: FloatArray, v: FloatArray, period: float) -> FloatArray:
        """Where a joint at ``x`` moving at ``v`` [rad/s] stops at the latest: a period more at
        that speed (until the next line), then braking at its acceleration limit."""
        return x + v * period + v * np.abs(v) / (2.0 * self._amax)

    def _brakeable(self, p0: FloatArray, v: FloatArray, v0: FloatArray, c: FloatArray, period: float) -> FloatArray:
        """``v``, or as little slower as keeps every joint able to stop inside every position
        limit, braking by its acceleration limit from the nearest target it may be sent (a
        period and the base lead on): the board is never on a motion that only a harder stop
        than the limits allow could end inside them. The most it slows is ``c`` toward rest, the acceleration budget; a
        state the limits already forbid that way is left to :meth:`_inside` (the position
        limits before the acceleration's)."""

        def stops_inside(u: FloatArray) -> bool:
            return self._within(self._stop_point(p0 + u * (period + self.lead), u, period))

        if stops_inside(v):
            return v
        toward_rest = np.where(v0 > 0.0, np.maximum(v0 - c, 0.0), np.minimum(v0 + c, 0.0))
        brake = np.where(np.abs(v) <= np.abs(toward_rest), v, toward_rest)
        if not stops_inside(brake):
            return brake
        lo, hi = 0.0, 1.0  # the fraction of the way from braking to v
        for _ in range(20):
            mid = (lo + hi) / 2
            lo, hi = (mid, hi) if stops_inside(brake + mid * (v - brake)) else (lo, mid)
        return brake + lo * (v - brake)

    def _target(self, p0: FloatArray, v: FloatArray, span: float, period: float) -> FloatArray:
        """Where a servo moving at ``v`` is sent: a span on, or nearer (a period and the base
        lead on at the least: a line a little late still finds it moving) as far as it could
        still stop from there inside the limits (:meth:`_stop_point`). A board whose adapter
        stalls runs on to its targets and stops there; running on less than a span, it is then
        still on a motion the limits allow. A timed group's target is its speed's (a span on:
        its speed is its way over T, and its target, for a joint behind a linkage, where its
        pulses run on to in ``span`` once they bring the joint ``v`` a period on: the board draws
        that period's chord at ``v`` exactly, the speed that was aimed, curve or not)."""
        full = p0 + v * span
        if self._timed_joint.any():
            amap = self.robot.actuators
            c0 = amap.command_values(p0)
            c1 = amap.command_values(np.where(self._timed_joint, p0 + v * period, p0))
            try:
                run = amap.joints_from_commands(
                    np.where(self._timed_servo, c0 + (c1 - c0) * (span / period), c0), tol=np.inf
                )
                full = np.where(self._timed_joint, run, full)
            except (ActuatorMapError, BadRequest):  # (pulses the linkage cannot take: the joints' straight way)
                pass
        if self._within(self._stop_point(full, v, period)):
            return full
        near = np.where(self._timed_joint, full, p0 + v * min(period + self.lead, span))
        lo, hi = 0.0, 1.0
        for _ in range(20):
            mid = (lo + hi) / 2
            x = near + mid * (full - near)
            lo, hi = (mid, hi) if self._within(self._stop_point(x, v, period)) else (lo, mid)
        return near + lo * (full - near)

    def _unsure(self, v: FloatArray, v0: FloatArray) -> FloatArray:
        """How far [rad] the board may be from the model when a line that changes the speeds
        from ``v0`` to ``v`` reaches it: each line on its way (no answer after it yet) may reach
        it late, the speeds before it kept that much longer (by how long it has been on its way,
        or as late as the latest of the last ``LATENCY_WINDOW``, the longer), and so may this one."""
        now = time.monotonic()
        while self._held_lines and self._held_lines[0][0] < now - LATENCY_WINDOW:
            self._held_lines.popleft()
        late = max((held for _, held in self._held_lines), default=0.0)  # [s] the latest line lately
        off = np.abs(v - v0) * late
        for aimed, before, after, _ in self._sent_lines.values():
            off += np.abs(before - after) * max(now - aimed, late)
        return off

    def _beyond(self, p0: FloatArray, v: FloatArray, v0: FloatArray, x: FloatArray) -> FloatArray:
        """``x``, or farther along ``v`` where the board, off the model by up to :meth:`_unsure`,
        may be past it: a servo sent to a target behind it goes back (near a joint's turn, where
        targets are near)."""
        margin = 2.0 * (self._unsure(v, v0) + self._half_pulse)  # (twice: the lines on their way may be held on)
        short = self._tracking & ~self._timed_joint & (v != 0.0) & (np.abs(x - p0) < margin)
        return np.where(short, p0 + np.sign(v) * margin, x)

    def _inside(self, p0: FloatArray, x: FloatArray) -> FloatArray:
        """``x`` brought back toward ``p0``, along the way between them, as far as it must be to keep
        every position limit (the box, the coupled limits and the servos' ranges)."""
        if self._within(x):
            return x
        if not self._within(p0):
            return self.robot.limits.clip(p0)
        lo, hi = 0.0, 1.0
        for _ in range(30):
            mid = (lo + hi) / 2
            lo, hi = (mid, hi) if self._within(p0 + mid * (x - p0)) else (lo, mid)
        return p0 + lo * (x - p0)

    def _within(self, q: FloatArray) -> bool:
        if not self.robot.limits.contains(q, tol=0.0):
            return False
        try:
            self.robot.actuators.commands(q)
        except BadRequest:
            return False
        return True

    # -- the Adapter hooks ----------------------------------------------------------------------

    def admit(self, cmd: Command) -> None:
        """Refuse, before any pulse is sent, a trajectory the link cannot carry."""
        self.stride_for(cmd)

    def stride_for(self, cmd: Command) -> int:
        """Every how many samples a line is sent, so the stream fits ``LINK_SHARE`` of the link."""
        per_second = LINK_SHARE * self.baud / 10.0 / self._line_bytes()  # lines the link carries [1/s]
        stride = max(1, math.ceil(cmd.rate_hz / per_second - 1e-9))
        if stride / cmd.rate_hz > MAX_PERIOD + 1e-9 and len(cmd.times) > 1:
            raise BadRequest(
                f"at {self.baud} baud the link carries {per_second:.1f} lines of "
                f"{len(self.channels)} servos a second: samples {stride / cmd.rate_hz * 1000:.0f} ms "
                f"apart, more than {MAX_PERIOD * 1000:.0f} ms; raise the SSC-32's baud rate "
                f"(--baud and the board's)",
                field="rate_hz",
                baud=self.baud,
            )
        return stride

    def execute(self, cmd: Command, t: float, first: bool) -> bool:
        if self.gone is not None:  # (no line can go: the board holds where its last move ends)
            raise ControllerFault(self.gone)
        self._poll_reply()
        if self._dark:  # (a board without pulses: the first line to a channel jumps its servo; nothing is sent)
            return True
        now = time.monotonic()
        if first:
            self._stride = self.stride_for(cmd)
            self._settled = cmd.kind == "stop" and self._resting_at(cmd, now)  # (a stop at rest: nothing to send)
            if cmd.kind != "stop":
                self._tracking = cmd.track is not None
        period = self._stride / cmd.rate_hz
        # the lead grows with how late this loop has run lately (a busy machine), up to MAX_LEAD
        self._lateness *= LATENESS_DECAY ** max(now - self._seen_at, 0.0)
        self._lateness = max(self._lateness, self._held_for(now))  # (the board's answers late: bytes held)
        self._seen_at = now
        lead = min(max(self.lead, period, 2.0 * self._lateness), max(MAX_LEAD, period))
        if self._tracking:  # a stream's, and a stop's of one: lines held on their way still find the board moving
            lead = max(MAX_LEAD, period)
        elif cmd.kind == "stop":  # a stop of a move keeps its lead short: stalled in a stop, the board holds anyway
            lead = max(self.lead, period)
        link = max(self._link_free - now, 0.0) + self._line_bytes() * 10.0 / self.baud  # until the board has it
        due = self._rhythm - link  # when the next move should be written: a period after this one
        if not self._settled and (first or now >= due):
            if not first:
                self._lateness = max(self._lateness, now - due)
                if now + link > self._t_end:  # the board got there first, and stopped
                    self._stopped_late(cmd, now + link - self._t_end)
            self._stream(cmd, first, period, lead)
            self._ask_delivered(time.monotonic())
        return self._settled and now >= float(np.max(self._until))

    def _resting_at(self, cmd: Command, now: float) -> bool:
        """Whether the board, as the model has it, rests where ``cmd`` ends (within a
        microsecond of every servo: a stop planned from rest, its pulses rounded). A line to
        where it rests would move nothing on a board that is there; on one that is not (a
        fault: someone else moved a servo) it would creep there at a few us/s: none is sent."""
        if now < float(np.max(self._until)):
            return False
        goal = self.robot.actuators.joints_from_commands(cmd.commands[-1], tol=np.inf)
        return bool(np.all(np.abs(goal - self._p1) <= 2.0 * self._half_pulse))

    def _stopped_late(self, cmd: Command, late: float) -> None:
        """Said when the control loop ran so late (a stalled process) that the board finished its
        move and held: a stop at the speed it had, which no command of the SSC-32 can soften."""
        v = float(np.max(np.abs(self._p1 - self._p0) / np.maximum(self._until - self._since, 1e-6) / self._vmax))
        log.warning(
            "%s: the adapter ran %.0f ms late: the board finished its move and held (from %.0f%% of a "
            "velocity limit); resuming from rest",
            self.robot.name,
            late * 1000,
            100 * v,
        )
        self.event("late", id=cmd.id, late=late, speed_ratio=v)

    def spliced(self, before: Command, cmd: Command) -> None:
        """A stream's next trajectory takes over: the plan's clock (``_tau``, which slips with
        the board's) goes on in its time, and lines go on (the last one may have been final)."""
        self._tau -= cmd.at
        self._settled = False

    def finished(self, cmd: Command) -> None:
        self._save_pose()

    def hold(self) -> None:
        """Stop sending: the board completes the move in hand (at most the lead and a period) and
        holds there, a stop at the speed it had; the model already runs on with it. The fallback
        where no stop can be streamed: on a fault a stop streams through :meth:`execute`, which
        needs no fault-free state (answers that come meanwhile are kept for the recovery)."""
        return None

    def measure(self) -> JointState:
        p, v = self._at(time.monotonic())
        return JointState(p, v, np.zeros(self.robot.nq))

    def check(self) -> None:
        """The control loop's look at the board, never waiting: read a QP answer if it came,
        fault if it is overdue, ask again when it is time (after an overdue answer, once the link
        has been quiet for ``QUIET``: its late bytes must not be taken for the next answer).

        An answer off the model (:meth:`_mismatch`) is asked again at once, and only a second one
        in a row, with a servo off the same way, is a fault (:meth:`_poll_reply`). Faulted, the
        board is asked every ``FAULT_QUERY_PERIOD``, and recovered (:meth:`_recover`) by an answer
        that agrees with the model, or once it stands still elsewhere: from where it is then.

        A port that vanished (:meth:`port_gone`) is opened again with a back-off; found again,
        ``VER`` must answer like an SSC-32, and the board is then asked as after any fault."""
        if self.gone is not None:
            self._find_again()
        self._poll_reply()
        now = time.monotonic()
        if self.fault and not self._fault_noted:  # (whatever raised it: recovery needs an answer since)
            self._faulted_at = max(self._faulted_at, now)
            self._fault_noted = True
            self._suspect, self._still, self._same_since = None, None, math.inf
        elif not self.fault:
            self._fault_noted = False
        query = self._queries[0] if self._queries else None
        overdue = query is not None and now - query.asked > self.timeout + query.size * 10.0 / self.baud
        if overdue:
            self._queries.clear()
            self._reply = b""
            self._quiet_since = now
            self._suspect = None
        reason = self.fault
        if self.fault:
            if self._answered > self._faulted_at:  # (each answer since the fault looked at once)
                self._faulted_at = self._answered
                reason = self._recover()
                if reason is None:
                    return
        elif overdue:
            self._faulted_at = now
            asked = "QP" if query is not None and query.pulses else "Q"
            raise ControllerFault(f"SSC-32 on {self.port} does not answer ({asked} got no reply in {self.timeout} s)")
        asking = any(q.pulses for q in self._queries)  # (a QP at a time)
        if (self.fault or self._followed is not None) and not asking:  # (asked often)
            self._next_query = min(self._next_query, self._asked + self._often())
        qp_due = now >= self._next_query
        sense_due = bool(self.sensors) and not self.fault and now >= self.sensors.ready_at
        if not asking and (qp_due or sense_due) and self._quiet(now):
            self._ask_board(now, sense_due)
        if reason is not None:
            raise ControllerFault(reason)

    def _find_again(self) -> None:
        """The vanished port, opened again when its back-off allows, and ``VER`` answered like
        an SSC-32; :class:`ControllerFault` (why not) until then."""
        if not self.reopen(self._identify):
            raise ControllerFault(str(self.gone))
        now = time.monotonic()
        log.info("%s: an SSC-32 answers on %s again: asked where the board is", self.robot.name, self.port)
        self._reply, self._quiet_since, self._suspect = b"", None, None
        self._queries.clear()
        self._faulted_at = self._next_query = now  # (the recovery needs an answer asked from now)

    def _often(self) -> float:
        """How often [s] the board is asked while faulted, or while servos found off the model
        are followed: every ``FAULT_QUERY_PERIOD``, or as often as the link's share left to the
        checks carries a ``QP`` and its answer (a slow link)."""
        size = len(self._qp_request()) + len(self.channels)  # [bytes] there and back
        return max(FAULT_QUERY_PERIOD, size * 10.0 / self.baud / (1.0 - LINK_SHARE))

    def _ask_board(self, now: float, sense: bool) -> None:
        """Write a ``QP`` of every channel (and, with ``sense``, the sensors' request: one write,
        the board's answers in order, docs: ssc32_sensors); its answer is read by later passes."""
        request = self._qp_request() + (self.sensors.request if sense else b"")
        size = len(self.channels) + (self.sensors.reply_size if sense else 0)
        self._queries.append(self._put_question(now, request, size, sense, pulses=True))
        self._next_query = now + self.query_period

    def _ask_delivered(self, now: float) -> None:
        """Write a ``Q`` after a line (two bytes; the board answers one, ``+`` or ``.``): its
        answer says that every line written before it has reached the board, and by when at
        the latest (:meth:`_reached`), over which :meth:`_aim` budgets the next change of speed."""
        if len(self._queries) >= MAX_ASKED or not self._quiet(now):
            return
        self._queries.append(self._put_question(now, b"Q\r", 1, False, pulses=False))

    def _put_question(self, now: float, request: bytes, size: int, sense: bool, pulses: bool) -> _Query:
        """Write ``request``, whose answer has ``size`` bytes (what came before it, if no answer
        is awaited, is dropped first: the late bytes of an overdue one)."""
        if self.gone is not None:
            raise ControllerFault(self.gone)
        if not self._queries:
            with self._io:
                try:
                    self.serial.reset_input_buffer()
                except PORT_ERRORS as e:
                    raise self.port_gone(e) from None
        asked = max(now, self._link_free)  # (before the write: a process stopped in it asked then)
        self._write(request)
        return _Query(asked, len(request), size, sense, self._lines, pulses)

    def _reached(self, query: _Query, now: float, heard: float) -> None:
        """An answer to ``query`` came (read at ``now``): the lines written before it reached
        the board by when it left at the latest (``now`` less its bytes' time on the link and
        the board's latency), and were held on their way if it came ``ANSWER_TOL`` later than
        those account for. When they reached it, for the model, is taken from when it was
        ``heard``: ``now``, or, if this thread was held up since it last looked, then (an answer
        that waited for this thread is no sign of a late line)."""
        byte = 10.0 / self.baud
        board = self._latency(now, query.asked, query.request, query.size)
        late = self._late(query, now) > 0.0
        self._delivered = (query.lines, now - query.size * byte - board, late)
        sent = self._sent_lines.pop(query.lines, None)
        for k in [k for k in self._sent_lines if k < query.lines]:  # (lines before it: on the board too)
            del self._sent_lines[k]
        if self._tracking and late and not query.pulses and sent is not None:  # (a Q right after it: came with it)
            self._arrived_late(*sent, heard - (query.request + query.size) * byte - board)

    def _arrived_late(
        self, aimed: float, before: FloatArray, after: FloatArray, since: FloatArray, arrived: float
    ) -> None:
        """A line aimed to reach the board at ``aimed`` [s] reached it at ``arrived``, held on its
        way (a frame or more: less leaves the board within what the QP check allows). The board
        kept the speeds ``before`` that much longer than the model had it, and is off the model
        by the difference from then on (each servo moves at the speed it was sent toward its
        target, from wherever it is): that line's piece of the model (it started at ``since``)
        starts then, where the one before had got to, and the pieces after it start off by the
        difference. (A timed group, whose speed a late line changes, is left as it is.)"""
        late = arrived - aimed
        if late < FRAME:
            return
        self._held_lines.append((arrived, late))
        kept = np.where(self._timed_joint, 0.0, late)  # [s] per joint
        dq = (before - after) * kept

        def moved(piece: tuple[FloatArray, FloatArray, FloatArray, FloatArray], own: bool) -> tuple[FloatArray, ...]:
            p0, t0, p1, t1 = piece
            speed = np.abs(p1 - p0) / np.maximum(t1 - t0, 1e-9)  # [rad/s] (0: a piece that holds)
            q0, s0 = (p0 + before * kept, t0 + kept) if own else (p0 + dq, t0)
            s1 = np.where(speed > 0.0, s0 + np.abs(p1 - q0) / np.where(speed > 0.0, speed, 1.0), t1 + (s0 - t0))
            return q0, s0, p1, s1

        found = False
        for k, piece in enumerate(self._pieces):
            own = piece[1] is since
            found = found or own
            if found:
                self._pieces[k] = moved(piece, own)  # type: ignore[assignment]
        if found:
            self._p0, self._since, self._p1, self._until = self._pieces[-1]
            log.debug("%s: a line reached the board %.1f ms late: the model moved %s", self.robot.name, late * 1e3, dq)

    def _latency(self, now: float, asked: float, request: int, size: int) -> float:
        """The board's latency [s]: the least, over the last ``LATENCY_WINDOW``, of how long its
        answers took beyond their bytes' time on the link (the board's own time to answer, 50 us
        to 5 ms by the guide, and a host that held neither way), with one more answer, asked at
        ``asked`` (``request`` bytes) and read whole (``size``) at ``now``."""
        self._latencies.append((now, now - asked - (request + size) * 10.0 / self.baud))
        while self._latencies[0][0] < now - LATENCY_WINDOW:
            self._latencies.popleft()
        return max(min(lat for _, lat in self._latencies), 0.0)

    def _late(self, query: _Query, now: float) -> float:
        """How much later [s] than ``ANSWER_TOL`` past its time (its bytes' on the link and the
        board's latency) ``query``'s answer is at ``now``: > 0, the host holds the bytes."""
        board = max(min((lat for _, lat in self._latencies), default=0.0), 0.0)
        return now - query.asked - (query.request + query.size) * 10.0 / self.baud - board - ANSWER_TOL

    def _held_for(self, now: float) -> float:
        """How long [s] the oldest answer awaited is overdue: the host holds the bytes on their
        way (0 if it does not)."""
        return max(self._late(self._queries[0], now), 0.0) if self._queries else 0.0

    def _last_line_held(self, now: float) -> bool | None:
        """Whether the last line written was held on its way (a busy host lets bytes go
        together, late): True if the answer after it came late or is overdue, False if it came
        on time or is not overdue yet (a board slow to answer, as ``QP`` may be), None if no
        question followed it."""
        lines, _, late = self._delivered
        if lines >= self._lines:
            return late
        after = [q for q in self._queries if q.lines >= self._lines]
        return None if not after else self._late(after[0], now) > 0.0

    def _quiet(self, now: float) -> bool:
        """Whether the link from the board has been quiet ``QUIET`` since an overdue answer (its
        bytes read and dropped meanwhile); True when no answer was overdue."""
        if self._quiet_since is None:
            return True
        if self._read_waiting():  # (late: dropped)
            self._quiet_since = now
        if now - self._quiet_since < QUIET:
            return False
        self._quiet_since = None
        return True

    def _read_waiting(self) -> bytes:
        """Whatever the board has sent that is not read yet (never waiting)."""
        if self.gone is not None:
            raise ControllerFault(self.gone)
        try:
            with self._io:
                waiting = self.serial.in_waiting
                return bytes(self.serial.read(waiting)) if waiting else b""
        except PORT_ERRORS as e:
            raise self.port_gone(e) from None

    def _poll_reply(self) -> None:
        """Read the board's answer if it has come (never waiting) and look at it: within what
        the model allows, the sensors' part is used; off it, the board is asked again at once
        (the stream goes on), and a second answer in a row with a servo off the same way is a
        fault. Those servos are then followed (:meth:`_follow`) by every answer while the model
        moves: the stop that brakes the arm after the fault brakes from where the board is."""
        now, looked = time.monotonic(), self._polled
        self._polled = now
        if not self._queries:
            return
        self._reply += self._read_waiting()
        heard = (
            now if now - looked <= ANSWER_TOL else looked
        )  # [s] (this thread held up since it last looked: then, at the soonest)
        while self._queries and len(self._reply) >= self._queries[0].size:
            query = self._queries.popleft()
            answer, self._reply = self._reply[: query.size], self._reply[query.size :]
            if not query.pulses and answer not in (b"+", b"."):  # (not the board's answer to Q: out of step)
                log.info("%s: Q got %r: the answers awaited are dropped", self.robot.name, answer)
                self._queries.clear()
                self._reply, self._quiet_since = b"", time.monotonic()
                return
            self._reached(query, time.monotonic(), heard)
            if query.pulses:
                self._look_at(answer, query.asked, query.sense)

    def _look_at(self, answer: bytes, asked: float, sensed: bool) -> None:
        """A ``QP`` answer (and the sensors' part after it, if ``sensed``), as :meth:`_poll_reply` says."""
        n, size = len(self.channels), len(answer)
        reply, sensors = answer[:n], answer[n:]
        self._answered, self._asked = time.monotonic(), asked
        self._answer = np.array([10.0 * b for b in reply])
        if self._followed is not None:  # (servos found off the model: followed while the model moves)
            if asked < float(np.max(self._until)):
                self._follow(*self._offsets(self._answer, asked, self._answered), asked, self._answered)
            else:
                self._followed = self._bounds = None
        if self.fault:
            return  # answering again: the recovery follows (check; the sensors' part is not looked at)
        off, model = self._mismatch(self._answer, asked, self._answered)
        side = np.where(off > 0.0, np.sign(self._answer - model), 0.0)  # [per servo] the board above (+1), below
        if not side.any():
            self._suspect = None
            if sensed:  # the board as the adapter has it: the readings published, the scanners stepped (or sent again)
                self._sensed(sensors, size)
            return
        again = self._suspect is not None and bool(np.any((side != 0.0) & (side == self._suspect)))
        if not again:  # (a host that held a line longer than a frame, a stray byte): asked again before believed
            self._suspect = side
            self._suspect_bounds = self._offsets(self._answer, asked, self._answered)
            i = int(np.argmax(off))
            log.info(
                "%s: QP: channel %d outputs %.0f us, %.0f us beyond what the model allows: asked again",
                self.robot.name,
                self.channels[i],
                self._answer[i],
                off[i],
            )
            self._ask_board(time.monotonic(), sense=False)
            return
        i = int(np.argmax(np.where(side == self._suspect, off, -np.inf)))
        self._suspect = None
        self._faulted_at = self._answered
        if np.all(self._answer[side != 0.0] > 0):
            self._followed, self._bounds = side != 0.0, self._suspect_bounds
            self._follow(*self._offsets(self._answer, asked, self._answered), asked, self._answered)
        else:  # (no pulse: a board reset, its servos limp and nowhere known; a line would jump them)
            self._dark = True
        raise ControllerFault(
            f"SSC-32 on {self.port}: channel {self.channels[i]} outputs {self._answer[i]:.0f} us, "
            f"the adapter commanded {model[i]:.0f} us ({off[i]:.0f} us beyond what it allows, twice in a row: "
            "someone else moved it, or the board was reset)"
        )

    def _sensed(self, reply: bytes, size: int) -> None:
        """The sensors' part of an answer that agreed with the model: the readings published,
        the scanners stepped (or sent again), the next read due."""
        self.sensors.answered(reply)
        step = self.sensors.aim()
        if step:
            self._write(step)
        now = time.monotonic()
        share = (len(self.sensors.request) + len(step) + size) / (SENSOR_SHARE * self.baud / 10.0)  # [s]
        self.sensors.ready_at = max(max(now, self._link_free) + self.sensors.settle_time(), now + share)

    def _window(self, asked: float, answered: float) -> FloatArray:
        """The model's pulses [us] where a QP answer may show the board (a row each: two frames
        before it was asked, until it was answered, every piece's start and end between). The
        board answers the pulse of its frame in progress (one every ``FRAME``): the model's up
        to a frame before the query ran; and a line that reached the board up to a frame late
        (a busy host, a slow link) leaves the board where the model was up to a frame before
        that: at a servo's speed, what it moves in a frame (38 us at 3 rad/s on an AL5 arm)."""
        amap = self.robot.actuators
        start = asked - 2.0 * FRAME
        inside = {float(t) for _, t0, _, t1 in self._pieces for t in (*t0, *t1) if start < t < answered}
        return np.array([amap.command_values(self._was_at(t)) for t in sorted({start, answered, *inside})])

    def _mismatch(self, pulses: FloatArray, asked: float, answered: float) -> tuple[FloatArray, FloatArray]:
        """How far a QP answer [us] is beyond what the model allows, per servo (> 0: beyond it),
        and the model's pulses when it was answered [us]. Allowed: the model's pulses anywhere
        in :meth:`_window`, give or take ``QP_RESOLUTION`` (the answer's 10 us) and
        ``MODEL_TOL`` (a board adopted from a QP answer): 15 us at rest; at 3 rad/s, 91 us
        behind where the model was when the query was asked."""
        model = self._window(asked, answered)
        tol = QP_RESOLUTION + MODEL_TOL
        return np.maximum(pulses - model.max(axis=0), model.min(axis=0) - pulses) - tol, model[-1]

    def _offsets(self, pulses: FloatArray, asked: float, answered: float) -> tuple[FloatArray, FloatArray]:
        """Per servo, the least and the most [us] the board may be from the model by a QP answer:
        the answer is the pulse less under ``QP_RESOLUTION`` (it truncates), anywhere in
        :meth:`_window`."""
        model = self._window(asked, answered)
        return pulses - model.max(axis=0), pulses + QP_RESOLUTION - model.min(axis=0)

    def _follow(self, lo: FloatArray, hi: FloatArray, asked: float, answered: float) -> None:
        """The model of the servos ``_followed`` moved onto the board, which is ``lo`` to ``hi``
        [us] from it (:meth:`_offsets`), and so by every answer since they were found off
        (narrower each time, while the board follows the adapter's commands from where it is,
        as a stop's): put at the middle. Each joint moved heads from there for its target at the
        speed it had (the board's command in force), or holds if it was not moving. Answers that
        no longer fit together (the board reached a target sooner, someone moved it again)
        start again from the last."""
        followed = self._followed
        if followed is None:
            return
        if self._bounds is not None:
            nlo, nhi = np.maximum(lo, self._bounds[0]), np.minimum(hi, self._bounds[1])
            if np.all(nlo[followed] <= nhi[followed]):
                lo, hi = nlo, nhi
        shift = np.where(followed, (lo + hi) / 2.0, 0.0)  # [us]
        self._bounds = (lo - shift, hi - shift)
        if np.all(np.abs(shift) < 0.5):
            return
        amap = self.robot.actuators
        try:
            q = amap.joints_from_commands(amap.command_values(self._p0) + shift, tol=np.inf)
        except ActuatorMapError:  # (a linkage's servo where the linkage cannot be: the recovery says so)
            return
        if not self.robot.limits.contains(q, tol=0.02):  # (the recovery says so, and stays faulted)
            return
        q = self.robot.limits.clip(q)
        moved = np.abs(q - self._p0) > 1e-12
        t = 0.5 * (asked - 2.0 * FRAME + answered)  # [s] (about when the answer shows the board: _window)
        speed = np.abs(self._p1 - self._p0) / np.maximum(self._until - self._since, 1e-9)  # [rad/s]
        on = moved & (self._until > t) & (speed > 0.0)  # (heading for its target: the board's command in force)
        p1 = np.where(moved & ~on, q, self._p1)
        until = np.where(
            on, self._since + np.abs(self._p1 - q) / np.where(on, speed, 1.0), np.where(moved, self._since, self._until)
        )
        log.info("%s: the model put where the board says it is (%s us)", self.robot.name, np.round(shift, 1))
        dq = np.where(moved, q - self._p0, 0.0)
        if self._pieces:
            self._pieces.pop()
        for k, (a0, s0, a1, s1) in enumerate(self._pieces):  # (the pieces a later answer's window may see: shifted)
            if float(np.max(s1)) > asked - 2.0 * FRAME:
                self._pieces[k] = (a0 + dq, s0, a1 + dq, s1)
        self._p0, self._p1, self._until = self._p0 + dq, p1, until
        self._pieces.append((self._p0, self._since, self._p1, self._until))

    def _recover(self) -> str | None:
        """From the board's last answer, None (recovered), or the fault's reason: a board that
        agrees with the model needs nothing (the model is kept as it is); one that stands
        still elsewhere (the same answer for ``STILL``, asked after the adapter's own moves had
        ended: where it is now, not where it was while it moved on) is taken where it is; a
        board that outputs no pulse, or holds the arm where no joint vector is or outside the
        limits, stays a fault with that reason."""
        pulses = self._answer
        if pulses is None:
            return "no QP answer"
        if not np.all(pulses > 0):
            self._dark = True
            ch = self.channels[int(np.argmin(pulses))]
            return (
                f"SSC-32 on {self.port}: channel {ch} outputs 0 us (the board was reset or powered off): "
                "restart the adapter to command the arm's pose again"
            )
        if np.all(self._mismatch(pulses, self._asked, self._answered)[0] <= 0.0):
            log.info("%s: the board is where the adapter has it", self.robot.name)
            return None
        if self._still is None or not np.array_equal(pulses, self._still):
            self._still, self._same_since = pulses, self._asked
        if self._asked - self._same_since < STILL or self._same_since < float(np.max(self._until)):
            return self.fault  # (it may still move: not yet where it will be)
        try:
            q = self.robot.actuators.joints_from_commands(pulses + QP_RESOLUTION / 2.0, tol=np.inf)
        except ActuatorMapError as e:  # (a linkage's servo where the linkage cannot be)
            return f"SSC-32 on {self.port} holds the arm where no joint vector is ({e.message})"
        if not self.robot.limits.contains(q, tol=0.02):
            bad = self.robot.limits.violations(q, tol=0.02)[0].message
            return f"SSC-32 on {self.port} holds the arm outside its limits ({bad})"
        self._hold_at(self.robot.limits.clip(q))
        log.info("%s: the board stands still elsewhere: taken where it is", self.robot.name)
        return None

    def grip(self, opening: float) -> None:
        """Open (1) or close (0) the gripper, or anything between: its own channel, over 0.5 s."""
        g = self.robot.gripper
        if g is None:
            raise BadRequest(f"{self.robot.name} has no gripper", field="gripper")
        self._write(f"#{g.channel}P{g.pulse(opening)}T500\r".encode())
        self.gripper_opening = opening

    def shutdown(self) -> None:
        self._save_pose()
        for pub in self._sensor_pubs.values():
            with contextlib.suppress(zenoh.ZError):
                pub.undeclare()
        try:
            self.serial.close()
        except Exception:  # already gone
            log.debug("close failed", exc_info=True)
