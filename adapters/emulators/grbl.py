"""An emulator of a GRBL 1.1h controller (an Arduino driving stepper motors), for tests: not firmware.

It speaks GRBL 1.1's serial protocol on a pseudo-terminal, so that an adapter opens
``serial.Serial(emulator.port, 115200, timeout=...)`` exactly as it opens ``/dev/ttyACM0``, and
it records what it received (``lines``, ``overflows``, ``max_rx_used``) for tests to check. Run
one by hand with ``python -m armd.adapters.emulators.grbl``: it prints the port and serves until Ctrl-C.
Units are GRBL's "mm": for armd, degrees of the actuator. Times are in seconds. It is written
from GRBL's source (gnea/grbl, grbl/*.c) and its doc/markdown; the file each behaviour follows
is named below.

Covered:

- Motion (planner.c, stepper.c). A 15-block planner (BLOCK_BUFFER_SIZE 16, one kept empty; the
  running block is one of them). Each G0/G1 block: targets rounded to whole steps (``lround``),
  length from the rounded steps; nominal speed the programmed rate (G0: the rapid rate) capped by
  ``$110``.. along the unit vector (limit_value_by_axis_maximum), at least 1 mm/min; acceleration
  ``$120``.. likewise; the junction's max speed from junction deviation ``$11`` exactly as
  plan_buffer_line computes it (junction_cos_theta, the half-angle sine, the junction's own
  acceleration limit, 0 for a reversal, unlimited straight on, 0 when the planner was empty),
  then capped by the smaller nominal speed of the two blocks. planner_recalculate's reverse pass
  (the newest block always planned to a stop) and forward pass, with GRBL's planned pointer.
  The running block runs st_prep_buffer's profiles (acceleration, cruise, deceleration;
  triangle, trapezoid, deceleration- or acceleration-only) computed from what is left of it
  (pl_block->millimeters) and its speed now, and is re-profiled when the planner changes its
  exit speed (st_update_plan_block_parameters). Hence a host streaming short blocks moves
  slower than it asked: within 15 blocks the machine must always be able to stop. The motion
  is integrated exactly in time from ``clock`` (no step timing): ``steps()`` (GRBL's
  sys_position) is whole steps along the block. A cycle starts when the receive buffer runs dry,
  the planner is full, or a command waits for it to empty (protocol_auto_cycle_start).
- ``!`` feed hold (protocol.c, stepper.c): the running block's profile is replaced by a
  deceleration to zero at its acceleration, continuing into the next blocks at theirs (a block
  loaded mid-hold enters at the speed reached); ``Hold:1``, then ``Hold:0`` where it stopped, never
  going back. In ``Hold:0`` GRBL's main loop is suspended: no line is read or answered until ``~``.
  ``~`` resumes from rest (plan_cycle_reinitialize), and is ignored during ``Hold:1``. A hold when
  idle is ``Hold:0`` at once.
- Two positions: GRBL's counters (``steps()``, ``position()``, the reports' MPos) and the arm's
  ``physical()`` position, relative to its own zero (``physical_start``). Opening the port resets
  the Arduino (its DTR auto-reset, main.c): the counters restart at 0 where the arm stands, and
  after a short boot (bytes sent meanwhile are lost) the welcome
  ``\\r\\nGrbl 1.1h ['$' for help]\\r\\n``. With ``$22=1`` GRBL starts in Alarm after any reset
  (HOMING_INIT_LOCK): ``[MSG:'$H'|'$X' to unlock]``.
- Homing ``$H`` (limits.c, motion_control.c, system.c): error 5 unless ``$22=1``. With
  ``home_switches`` (physical, per axis), it runs in machine time, state ``Home``: the cycles of
  ``homing_cycles`` (config.h: Z, then X and Y together), each a search at ``$25`` (times sqrt of
  the axes moving together) over 1.5 x ``$13x``, pull-off ``$27`` at ``$25``, a locating
  approach at ``$24`` over 10 x ``$27``, pull-off again, ``$26`` ms of debounce between, towards
  ``+`` or, for the axes in ``$23``, ``-``; each axis stops on its switch, the move ends when all
  have. Then GRBL's position is ``-$27`` (``-$13x + $27`` for ``$23`` axes), axes outside the cycles
  untouched, and the arm stands ``$27`` off its switches. A missing switch: ``ALARM:9``; a switch
  still pressed after the pull-off: ``ALARM:8``; a reset during homing: ``ALARM:6``; then GRBL's own
  reset (welcome, Alarm). Status reports wait until homing ends (its loop runs no real-time
  commands). Without ``home_switches``, ``$H`` sets that position at once and nothing moves.
- Work coordinates (gcode.c, settings.c, report.c): G54-G59 selection, ``G10 L2 Pn`` and
  ``G10 L20 Pn`` (P0 the active system; errors 20, 24, 26, 28, 29), ``G92``, ``G92.1``, ``G53``;
  the coordinate data are EEPROM (``coords``, ``offsets`` to start with some, kept across resets
  and DTR resets, cleared by ``$RST=#`` or ``$RST=*``), G92 is cleared by every reset (gc_init
  memsets the parser state, then reloads G54). These commands wait for the planner to empty
  (FORCE_BUFFER_SYNC_DURING_WCO_CHANGE, _EEPROM_WRITE), as do ``G4`` and spindle/coolant changes
  outside laser mode. ``$#`` prints ``[G54:..]``..``[G59:..]``, ``[G28:..]``, ``[G30:..]``,
  ``[G92:..]``, ``[TLO:0.000]``, ``[PRB:0.000,..:0]``; ``$G`` shows the active system.
- Status reports (report.c): ``<Idle|MPos:...|FS:...>`` with ``$10`` bit 0 MPos, else WPos =
  MPos - WCO (WCO = the active G54-G59 data + G92); bit 1 ``Bf:`` (planner blocks free, receive
  bytes free); ``FS:`` the current speed; ``Pn:`` the axes whose switch is pressed (with
  ``home_switches``); ``WCO:`` in the first report, every 10th idle or 30th
  busy one, and the next after an offset changes; ``Ov:`` every 10th/20th, the one after a WCO.
  With ``$13=1`` positions are reported in inches (4 decimals) and rates in inches/min (1
  decimal), in reports, ``$#`` and ``$G``'s F (print.c), whatever G20/G21 say.
  A ``?`` is answered ``status_delay`` later (GRBL's next main-loop pass); a ``?`` arriving before
  that report is merged into it, as GRBL's report flag does.
- Alarms (limits.c, protocol.c, motion_control.c): a hard limit (``inject_alarm(1)``, or, with
  ``$21=1`` and ``home_switches``, a move that presses or leaves a switch: any change of a limit
  pin, as without HARD_LIMIT_FORCE_STATE_CHECK; cut at that step) kills motion at once,
  no deceleration: a real machine may lose steps there and its position then be wrong (here both
  positions stay consistent). A soft limit (``inject_alarm(2)``, or with ``$20=1`` a target
  outside ``[-$13x, 0]``) first stops under control like a feed hold, so no position is lost. Both
  then print ``ALARM:n`` and ``[MSG:Reset to continue]``, read no line and answer no ``?``
  until a reset (protocol.c's critical loop does nothing but wait for the reset flag, and the
  reset clears a status request made meanwhile), and after it stay in Alarm until ``$X`` or
  ``$H``; G-code is ``error:9`` in Alarm. A reset while moving is ``ALARM:3``, not when stopped
  (Idle, ``Hold:0``): the position is kept. A line the parser was inside of at a reset is
  answered ``ok`` (gc_execute_line returns).
- Lines end with ``\\n`` or ``\\r``, each of which ends a line: ``\\r\\n`` is a line and an empty
  line, answered ``ok`` twice, as GRBL does. Spaces, ``(...)`` and ``;`` comments are dropped and
  letters upcased; a line longer than 79 characters is ``error:11``. A number counts 8 digits at
  most, leading zeros too (nuts_bolts.c's read_float: ``$11=0.00001432`` is 0.0000143). Every
  line is answered once, ``ok`` or ``error:N``, when the parser has taken it: a motion once it is
  in the planner, not when it is done. With the planner full the parser waits, and the bytes
  behind it wait in the ``rx_buffer``-byte receive buffer; bytes arriving when that is full are
  lost (``overflows``), as on the Arduino. Hence character counting: a host whose unanswered
  lines never exceed 128 bytes never loses any.
- G-code (gcode.c): ``G0``, ``G1 ... F`` (units/min), ``G4 P<s>``, ``G10``, ``G28``/``G30`` (rapid,
  through the block's point if any, to the stored position on the axes named, or all),
  ``G28.1``/``G30.1`` (store the position), ``G53``, ``G54``-``G59``, ``G90``/``G91``, ``G91.1``,
  ``G92``/``G92.1``, ``G20``/``G21``, ``N``, ``M0`` (after the line's moves, a feed hold; ``ok`` at the
  resume), ``M1`` (ignored), ``M2``/``M30`` (after the moves: G1 G54 G90 M5 M9, ``[MSG:Pgm End]``),
  ``M3``/``M4``/``M5`` with ``S``, ``M8``/``M9``, and the no-op modes ``G17``-``G19``, ``G40``,
  ``G49``, ``G61``, ``G80``, ``G94`` (``M7`` is ``error:20``, as in GRBL's default build). Errors 1,
  2, 4, 9, 11, 15, 16, 20-31, 36, 38 as GRBL numbers and orders them (``G0 G1`` is 24, as
  gc_execute_line finds the axis conflict first).
- ``$`` help, ``$$`` (``$100=250.000`` style), ``$<n>=<value>`` (errors 2, 3, 4, 6, 8, 10, 12;
  ``$22=0`` also clears ``$20``), ``$X``, ``$G``, ``$I``, ``$#``, ``$H``, ``$RST=$``/``#``/``*`` (then
  GRBL resets itself), ``$N`` and ``$N0=``/``$N1=`` startup lines (system.c: run to check them when
  stored; run after every reset out of Alarm and after ``$H``, each reported ``>line:ok``).
  ``0x18`` soft reset. Overrides (protocol.c, planner.c): feed ``0x90``-``0x94`` (10-200 %), rapid
  ``0x95``-``0x97`` (100, 50, 25 %), spindle ``0x99``-``0x9D``; a feed or rapid change re-plans every
  block (plan_update_velocity_profile_parameters) and the running one ramps to its new rate,
  down by stepper.c's deceleration-override ramp; jogs and homing ignore the feed override;
  ``Ov:`` shows them, in the next report after a change; M2/M30 restore them. Other bytes
  0x80-0xFF are dropped.
- Jogging (gcode.c, jog.c, protocol.c, serial.c): ``$J=`` with axis words, its own ``F``, and
  optionally ``G90``/``G91``, ``G20``/``G21``, ``G53`` (others error 16, no F 22), in Idle or Jog
  (else error 8). Its blocks go through the same planner as G1 (acceleration and junction
  deviation, no feed override); from Idle it starts at once if it planned a block (jog_execute:
  one to where the machine is plans none, and it stays Idle), state ``Jog``, and changes no modal
  state but the parser's position; a ``$J=`` with no axis word goes to machine zero (gc_execute_line
  zeroes its block, and only axis words set the target). With ``$20=1`` a jog beyond the travel
  is error 15 (no alarm). G-code lines while jogging are error 9; ``$$``, ``$G`` and ``$X`` are
  answered, other ``$`` commands (``$H``, ``$#``, ``$I``, settings) error 8 (system.c). ``0x85``
  (only in the Jog state: the serial interrupt ignores it elsewhere) or ``!`` cancel it: a
  deceleration along the queued blocks at their accelerations (the feed hold's), during which the
  main loop is suspended (it reads no line and the parser waits where it is), then the planner is
  flushed, parser and planner synced to where it stopped, and the state is Idle, no alarm. A line
  not yet in the planner when the cancel is taken (in the receive buffer, or the parser waiting in
  mc_line for a free block) is then executed, from where it stopped: the machine moves again after
  the cancel (GRBL 1.1h's known flaw, gnea/grbl#95, #423, #837).
- For tests: ``trace`` (clock time, physical position per axis) at every pass of the machine
  model while moving (the thread's 2 ms poll, and every query) and at each block's end, and
  ``pieces``, the exact motion before its whole steps (pieces of constant acceleration, each
  with its position, velocity and acceleration per axis: where GRBL turns from one block to the
  next, each axis' speed steps at once), both cleared by ``clear_trace()``; ``inject_alarm(code)``
  (other codes: motion stops, the planner empties, a waiting line is ``error:9``),
  ``inject_error_on_next_line(code)``, and ``responding = False`` (silent: reads and drops all);
  ``settings`` and ``startup_lines`` to start with (``{22: 1}``).

Where real GRBL differs, or may:

- Timing: GRBL cuts its profiles into 10 ms segments of constant step rate (DT_SEGMENT, AMASS)
  and prepares up to 5 of them ahead, so a planner change or a hold takes effect up to ~50 ms
  late there, and its planner already counts the prepared distance as done; here every change
  takes effect at once and speeds change continuously. GRBL also frees a planner block once it
  is prepared, so there ``Bf:`` and the ``ok`` of a line waiting for room come up to ~50 ms
  earlier than here. GRBL computes in 32-bit floats, here in doubles. Steps are interpolated
  linearly along each block, not Bresenham-timed.
- Not emulated (``error:20``/``error:3`` here, accepted there): arcs ``G2``/``G3``, ``G38.x``
  probing, ``G43.1``, ``G93``, ``$C``, ``$SLP``, ``$I=``; the spindle stop and coolant override
  toggles; the safety door, probe and spindle are absent; ``$5`` (inverted limit pins) is
  ignored. ``$RST=$`` restores this emulator's defaults.
- Switches exist only with ``home_switches``, one per axis, and trip exactly at their step (no
  switch travel, no bounce, no dual axes, no switch at the other end of an axis).
- ``!`` or ``~`` during homing are dropped (GRBL acts on them once homing ends). A real reset
  also loses bytes arriving during it, and the ``?`` latency varies with the main loop's load.
- ``inject_alarm`` with a code other than 1 and 2 prints only ``ALARM:<code>``; GRBL raises those
  (3-9) with mc_reset, so its welcome follows (reset yourself). ``$N2=`` and beyond are
  ``error:3`` here; GRBL does not check and writes past its two lines.
- ``physical()`` uses the current ``$10x``: changing steps/unit rescales it, where a real arm's
  gearing would not change.
- The pseudo-terminal has no baud rate: bytes arrive as fast as the host writes them, unless
  ``baud`` paces them (both ways, in 1-2 ms batches); either way the parser takes a line faster
  than GRBL's few milliseconds of parsing and planning.
- Linux pseudo-terminals: the port's open and close are seen as the master's hang-up clearing and
  setting, polled every 2 ms; a close and reopen quicker than that goes unseen (no reset, no welcome).
"""

from __future__ import annotations

import argparse
import contextlib
import math
import os
import re
import select
import threading
import time
from collections import deque
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field

from .pty import PtyEmulator

VERSION = "1.1h"
WELCOME = f"\r\nGrbl {VERSION} ['$' for help]\r\n"
BOOT_S = 0.1  # [s] wall time from opening the port to the welcome (a real Arduino takes ~1 s)
LINE_MAX = 79  # [characters] GRBL's line buffer, after spaces and comments are dropped
MAX_STEP_RATE = 30000  # [steps/s] the step rate GRBL refuses settings beyond (error:12)
MAX_INT_DIGITS = 8  # nuts_bolts.h: the digits of a number GRBL reads
AXIS_LETTERS = "XYZABC"
COORD_NAMES = ("G54", "G55", "G56", "G57", "G58", "G59", "G28", "G30")  # GRBL's EEPROM coordinate slots
MINIMUM_FEED_RATE = 1.0 / 60.0  # [units/s] config.h: 1 mm/min, the slowest nominal speed
MINIMUM_JUNCTION_SPEED = 0.0  # [units/s] config.h
SOME_LARGE_VALUE = 1.0e38  # nuts_bolts.h: a straight junction's speed limit (squared)
HOMING_AXIS_SEARCH_SCALAR = 1.5  # limits.c: the first approach searches 1.5 x $13x
HOMING_AXIS_LOCATE_SCALAR = 10.0  # limits.c: the locating approach searches 10 x $27
N_HOMING_LOCATE_CYCLE = 1  # config.h

_POLL_MS = 2  # the thread's period [ms]
_RESET, _STATUS, _HOLD, _RESUME, _JOG_CANCEL = 0x18, ord("?"), ord("!"), ord("~"), 0x85
_NUMBER = re.compile(r"[+-]?(?:\d+\.?\d*|\.\d+)")
_SETTING = re.compile(r"\$(" + _NUMBER.pattern + r")(?:(=)(" + _NUMBER.pattern + r")?)?(.*)")
_ACCEL, _CRUISE, _DECEL, _DECEL_OVERRIDE = 0, 1, 2, 3  # stepper.c's ramp types

# The settings GRBL 1.1 has, with its defaults; axis settings ($100+i ...) are added per axis.
_DEFAULTS: dict[int, float] = {
    0: 10,
    1: 25,
    2: 0,
    3: 0,
    4: 0,
    5: 0,
    6: 0,
    10: 1,
    11: 0.010,
    12: 0.002,
    13: 0,
    20: 0,
    21: 0,
    22: 0,
    23: 0,
    24: 25.0,
    25: 500.0,
    26: 250,
    27: 1.0,
    30: 1000,
    31: 0,
    32: 0,
}
_AXIS_DEFAULTS = {100: 250.0, 110: 500.0, 120: 10.0, 130: 200.0}  # steps/unit, units/min, units/s^2, units
_BOOLS = {4, 5, 6, 13, 20, 21, 22, 32}
_INTEGERS = {0, 1, 2, 3, 10, 23, 26} | _BOOLS
_G_GROUPS = {
    0: "motion",
    1: "motion",
    80: "motion",
    4: "non-modal",
    10: "non-modal",
    28: "non-modal",
    30: "non-modal",
    53: "non-modal",
    92: "non-modal",
    17: "plane",
    18: "plane",
    19: "plane",
    20: "units",
    21: "units",
    40: "cutter",
    49: "tool length",
    54: "wcs",
    55: "wcs",
    56: "wcs",
    57: "wcs",
    58: "wcs",
    59: "wcs",
    61: "control",
    90: "distance",
    91: "distance",
    94: "feed mode",
}
_M_GROUPS = {
    0: "flow",
    1: "flow",
    2: "flow",
    30: "flow",
    3: "spindle",
    4: "spindle",
    5: "spindle",
    8: "coolant",
    9: "coolant",
}


def _read_float(text: str) -> float:
    """nuts_bolts.c's read_float: at most MAX_INT_DIGITS (8) digits count, leading zeros too;
    further digits are dropped (after the point) or scale the value by ten (before it)."""
    digits, scale, point, kept = 0, 0, False, ""
    for c in text.lstrip("+-"):
        if c == ".":
            point = True
        elif digits < MAX_INT_DIGITS:
            digits += 1
            kept += c
            scale -= point
        elif not point:
            scale += 1
    value = float(f"{kept or 0}e{scale}")
    return -value if text.startswith("-") else value


def _round_steps(x: float) -> int:
    """C's lround: to the nearest integer, halves away from zero (GRBL's rounding of targets to steps)."""
    return int(math.copysign(math.floor(abs(x) + 0.5), x))


def _limit_by_axis_maximum(max_value: list[float], unit: list[float]) -> float:
    """nuts_bolts.c's limit_value_by_axis_maximum: the largest value along ``unit`` no axis' share exceeds."""
    limit = SOME_LARGE_VALUE
    for m, u in zip(max_value, unit, strict=True):
        if u != 0.0:
            limit = min(limit, abs(m / u))
    return limit


_Piece = tuple[float, float, tuple[float, ...], tuple[float, ...], tuple[float, ...]]  # see GrblEmulator.pieces


@dataclass
class _Block:
    """A planner block (planner.h's plan_block_t), in units, units/s and units/s^2."""

    start: list[int]  # [steps] the planner position it starts from
    target: list[int]  # [steps]
    length: float  # [units]
    millimeters: float  # [units] still to go: the stepper counts it down, as GRBL's pl_block->millimeters
    acceleration: float
    rapid_rate: float
    programmed_rate: float
    rapid: bool
    system: bool = False  # a homing move: planned alone, from rest to rest
    entry_speed_sqr: float = 0.0
    max_entry_speed_sqr: float = 0.0
    max_junction_speed_sqr: float = 0.0
    stop_rem: float = -1.0  # [units] homing approach: killed at once when millimeters reaches this
    clamp: list[int | None] | None = None  # homing approach: per axis, the step count its switch trips at

    no_feed_override: bool = False  # jogs and homing: PL_COND_FLAG_NO_FEED_OVERRIDE

    def nominal_speed(self, feed_override: int = 100, rapid_override: int = 100) -> float:
        """planner.c's plan_compute_profile_nominal_speed, with the overrides [%]."""
        if self.rapid:
            speed = self.programmed_rate * 0.01 * rapid_override
        else:
            speed = self.programmed_rate * (1.0 if self.no_feed_override else 0.01 * feed_override)
            speed = min(speed, self.rapid_rate)
        return max(speed, MINIMUM_FEED_RATE)


@dataclass
class _Profile:
    """stepper.c's st_prep_t velocity profile of the running block; distances are what is left to go."""

    ramp: int = _ACCEL
    accelerate_until: float = 0.0
    decelerate_after: float = 0.0
    maximum_speed: float = 0.0
    exit_speed: float = 0.0
    mm_complete: float = 0.0


@dataclass
class _Modal:
    """The G-code parser's modal state, as gc_init leaves it after a reset."""

    motion: int = 0
    absolute: bool = True
    inches: bool = False
    feed: float = 0.0  # [units/min]
    spindle: int = 5
    speed: float = 0.0  # [rpm]
    coolant: int = 9
    tool: int = 0
    coord_select: int = 0  # 0..5: G54..G59


@dataclass
class _Homing:
    """A homing cycle in progress (limits.c's limits_go_home), one phase at a time."""

    cycles: deque[list[int]]  # the axis index groups still to home, in order
    phases: deque[tuple[bool, float, float]] = field(default_factory=deque)  # approach?, travel, rate/min
    mask: list[int] = field(default_factory=list)  # the axes of the cycle being homed
    approach: bool = True
    pause: float = 0.0  # [machine s] the debounce delay ($26) still to wait


def _words(line: str) -> Iterator[tuple[str, float] | int]:
    """GRBL's word-by-word read of a block (gc_execute_line): ``(letter, value)`` per word, or,
    where a word cannot be read, its status code (1: not a letter, 2: no number) and nothing more."""
    i = 0
    while i < len(line):
        letter = line[i]
        if not "A" <= letter <= "Z":
            yield 1
            return
        m = _NUMBER.match(line, i + 1)
        if not m:
            yield 2
            return
        i = m.end()
        yield letter, _read_float(m.group())


class GrblEmulator(PtyEmulator):
    """A GRBL 1.1 controller on a pseudo-terminal: ``start()`` it, open ``port`` with pyserial."""

    name = "grbl-emulator"
    keep_slave = False  # a client's open shows as the hang-up clearing: the Arduino resets then

    def __init__(
        self,
        *,
        axes: str = "XYZ",
        rx_buffer: int = 128,
        planner_blocks: int = 15,
        time_scale: float = 1.0,
        clock: Callable[[], float] = time.monotonic,
        settings: Mapping[int, float] | None = None,
        offsets: Mapping[str, Mapping[str, float]] | None = None,
        physical_start: Mapping[str, float] | None = None,
        home_switches: Mapping[str, float] | None = None,
        homing_cycles: tuple[str, ...] = ("Z", "XY"),
        status_delay: float = 0.003,
        trace_max: int = 200_000,
        baud: int | None = None,
        startup_lines: tuple[str, ...] = (),
    ) -> None:
        """``axes``: the axis letters (from XYZABC), in report order; ``rx_buffer`` [bytes] and
        ``planner_blocks``: GRBL's buffer sizes (15 usable blocks of BLOCK_BUFFER_SIZE 16);
        ``time_scale``: machine seconds per clock second (10 runs motion and dwells 10 times as fast);
        ``clock`` [s]: drives motion and dwells; ``settings``: ``$n`` values already in the board's
        EEPROM (``{22: 1}``: homing enabled); ``offsets``: coordinate data already in EEPROM, by name
        (``{"G54": {"X": 10.0}}``, names in ``COORD_NAMES``); ``physical_start`` [units]: where the arm
        is, relative to its own zero, per axis (default 0); ``home_switches`` [units]: where each
        axis' homing switch is, in the same frame (None: ``$H`` sets the homed position without
        moving); ``homing_cycles``: the axes homed together, cycle by cycle (config.h's
        HOMING_CYCLE_0, _1: Z, then X and Y); ``status_delay`` [wall s]: from ``?`` to its report
        (GRBL answers at its next main-loop pass); ``trace_max``: the samples ``trace`` keeps;
        ``baud``: pass bytes both ways no faster than this serial line would (8N1: baud / 10 bytes/s;
        None: as fast as the pseudo-terminal does); ``startup_lines``: ``$N0``, ``$N1`` already in EEPROM
        (G-code GRBL runs after every reset out of Alarm, and after ``$H``)."""
        super().__init__()
        axes = axes.upper()
        if not axes or len(set(axes)) != len(axes) or any(a not in AXIS_LETTERS for a in axes):
            raise ValueError(f"axes must be distinct letters of {AXIS_LETTERS}, not {axes!r}")
        if rx_buffer < 1 or planner_blocks < 1 or time_scale <= 0 or status_delay < 0 or (baud or 1) <= 0:
            raise ValueError("rx_buffer, planner_blocks and time_scale must be positive, status_delay not negative")
        self.axes = axes
        self.rx_buffer = rx_buffer
        self.planner_blocks = planner_blocks
        self.time_scale = time_scale
        self.status_delay = status_delay
        self.baud = baud
        self._wire = bytearray()  # bytes on their way in over the serial line (with ``baud``)
        self._rx_credit = self._tx_credit = 0.0  # [bytes] the line's capacity not yet used, each way
        self._wire_last = time.monotonic()
        self._clock = clock
        self.settings: dict[int, float] = dict(_DEFAULTS)
        for base, value in _AXIS_DEFAULTS.items():
            self.settings.update({base + i: value for i in range(len(axes))})
        for n, v in (settings or {}).items():
            if n not in self.settings:
                raise ValueError(f"${n} is not a GRBL 1.1 setting for axes {axes}")
            self.settings[n] = float(v)
        self.coords: list[list[float]] = [[0.0] * len(axes) for _ in COORD_NAMES]  # GRBL's EEPROM
        for name, values in (offsets or {}).items():
            if name not in COORD_NAMES or any(a not in axes for a in values):
                raise ValueError(f"offsets: {name} {dict(values)} is not one of {COORD_NAMES} on axes {axes}")
            for a, v in values.items():
                self.coords[COORD_NAMES.index(name)][axes.index(a)] = float(v)
        bad = [a for a in {**(physical_start or {}), **(home_switches or {})} if a not in axes]
        if bad or any(a not in axes for cycle in homing_cycles for a in cycle.upper()):
            raise ValueError(f"physical_start, home_switches and homing_cycles must name axes of {axes}")
        if len(startup_lines) > 2:
            raise ValueError("GRBL keeps two startup lines ($N0, $N1)")
        self.startup_lines = [("".join(s.split())).upper() for s in startup_lines] + [""] * (2 - len(startup_lines))
        self.home_switches = None if home_switches is None else dict(home_switches)
        self.homing_cycles = tuple(c.upper() for c in homing_cycles)
        self.lines: list[str] = []  # every line the parser took, as received without its end
        self.overflows = 0  # [bytes] lost to a full receive buffer
        self.max_rx_used = 0  # [bytes] the most ever waiting in the receive buffer
        self.responding = True  # False: read and drop everything, answer nothing
        self._trace: deque[tuple[float, tuple[float, ...]]] = deque(maxlen=trace_max)
        self._pieces: deque[_Piece] = deque(maxlen=trace_max)
        self._lock = threading.RLock()
        self._tx = bytearray()
        self._inject_error: int | None = None
        self._last = self._clock()
        self._steps_done = [0] * len(axes)  # [steps] GRBL's sys_position at the running block's start
        # [steps] the arm's physical position is (_origin + GRBL's steps) / $10x
        self._origin = [
            _round_steps(float((physical_start or {}).get(a, 0.0)) * self._spu(i)) for i, a in enumerate(axes)
        ]
        self._status_due: float | None = None
        self._alarm = False
        self._blocks: deque[_Block] = deque()
        self._system_reset()
        self._power_up()
        self._boot_until: float | None = None  # [wall s] the welcome is due then; input is lost till then

    # -- the public side -----------------------------------------------------------------------

    def position(self) -> dict[str, float]:
        """GRBL's machine position now, per axis [units]: ``steps() / $10x`` (MPos)."""
        with self._lock:
            self._advance()
            return dict(zip(self.axes, self._units(self._steps_now()), strict=True))

    def steps(self) -> dict[str, int]:
        """GRBL's machine position now, per axis [steps] (its sys_position counters)."""
        with self._lock:
            self._advance()
            return dict(zip(self.axes, self._steps_now(), strict=True))

    def physical(self) -> dict[str, float]:
        """Where the arm really is now, per axis [units], relative to its own zero (not reset by a reset)."""
        with self._lock:
            self._advance()
            return dict(zip(self.axes, self._physical(), strict=True))

    def work_offset(self) -> dict[str, float]:
        """The work coordinate offset now (the active G54-G59 data plus G92), per axis [units]: ``WCO:``."""
        with self._lock:
            return dict(zip(self.axes, self._wco(), strict=True))

    @property
    def trace(self) -> list[tuple[float, tuple[float, ...]]]:
        """The motion recorded since ``clear_trace()``: (clock time [s], the physical position per axis
        [units], in ``axes`` order), at every pass of the machine model while it moves (the thread's
        2 ms poll and every query) and at each block's end; the last ``trace_max`` samples. A copy."""
        with self._lock:
            return list(self._trace)

    @property
    def pieces(self) -> list[_Piece]:
        """The exact motion since ``clear_trace()``, as the planner and the stepper profiles make it
        (before its rounding to whole steps): pieces of constant acceleration along a block, each
        (clock time of its start [s], its duration [s], the physical position per axis at its start
        [units], the velocity per axis at its start [units/s], the acceleration per axis
        [units/s^2]), in time order; the last ``trace_max``. Where one block hands over to the
        next the velocity keeps its speed and turns to the new block's direction at once, as in
        GRBL. (A homing approach's axes stopped by their switches are not in it.) A copy."""
        with self._lock:
            return list(self._pieces)

    def clear_trace(self) -> None:
        """Forget the recorded motion trace and pieces."""
        with self._lock:
            self._trace.clear()
            self._pieces.clear()

    @property
    def state(self) -> str:
        """``"Idle"``, ``"Run"``, ``"Hold"``, ``"Home"`` or ``"Alarm"``, now."""
        with self._lock:
            self._advance()
            return self._state()

    def inject_alarm(self, code: int) -> None:
        """Raise ``ALARM:<code>``. 1 (hard limit): motion killed at once, then, as 2 (soft limit) does
        after a controlled stop, ``[MSG:Reset to continue]`` and nothing read until a reset; other
        codes: motion stops, the planner empties, a waiting line is answered ``error:9``. G-code is
        then locked until ``$X`` or ``$H``."""
        with self._lock:
            self._advance()
            if code == 2:
                self._soft_limit()
                return
            if code == 1:
                if not self._alarm:  # limits.c: the limit pin is ignored in the alarm state
                    self._abort_motion(keep_parser=True)
                    self._critical_alarm(1)
                return
            if self._parser_busy():
                self._reply(9)  # the line the parser was waiting with is dropped with the planner
            self._abort_motion()
            self._alarm = True
            self._send(f"ALARM:{code}")

    def inject_error_on_next_line(self, code: int) -> None:
        """Answer the next G-code line (not ``$``, not empty) ``error:<code>``, and drop it."""
        with self._lock:
            self._inject_error = code

    # -- the machine ----------------------------------------------------------------------------

    def _power_up(self) -> None:
        """The Arduino's reset (DTR, on opening the port): GRBL's counters restart at 0 where the arm
        stands; settings and coordinate data stay (EEPROM); with homing enabled it starts in Alarm."""
        self._advance()
        steps = self._steps_now()
        self._origin = [o + s for o, s in zip(self._origin, steps, strict=True)]
        self._steps_done = [0] * len(self.axes)
        self._blocks.clear()
        self._alarm = self.settings[22] != 0  # HOMING_INIT_LOCK
        self._system_reset()

    def _system_reset(self) -> None:
        """main.c's loop after a reset: buffers, parser (gc_init), planner (plan_reset), stepper."""
        self._rx: deque[int] = deque()
        self._line: list[str] = []
        self._raw = bytearray()
        self._comment = ""  # "(" or ";" while in a comment
        self._line_overflow = False
        # moves waiting for planner room: target [steps], rate [units/min], a jog?
        self._waiting: deque[tuple[list[int], float, bool]] = deque()
        self._flow: int | None = None  # M0, M2 or M30: done once the line's moves have run (a buffer sync)
        self._paused = False  # an M0 holding: its line is answered at the resume
        self._pending: str | None = None  # a line waiting for the planner to empty (a buffer sync)
        self._dwell_left: float | None = None  # [machine s] a G4 dwelling
        self._homing: _Homing | None = None
        self._soft_limit_wait = False  # a soft limit decelerating to its alarm
        self._held_line = False  # a line the parser is stuck in (a soft limit): answered ok at the reset
        self._critical = False
        self._modal = _Modal()
        self._g92 = [0.0] * len(self.axes)
        self._coord_system = list(self.coords[0])
        self._wco_count = 0
        self._ovr_count = 0
        self._status_due = None
        self._blocks.clear()
        self._planned = 0  # block_buffer_planned, relative to the tail
        self._prof: _Profile | None = None  # the running block's profile; None: not loaded (pl_block NULL)
        self._recalc = False  # PREP_FLAG_RECALCULATE: re-profile the running block, keep its speed
        self._v = 0.0  # [units/s] prep.current_speed
        self._cycle = False  # STATE_CYCLE (or STATE_JOG)
        self._f_ovr, self._r_ovr, self._s_ovr = 100, 100, 100  # [%] the overrides, reset by every reset
        self._decel_override = False  # PREP_FLAG_DECEL_OVERRIDE: the next block enters at the speed reached
        self._jog = False  # the motion is a $J= jog: state Jog; a hold cancels it
        self._hold = 0  # 0 none, 1 decelerating (Hold:1), 2 complete (Hold:0: the main loop is suspended)
        self._pl_position = list(self._steps_done)  # plan_sync_position
        self._prev_unit = [0.0] * len(self.axes)
        self._prev_nominal = 0.0
        self._gc_pos = self._units(self._steps_done)  # gc_sync_position [units]

    def _spu(self, i: int) -> float:
        """Axis i's steps per unit ($100+i; 0 counts as 1)."""
        return self.settings[100 + i] or 1.0

    def _units(self, steps: list[int]) -> list[float]:
        return [s / self._spu(i) for i, s in enumerate(steps)]

    def _physical(self) -> list[float]:
        return [(o + s) / self._spu(i) for i, (o, s) in enumerate(zip(self._origin, self._steps_now(), strict=True))]

    def _wco(self) -> list[float]:
        return [c + g for c, g in zip(self._coord_system, self._g92, strict=True)]

    def _state(self) -> str:
        if self._alarm:
            return "Alarm"
        if self._homing is not None:
            return "Home"
        if self._jog:
            return "Jog"  # also while a jog cancel decelerates
        if self._hold:
            return "Hold"
        return "Run" if self._cycle else "Idle"

    def _moving(self) -> bool:
        return bool(self._blocks) and (self._cycle or self._homing is not None) and self._hold != 2

    def _suspended(self) -> bool:
        """GRBL's ``sys.suspend`` (protocol_exec_rt_suspend): the main loop reads no line and the
        parser waits where it is, in a completed hold (Hold:0) and for the whole of a jog cancel
        (SUSPEND_JOG_CANCEL is set when the cancel is taken, cleared when it has stopped)."""
        return self._hold == 2 or (self._hold == 1 and self._jog)

    def _steps_now(self) -> list[int]:
        if not self._blocks:
            return list(self._steps_done)
        b = self._blocks[0]
        f = min((b.length - b.millimeters) / b.length, 1.0)
        steps = [s + int(f * (t - s)) for s, t in zip(b.start, b.target, strict=True)]
        if b.clamp is not None:
            for i, c in enumerate(b.clamp):
                if c is not None:
                    steps[i] = min(steps[i], c) if b.target[i] > b.start[i] else max(steps[i], c)
        return steps

    def _advance(self) -> None:
        """Run the machine on to the clock's now, exactly (no step timing), and trace it."""
        now = self._clock()
        if now == self._last:
            return
        t0, dt = self._last, (now - self._last) * self.time_scale
        self._last = now
        used = 0.0
        while dt - used > 1e-12:
            left = dt - used
            h = self._homing
            if h is not None and h.pause > 0.0:
                step = min(left, h.pause)
                h.pause -= step
                used += step
                if h.pause <= 0.0:
                    self._homing_next()
            elif self._moving():
                n = len(self._blocks)
                used += self._ramp(left, t0 + used / self.time_scale)
                if len(self._blocks) != n:  # a block boundary: trace it at its own time
                    self._trace.append((t0 + used / self.time_scale, tuple(self._physical())))
            elif self._dwell_left is not None and self._synced():
                step = min(left, self._dwell_left)
                self._dwell_left -= step
                used += step
                if self._dwell_left <= 0.0:
                    break  # the parser goes on at the next service pass
            else:
                break
        if self._moving() or self._hold == 1:
            self._trace.append((now, tuple(self._physical())))

    # -- the stepper (stepper.c's st_prep_buffer, integrated exactly) ---------------------------------

    def _ramp(self, left: float, at: float) -> float:
        """Run the running block for up to ``left`` [machine s] within its current ramp, from clock
        time ``at`` [s]; return the time used."""
        b = self._blocks[0]
        if self._prof is None:
            self._load_profile(b)
        p = self._prof
        assert p is not None
        a, rem, v = b.acceleration, b.millimeters, self._v
        if p.ramp == _ACCEL:
            end, v_end, acc = p.accelerate_until, p.maximum_speed, a
        elif p.ramp == _CRUISE:
            end, v_end, acc = p.decelerate_after, v, 0.0
        elif p.ramp == _DECEL_OVERRIDE:
            end, v_end, acc = p.accelerate_until, p.maximum_speed, -a
        else:
            end, v_end, acc = p.mm_complete, p.exit_speed, -a
        stop = max(end, b.stop_rem)
        d = max(rem - stop, 0.0)
        if stop > end:  # a homing switch trips inside this ramp
            t = d / max(v, 1e-12) if acc == 0.0 else (math.sqrt(max(v * v + 2.0 * acc * d, 0.0)) - v) / acc
        else:
            t = 2.0 * d / (v + v_end) if v + v_end > 0.0 else 0.0  # at rest with nowhere to go: done
        self._piece(b, at, min(t, left), v, acc)
        if t > left:
            dd = min(max(v * left + 0.5 * acc * left * left, 0.0), d)
            b.millimeters = rem - dd
            self._v = max(v + acc * left, 0.0)
            return left
        b.millimeters = stop
        if stop > end:
            self._v = v + acc * t
            self._tripped()
            return t
        self._v = v_end
        if p.ramp == _ACCEL:
            p.ramp = _DECEL if end == p.decelerate_after else _CRUISE
        elif p.ramp == _CRUISE:
            p.ramp = _DECEL
        elif p.ramp == _DECEL_OVERRIDE:
            p.ramp = _CRUISE
        elif stop > 0.0:  # the end of a feed hold's deceleration, inside the block
            self._v = 0.0
            self._cycle_stop()
        else:
            self._block_done()
        return t

    def _piece(self, b: _Block, at: float, duration: float, v: float, acc: float) -> None:
        """Record a piece of the exact motion: block ``b`` from where it is now, for ``duration``
        [machine s] from clock time ``at``, at speed ``v`` [units/s] and acceleration ``acc`` along it."""
        if duration <= 0.0:
            return
        f = (b.length - b.millimeters) / b.length
        unit = [(t - s) / self._spu(i) / b.length for i, (s, t) in enumerate(zip(b.start, b.target, strict=True))]
        k = self.time_scale
        self._pieces.append(
            (
                at,
                duration / k,
                tuple(
                    (o + s + f * (t - s)) / self._spu(i)
                    for i, (o, s, t) in enumerate(zip(self._origin, b.start, b.target, strict=True))
                ),
                tuple(u * v * k for u in unit),
                tuple(u * acc * k * k for u in unit),
            )
        )

    def _load_profile(self, b: _Block) -> None:
        """st_prep_buffer's (re)computation of the running block's velocity profile."""
        if self._recalc:
            self._recalc = False
        elif self._hold == 1 or self._decel_override:  # mid-hold (or override) it enters at the speed reached
            b.entry_speed_sqr = self._v * self._v
            self._decel_override = False
        else:
            self._v = math.sqrt(b.entry_speed_sqr)
        p = _Profile()
        mm, entry, a = b.millimeters, b.entry_speed_sqr, b.acceleration
        inv_2_accel = 0.5 / a
        if self._hold == 1:  # forced deceleration to zero speed
            p.ramp = _DECEL
            decel_dist = mm - inv_2_accel * entry
            if decel_dist < 0.0:
                p.exit_speed = math.sqrt(max(entry - 2.0 * a * mm, 0.0))
            else:
                p.mm_complete = decel_dist
        else:
            p.accelerate_until = mm
            exit_sqr = 0.0 if b.system or len(self._blocks) < 2 else self._blocks[1].entry_speed_sqr
            p.exit_speed = math.sqrt(exit_sqr)
            nominal = b.nominal_speed(self._f_ovr, self._r_ovr)
            nominal_sqr = nominal * nominal
            intersect = 0.5 * (mm + inv_2_accel * (entry - exit_sqr))
            if entry > nominal_sqr:  # only with overrides in GRBL; kept for completeness
                p.accelerate_until = mm - inv_2_accel * (entry - nominal_sqr)
                if p.accelerate_until <= 0.0:
                    p.ramp = _DECEL
                    p.exit_speed = math.sqrt(max(entry - 2.0 * a * mm, 0.0))
                    self._decel_override = True
                else:
                    p.decelerate_after = inv_2_accel * (nominal_sqr - exit_sqr)
                    p.maximum_speed = nominal
                    p.ramp = _DECEL_OVERRIDE
            elif intersect > 0.0:
                if intersect < mm:  # trapezoid or triangle
                    p.decelerate_after = inv_2_accel * (nominal_sqr - exit_sqr)
                    if p.decelerate_after < intersect:
                        p.maximum_speed = nominal
                        if entry == nominal_sqr:
                            p.ramp = _CRUISE
                        else:
                            p.accelerate_until -= inv_2_accel * (nominal_sqr - entry)
                    else:
                        p.accelerate_until = p.decelerate_after = intersect
                        p.maximum_speed = math.sqrt(2.0 * a * intersect + exit_sqr)
                else:  # deceleration only
                    p.ramp = _DECEL
            else:  # acceleration only
                p.accelerate_until = 0.0
                p.maximum_speed = p.exit_speed
        self._prof = p

    def _st_update(self) -> None:
        """stepper.c's st_update_plan_block_parameters: re-profile the running block from its speed now."""
        if self._prof is not None and self._blocks:
            self._blocks[0].entry_speed_sqr = self._v * self._v
            self._prof = None
            self._recalc = True

    def _block_done(self) -> None:
        self._steps_done = self._steps_now()  # the target, or short of it on axes a homing switch stopped
        self._blocks.popleft()
        self._prof, self._recalc = None, False
        self._planned = max(self._planned - 1, 0)  # plan_discard_current_block
        if self._homing is not None:
            self._homing_move_done(tripped=False)
        elif not self._blocks:
            self._cycle_stop()

    def _cycle_stop(self) -> None:
        """protocol.c's EXEC_CYCLE_STOP: a hold completes (Hold:0), or the cycle ends (Idle)."""
        self._cycle = False
        if self._jog:  # a jog ends, or its cancel has stopped: flush the planner and sync (protocol.c)
            self._jog = False
            if self._hold:
                self._abort_motion(keep_parser=True)
            return
        if self._hold == 1 and not self._soft_limit_wait:
            self._hold = 2
            self._st_update()  # plan_cycle_reinitialize: re-plan from rest
            self._planned = 0
            self._recalculate()
        else:
            self._hold = 0
        if self._soft_limit_wait:
            self._abort_motion(keep_parser=True)
            self._critical_alarm(2)

    def _abort_motion(self, keep_parser: bool = False) -> None:
        """Stop dead where the machine is (st_go_idle), empty the planner, sync parser and planner to it."""
        self._steps_done = self._steps_now()
        self._blocks.clear()
        self._prof, self._recalc, self._v, self._planned = None, False, 0.0, 0
        self._cycle, self._hold, self._homing, self._jog = False, 0, None, False
        self._decel_override = False
        self._pl_position = list(self._steps_done)
        self._prev_unit, self._prev_nominal = [0.0] * len(self.axes), 0.0
        self._gc_pos = self._units(self._steps_done)
        if not keep_parser:
            self._waiting, self._pending, self._dwell_left, self._flow = deque(), None, None, None
            self._paused = False
            self._soft_limit_wait = self._held_line = False

    def _critical_alarm(self, code: int) -> None:
        """Hard and soft limits (protocol_exec_rt_system): Alarm, and nothing read until a reset."""
        self._alarm = True
        self._soft_limit_wait = False
        self._send(f"ALARM:{code}")
        self._send("[MSG:Reset to continue]")
        self._critical = True
        self._status_due = None  # (a report asked before it is never made: the alarm comes first)

    def _soft_limit(self) -> None:
        """limits.c's limits_soft_check: a controlled stop (a feed hold) if moving, then ALARM:2."""
        if self._alarm:
            return
        if self._cycle:
            self._soft_limit_wait = True
            if self._hold == 0:
                self._st_update()
                self._hold = 1
        else:
            self._abort_motion(keep_parser=True)
            self._critical_alarm(2)

    # -- the planner (planner.c) -----------------------------------------------------------------

    def _plan_line(self, target: list[int], rate: float, *, system: bool = False, jog: bool = False) -> _Block | None:
        """plan_buffer_line: ``rate`` [units/min], 0 for a rapid; returns the block, None if it makes no step."""
        start = self._steps_now() if system else self._pl_position
        delta = [(t - s) / self._spu(i) for i, (s, t) in enumerate(zip(start, target, strict=True))]
        length = math.sqrt(sum(d * d for d in delta))
        if all(t == s for s, t in zip(start, target, strict=True)):
            return None  # GRBL drops a block that makes no step
        unit = [d / length for d in delta]
        accel = _limit_by_axis_maximum([self.settings[120 + i] for i in range(len(unit))], unit)
        rapid_rate = _limit_by_axis_maximum([self.settings[110 + i] / 60.0 for i in range(len(unit))], unit)
        rapid = rate <= 0.0 and not system
        b = _Block(
            list(start),
            list(target),
            length,
            length,
            accel,
            rapid_rate,
            rapid_rate if rapid else rate / 60.0,
            rapid,
            system,
            no_feed_override=system or jog,
        )
        if system:
            return b
        if self._blocks:  # the junction with the previous block: planner.c's junction deviation
            cos_theta = -sum(p * u for p, u in zip(self._prev_unit, unit, strict=True))
            if cos_theta > 0.999999:  # a reversal
                b.max_junction_speed_sqr = MINIMUM_JUNCTION_SPEED**2
            elif cos_theta < -0.999999:  # straight on
                b.max_junction_speed_sqr = SOME_LARGE_VALUE
            else:
                junction = [u - p for p, u in zip(self._prev_unit, unit, strict=True)]
                norm = math.sqrt(sum(j * j for j in junction))
                junction = [j / norm for j in junction]
                junction_accel = _limit_by_axis_maximum([self.settings[120 + i] for i in range(len(unit))], junction)
                sin_theta_d2 = math.sqrt(0.5 * (1.0 - cos_theta))
                b.max_junction_speed_sqr = max(
                    MINIMUM_JUNCTION_SPEED**2, junction_accel * self.settings[11] * sin_theta_d2 / (1.0 - sin_theta_d2)
                )
        nominal = b.nominal_speed(self._f_ovr, self._r_ovr)  # plan_compute_profile_parameters
        b.max_entry_speed_sqr = min(nominal, self._prev_nominal) ** 2
        b.max_entry_speed_sqr = min(b.max_entry_speed_sqr, b.max_junction_speed_sqr)
        self._prev_nominal, self._prev_unit, self._pl_position = nominal, unit, list(target)
        if self.settings[21] and self.home_switches:  # hard limits: where the block would change a limit pin
            for i in range(len(unit)):
                switch = self._switch_steps(i)
                pressed = self._pressed(i, start[i])
                if switch is not None and pressed != self._pressed(i, target[i]):
                    if pressed:  # leaving the switch: its pin changes too (no HARD_LIMIT_FORCE_STATE_CHECK)
                        switch += -1 if not int(self.settings[23]) >> i & 1 else 1
                    trip = (switch - start[i]) / (target[i] - start[i]) * length
                    b.stop_rem = max(b.stop_rem, length - trip)
        self._blocks.append(b)
        self._recalculate()
        return b

    def _recalculate(self) -> None:
        """planner.c's planner_recalculate: reverse pass from a stop at the newest block, forward pass."""
        blocks, n = self._blocks, len(self._blocks)
        i = n - 1
        if i <= self._planned:
            return
        current = blocks[i]
        current.entry_speed_sqr = min(current.max_entry_speed_sqr, 2.0 * current.acceleration * current.millimeters)
        i -= 1
        if i == self._planned:
            if i == 0:
                self._st_update()
        else:
            while i != self._planned:
                nxt, current = current, blocks[i]
                i -= 1
                if i == 0:
                    self._st_update()
                if current.entry_speed_sqr != current.max_entry_speed_sqr:
                    entry = nxt.entry_speed_sqr + 2.0 * current.acceleration * current.millimeters
                    current.entry_speed_sqr = min(entry, current.max_entry_speed_sqr)
        nxt = blocks[self._planned]
        i = self._planned + 1
        while i < n:
            current, nxt = nxt, blocks[i]
            if current.entry_speed_sqr < nxt.entry_speed_sqr:
                entry = current.entry_speed_sqr + 2.0 * current.acceleration * current.millimeters
                if entry < nxt.entry_speed_sqr:
                    nxt.entry_speed_sqr = entry
                    self._planned = i
            if nxt.entry_speed_sqr == nxt.max_entry_speed_sqr:
                self._planned = i
            i += 1

    # -- homing (limits.c's limits_go_home, motion_control.c's mc_homing_cycle) ----------------------

    def _home(self) -> int | None:
        """``$H``: error 5 unless ``$22=1``; with switches, the homing cycles run in machine time."""
        if not self.settings[22]:
            return 5
        cycles = [[self.axes.index(a) for a in c if a in self.axes] for c in self.homing_cycles]
        cycles = [c for c in cycles if c]
        if self.home_switches is None:  # no switches modelled: the homed position, at once
            for mask in cycles:
                self._set_homed(mask)
            self._alarm = False
            self._sync_positions()
            self._run_startup()
            return 0
        self._homing = _Homing(deque(cycles))
        self._alarm = False  # STATE_HOMING
        self._homing_next_cycle()
        return None  # answered when homing ends

    def _homing_next_cycle(self) -> None:
        h = self._homing
        assert h is not None
        if not h.cycles:
            self._homing = None
            self._alarm = False
            self._sync_positions()
            self._run_startup()
            self._reply(0)
            return
        h.mask = h.cycles.popleft()
        seek, feed, pulloff = self.settings[25], self.settings[24], self.settings[27]
        search = max(HOMING_AXIS_SEARCH_SCALAR * self.settings[130 + i] for i in h.mask)
        h.phases = deque([(True, search, seek)])
        for _ in range(N_HOMING_LOCATE_CYCLE):
            h.phases += [(False, pulloff, seek), (True, pulloff * HOMING_AXIS_LOCATE_SCALAR, feed)]
        h.phases.append((False, pulloff, seek))
        self._homing_next()

    def _homing_next(self) -> None:
        """Start the next homing move: GRBL zeroes the cycle's counters, then moves them all together."""
        h = self._homing
        assert h is not None
        if not h.phases:
            self._set_homed(h.mask)
            self._homing_next_cycle()
            return
        approach, travel, rate = h.phases.popleft()
        h.approach = approach
        steps = self._steps_now()
        for i in h.mask:
            self._origin[i] += steps[i]
            steps[i] = 0
        self._steps_done = steps
        target = list(steps)
        for i in h.mask:
            negative = bool(int(self.settings[23]) >> i & 1) == approach
            target[i] = _round_steps((-travel if negative else travel) * self._spu(i))
        b = self._plan_line(target, rate * math.sqrt(len(h.mask)), system=True)
        if b is None:
            self._homing_move_done(tripped=not approach)
            return
        if approach:
            b.clamp = [None] * len(self.axes)
            trip = 0.0
            for i in h.mask:
                switch = self._switch_steps(i)
                if switch is None:
                    trip = math.inf  # never trips: the approach runs its whole search, then ALARM:9
                elif self._pressed(i, b.start[i]):
                    b.clamp[i] = b.start[i]  # pressed already: the axis is locked at once
                else:
                    b.clamp[i] = switch
                    share = abs(b.target[i] - b.start[i]) / self._spu(i) / b.length
                    trip = max(trip, abs(switch - b.start[i]) / self._spu(i) / share)
            if trip < b.length:
                b.stop_rem = b.length - trip
        self._blocks.append(b)

    def _switch_steps(self, i: int) -> int | None:
        """Axis i's switch, in GRBL's step counts now (None: no switch)."""
        if self.home_switches is None or self.axes[i] not in self.home_switches:
            return None
        return _round_steps(self.home_switches[self.axes[i]] * self._spu(i)) - self._origin[i]

    def _pressed(self, i: int, steps: int) -> bool | None:
        """Is axis i's switch pressed with GRBL's count at ``steps``? (None: it has no switch.)"""
        switch = self._switch_steps(i)
        if switch is None:
            return None
        negative = bool(int(self.settings[23]) >> i & 1)
        return steps <= switch if negative else steps >= switch

    def _tripped(self) -> None:
        """A switch is pressed: the hard-limit ISR kills motion at once (ALARM:1); or every axis of a
        homing approach found its switch, and st_reset kills the move at once."""
        if self._homing is None:
            self._abort_motion(keep_parser=True)
            self._critical_alarm(1)
            return
        self._steps_done = self._steps_now()
        self._blocks.clear()
        self._prof, self._recalc, self._v = None, False, 0.0
        self._homing_move_done(tripped=True)

    def _homing_move_done(self, tripped: bool) -> None:
        h = self._homing
        assert h is not None
        self._v = 0.0
        if h.approach and not tripped:
            self._homing_fail(9)  # the approach ended without finding a switch
            return
        if not h.approach and any(self._pressed(i, self._steps_done[i]) for i in h.mask):
            self._homing_fail(8)  # pull-off did not clear the switch
            return
        h.pause = self.settings[26] / 1000.0
        if h.pause <= 0.0:
            self._homing_next()

    def _homing_fail(self, code: int) -> None:
        """A homing alarm: mc_reset kills motion, ALARM:<code>, then the reset GRBL does itself."""
        self._abort_motion(keep_parser=True)
        self._alarm = True
        self._send(f"ALARM:{code}")
        self._reply(0)  # system_execute_line returns after the abort: the $H line is answered ok
        self._system_reset()
        self._welcome()

    def _set_homed(self, mask: list[int]) -> None:
        """GRBL's machine position after homing: -$27, or -$13x + $27 for axes homed in the negative
        direction ($23); the arm does not move."""
        steps = self._steps_now()
        for i in mask:
            if int(self.settings[23]) >> i & 1:
                new = _round_steps((-self.settings[130 + i] + self.settings[27]) * self._spu(i))
            else:
                new = _round_steps(-self.settings[27] * self._spu(i))
            self._origin[i] += steps[i] - new
            steps[i] = new
        self._steps_done = steps

    def _sync_positions(self) -> None:
        """gc_sync_position and plan_sync_position."""
        self._pl_position = list(self._steps_done)
        self._gc_pos = self._units(self._steps_done)

    # -- the serial side ------------------------------------------------------------------------

    def _serve(self) -> None:
        """The thread: read the port, run the machine, answer."""
        poller = select.poll()
        poller.register(self._master, select.POLLIN)
        connected = False
        while not self._stop.is_set():
            timeout = 1 if self._wire or (self.baud and self._tx) else _POLL_MS
            if self._status_due is not None and self._homing is None:
                timeout = max(0, min(timeout, math.ceil((self._status_due - time.monotonic()) * 1000)))
            events = poller.poll(timeout)
            hung_up = any(ev & select.POLLHUP for _, ev in events)
            data = b""
            if not hung_up and any(ev & select.POLLIN for _, ev in events):
                try:
                    data = os.read(self._master, 4096)
                except OSError:
                    hung_up = True
            with self._lock:
                data, tx_room = self._line_rate(data)
                if hung_up:
                    connected = False
                    self._wire.clear()
                elif not connected:  # a client opened the port: the Arduino resets
                    connected = True
                    self._power_up()
                    self._boot_until = time.monotonic() + BOOT_S
                if self._boot_until is not None and time.monotonic() >= self._boot_until:
                    self._boot_until = None
                    self._welcome()
                self._service()
                self._receive(data)
                if self._status_due is not None and time.monotonic() >= self._status_due:
                    self._status_report()
                if not connected:
                    self._tx.clear()
                elif self._tx and tx_room:
                    with contextlib.suppress(BlockingIOError):
                        sent = os.write(self._master, self._tx[:tx_room])
                        del self._tx[:sent]
                        self._tx_credit -= sent if self.baud else 0
            if hung_up:
                time.sleep(_POLL_MS / 1000)  # the master reports the hang-up at once, every time

    def _line_rate(self, data: bytes) -> tuple[bytes, int]:
        """With ``baud``: the bytes that have crossed the line by now, and how many may go out."""
        if not self.baud:
            return data, len(self._tx)
        now = time.monotonic()
        rate, dt = self.baud / 10.0, now - self._wire_last
        self._wire_last = now
        self._wire += data
        self._rx_credit = min(self._rx_credit + dt * rate, max(len(self._wire), 1))
        self._tx_credit = min(self._tx_credit + dt * rate, max(len(self._tx), 1))
        n = int(self._rx_credit)
        data = bytes(self._wire[:n])
        del self._wire[:n]
        self._rx_credit -= len(data)
        return data, int(self._tx_credit)

    def _receive(self, data: bytes) -> None:
        """Bytes from the host: real-time ones act now, the rest go through the receive buffer."""
        if not self.responding or self._boot_until is not None:
            return
        for c in data:
            if c == _RESET:
                self._soft_reset()
            elif c == _STATUS:
                # (protocol.c's critical loop: no report until the reset, which clears the flag)
                if self._status_due is None and not self._critical:  # GRBL's report flag: a '?' merges into it
                    self._status_due = time.monotonic() + self.status_delay
                    if self.status_delay <= 0.0:
                        self._status_report()
            elif c == _HOLD:
                self._feed_hold()
            elif c == _RESUME:
                self._cycle_start()
            elif 0x90 <= c <= 0x9D:
                self._override(c)
            elif c == _JOG_CANCEL:
                self._advance()
                if self._jog and not self._hold:
                    self._st_update()
                    self._hold = 1
            elif c < 0x80:
                if len(self._rx) < self.rx_buffer:
                    self._rx.append(c)
                    self.max_rx_used = max(self.max_rx_used, len(self._rx))
                else:
                    self.overflows += 1
                self._read_lines()

    def _service(self) -> None:
        """Run the machine to now; finish the line the parser waits with; read on if it can."""
        self._advance()
        self._unblock()
        self._read_lines()

    def _synced(self) -> bool:
        """protocol_buffer_synchronize's end: the planner empty and no cycle."""
        return not self._blocks and not self._cycle and self._homing is None

    def _parser_busy(self) -> bool:
        return (
            bool(self._waiting)
            or self._pending is not None
            or self._dwell_left is not None
            or self._flow is not None
            or self._paused
            or self._homing is not None
            or self._soft_limit_wait
            or self._held_line
        )

    def _auto_cycle_start(self) -> None:
        """protocol_auto_cycle_start: queued blocks start moving (from Idle only)."""
        if self._blocks and not self._cycle and not self._hold and not self._alarm and self._homing is None:
            self._cycle = True

    def _unblock(self) -> None:
        """Finish the line the parser waits with, if the machine has made room or synced."""
        if self._critical or self._suspended():
            return
        if self._pending is not None:
            self._auto_cycle_start()
            if self._synced():
                line, self._pending = self._pending, None
                status = self._gcode(line, synced=True)
                if status is not None:
                    self._reply(status)
        if self._dwell_left is not None and self._dwell_left <= 0.0:
            self._dwell_left = None
            if not self._waiting and self._flow is None:
                self._reply(0)
        while self._waiting and self._dwell_left is None:
            if len(self._blocks) >= self.planner_blocks:
                self._auto_cycle_start()  # mc_line: a full planner starts the cycle
                return
            target, rate, jog = self._waiting.popleft()
            self._plan_line(target, rate, jog=jog)
            if jog and self._blocks and not self._cycle and not self._hold and not self._alarm:
                self._cycle = self._jog = True  # jog_execute: from Idle, a jog starts at once (if it planned a block)
            if not self._waiting and self._flow is None:
                self._reply(0)
        if self._flow is not None and self._dwell_left is None:
            self._auto_cycle_start()  # protocol_buffer_synchronize
            if self._synced():
                self._program_flow()

    def _program_flow(self) -> None:
        """gc_execute_line's last step, once the planner is empty: M0 pauses (a feed hold, the line
        answered at the resume), M2 and M30 end the program (some modal groups reset)."""
        flow, self._flow = self._flow, None
        if flow == 0:
            self._hold, self._paused = 2, True
            return
        mod = self._modal
        mod.motion, mod.absolute, mod.spindle, mod.coolant = 1, True, 5, 9
        mod.coord_select = 0
        self._coord_system = list(self.coords[0])
        self._wco_changed()
        self._f_ovr, self._r_ovr, self._s_ovr = 100, 100, 100  # RESTORE_OVERRIDES_AFTER_PROGRAM_END
        self._send("[MSG:Pgm End]")
        self._reply(0)

    def _read_lines(self) -> None:
        """GRBL's protocol loop: take characters from the receive buffer while the parser is free."""
        while self._rx and not self._parser_busy() and not self._critical and not self._suspended():
            c = self._rx.popleft()
            if c in (0x0A, 0x0D):
                self._end_line()
                continue
            self._raw.append(c)
            ch = chr(c)
            if self._comment or self._line_overflow:
                if ch == ")" and self._comment == "(":
                    self._comment = ""
            elif c <= 0x20 or ch == "/":
                pass  # spaces, control characters and block delete are dropped
            elif ch in "(;":
                self._comment = ch
            elif len(self._line) >= LINE_MAX:
                self._line_overflow = True
            else:
                self._line.append(ch.upper())
        if not self._rx:
            self._auto_cycle_start()  # the receive buffer ran dry: queued motion starts

    def _end_line(self) -> None:
        line, raw, overflow = "".join(self._line), self._raw.decode("ascii", "replace"), self._line_overflow
        self._line, self._raw, self._comment, self._line_overflow = [], bytearray(), "", False
        if raw.strip():
            self.lines.append(raw)
        if overflow:
            self._reply(11)
        elif not line:
            self._reply(0)
        elif line.startswith("$"):
            status = self._system(line)
            if status is not None:
                self._reply(status)
        elif self._inject_error is not None:
            code, self._inject_error = self._inject_error, None
            self._reply(code)
        elif self._alarm or self._jog:
            self._reply(9)  # protocol_main_loop: G-code is locked out in Alarm and while jogging
        else:
            status = self._gcode(line)
            if status is not None:
                self._reply(status)
            else:
                self._unblock()  # the line may go through at once

    def _send(self, text: str) -> None:
        if self.responding:
            self._tx += (text + "\r\n").encode()

    def _reply(self, status: int) -> None:
        self._send("ok" if status == 0 else f"error:{status}")

    def _welcome(self) -> None:
        """report_init_message, then protocol_main_loop's start: the Alarm lock's message, or the startup lines."""
        self._send(WELCOME[:-2])
        if self._alarm:
            self._send("[MSG:'$H'|'$X' to unlock]")
        else:
            self._run_startup()

    def _run_startup(self) -> None:
        """system_execute_startup: each stored line runs as G-code, reported ``>line:ok``. Its moves
        are planned at once (the planner is empty then); a G4 or M0/M2 in it is not waited for."""
        for line in self.startup_lines:
            if line:
                status = self._gcode(line, synced=True)
                while self._waiting:
                    self._plan_line(*self._waiting.popleft()[:2])
                self._dwell_left = self._flow = None
                self._send(f">{line}:{'ok' if not status else f'error:{status}'}")

    def _soft_reset(self) -> None:
        """Ctrl-X (mc_reset, then main.c's re-initialisation): stop, empty every buffer, keep the
        position; ALARM:3 if it was moving (ALARM:6 if homing); a line the parser was waiting with is
        answered ``ok`` as gc_execute_line returns; G54 reloaded, G92 cleared (gc_init)."""
        self._advance()
        homing = self._homing is not None
        moving = self._cycle or self._hold == 1 or homing
        waiting = self._parser_busy()
        self._abort_motion()
        if moving and not self._critical:
            self._alarm = True
            self._send(f"ALARM:{6 if homing else 3}")
        if waiting:
            self._reply(0)
        self._system_reset()
        self._welcome()

    def _feed_hold(self) -> None:
        """``!``: decelerate along the path (stepper.c's forced deceleration), Hold:1 then Hold:0 (while
        jogging: a jog cancel)."""
        self._advance()
        if self._alarm or self._hold or self._homing is not None:
            return
        if self._cycle:
            self._st_update()
            self._hold = 1
        else:
            self._hold = 2  # GRBL holds when idle too: queued moves wait for ``~``

    def _cycle_start(self) -> None:
        """``~``: resume a completed hold (ignored during Hold:1, as GRBL does), or start queued blocks."""
        self._advance()
        if self._alarm or self._homing is not None:
            return
        if self._hold == 2:
            self._hold = 0
            if self._blocks:
                self._cycle = True
            if self._paused:  # the M0 line goes on
                self._paused = False
                self._reply(0)
        elif self._hold == 0:
            self._auto_cycle_start()

    def _override(self, c: int) -> None:
        """protocol.c's overrides: feed 0x90-0x94 (10-200 %), rapid 0x95-0x97 (100/50/25 %), spindle
        0x99-0x9D (10-200 %); a motion override re-plans every block (plan_update_velocity_profile_
        parameters, plan_cycle_reinitialize); each change puts Ov: in the next report."""
        self._advance()
        f, r, s = self._f_ovr, self._r_ovr, self._s_ovr
        if c <= 0x94:
            f = 100 if c == 0x90 else f + {0x91: 10, 0x92: -10, 0x93: 1, 0x94: -1}[c]
            f = min(max(f, 10), 200)
        elif c <= 0x97:
            r = {0x95: 100, 0x96: 50, 0x97: 25}[c]
        elif c >= 0x99:
            s = 100 if c == 0x99 else s + {0x9A: 10, 0x9B: -10, 0x9C: 1, 0x9D: -1}[c]
            s = min(max(s, 10), 200)
        if (f, r, s) == (self._f_ovr, self._r_ovr, self._s_ovr):
            return
        self._ovr_count = 0
        motion = (f, r) != (self._f_ovr, self._r_ovr)
        self._f_ovr, self._r_ovr, self._s_ovr = f, r, s
        if motion:
            prev = SOME_LARGE_VALUE
            for b in self._blocks:
                nominal = b.nominal_speed(f, r)
                b.max_entry_speed_sqr = min(min(nominal, prev) ** 2, b.max_junction_speed_sqr)
                prev = nominal
            self._prev_nominal = prev
            self._st_update()
            self._planned = 0
            self._recalculate()

    def _status_report(self) -> None:
        """report.c's report_realtime_status."""
        if self._homing is not None:
            return  # GRBL's homing loop does not run the real-time commands: the report waits
        self._status_due = None
        self._advance()
        mask = int(self.settings[10])
        state = self._state()
        busy = state in ("Run", "Hold", "Home")
        if state == "Hold":
            state += ":0" if self._hold == 2 else ":1"
        pos = self._units(self._steps_now())
        wco = self._wco()
        if not mask & 1:
            pos = [p - w for p, w in zip(pos, wco, strict=True)]
        fields = [state, f"{'MPos' if mask & 1 else 'WPos'}:{self._values(pos)}"]
        if mask & 2:
            planned = len(self._blocks) if self._homing is None else 0  # homing moves are outside the buffer
            fields.append(f"Bf:{self.planner_blocks - planned},{self.rx_buffer - len(self._rx)}")
        speed = self._modal.speed * 0.01 * self._s_ovr  # spindle_compute_pwm_value's clamp to $31..$30
        speed = min(max(speed, self.settings[31]), self.settings[30]) if self._modal.spindle != 5 else 0.0
        rate = self._v * 60.0 if self._moving() or self._hold == 1 else 0.0
        fields.append(f"FS:{self._rate(rate)},{speed:.0f}")
        steps = self._steps_now()
        pins = "".join(a for i, a in enumerate(self.axes) if self._pressed(i, steps[i]))
        if pins:
            fields.append(f"Pn:{pins}")  # the limit pins pressed (REPORT_FIELD_PIN_STATE)
        if self._wco_count > 0:
            self._wco_count -= 1
        else:
            self._wco_count = (30 if busy else 10) - 1
            self._ovr_count = self._ovr_count or 1
            fields.append(f"WCO:{self._values(wco)}")
        if self._ovr_count > 0:
            self._ovr_count -= 1
        else:
            self._ovr_count = (20 if busy else 10) - 1
            fields.append(f"Ov:{self._f_ovr},{self._r_ovr},{self._s_ovr}")
            acc = {3: "S", 4: "C"}.get(self._modal.spindle, "") + ("F" if self._modal.coolant == 8 else "")
            if acc:
                fields.append(f"A:{acc}")
        self._send("<" + "|".join(fields) + ">")

    def _values(self, values: list[float]) -> str:
        """print.c's printFloat_CoordValue: mm with 3 decimals, or with ``$13=1`` inches with 4."""
        if self.settings[13]:
            return ",".join(f"{v / 25.4 + 0.0:.4f}" for v in values)
        return ",".join(f"{v + 0.0:.3f}" for v in values)  # + 0.0: no "-0.000"

    def _rate(self, rate: float) -> str:
        """printFloat_RateValue [units/min]: no decimals, or with ``$13=1`` inches/min with 1."""
        return f"{rate / 25.4:.1f}" if self.settings[13] else f"{rate:.0f}"

    def _wco_changed(self) -> None:
        """system_flag_wco_change: the next report carries WCO:."""
        self._wco_count = 0

    # -- the commands ---------------------------------------------------------------------------

    def _system(self, line: str) -> int | None:
        """A ``$`` line (GRBL's system_execute_line); return the status code (None: answered later)."""
        state = self._state()
        cmd = line[1:]
        if not cmd:
            self._send("[HLP:$$ $# $G $I $N $x=val $Nx=line $J=line $SLP $C $X $H ~ ! ? ctrl-x]")
            return 0
        if cmd[0] == "J":  # before the Idle/Alarm check: jogs may follow jogs
            if state not in ("Idle", "Jog"):
                return 8
            return self._jog_line(cmd[2:]) if cmd.startswith("J=") else 3
        if cmd[0] in "$GX" and len(cmd) > 1:
            return 3
        if cmd == "$":
            if state in ("Run", "Hold"):
                return 8
            for n in sorted(self.settings):
                v = self.settings[n]
                self._send(f"${n}={v:.0f}" if n in _INTEGERS or n in (30, 31) else f"${n}={v:.3f}")
            return 0
        if cmd == "G":
            mod = self._modal
            self._send(
                f"[GC:G{mod.motion} G{54 + mod.coord_select} G17 G{20 if mod.inches else 21} "
                f"G{90 if mod.absolute else 91} G94 M{mod.spindle} M{mod.coolant} T{mod.tool} "
                f"F{self._rate(mod.feed)} S{mod.speed:.0f}]"
            )  # F in $13's unit, not G20's
            return 0
        if cmd == "X":
            if self._alarm:
                self._send("[MSG:Caution: Unlocked]")
                self._alarm = False
            return 0
        if state not in ("Idle", "Alarm"):
            return 8
        if cmd[0] == "#":
            if cmd != "#":
                return 3
            for name, data in zip(COORD_NAMES, self.coords, strict=True):
                self._send(f"[{name}:{self._values(data)}]")
            self._send(f"[G92:{self._values(self._g92)}]")
            self._send(f"[TLO:{self._values([0.0])}]")
            self._send(f"[PRB:{self._values([0.0] * len(self.axes))}:0]")
            return 0
        if cmd == "I":
            self._send(f"[VER:{VERSION}.20190830:]")
            self._send(f"[OPT:V,{self.planner_blocks},{self.rx_buffer}]")
            return 0
        if cmd == "H":
            return self._home()
        if cmd.startswith("RST="):
            return self._restore(cmd[4:])
        if cmd == "N":
            for n, stored in enumerate(self.startup_lines):
                self._send(f"$N{n}={stored}")
            return 0
        m = re.fullmatch(r"N(\d+)=(.*)", cmd)
        if m:
            if state != "Idle":
                return 8  # stored only when idle: GRBL prevents motion during Alarm
            if int(m.group(1)) > 1:
                return 3  # N_STARTUP_LINE is 2 (GRBL itself does not check: it would write past them)
            status = self._gcode(m.group(2)) if m.group(2) else 0  # run to check it, as GRBL does
            if not status:
                self.startup_lines[int(m.group(1))] = m.group(2)
            return status
        if cmd[0] in "CJNRSI":
            return 3  # $C, $J=, $N, $SLP, $I=: not emulated
        m = _SETTING.fullmatch(line)
        if not m:
            return 2  # not a setting's number
        if m.group(2) is None:
            return 3
        if m.group(3) is None:
            return 2
        if m.group(4):
            return 3
        return self._store_setting(int(_read_float(m.group(1))), _read_float(m.group(3)))

    def _restore(self, what: str) -> int | None:
        """``$RST=$`` (settings), ``$RST=#`` (coordinate data), ``$RST=*`` (both), then GRBL resets itself."""
        if what not in ("$", "#", "*"):
            return 3
        if what in "$*":
            self.settings = dict(_DEFAULTS)
            for base, value in _AXIS_DEFAULTS.items():
                self.settings.update({base + i: value for i in range(len(self.axes))})
        if what in "#*":
            self.coords = [[0.0] * len(self.axes) for _ in COORD_NAMES]
        self._send("[MSG:Restoring defaults]")
        self._reply(0)
        self._system_reset()
        self._welcome()
        return None

    def _store_setting(self, n: int, value: float) -> int:
        """``$n=value`` (GRBL's settings_store_global_setting); return the status code."""
        if value < 0.0:
            return 4
        if n not in self.settings or n > 255:
            return 3
        if n == 0 and value < 3.0:
            return 6
        if n == 20 and value and not self.settings[22]:
            return 10
        i = n % 10
        if 100 <= n < 120:  # steps/unit x max rate [steps/min] must stay within MAX_STEP_RATE
            other = self.settings[110 + i] if n < 110 else self.settings[100 + i]
            if value * other > MAX_STEP_RATE * 60.0:
                return 12
        if n in _BOOLS:
            value = 1.0 if int(value) else 0.0
        elif n in _INTEGERS:
            value = float(int(value))
        self.settings[n] = value
        if n == 22 and not value:
            self.settings[20] = 0.0  # settings.c: disabling homing disables soft limits
        return 0

    def _jog_line(self, line: str) -> int | None:
        """``$J=...`` (gc_execute_line with GC_PARSER_JOG_MOTION, then jog_execute): a G1 at its own F
        in its own G90/G91, G20/G21 or G53, changing no modal state; beyond soft limits error 15."""
        words: dict[str, float] = {}
        groups: dict[str, int] = {}
        for word in _words(line):
            if isinstance(word, int):
                return word
            letter, value = word
            if letter in "GM":
                code = int(value)
                if code not in (_G_GROUPS if letter == "G" else _M_GROUPS):
                    return 20
                group = {90: "distance", 91: "distance", 20: "units", 21: "units", 53: "non-modal"}.get(code)
                if letter == "M" or group is None or code != value:
                    return 16  # only distance, units and G53 words in a jog
                if group in groups:
                    return 21
                groups[group] = code
            elif letter in self.axes or letter in "FIJKLNPRST":
                if letter in words:
                    return 25
                if letter in "FN" and value < 0.0:
                    return 4
                words[letter] = value
            else:
                return 20
        if any(w not in self.axes and w not in "FN" for w in words):
            return 16
        if "F" not in words:
            return 22  # a jog needs its own feed rate
        mod = self._modal
        scale = 25.4 if {20: True, 21: False}.get(groups.get("units", -1), mod.inches) else 1.0
        absolute = groups.get("distance", 90 if mod.absolute else 91) == 90
        target = list(self._gc_pos)
        if not any(a in words for a in self.axes):  # gc_execute_line zeroes its block and only axis words
            target = [0.0] * len(self.axes)  # set the target: a jog with none goes to machine zero
        for j, a in enumerate(self.axes):
            if a in words:
                v = words[a] * scale
                if "non-modal" in groups:
                    target[j] = v
                elif absolute:
                    target[j] = v + self._coord_system[j] + self._g92[j]
                else:
                    target[j] += v
        if self.settings[20] and any(t > 0.0 or t < -self.settings[130 + j] for j, t in enumerate(target)):
            return 15  # jog_execute: a jog beyond the soft limits is refused, no alarm
        self._gc_pos = target
        self._waiting.append(([_round_steps(p * self._spu(j)) for j, p in enumerate(target)], words["F"] * scale, True))
        return None

    def _gcode(self, line: str, synced: bool = False) -> int | None:
        """A G-code block (GRBL's gc_execute_line); return the status, or None if it waits for the machine.
        A block that needs the planner empty (G4, G10, G92, a G54-G59 change, spindle or coolant
        changes) is validated, then waits as a whole in ``_pending`` and is executed once synced."""
        words: dict[str, float] = {}
        groups: dict[str, int] = {}
        mantissas: dict[str, int] = {}
        axis_command = ""  # "motion" or "non-modal" (G10, G92), as GRBL's axis_command
        for word in _words(line):
            if isinstance(word, int):
                return word
            letter, value = word
            if letter in "GM":
                code, mantissa = int(value), round(100 * (value - int(value)))
                table = _G_GROUPS if letter == "G" else _M_GROUPS
                if letter == "M" and mantissa > 0:
                    return 23
                if letter == "G" and code == 91 and mantissa == 10:
                    group = "arc distance"  # G91.1: arc IJK incremental, GRBL's only mode
                    mantissa = 0
                elif code not in table:
                    return 20
                else:
                    group = table[code]
                if letter == "G" and code in (10, 28, 30, 92) and mantissa == 0:
                    if axis_command:
                        return 24
                    axis_command = "non-modal"
                if letter == "G" and code in (28, 30, 92):  # G28.1, G30.1, G92.1
                    if mantissa not in (0, 10):
                        return 20
                    mantissas[str(code)], mantissa = mantissa, 0
                if letter == "G" and code in (0, 1):
                    if axis_command:
                        return 24
                    axis_command = "motion"
                if mantissa > 0:
                    return 23
                if group in groups:
                    return 21
                groups[group] = code
            elif letter in self.axes or letter in "FIJKLNPRST":
                if letter in words:
                    return 25
                if letter in "FNPST" and value < 0.0:
                    return 4
                words[letter] = value
            else:
                return 20
        non_modal = groups.get("non-modal", -1)
        if mantissas.get(str(non_modal)) == 10:
            non_modal = non_modal * 10 + 1  # 281, 301, 921: G28.1, G30.1, G92.1
        g92_1 = non_modal == 921
        if words.get("N", 0.0) > 9999999:
            return 27
        if words.get("T", 0.0) > 255:
            return 38
        mod = self._modal
        inches = {20: True, 21: False}.get(groups.get("units", -1), mod.inches)
        scale = 25.4 if inches else 1.0
        axis = {a: words[a] * scale for a in self.axes if a in words}
        if axis and not axis_command:
            axis_command = "motion"  # axis words alone: the modal motion
        motion = groups.get("motion", mod.motion)
        feed = words["F"] * scale if "F" in words else mod.feed
        coord_select = groups["wcs"] - 54 if "wcs" in groups else mod.coord_select
        block_coords = self.coords[coord_select] if coord_select != mod.coord_select else self._coord_system
        if non_modal == 4 and "P" not in words:
            return 28
        coord_data: tuple[int, list[float]] | None = None
        g92: list[float] | None = None
        if non_modal == 10:
            if not axis:
                return 26
            if "P" not in words or "L" not in words:
                return 28
            p = int(words["P"])
            if p > 6:
                return 29
            if int(words["L"]) not in (2, 20) or (int(words["L"]) == 2 and "R" in words):
                return 20
            slot = p - 1 if p > 0 else coord_select
            data = list(self.coords[slot])
            for j, a in enumerate(self.axes):
                if a in axis:
                    data[j] = self._gc_pos[j] - self._g92[j] - axis[a] if int(words["L"]) == 20 else axis[a]
            coord_data = (slot, data)
        elif non_modal == 92:
            if not axis:
                return 26
            g92 = [
                self._gc_pos[j] - block_coords[j] - axis[a] if a in axis else self._g92[j]
                for j, a in enumerate(self.axes)
            ]
        if non_modal == 53 and motion not in (0, 1):
            return 30
        if motion == 80 and axis:
            return 31
        moving = axis_command == "motion" and motion in (0, 1) and bool(axis)
        if axis_command == "motion" and motion == 1 and feed == 0.0:
            return 22
        used = {"P"} if non_modal == 4 else {"P", "L"} if non_modal == 10 else set()
        if any(w in words for w in "IJKLRP" if w not in used):
            return 36  # the last of gc_execute_line's checks: value words no command used
        speed = words.get("S")
        spindle, coolant = groups.get("spindle", mod.spindle), groups.get("coolant", mod.coolant)
        sync = non_modal in (4, 10, 92, 921, 281, 301) or coord_select != mod.coord_select
        if (spindle, coolant) != (mod.spindle, mod.coolant) or (speed not in (None, mod.speed) and spindle != 5):
            sync = sync or not self.settings[32]  # outside laser mode GRBL waits for the planner to empty
        if sync and not synced:
            self._pending = line  # valid: executed once the planner is empty
            return None
        # the block is valid (and synced if it must be): apply it, in GRBL's order
        mod.inches, mod.feed, mod.motion = inches, feed, motion
        mod.tool = int(words.get("T", mod.tool))
        mod.spindle, mod.coolant = spindle, coolant
        mod.speed = mod.speed if speed is None else speed
        if non_modal == 4:
            self._dwell_left = words["P"]
        if coord_select != mod.coord_select:
            mod.coord_select = coord_select
            self._coord_system = list(block_coords)
            self._wco_changed()
        if "distance" in groups:
            mod.absolute = groups["distance"] == 90
        if coord_data is not None:
            slot, data = coord_data
            self.coords[slot] = data
            if slot == mod.coord_select:
                self._coord_system = list(data)
                self._wco_changed()
        if g92 is not None:
            self._g92 = g92
            self._wco_changed()
        if g92_1:
            self._g92 = [0.0] * len(self.axes)
            self._wco_changed()
        if non_modal in (281, 301):  # G28.1, G30.1: the parser's position into EEPROM
            self.coords[6 if non_modal == 281 else 7] = list(self._gc_pos)
        targets: list[tuple[list[float], float]] = []
        if moving or (non_modal in (28, 30) and axis):
            target_units = list(self._gc_pos)
            for j, a in enumerate(self.axes):
                if a in axis:
                    if non_modal == 53:
                        target_units[j] = axis[a]
                    elif mod.absolute:
                        target_units[j] = axis[a] + self._coord_system[j] + self._g92[j]
                    else:
                        target_units[j] += axis[a]
            targets.append((target_units, 0.0 if motion == 0 or non_modal in (28, 30) else feed))
        if non_modal in (28, 30):  # G28, G30: rapid to the stored position (of the axes named, if any)
            stored = self.coords[6 if non_modal == 28 else 7]
            final = [
                stored[j] if not axis or a in axis else p
                for j, (a, p) in enumerate(zip(self.axes, self._gc_pos, strict=True))
            ]
            targets.append((final, 0.0))
        for target_units, rate in targets:
            if self.settings[20] and any(t > 0.0 or t < -self.settings[130 + j] for j, t in enumerate(target_units)):
                self._held_line = True  # limits_soft_check: the parser stays in this line till the reset
                self._soft_limit()
                return None
            self._gc_pos = target_units
            self._waiting.append(([_round_steps(p * self._spu(j)) for j, p in enumerate(target_units)], rate, False))
        flow = groups.get("flow")
        if flow in (0, 2, 30):
            self._flow = flow
        if self._dwell_left is not None or self._waiting or self._flow is not None:
            return None
        return 0


def main(argv: list[str] | None = None) -> None:
    """Serve one emulator until Ctrl-C, printing its port."""
    parser = argparse.ArgumentParser(prog="python -m armd.adapters.emulators.grbl", description=__doc__.splitlines()[0])
    parser.add_argument("--axes", default="XYZ", help="axis letters, from XYZABC (default XYZ)")
    parser.add_argument("--time-scale", type=float, default=1.0, help="machine seconds per second (default 1)")
    args = parser.parse_args(argv)
    with GrblEmulator(axes=args.axes, time_scale=args.time_scale) as emulator:
        print(emulator.port, flush=True)
        with contextlib.suppress(KeyboardInterrupt):
            while True:
                time.sleep(1.0)


if __name__ == "__main__":
    main()
