"""The GRBL adapter: stepper arms on an Arduino running GRBL 1.1 (seed 002's arm).

``armd adapter grbl ROBOT --port /dev/ttyACM0 [--baud B]``. The port may be any pyserial URL;
the baud rate defaults to the arm's ``[controller] baud`` (GRBL 1.1: 115200).

Joint i's stepper is GRBL axis X, Y or Z (the actuator map's ``axis``), in degrees of the
actuator angle (GRBL's "mm" are degrees here).

Where the arm is. Opening the port resets an Arduino (its DTR line), and GRBL restarts with
its machine position at 0 wherever the arm stands; GRBL has no command that sets the machine
position except homing. So the adapter never assumes it: it starts with ``homed = False`` (the
state says so, ``move`` answers ``position_unknown``) until one of

- homing: ``$H``, for an arm whose robot.toml says it has switches (``[controller] homing =
  true``, ``home_pose = [...]``: the joint angles after GRBL's homing cycle, pull-off included);
  ``armd unlock ROBOT --home`` (or the constructor's ``home=True``);
- an operator's word that the arm is at its rest pose (``[controller] rest_pose``, else the
  arm's neutral): ``armd unlock ROBOT --assume-rest``, or ``assume_rest=True`` at start.

Either sets an adapter-side offset, in whole micro-steps per axis, between GRBL's machine
position and the actuators' (``actuator steps = GRBL steps + offset``): GRBL's own frame is
left alone, so nothing here depends on work offsets, and GRBL's whole-step positions stay whole.
Every move is in machine coordinates (``G53`` on every line), positions are read as ``MPos``
(``$10=1``, set by the adapter), so a stored ``G54``-``G59`` or ``G92`` offset does not shift the
arm; the adapter writes none (``G10`` would write EEPROM, ``G92`` would be a work offset again).

Set-up: wait for GRBL's welcome (a board that says nothing within 3 s, even after a reset, is a
:class:`~clients.adapter.ControllerFault` naming the port); read ``$$``; write only the settings
that differ, then read ``$$`` again and refuse to start, saying which, if GRBL did not take one:

- ``$100+i``: micro-steps per degree; ``$110+i`` [deg/min] and ``$120+i`` [deg/s^2]: the actuator's
  velocity and acceleration bound (``|M| @`` the joints' limits). GRBL's planner never exceeds
  them on any axis, so each block it runs moves every joint within its limits;
- ``$11`` junction deviation [deg] = ``min($12x) * (0.1 * 10 ms)^2 / 8``. Where GRBL turns from one
  line to the next it keeps its speed and turns the velocity at once, so each axis' speed steps
  by the junction speed times the change of the unit vector; GRBL's junction speed
  (planner.c: ``v^2 = a delta sin(theta/2) / (1 - sin(theta/2))``, ``a`` the axes' limits along
  the turn) bounds that step on axis ``i`` by ``sqrt(8 a_i delta)``: here a tenth of what the
  axis' limit gives in 10 ms (GRBL's own step segment, stepper.c's DT_SEGMENT). Lines last 30 ms
  at least, so any +-10 ms of the motion holds one junction at most: over any +-10 ms no axis
  changes speed by more than 1.1 x its limit allows (GRBL's ramps, along each line, keep within
  ``$12x``). Sharper turns are taken slower, never faster. GRBL prints settings to 3 decimals,
  so the adapter writes ``$11`` at every start (7 decimals: GRBL reads 8 digits).
- ``$10=1`` (MPos in reports), ``$13=0`` (reports in "mm"), and with homing ``$22=1``.

Streaming, so that GRBL's own planner executes the plan within the limits: ``G53 G1`` lines, each to
a whole-step position next to the trajectory's at some time, the last one to the final sample's
position; made one at a time as GRBL's buffers take them. Each line ends 30 ms to 0.3 s
(``segment`` = 60 ms: half of it to five times) after the one before, at a speed (``F``,
deg/min) with which GRBL, accelerating at its limits, takes the time the trajectory does (from
the line's average speed up to the trajectory's fastest there), and where GRBL falls behind the
plan least: the ends are chosen among the corners of the whole-step cells round the trajectory
every 5 ms, so that where the trajectory goes straight the lines keep GRBL's direction (it takes
their junctions at full speed), and where it curves the lines are chords within 0.002 rad (and
a step) of it, at whose corners GRBL slows down to turn within ``$11``. GRBL plans up to 15
blocks ahead and always keeps the distance to stop within them; 12 of the shortest lines hold
far more than the ``v / 2a`` a stop needs (0.2 s at 0.8 rad/s, 2 rad/s^2), so it never slows
down for want of blocks. (An arm whose ``v / 2a`` exceeds 12 of them gets longer ones.)
Measured on the emulator with GRBL's planner (tests/test_adapter_grbl.py; the executed motion
before its whole steps, ``GrblEmulator.pieces``, by +-10 ms finite differences), on gupta3: a 2 s
joint move runs 1.05-1.07 x its planned time (1.01 x with 256 micro-steps), peak acceleration
1.00-1.02 x the limit (the 60 ms lines of before: 1.03 x the time, 1.88 x the limit, the
rounding of their ends turning GRBL at full speed); a Cartesian line (curved in joint space)
1.55-1.58 x its planned time at 1.00 x (before: 1.01 x, 4.1 x), a path through two waypoints
where every joint reverses 1.65-1.72 x at 1.02 x (before: 1.06 x, 5.2 x). Where a path curves in
joint space GRBL must nearly stop at each corner to stay within the limits (a move slowed by
``speed`` takes its planned time, 0.99-1.00 x; random full-speed joint moves 1.07-1.5 x, lines
1.2-1.3 x). Fitted over 40 ms as before, the 2 s move with 256 micro-steps peaks at 1.08-1.12 x,
where the plan itself, stepped, measures 1.08-1.11 x. A stop comes to rest within 15 % of the
time announced, no joint reversing. (``$J=`` jogging runs the same planner, jog.c: the same figures.)
Character counting keeps the bytes of unacknowledged lines within GRBL's 128-byte receive
buffer. A move is done when GRBL reports ``Idle`` (a report after the last ``ok``) at the final
position, to the step.

Tracking streams (``splices``): GRBL follows a stream's trajectories, as spliced, with the same
``G53 G1`` lines, made of :class:`_Path` (each trajectory up to where the next takes over) from
the end of the last line sent. What GRBL holds it runs: no command replaces a block in its
planner, and its planner keeps the distance to stop within what it holds (the newest block is
planned to exit at rest). So the adapter sends a stream's next line only while GRBL holds less
of the path, beyond where it is (:class:`_Held`: the lines sent that it has not run to their
end, GRBL's report projected on them), than ``STREAM_LEAD`` and ``STREAM_KEEP`` times the time
to brake from the path's speed there (:meth:`_window`): enough not to slow down for the end of
what it holds, no more. A splice, on the control loop at its time (:meth:`spliced`), makes the
lines from there on of the new path: GRBL runs the old one to the end of what it held (up to the
window and a line beyond the splice's time), then a line joins the new one. Where the path turns
in joint space GRBL runs behind the plan's time (it slows down at each corner, as for a move);
then it holds nothing beyond the splice's time, and the new trajectory changes its motion from
there on, late: the path is followed, not cut across (every point of it was checked against the
arm's world). More than ``STREAM_LAG`` behind, the stream's splices are refused (:meth:`admit`):
the arm goes on to the end of what it runs, at rest, and the stream starts again from there, on
time (a lag that grew on a turning path would leave the arm moving for seconds after the puts
stop). A stream's lines are at most ``STREAM_LINE`` long, chords within
``STREAM_CHORD_TOL`` of its path (a move's: ``CHORD_TOL``; a stream's path turns all the time,
and GRBL nearly stops at each corner: the junction changes no axis' speed by more than a tenth
of what its limit gives in 10 ms), never faster than the path there. A stream ends where its
last trajectory does (at rest, where the deadman said), to the step.

Not ``$J=`` jogging, though GRBL meant it for this: a jog cancel (``0x85``, or ``!`` while
jogging) brakes along the blocks as a feed hold does and flushes the planner, back to Idle with
no reset, but a ``$J=`` line that is not yet in the planner when the cancel is taken (still in
the receive buffer, or the parser waiting for a free block) is then run, from where the arm
stopped (protocol.c, motion_control.c; gnea/grbl#95, #423, #837): the arm moves again after the
stop. Waiting for its ``ok`` first would make the stop late. A feed hold of ``G1`` lines ends in
``Hold:0``, where GRBL's main loop reads nothing, and the reset there empties every buffer: nothing
runs after it. And a jog cancel cannot change what is queued either: it only brakes it to rest.

Stops (an estop, a ``stop``, a fault, a new move while one runs): feed hold ``!`` (GRBL
decelerates along the path at ``$12x``: no joint reverses; the stop is announced with the time
that takes, GRBL's reported speed over its deceleration along the line it runs), status reports
until ``Hold:0``, then a soft reset to empty GRBL's buffers (in ``Hold:0`` it keeps the position
and raises no alarm; in ``Hold:1`` it would raise ALARM:3), welcome, ``G21 G90 G94``. Only
``Hold:0`` ends a hold (GRBL held in Idle goes there at once): a report of ``Idle`` was made
before the hold was taken, and a line on its way could start GRBL before the reset came. A new move
runs after that only if it starts within ``START_TOL`` of where the arm was held; else it is
rejected with the reason (the client plans again from rest). An estop while the position is
unknown or the adapter faulted still sends ``!``.

Errors and alarms: ``error:N`` and ``ALARM:N`` are reported with GRBL's documented meanings (its
doc/csv tables). An error aborts the trajectory (the feed-hold stop above; the position is kept).
An alarm means the position is lost or the arm hit a limit: the trajectory is aborted (a
``fault`` event with the alarm's meaning), ``homed`` becomes False, and the adapter sends neither
``$X`` nor a reset by itself. GRBL still answers, so the adapter then reports ``recovered`` and
keeps its token: ``move`` answers ``position_unknown`` (not ``no_adapter``) and the unlock can
reach it. Only an operator's unlock clears it: ``home`` (a reset if GRBL wants one after a limit
alarm, "Reset to continue", then ``$H``) or ``assume_rest`` (the same reset, then ``$X`` because
the operator said the arm is at rest).

robot.toml, ``[controller]``: ``homing = true`` (the arm has homing switches wired to GRBL; the
adapter sets ``$22=1``; GRBL's other homing settings, ``$23``-``$27``, are the board's),
``home_pose = [...]`` (joint angles [rad] GRBL's homing cycle leaves the arm at, pull-off
included; needed with ``homing``), ``rest_pose = [...]`` (joint angles [rad] an operator
confirms with ``--assume-rest``; default: the arm's neutral). Angles as numbers or like ``"pi/2"``.
"""

from __future__ import annotations

import collections
import logging
import re
import time
from collections.abc import Iterable, Iterator, Sequence
from typing import NamedTuple

import numpy as np
import serial
import zenoh

from armd.errors import BadRequest, ControllerFault
from armd.planning import JointState
from armd.robots import Robot, Stepper
from armd.robots.units import parse_angle

from .base import START_TOL, actuators_of
from .serial_port import SerialAdapter
from .trajectory_message import Command, FloatArray, motion

log = logging.getLogger(__name__)

RX_BUFFER = 128  # [bytes] GRBL's serial receive buffer
PLANNER_BLOCKS = 15  # GRBL's look-ahead (BLOCK_BUFFER_SIZE 16, one kept free)
LINE_MAX = 79  # [characters] GRBL's line buffer
AXES = "XYZABC"
SEGMENT = 0.06  # [s] the time of one streamed line (a segment of the trajectory), about
SEGMENT_RANGE = (0.5, 5.0)  # each line's time within these multiples of it (the one where GRBL loses least)
STREAM_LINE = 0.3  # [s] a tracking stream's lines' longest (what is sent, GRBL runs: a splice waits for it)
STREAM_LEAD = 0.05  # [s] how much of a stream's path GRBL holds beyond where it is, at the least ...
STREAM_KEEP = 1.25  # ... and this many times the time it takes to brake from the path's speed there
STREAM_LAG = 0.5  # [s] how far GRBL may run behind a stream's time before its splices are refused
STEP_WINDOW = 0.01  # [s] GRBL's step segment (stepper.c's DT_SEGMENT): the time scale of its speed changes
JUNCTION_SHARE = 0.1  # what a junction may change an axis' speed by, of its acceleration limit x STEP_WINDOW
CHORD_TOL = 0.002  # [rad] of an actuator: how far a segment's straight line may pass from the trajectory
STREAM_CHORD_TOL = 0.01  # [rad] ... a stream's (longer lines: fewer corners, where GRBL must slow down)
CANDIDATE_DT = 0.005  # [s] the times at which a segment may end
FEED_STEPS = 40  # a segment's speed is tried from its average to twice that, in this many steps
WELCOME_S = 3.0  # [s] how long GRBL may take to print its welcome (an Arduino boots in ~1 s)
HOMING_S = 120.0  # [s] how long a homing cycle may take
HOLD_S = 1.0  # [s] a feed hold may take this long more than the planned stop
STATUS_EVERY = 0.01  # [s] the status requests' period while waiting for GRBL
_STATUS = re.compile(r"<([A-Za-z]+)(?::(\d))?\|(MPos|WPos):([-\d.,]+)")
_FEED = re.compile(r"\|FS?:([\d.]+)")  # the speed GRBL moves at [units/min] (F: in builds without a spindle PWM)
_SETTING = re.compile(r"\$(\d+)=(-?[\d.]+)")
_MODES = "G21G90G94"  # mm (degrees here), absolute, units per minute: after every reset

# GRBL 1.1's codes and meanings (gnea/grbl doc/csv/error_codes_en_US.csv, alarm_codes_en_US.csv)
ERRORS = {
    1: "Expected command letter: G-code words consist of a letter and a value. Letter was not found.",
    2: "Bad number format: missing the expected G-code word value or numeric value format is not valid.",
    3: "Invalid statement: Grbl '$' system command was not recognized or supported.",
    4: "Value < 0: negative value received for an expected positive value.",
    5: "Setting disabled: homing cycle failure. Homing is not enabled via settings.",
    6: "Value < 3 usec: minimum step pulse time must be greater than 3usec.",
    7: "EEPROM read fail. Using defaults: auto-restoring affected EEPROM to default values.",
    8: "Not idle: Grbl '$' command cannot be used unless Grbl is IDLE.",
    9: "G-code lock: G-code commands are locked out during alarm or jog state.",
    10: "Homing not enabled: soft limits cannot be enabled without homing also enabled.",
    11: "Line overflow: max characters per line exceeded. Received command line was not executed.",
    12: "Step rate > 30kHz: Grbl '$' setting value cause the step rate to exceed the maximum supported.",
    13: "Check Door: safety door detected as opened and door state initiated.",
    14: "Line length exceeded: build info or startup line exceeded EEPROM line length limit.",
    15: "Travel exceeded: jog target exceeds machine travel. Jog command has been ignored.",
    16: "Invalid jog command: jog command has no '=' or contains prohibited g-code.",
    17: "Setting disabled: laser mode requires PWM output.",
    20: "Unsupported command: unsupported or invalid g-code command found in block.",
    21: "Modal group violation: more than one g-code command from same modal group found in block.",
    22: "Undefined feed rate: feed rate has not yet been set or is undefined.",
    23: "G-code command in block requires an integer value.",
    24: "More than one g-code command that requires axis words found in block.",
    25: "Repeated g-code word found in block.",
    26: "No axis words found in block for g-code command or current modal state which requires them.",
    27: "Line number value is invalid.",
    28: "G-code command is missing a required value word.",
    29: "G59.x work coordinate systems are not supported.",
    30: "G53 only allowed with G0 and G1 motion modes.",
    31: "Axis words found in block when no command or current modal state uses them.",
    32: "G2 and G3 arcs require at least one in-plane axis word.",
    33: "Motion command target is invalid.",
    34: "Arc radius value is invalid.",
    35: "G2 and G3 arcs require at least one in-plane offset word.",
    36: "Unused value words found in block.",
    37: "G43.1 dynamic tool length offset is not assigned to configured tool length axis.",
    38: "Tool number greater than max supported value.",
}
ALARMS = {
    1: "Hard limit: hard limit has been triggered. Machine position is likely lost due to sudden halt. "
    "Re-homing is highly recommended.",
    2: "Soft limit: G-code motion target exceeds machine travel. Machine position retained. Alarm may be safely "
    "unlocked.",
    3: "Abort during cycle: reset while in motion. Machine position is likely lost due to sudden halt. Re-homing "
    "is highly recommended.",
    4: "Probe fail: probe is not in the expected initial state before starting probe cycle.",
    5: "Probe fail: probe did not contact the workpiece within the programmed travel for G38.2 and G38.4.",
    6: "Homing fail: the active homing cycle was reset.",
    7: "Homing fail: safety door was opened during homing cycle.",
    8: "Homing fail: pull off travel failed to clear limit switch. Try increasing pull-off setting or check wiring.",
    9: "Homing fail: could not find limit switch within search distances. Try increasing max travel, decreasing "
    "pull-off distance, or check wiring.",
    10: "Homing fail: second dual axis limit switch failed to trigger within configured search distance after first.",
}


def describe(line: str) -> str:
    """``error:N`` or ``ALARM:N`` with GRBL's documented meaning."""
    kind, _, code = line.partition(":")
    table = ERRORS if kind == "error" else ALARMS
    try:
        meaning = table.get(int(code), "not a code GRBL 1.1 documents")
    except ValueError:
        meaning = "not a code GRBL 1.1 documents"
    return f"{line} ({meaning})"


class _Line(NamedTuple):
    """A streamed line and where it leaves GRBL: its end [GRBL steps], the time it ends at [s]
    (of the trajectory it was made of; once sent, a stream's: of the stream), its direction (a
    unit vector, in degrees) and speed [deg/s]."""

    text: bytes
    steps: np.ndarray
    t: float
    unit: np.ndarray | None
    feed: float


class _Lines:
    """Lines made one at a time as they are taken (from an iterator), the next one made ahead."""

    def __init__(self, lines: Iterable[_Line] = ()) -> None:
        self._lines = iter(lines)
        self._next: _Line | None = None

    def peek(self) -> _Line:
        """The next line (the iterator must not be exhausted: see ``bool``)."""
        if self._next is None:
            self._next = next(self._lines)
        return self._next

    def pop(self) -> _Line:
        line = self.peek()
        self._next = None
        return line

    def __bool__(self) -> bool:
        if self._next is None:
            self._next = next(self._lines, None)
        return self._next is not None

    def clear(self) -> None:
        self._lines, self._next = iter(()), None


class _Held:
    """A stream's lines that GRBL was sent and has not run to their end: what it will run
    whatever comes next (no command replaces a block in its planner). Times are the stream's
    [s] (:class:`_Path`); positions GRBL's steps."""

    def __init__(self, start: np.ndarray, t: float) -> None:
        self.lines: collections.deque[_Line] = collections.deque()
        self.start, self.t0 = start, t  # where the first line held starts, and its time
        self.at = t  # [s] the stream's time where GRBL is along them

    @property
    def end(self) -> float:
        """[s] the stream's time the last line held ends at."""
        return self.lines[-1].t if self.lines else self.t0

    def advance(self, steps: np.ndarray, spd: np.ndarray, idle: bool) -> float:
        """Where GRBL is along the lines, from its report (at ``steps``; ``idle``: it said Idle
        after the last ``ok``, so it ran them all): the lines it ran are let go, and its time
        along the one it runs [s] is returned (``at``). GRBL runs each line straight: it is on
        the one nearest where it is (a line that goes back over the one before it: the later),
        as far along as it projects on it."""
        if idle:
            while self.lines:
                line = self.lines.popleft()
                self.start, self.t0 = line.steps, line.t
        if not self.lines:
            self.at = self.t0
            return self.at
        ends = np.array([line.steps for line in self.lines], dtype=float) / spd  # [deg]
        starts = np.vstack([self.start / spd, ends[:-1]])
        way = ends - starts
        length = np.sum(way * way, axis=1)
        here = steps / spd
        done = np.clip(np.sum((here - starts) * way, axis=1) / np.maximum(length, 1e-12), 0.0, 1.0)
        off = np.linalg.norm(starts + done[:, None] * way - here, axis=1)
        k = int(np.flatnonzero(off <= off.min() + 0.5 / float(np.max(spd)))[-1])  # (within half a step)
        along = float(done[k])
        if along >= 1.0 - 1e-9:  # (at its end: on the next one, at its start)
            k, along = k + 1, 0.0
        for _ in range(k):
            line = self.lines.popleft()
            self.start, self.t0 = line.steps, line.t
        self.at = self.t0 + along * (self.lines[0].t - self.t0) if self.lines else self.t0
        return self.at


class _Path:
    """A tracking stream's trajectories as spliced, each up to where the next takes over (the
    motion the stream commands, with no jump: each starts at the sample it takes over at), kept
    from where GRBL's next line begins: the path GRBL follows. Its times [s] count from the
    stream's start (a sample's: its index over the rate), so the lines held keep theirs."""

    def __init__(self, cmd: Command) -> None:
        self.cmd = cmd  # the stream's trajectory from sample ``first`` on (velocity and acceleration with it)
        self.first = 0  # the stream's sample that is ``cmd``'s first
        self.k0 = 0  # the stream's sample where the running trajectory began

    @property
    def start(self) -> float:
        """[s] the stream's time of ``cmd``'s first sample."""
        return self.first / self.cmd.rate_hz

    def sample(self, t: float) -> int:
        """``cmd``'s sample at the stream's time ``t`` [s] (clamped to it)."""
        return min(max(int(t * self.cmd.rate_hz) - self.first, 0), len(self.cmd.times) - 1)

    def splice(self, cmd: Command, sent: float) -> None:
        """``cmd`` takes over at its ``at`` from the running trajectory; what is before ``sent``
        [s, the stream's time], where the next line begins, is let go."""
        cut = self.k0 + round(cmd.at * cmd.rate_hz) - self.first  # (a splice's at: a whole sample)
        keep = min(max(int(sent * cmd.rate_hz) - 1 - self.first, 0), cut)
        old = self.cmd
        position = np.vstack([old.position[keep:cut], cmd.position])
        velocity = np.vstack([old.velocity[keep:cut], cmd.velocity])
        acceleration = np.vstack([old.acceleration[keep:cut], cmd.acceleration])
        times = np.arange(len(position)) / cmd.rate_hz
        self.cmd = Command(
            cmd.id, cmd.kind, cmd.rate_hz, times, position, velocity, acceleration, cmd.commands[-1:], track=cmd.track
        )
        self.first += keep
        self.k0 = self.first + cut - keep


class GrblAdapter(SerialAdapter):
    kind = "grbl"
    splices = True  # a stream's lines go on from what GRBL holds (:meth:`spliced`): see "Tracking streams"

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
        check_period: float = 0.5,
        assume_rest: bool = False,
        home: bool = False,
        segment: float = SEGMENT,
        serial_port: serial.SerialBase | None = None,
    ) -> None:
        self.steppers = actuators_of(robot, Stepper, "GRBL")
        self.axes = [a.axis for a in self.steppers]
        if any(ax not in AXES for ax in self.axes) or len(set(self.axes)) != len(self.axes):
            raise BadRequest(
                f"GRBL axes are distinct letters of {AXES}; {robot.name} uses {', '.join(self.axes)}", field="axis"
            )
        if not 0.01 <= segment <= 0.5:
            raise BadRequest(f"segment must be in [0.01, 0.5] s, got {segment}", field="segment")
        ctl = robot.controller
        self.homing = ctl.get("homing", False) is True
        if self.homing and "home_pose" not in ctl:
            raise BadRequest(f"{robot.name}: [controller] homing = true needs home_pose", field="home_pose")
        self.rest_steps = self._pose_steps(robot, ctl.get("rest_pose", list(robot.neutral)), "rest_pose")
        self.home_steps = self._pose_steps(robot, ctl["home_pose"], "home_pose") if self.homing else None
        if home and not self.homing:
            raise BadRequest(
                f"{robot.name} has no homing switches ([controller] homing = true): it cannot home", field="home"
            )
        self.timeout = timeout  # [s] how long the controller may take to answer (the port's reads poll)
        # GRBL must always hold the distance to stop: 15 blocks, less the running one and a margin
        stop_time = float(np.max(robot.limits.velocity / (2.0 * robot.limits.acceleration)))  # [s] of travel
        self.segment = max(segment, stop_time / (PLANNER_BLOCKS - 3))
        if self.segment > segment:
            log.info(
                "%s: segments of %.0f ms (GRBL's %d blocks must hold a stop's %.2f s of travel)",
                robot.name,
                self.segment * 1000,
                PLANNER_BLOCKS,
                stop_time,
            )
        self._spd = np.array([a.steps_per_degree for a in self.steppers])
        speed, accel = robot.actuators.rate_bounds(robot.limits.velocity, robot.limits.acceleration)
        self._vmax = np.degrees(speed)  # [deg/s] each axis' velocity bound ($110.. / 60)
        self._amax = np.degrees(accel)  # [deg/s^2] each axis' acceleration bound ($120..)
        self._deviation = float(np.min(self._amax)) * (JUNCTION_SHARE * STEP_WINDOW) ** 2 / 8.0  # [deg] $11
        # [s] the shortest and longest segments: one junction at most in any STEP_WINDOW either side, and
        # GRBL's blocks still holding a stop's travel
        self._shortest = max(self.segment * SEGMENT_RANGE[0], 2.0 * STEP_WINDOW, stop_time / (PLANNER_BLOCKS - 3))
        self._longest = max(self.segment * SEGMENT_RANGE[1], self._shortest)
        self._stream_line = max(STREAM_LINE, self._shortest)  # [s] a stream's longest lines
        if np.any(self._spd > 500.0):  # GRBL reports positions to 0.001 (N_DECIMAL_COORDVALUE_MM)
            log.warning("%s: over 500 steps a degree: GRBL's reports (3 decimals) may be a step off", robot.name)
        self._index = [AXES.index(ax) for ax in self.axes]
        super().__init__(
            session,
            robot,
            port,
            baud=baud or int(robot.controller.get("baud", 115200)),  # type: ignore[call-overload]
            timeout=0.02,
            write_timeout=timeout,
            prefix=prefix,
            state_hz=state_hz,
            check_period=check_period,
            serial_port=serial_port,
        )
        self.position_source = "measured"
        self.homed = False
        self.lost = "GRBL restarts with its position at 0 when the port opens"  # why homed is False
        self._offset = np.zeros(len(self.axes), dtype=np.int64)  # actuator steps = GRBL steps + offset
        self._buffer = b""
        self._trouble: str | None = None
        self._pending: collections.deque[int] = collections.deque()  # lengths of unacknowledged lines
        self._queue = _Lines()  # lines of the running trajectory not sent yet
        self._state = "Unknown"
        self._sub: str | None = None  # Hold:0 / Hold:1's digit
        self._fresh = False  # a status report came after the last ok (and after the last feed hold)
        self._steps = np.zeros(len(self.axes), dtype=np.int64)  # GRBL's machine position [steps]
        self._last_status = 0.0
        self._asked = 0.0
        self._reset_wanted = False  # GRBL said "Reset to continue": it answers nothing, not even '?', until a reset
        self._holding: float | None = None  # a feed hold is under way: its deadline
        self._streaming = False
        self._speed = 0.0  # [deg/s] the speed along its path GRBL last reported
        self._sample = 0  # the running trajectory's sample nearest where GRBL last was
        self._target: np.ndarray | None = None  # [GRBL steps] where the running trajectory ends
        self._sent: _Line | None = None  # the last line sent of the running trajectory (a stream goes on from it)
        self._held: _Held | None = None  # a stream's lines GRBL holds
        self._path: _Path | None = None  # a stream's path, as spliced
        self._lag = 0.0  # [s] how far GRBL runs behind the stream's time
        self._v = np.zeros(robot.nq)
        self._a = np.zeros(robot.nq)
        try:
            self._welcome(reset_first=False)
            self._configure()
            self._poll_status(wait=True)
            if self._state != "Alarm":
                self._command(_MODES)
            if home:
                self._home()
            elif assume_rest:
                self._assume_rest()
        except BaseException:
            self.serial.close()
            raise
        if not self.homed:
            log.warning(
                "%s: position unknown (%s): home it or confirm its rest pose (armd unlock %s) before moving it",
                robot.name,
                self.lost,
                robot.name,
            )
        self.activate()

    @staticmethod
    def _pose_steps(robot: Robot, pose: object, name: str) -> np.ndarray:
        """A ``[controller]`` pose (joint angles [rad], numbers or like ``"pi/2"``) as actuator steps."""
        try:
            if isinstance(pose, str) or not isinstance(pose, Sequence) or len(pose) != robot.nq:
                raise ValueError("not a list")
            q = robot.joint_vector([parse_angle(v) for v in pose], name)
        except ValueError:
            raise BadRequest(
                f"{robot.name}: [controller] {name} must list {robot.nq} joint angles [rad] (numbers, "
                f"or like 'pi/2'), got {pose!r}",
                field=name,
            ) from None
        if not robot.limits.contains(q, tol=1e-9):
            raise BadRequest(
                f"{robot.name}: [controller] {name} is outside the limits: "
                f"{robot.limits.violations(q, tol=1e-9)[0].message}",
                field=name,
            )
        return np.asarray(robot.actuators.commands(q), dtype=np.int64)

    # -- the wire ------------------------------------------------------------------------

    def _write(self, data: bytes) -> None:
        try:
            with self._io:
                self.serial.write(data)
        except (serial.SerialException, serial.SerialTimeoutException) as e:
            raise ControllerFault(f"GRBL on {self.port}: write failed: {e}") from None

    def _lines(self) -> list[str]:
        """Complete lines received so far (status reports included)."""
        try:
            with self._io:
                waiting = self.serial.in_waiting
                chunk = self.serial.read(waiting) if waiting else b""
        except (serial.SerialException, OSError) as e:
            raise ControllerFault(f"GRBL on {self.port}: read failed: {e}") from None
        self._buffer += chunk
        *lines, self._buffer = self._buffer.split(b"\n")
        return [ln.decode(errors="replace").strip() for ln in lines if ln.strip()]

    def _handle(self, line: str) -> None:
        if line == "ok":
            if self._pending:
                self._pending.popleft()
            self._fresh = False
        elif line.startswith("error:"):
            if self._pending:
                self._pending.popleft()
            self._fresh = False
            self._trouble = f"GRBL on {self.port} answered {describe(line)}"
        elif line.startswith("ALARM:"):
            self.homed = False
            self.lost = f"GRBL raised {describe(line)}"
            self._state = "Alarm"
            self._trouble = (
                f"GRBL on {self.port} raised {describe(line)}: the arm's position is not trusted; the "
                f"adapter sends no unlock nor reset by itself: home it or confirm its rest pose "
                f"(armd unlock {self.robot.name})"
            )
        elif line.startswith("[MSG:Reset to continue]"):
            self._reset_wanted = True
        elif line.startswith("<"):
            m = _STATUS.match(line)
            if m:
                if m.group(3) != "MPos":
                    self._trouble = f"GRBL on {self.port} reports WPos: someone changed $10 (the adapter set $10=1)"
                    return
                self._state, self._sub = m.group(1), m.group(2)
                vals = [float(v) for v in m.group(4).split(",")]
                self._steps = np.rint(np.array([vals[i] for i in self._index]) * self._spd).astype(np.int64)
                feed = _FEED.search(line)
                self._speed = float(feed.group(1)) / 60.0 if feed else 0.0
                self._last_status = time.monotonic()
                self._fresh = True

    def _pump(self) -> None:
        """Read and handle what GRBL said; raise an error or alarm it reported."""
        for line in self._lines():
            self._handle(line)
        if self._trouble:
            trouble, self._trouble = self._trouble, None
            raise ControllerFault(trouble)

    def _welcome(self, *, reset_first: bool) -> None:
        """Wait for GRBL's welcome (resetting it if it says nothing); what came before it is dropped."""
        deadline = time.monotonic() + WELCOME_S
        if reset_first:
            self._write(b"\x18")
        seen = ""
        while time.monotonic() < deadline:
            for line in self._lines():
                seen = line
                if line.startswith("Grbl"):
                    self._pending.clear()
                    self._queue.clear()
                    self._fresh = False
                    return
                if line.startswith("ALARM:"):
                    self._handle(line)
            if not reset_first and time.monotonic() > deadline - WELCOME_S / 2:
                self._write(b"\x18")  # no welcome on opening (a board that does not reset on open): reset it
                reset_first = True
            time.sleep(0.005)
        raise ControllerFault(
            f"no GRBL answers on {self.port} (nothing like GRBL's welcome within "
            f"{WELCOME_S:g} s, even after a reset; last line: {seen!r}): is it a GRBL 1.1 board, "
            "at this baud rate?"
        )

    def _command(self, line: str, timeout: float | None = None) -> list[str]:
        """Send one line and wait for its ``ok`` (not while streaming); the lines GRBL printed before it."""
        if len(line) > LINE_MAX:
            raise BadRequest(f"GRBL line of {len(line)} characters (at most {LINE_MAX}): {line!r}", field="line")
        self._pending.append(len(line) + 1)
        self._write((line + "\n").encode())
        deadline = time.monotonic() + (timeout if timeout is not None else self.timeout * 4)
        out: list[str] = []
        while self._pending:
            for got in self._lines():
                if not got.startswith(("ok", "error:", "ALARM:", "<")):
                    out.append(got)
                self._handle(got)
            if self._trouble:
                trouble, self._trouble = self._trouble, None
                raise ControllerFault(f"{trouble}, to {line!r}")
            if time.monotonic() > deadline:
                raise ControllerFault(f"GRBL on {self.port} did not acknowledge {line!r}")
            time.sleep(0.001)
        return out

    def _poll_status(self, wait: bool = False) -> None:
        asked = time.monotonic()
        self._asked = asked
        self._write(b"?")
        while wait and self._last_status < asked:
            self._pump()
            if time.monotonic() - asked > self.timeout:
                raise ControllerFault(f"GRBL on {self.port} does not answer status requests")
            time.sleep(0.001)

    def _settings(self) -> dict[int, float]:
        got: dict[int, float] = {}
        for line in self._command("$$"):
            m = _SETTING.fullmatch(line)
            if m:
                got[int(m.group(1))] = float(m.group(2))
        return got

    def wanted_settings(self) -> dict[int, float]:
        """The GRBL settings the adapter sets: ``{n: value}``."""
        want: dict[int, float] = {10: 1, 13: 0}
        for j, i in enumerate(self._index):
            want[100 + i] = float(self._spd[j])
            want[110 + i] = float(self._vmax[j]) * 60.0
            want[120 + i] = float(self._amax[j])
        want[11] = self._deviation
        if self.homing:
            want[22] = 1
        return want

    def _configure(self) -> None:
        """Write the settings that differ from ``wanted_settings`` (and ``$11``, finer than the 3
        decimals GRBL prints); read them all back."""
        want = self.wanted_settings()

        def off(have: dict[int, float], n: int) -> bool:  # GRBL prints 3 decimals
            return n not in have or abs(have[n] - want[n]) > 0.0011 + 1e-6 * abs(want[n])

        have = self._settings()
        for n in sorted(want):
            if off(have, n) or (n == 11 and want[n] != round(want[n], 3)):
                # GRBL reads 8 digits at most (read_float): $11 (below 1) with 7 decimals
                value = (f"{want[n]:.7f}" if n == 11 and want[n] < 1.0 else f"{want[n]:.4f}").rstrip("0").rstrip(".")
                try:
                    self._command(f"${n}={value}")
                except ControllerFault as e:
                    raise ControllerFault(
                        f"GRBL on {self.port} will not take ${n}={value} ({e.message}): refusing to start"
                    ) from None
        have = self._settings()
        bad = [n for n in sorted(want) if off(have, n)]
        if bad:
            n = bad[0]
            raise ControllerFault(
                f"GRBL on {self.port} will not take ${n}={want[n]:.4f} (it reads back "
                f"{have.get(n)}): refusing to start" + (" (status reports would not carry MPos)" if n == 10 else "")
            )

    def _reset(self) -> None:
        """Soft reset (only at rest: Idle or Hold:0, or in an alarm because an operator asked); wait for the
        welcome; set the modes unless GRBL is in an alarm."""
        self._write(b"\x18")
        self._welcome(reset_first=True)
        self._reset_wanted = False
        self._poll_status(wait=True)
        if self._state != "Alarm":
            self._command(_MODES)

    # -- positions -----------------------------------------------------------------------

    def _joints(self, grbl_steps: np.ndarray) -> FloatArray:
        return self.robot.actuators.joints_from_commands(grbl_steps + self._offset, tol=np.inf)

    def _line(self, grbl_steps: np.ndarray, feed: float) -> bytes:
        deg = grbl_steps / self._spd
        words = "".join(f"{ax}{d:.4f}" for ax, d in zip(self.axes, deg, strict=True))
        line = f"G53G1{words}F{max(feed, 1.0):.1f}"
        if len(line) > LINE_MAX:
            raise BadRequest(f"GRBL line of {len(line)} characters (at most {LINE_MAX}): {line!r}", field="line")
        return (line + "\n").encode()

    def _segments(
        self,
        cmd: Command,
        start: np.ndarray,
        *,
        t_start: float = 0.0,
        unit: np.ndarray | None = None,
        feed: float = 0.0,
    ) -> Iterator[_Line]:
        """The trajectory as ``G53 G1`` lines from GRBL's ``start`` [steps], each to a whole-step
        position next to the trajectory's at some time, the last one to the final sample's
        position; made one at a time, as GRBL's buffers take them.

        Each line ends between ``_shortest`` and ``_longest`` seconds after the one before, at
        ``CANDIDATE_DT`` steps of the trajectory's time, at a corner of the whole-step cell round
        the trajectory's position there, with the speed that has GRBL take the time the
        trajectory does (:meth:`_feeds`): the end where GRBL falls behind the plan least, about,
        per second of it; of equals, the one nearest ``segment`` seconds on. A
        line that passes farther than ``CHORD_TOL`` (and a step) from the trajectory between its
        ends, that turns from the line before by so little that GRBL takes the junction at full
        speed (planner.c: a cosine beyond 0.999999) with a step beyond ``JUNCTION_SHARE``, or that
        leaves a last line shorter than ``_shortest``, is not one (unless none is: then the
        shortest). So where the trajectory goes straight, the lines' whole-step ends keep GRBL's
        direction (it takes their junctions at full speed), and where it curves, the lines are
        long chords, at whose corners GRBL slows down to turn within ``JUNCTION_SHARE``. An end
        beyond the joints' limits (a whole step past a trajectory at its limit) is none.

        From ``t_start`` [s] of the trajectory on, where the line before (``unit``, at ``feed``
        [deg/s]) left GRBL at ``start``: a stream's path goes on from what GRBL was sent (its
        first line joins it if a splice changed it there); its lines are at most ``_stream_line``
        long (a splice waits for what GRBL holds) and within ``STREAM_CHORD_TOL`` of it (a
        stream's path turns all the time: fewer corners, where GRBL must slow down)."""
        times, duration = cmd.times, cmd.duration
        ideal = self.robot.actuators.command_values(cmd.position) - self._offset  # [steps], unrounded
        final = cmd.commands[-1] - self._offset
        tol = np.degrees(CHORD_TOL if cmd.track is None else STREAM_CHORD_TOL) * self._spd + 1.0  # [steps] per axis
        nj = len(self._spd)
        corners = np.array(np.meshgrid(*[[0, 1]] * nj, indexing="ij")).reshape(nj, -1).T  # (2^nj, nj)
        pace = np.linalg.norm(np.diff(ideal, axis=0) / self._spd, axis=1) * cmd.rate_hz  # [deg/s] between samples

        def at(t: np.ndarray) -> np.ndarray:  # the trajectory's position [steps] at times t [s]
            return np.column_stack([np.interp(t, times, ideal[:, j]) for j in range(nj)])

        here, t0 = np.asarray(start, dtype=np.int64), t_start
        longest = self._longest if cmd.track is None else self._stream_line
        soonest, latest = self._shortest, longest  # [s] after t0
        while t0 < duration:
            tc = t0 + np.arange(soonest, latest + 1e-9, CANDIDATE_DT)
            tc = tc[(tc < duration) & (duration - tc >= self._shortest - 1e-9)]
            ends = (np.floor(at(tc))[:, None, :] + corners[None]).reshape(-1, nj).astype(np.int64)
            tc = np.repeat(tc, len(corners))
            last = duration - t0 <= latest + 1e-9 or not len(tc)
            inside = self.robot.limits.contains_batch(self._joints(ends)) if len(ends) else np.zeros(0, dtype=bool)
            if last:  # the last line may end at the final sample
                ends, tc = np.vstack([ends, final[None]]), np.append(tc, duration)
                inside = np.append(inside, True)  # (the trajectory's own)
            d = (ends - here) / self._spd  # [deg]
            length = np.linalg.norm(d, axis=1)
            if not np.any(length > 0):
                if last:
                    return  # at the final position
                # the arm stands still: the next line takes its time too
                soonest, latest = latest, latest + longest
                continue
            keep = (length > 0) & inside if np.any((length > 0) & inside) else length > 0
            ends, tc, d, length = ends[keep], tc[keep], d[keep], length[keep]
            u = d / length[:, None]
            with np.errstate(divide="ignore"):
                accel = np.min(np.where(u != 0, self._amax / np.abs(u), np.inf), axis=1)  # [deg/s^2] GRBL's, along
            entry = np.minimum(feed, self._junction_speeds(unit, u)) if unit is not None else np.zeros(len(u))
            way = (at(np.minimum(tc + CANDIDATE_DT, duration)) - at(tc - CANDIDATE_DT)) / self._spd
            far = np.linalg.norm(way, axis=1)
            then = far / (2.0 * CANDIDATE_DT)  # [deg/s] the trajectory's speed at the end
            onward = np.where(far[:, None] > 0, way / np.maximum(far, 1e-12)[:, None], u)  # and its way there
            k0 = max(int(np.searchsorted(times, t0, side="right")) - 1, 0)
            fastest = np.maximum.accumulate(pace[k0:])  # [deg/s] the trajectory's fastest from t0 on
            k1 = np.clip(np.searchsorted(times, tc) - 1 - k0, 0, len(fastest) - 1)
            speed, took = self._feeds(length, tc - t0, entry, then, fastest[k1], accel, cmd.track is not None)
            # the time GRBL falls behind, with its slowing down at the next junction (toward the way there)
            lost = took - (tc - t0) + self._slowing(u, onward, speed, accel)
            if unit is not None:  # (slowing to the junction speed, at the end of the line before)
                lost += (feed - entry) ** 2 / (2.0 * accel * max(feed, 1e-9))
            # the trajectory between the ends, and how far each line passes from it [steps]
            inner = times[(times > t0) & (times < tc.max())]
            w = (at(inner) - here) / self._spd  # [deg]
            off = (w[None, :, :] - (w @ u.T).T[:, :, None] * u[:, None, :]) * self._spd
            inside = inner[None, :] < tc[:, None]
            fits = ~np.any(inside[:, :, None] & (np.abs(off) > tol), axis=(1, 2))
            if unit is not None:  # GRBL takes an all but straight junction at full speed: within the share?
                straight = -(u @ unit) < -0.999999
                step = np.minimum(speed, feed)[:, None] * np.abs(u - unit)  # [deg/s] per axis
                fits &= ~(straight & np.any(step > JUNCTION_SHARE * STEP_WINDOW * self._amax, axis=1))
            score = np.where(fits, lost / (tc - t0), np.inf)
            best = int(np.lexsort((np.abs(tc - t0 - self.segment), score))[0]) if fits.any() else int(np.argmin(tc))
            here, t0, unit, feed = ends[best], float(tc[best]), u[best], float(speed[best])
            yield _Line(self._line(here, feed * 60.0), here, t0, unit, feed)
            soonest, latest = self._shortest, longest

    @staticmethod
    def _feeds(
        length: np.ndarray,
        span: np.ndarray,
        entry: np.ndarray,
        then: np.ndarray,
        top: np.ndarray,
        accel: np.ndarray,
        capped: bool = False,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Each candidate line's speed [deg/s], and the time [s] GRBL takes on it, about: a line of
        ``length`` [deg] that the trajectory covers in ``span`` [s], entered at ``entry`` [deg/s]
        and left toward the trajectory's speed ``then``, GRBL accelerating and slowing at
        ``accel`` [deg/s^2]. The slowest speed, from the average up to the trajectory's fastest
        there (``top``), with which GRBL takes ``span``; else the one with which it takes least.
        ``capped`` (a stream's): never beyond ``top``, though GRBL then takes longer (the line that
        joins what GRBL held of one trajectory to the next may be longer than their way there)."""
        average = length / span
        most = np.maximum(top, 1e-3) if capped else np.maximum(top, average)
        average = np.minimum(average, most)
        best, took = average.copy(), np.full(len(length), np.inf)
        done = np.zeros(len(length), dtype=bool)
        for k in range(FEED_STEPS + 1):
            feed = np.minimum(average * (1.0 + k / FEED_STEPS), most)
            t = length / feed + ((feed - np.minimum(entry, feed)) ** 2 + (feed - np.minimum(then, feed)) ** 2) / (
                2.0 * accel * feed
            )
            better = ~done & ((t <= span) | (t < took))
            best, took = np.where(better, feed, best), np.where(better, t, took)
            done |= t <= span
        return best, took

    def _slowing(self, before: np.ndarray, after: np.ndarray, speed: np.ndarray, accel: np.ndarray) -> np.ndarray:
        """The time [s] GRBL loses, about, slowing from ``speed`` [deg/s] to its junction speed
        between ``before`` and ``after`` and back, at ``accel`` [deg/s^2]."""
        dip = np.maximum(speed - self._junction_speeds(before, after), 0.0)
        return dip**2 / (accel * np.maximum(speed, 1e-9))

    def _junction_speeds(self, before: np.ndarray, after: np.ndarray) -> np.ndarray:
        """The speed [deg/s] GRBL keeps through the junction of lines ``before`` and ``after``
        (unit vectors in degrees, broadcast), from ``$11``: planner.c's plan_buffer_line, without
        its rule that takes an all but straight junction (cosine beyond 0.999999) at any speed.
        Its velocity step per axis, this speed times the change of the unit vector, is then
        within ``JUNCTION_SHARE`` of what the axis' acceleration limit gives in ``STEP_WINDOW``."""
        before, after = np.broadcast_arrays(np.atleast_2d(before), np.atleast_2d(after))
        cos = -np.sum(before * after, axis=1)
        sin_half = np.sqrt(np.clip(0.5 * (1.0 - cos), 0.0, 1.0))
        turn = after - before
        size = np.linalg.norm(turn, axis=1)
        with np.errstate(divide="ignore", invalid="ignore"):
            share = np.abs(turn / size[:, None])
            accel = np.min(np.where(share > 0, self._amax / share, np.inf), axis=1)  # limit_value_by_axis_maximum
            speed = np.sqrt(accel * self._deviation * sin_half / (1.0 - sin_half))
        speed = np.where((sin_half >= 1.0) | (size == 0.0), np.inf, speed)  # straight on
        return np.where(cos > 0.999999, 0.0, speed)  # a reversal

    # -- stopping ------------------------------------------------------------------------

    def _begin_hold(self, planned: float) -> None:
        self._write(b"!")
        self._fresh = False
        self._holding = time.monotonic() + planned * 2.0 + HOLD_S
        self._streaming = False

    def _hold_complete(self) -> bool:
        """Advance a feed hold: True once GRBL is at rest and its buffers are empty (soft reset in
        Hold:0), or it is in an alarm (no reset: an operator must act; a limit alarm stopped it and
        answers no status request until then)."""
        assert self._holding is not None
        self._pump()
        if self._reset_wanted or (self._fresh and self._state == "Alarm"):
            self._holding = None
            self._queue.clear()
            self._pending.clear()
            return True
        # Hold:0 only: a feed hold of G1 lines always ends there (in Idle too, at once), and its
        # main loop, suspended, reads no line until the reset; an "Idle" is a report made before
        # the hold was taken, and a line still on its way could start GRBL after it
        if self._fresh and (self._state, self._sub) == ("Hold", "0"):
            self._holding = None
            self._reset()  # keeps the position: GRBL is at rest
            return True
        if time.monotonic() > self._holding:
            self._holding = None
            raise ControllerFault(
                f"GRBL on {self.port} did not complete its feed hold (state {self._state}"
                f"{':' + self._sub if self._sub else ''})"
            )
        if time.monotonic() - self._asked >= STATUS_EVERY:
            self._poll_status()
        return False

    def _busy(self) -> bool:
        return bool(self._queue or self._pending) or self._state not in ("Idle", "Unknown")

    # -- the Adapter hooks ----------------------------------------------------------------------

    def admit(self, cmd: Command) -> None:
        """A trajectory whose lines GRBL could not take (over 79 characters) is refused; so is a
        stream's splice while GRBL runs more than ``STREAM_LAG`` behind the stream's time (it
        slows down where the path turns): the arm goes on to the end of what it runs, at rest
        where that one's deadman said, and the stream starts again from there, on time."""
        widest = -np.max(np.abs(cmd.commands - self._offset), axis=0) - 1  # the most characters a line may need
        try:
            self._line(widest, 99999.0)
        except BadRequest as e:
            raise BadRequest(f"{self.robot.name}: {e.message}", field="position") from None
        lag = self._lag if self._streaming and self._path is not None else 0.0  # (a stream that runs)
        if cmd.after is not None and lag > STREAM_LAG:
            raise BadRequest(
                f"GRBL runs {lag:.2f} s behind the stream (it slows down where the path turns, at most "
                f"{STREAM_LAG:g} s): the arm goes on to the end of what it runs, and the stream starts again there",
                field="splice",
                lag=lag,
            )

    def stop_command(self, ident: str) -> Command:
        """A stop of kind ``stop``: ``execute`` runs it as GRBL's feed hold; its samples are that
        hold as GRBL runs it (:meth:`hold_duration`), so its duration is what the stop takes."""
        with self._lock:
            rate = self._cmd.rate_hz if self._cmd is not None else 50.0
        state = self.estimate() if self.fault else self.measure()  # (nothing asked of a faulty board)
        duration = self.hold_duration()
        t = np.append(np.arange(0.0, duration, 1.0 / rate), duration) if duration > 0.0 else np.zeros(1)
        v = state.velocity
        pos = state.position + np.outer(t - t**2 / (2.0 * max(duration, 1e-9)), v)  # to rest along the path
        vel, acc = motion(pos, 1.0 / rate)
        return Command(ident, "stop", rate, t, pos, vel, acc, np.zeros(pos.shape, dtype=np.int64))

    def hold_duration(self) -> float:
        """How long a feed hold takes from now [s], about: GRBL slows along the line it runs
        (the arm's direction now, :meth:`estimate`) from the speed it last reported, at that
        line's acceleration (the axes' ``$120``.. along it). 0 at rest."""
        state = self.estimate()
        rates = np.degrees(self.robot.actuators.jacobian(state.position) @ state.velocity)  # [deg/s] per axis
        speed = float(np.linalg.norm(rates))
        if speed <= 0.0 or self._speed <= 0.0:
            return 0.0
        share = np.abs(rates) / speed
        accel = float(np.min(self._amax[share > 0] / share[share > 0]))  # [deg/s^2] limit_value_by_axis_maximum
        return self._speed / accel

    def execute(self, cmd: Command, t: float, first: bool) -> bool:
        self._pump()
        if first:
            self._streaming = False
            self._target = None
            if cmd.kind == "stop" or self._busy() or self._holding is not None:
                self._begin_hold(cmd.duration)  # a stop, or a new move replacing a running one: stop first
        if self._holding is not None:
            if not self._hold_complete():
                return False
            self._v = np.zeros(self.robot.nq)
            self._a = np.zeros(self.robot.nq)
            if cmd.kind == "stop":
                return True
        if not self._streaming:
            return self._start(cmd, t)
        self._v, self._a = self._motion(cmd, t)
        if self._path is not None and self._held is not None:
            self._lag = self._path.k0 / cmd.rate_hz + t - self._held.at
        # send ahead while GRBL's receive buffer has room (character counting); a stream's, while due
        while (
            (self._held is None or self._due())  # (first: a line is made only when one is due)
            and self._queue
            and sum(self._pending) + len(self._queue.peek().text) <= RX_BUFFER
        ):
            line = self._queue.pop()
            self._pending.append(len(line.text))
            self._write(line.text)
            if self._path is not None and self._held is not None:  # (a stream's: in the stream's time)
                line = line._replace(t=line.t + self._path.start)
                self._held.lines.append(line)
            self._sent = line
        if (
            self._queue
            or self._pending
            or not self._fresh
            or self._state != "Idle"
            or (self._path is not None and t < cmd.duration)  # (a stream's: no splice may come for it now)
        ):
            if time.monotonic() - self._asked >= STATUS_EVERY:
                self._poll_status()
            return False
        assert self._target is not None
        if not np.array_equal(self._steps, self._target):
            raise ControllerFault(
                f"GRBL on {self.port} stopped at {self._steps.tolist()} steps, not at the "
                f"trajectory's end {self._target.tolist()}"
            )
        self._v = np.zeros(self.robot.nq)
        self._a = np.zeros(self.robot.nq)
        self._streaming = False
        return True

    def _start(self, cmd: Command, t: float) -> bool:
        """Stream ``cmd`` if it starts where GRBL is (else reject it: the client plans again)."""
        self._poll_status(wait=True)
        here = self._joints(self._steps)
        off = np.abs(cmd.position[0] - here)
        if np.any(off > START_TOL):
            j = int(np.argmax(off))
            reason = (
                f"trajectory {cmd.id} starts {off[j]:.4f} rad from where {self.robot.joint_names[j]} was held "
                f"({here[j]:.4f} rad; at most {START_TOL}): plan it again from where the arm is"
            )
            with self._lock:
                if self._cmd is cmd:
                    self._finished = True
            log.warning("%s: %s", self.robot.name, reason)
            self.event("rejected", id=cmd.id, reason=reason)
            return False
        self._target = cmd.commands[-1] - self._offset
        self._queue = _Lines(self._segments(cmd, self._steps))
        self._sent = _Line(b"", self._steps.copy(), 0.0, None, 0.0)
        stream = cmd.track is not None
        self._held = _Held(self._steps.copy(), 0.0) if stream else None
        self._path = _Path(cmd) if stream else None
        self._lag = 0.0
        self._streaming = True
        self._sample = 0
        return self.execute(cmd, t, False)

    def _due(self) -> bool:
        """Whether a stream's next line is to go now: while GRBL holds less of the path, beyond
        where it is, than the window (:meth:`_window`) there and at the end of what it holds."""
        assert self._held is not None
        held = self._held
        at = held.advance(self._steps, self._spd, self._ran_all())
        return held.end - at < max(self._window(at), self._window(held.end))

    def _ran_all(self) -> bool:
        """GRBL ran every line it was sent: it said Idle after the last ``ok``."""
        return self._fresh and self._state == "Idle" and not self._pending

    def _window(self, t: float) -> float:
        """How much of a stream's path [s] GRBL must hold beyond where it is, at the stream's time
        ``t``: ``STREAM_LEAD``, and ``STREAM_KEEP`` times the time it takes to brake at the limits
        from the path's speed there. GRBL plans a stop at the end of what it holds (planner.c: the
        newest block is planned to exit at rest), so, holding less, it slows down to be able to
        stop there; and what it holds it runs, whatever comes next: a splice changes the motion
        from the end of it on. So it holds that much, and no more."""
        assert self._path is not None
        path = self._path.cmd
        k = self._path.sample(t)
        rates = np.degrees(self.robot.actuators.jacobian(path.position[k]) @ path.velocity[k])  # [deg/s] per axis
        return STREAM_LEAD + STREAM_KEEP * float(np.max(np.abs(rates) / (2.0 * self._amax)))

    def spliced(self, before: Command, cmd: Command) -> None:
        """A stream's ``cmd`` takes over from ``before`` at ``cmd.at``: GRBL runs what it holds (no
        command replaces a block in its planner), and its path goes on through ``before`` up to
        ``cmd.at``, then through ``cmd`` (:class:`_Path`): the lines from the last one sent on
        are made of that. Where GRBL runs behind the plan's time (it slows down where the path
        turns), it has not been sent ``before``'s part beyond ``cmd.at``: it follows ``cmd`` from
        there, late; else the line after those held joins ``cmd`` from where they leave it."""
        if not self._streaming or self._sent is None or self._path is None:
            return  # (not started: execute starts it where GRBL is)
        path, sent = self._path, self._sent
        path.splice(cmd, sent.t)
        self._target = cmd.commands[-1] - self._offset
        self._queue = _Lines(
            self._segments(path.cmd, sent.steps, t_start=max(sent.t - path.start, 0.0), unit=sent.unit, feed=sent.feed)
        )

    def hold(self) -> None:
        """Feed hold now (from any thread: one byte); the control loop completes it (:meth:`check`)."""
        self._write(b"!")
        self._fresh = False
        if self._holding is None:
            self._holding = time.monotonic() + HOLD_S * 5
        self._streaming = False
        self._v = np.zeros(self.robot.nq)
        self._a = np.zeros(self.robot.nq)

    def _motion(self, cmd: Command, t: float) -> tuple[FloatArray, FloatArray]:
        """The arm's velocity and acceleration while ``cmd`` streams, about: the trajectory's where
        GRBL is along it (a stream's: along the lines it holds, on its path; a move's: its sample
        nearest, on from the last one's, within a second of it and not beyond the plan's time
        ``t`` [s]), the velocity scaled to the speed GRBL reports (it runs behind the plan, slower
        at corners)."""
        here = self._joints(self._steps)
        if self._held is not None and self._path is not None:
            cmd = self._path.cmd
            self._sample = self._path.sample(self._held.advance(self._steps, self._spd, self._ran_all()))
        else:
            now = min(int(t * cmd.rate_hz) + 1, len(cmd.times) - 1)
            self._sample = min(self._sample, now)
            ahead = cmd.position[self._sample : min(self._sample + int(cmd.rate_hz), now) + 1]
            self._sample += int(np.argmin(np.linalg.norm(ahead - here, axis=1)))
        v, a = cmd.velocity[self._sample], cmd.acceleration[self._sample]
        rates = np.degrees(self.robot.actuators.jacobian(here) @ v)  # [deg/s] per axis, as planned
        planned = float(np.linalg.norm(rates))
        return (v * (self._speed / planned) if planned > 0.0 else np.zeros_like(v)), a.copy()

    def measure(self) -> JointState:
        """The position GRBL last reported, through the offset (a status report is asked for at
        every call: the control loop parses the answer); velocity and acceleration as planned
        where GRBL is, the velocity at the speed GRBL reports (:meth:`_motion`)."""
        if time.monotonic() - self._asked >= STATUS_EVERY and not self._reset_wanted:
            self._write(b"?")
            self._asked = time.monotonic()
        return JointState(self._joints(self._steps), self._v.copy(), self._a.copy())

    def estimate(self) -> JointState:
        """As :meth:`measure`, from GRBL's last status report, with no ``?`` sent: the loop's
        every pass would double the status queries GRBL answers while it streams."""
        return JointState(self._joints(self._steps), self._v.copy(), self._a.copy())

    def check(self) -> None:
        self._pump()
        if self._holding is not None and not self._streaming:
            with self._lock:
                running = self._cmd is not None and not self._finished
            if not running:  # a hold from a fault or an estop with nothing running: complete it here
                while not self._hold_complete():
                    time.sleep(0.002)
        if self._reset_wanted:  # a limit alarm: GRBL stopped and answers no '?' until a reset, which
            return  # only an operator's unlock sends; what it said stands (homed false: position_unknown)
        self._poll_status(wait=True)

    def unlock(self, how: str) -> None:
        if self._holding is not None:
            while not self._hold_complete():
                time.sleep(0.002)
        self._operator_reset()  # (a limit alarm answers nothing else, status requests included)
        self._poll_status(wait=True)
        if how == "home":
            if not self.homing:
                raise BadRequest(
                    f"{self.robot.name} has no homing switches ([controller] homing = true in its "
                    "robot.toml): confirm its rest pose instead",
                    field="how",
                )
            self._home()
        else:
            self._assume_rest()

    def _operator_reset(self) -> None:
        """Because an operator asked: the reset GRBL wants after a limit alarm ("Reset to continue":
        it reads nothing else) before ``$X`` or ``$H``. GRBL is at rest then: the reset loses nothing."""
        if self._reset_wanted:
            self._reset()

    def _home(self) -> None:
        assert self.home_steps is not None
        self._operator_reset()
        log.info("%s: homing ($H)", self.robot.name)
        self._command("$H", timeout=HOMING_S)
        self._command(_MODES)
        self._set_offset(self.home_steps, "homed ($H)")

    def _assume_rest(self) -> None:
        self._operator_reset()
        if self._state == "Alarm":
            log.warning(
                "%s: GRBL is in an alarm: unlocking it ($X) because an operator said the arm is at rest",
                self.robot.name,
            )
            self._command("$X")
            self._command(_MODES)
        self._set_offset(self.rest_steps, "at its rest pose (an operator's word)")

    def _set_offset(self, actuator_steps: np.ndarray, how: str) -> None:
        self._poll_status(wait=True)
        self._offset = actuator_steps - self._steps
        self.homed = True
        self.lost = ""
        self._latest = JointState.at_rest(self._joints(self._steps))
        log.info(
            "%s: position known: %s; GRBL's machine position %s steps is the actuators' %s",
            self.robot.name,
            how,
            self._steps.tolist(),
            actuator_steps.tolist(),
        )

    def shutdown(self) -> None:
        try:
            self.serial.close()
        except Exception:  # already gone
            log.debug("close failed", exc_info=True)
