"""An emulator of a GRBL 1.1 controller (an Arduino driving stepper motors), for tests: not firmware.

It speaks GRBL 1.1's serial protocol on a pseudo-terminal, so that an adapter opens
``serial.Serial(emulator.port, 115200, timeout=...)`` exactly as it opens ``/dev/ttyACM0``, and
it records what it received (``lines``, ``overflows``, ``max_rx_used``) for tests to check. Run
one by hand with ``python -m clients.emulators.grbl``: it prints the port and serves until Ctrl-C.
Units are GRBL's "mm": for armd, degrees of the actuator. Times are in seconds.

Covered (gnea/grbl wiki: "Grbl v1.1 Interface", "Commands", "Configuration"):

- Opening the port resets the Arduino (its DTR auto-reset): machine position 0, and after a short
  boot (bytes sent meanwhile are lost) the welcome ``\\r\\nGrbl 1.1h ['$' for help]\\r\\n``.
- Lines end with ``\\n`` or ``\\r``, each of which ends a line: ``\\r\\n`` is a line and an empty
  line, answered ``ok`` twice, as GRBL does. Spaces, ``(...)`` and ``;`` comments are dropped and
  letters upcased; a line longer than 79 characters is ``error:11``. Every line is answered once,
  ``ok`` or ``error:N``, when the parser has taken it: a motion once it is in the planner (of
  ``planner_blocks`` blocks, the running one included), not when it is done. With the planner
  full the parser waits, and the bytes behind it wait in the ``rx_buffer``-byte receive buffer;
  bytes arriving when that is full are lost (counted in ``overflows``), as on the Arduino. Hence
  character counting: a host whose unanswered lines never exceed 128 bytes never loses any.
- G-code: ``G0`` (at the axes' max rates), ``G1 ... F`` (units/min, capped by the max rates, as
  GRBL caps the rate along the move's direction), ``G4 P<s>`` (waits for the planner to empty,
  then dwells, then answers), ``G90``/``G91``, ``G20``/``G21``, ``G53``, ``N``, ``M3``/``M4``/``M5`` with
  ``S`` and ``M8``/``M9`` (which, outside laser mode, also wait for the planner to empty, like GRBL),
  and the no-op modes ``G17``-``G19``, ``G40``, ``G49``, ``G54``-``G59`` (all offsets zero), ``G61``,
  ``G80``, ``G94`` (``M7`` is ``error:20``, as in GRBL's default build). Errors: 1, 2, 4, 9, 11, 20-23,
  25, 27, 28, 30, 31, 36, 38, as GRBL numbers them.
- ``$`` help, ``$$`` (every setting, ``$100=250.000`` style), ``$<n>=<value>`` (errors 2, 3, 4, 6, 8,
  10, 12), ``$X`` (``[MSG:Caution: Unlocked]``), ``$G``, ``$I``, ``$H`` (``error:5`` unless ``$22=1``).
- Real-time bytes, taken out of the stream wherever they come: ``?`` a status report
  (``<Idle|MPos:0.000,0.000,0.000|FS:0,0>``, ``Bf:`` with ``$10=2`` or 3, ``WPos:`` with ``$10=0``,
  ``WCO:`` and ``Ov:`` at GRBL's intervals), ``!`` feed hold (decelerates at ``$12x``: ``Hold:1``,
  then ``Hold:0``), ``~`` resume (ignored during ``Hold:1``, as GRBL does), ``0x18`` soft reset (empties
  the buffers, keeps the position, prints the welcome; in motion or ``Hold:1``, not ``Hold:0``, it
  first raises ``ALARM:3`` and stays in Alarm until ``$X``). Bytes 0x80-0xFF (overrides) are dropped.
- Machine position is kept in whole steps, as GRBL does: each target is rounded to steps with
  ``$10x``, and ``position()`` is ``steps() / $10x``.
- Test hooks: ``inject_alarm(code)`` (motion stops, the planner is emptied, ``ALARM:<code>``, a line
  waiting for planner room is answered ``error:9``; for 1 and 2, hard and soft limits, also
  ``[MSG:Reset to continue]`` and nothing is read, nor answered, until a reset),
  ``inject_error_on_next_line(code)``, and ``responding = False`` (silent: reads and drops all).

Where real GRBL differs, or may:

- No acceleration planning: each block runs at its constant rate from the start, corners are
  taken at full speed, and a resume restarts at full speed; only a feed hold decelerates. A real
  move takes longer, by about ``v / (2 a)`` per start and per stop (v [units/s], a = ``$12x``).
  Neither is the real step timing emulated: steps are interpolated linearly along each block.
- Not emulated (``error:20``/``error:3`` here, accepted there): arcs ``G2``/``G3``, ``G10``, ``G28``/``G30``,
  ``G38.x`` probing, ``G43.1``, ``G92``, ``G93``, ``G91.1``, ``M0``/``M1``/``M2``/``M30``, jogging
  ``$J=``, ``$#``, ``$N``, ``$C``, ``$RST=``, ``$SLP``, ``$I=``. No overrides, limit switches, soft limits,
  probe, door or spindle; ``$13`` (inches) does not change reports. ``$H`` homes at once, without moving.
- GRBL answers a status request within 5-20 ms and drops a ``?`` that comes before the previous
  report; here each ``?`` is answered at once. A real reset also loses bytes arriving during it.
- A real alarm is often accompanied by a reset (hard limit, homing failures) that prints the
  welcome; ``inject_alarm`` does not (reset yourself, as a host must anyway after 1 and 2).
- The pseudo-terminal has no baud rate: bytes arrive as fast as the host writes them.
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
from collections.abc import Callable
from dataclasses import dataclass

from .pty import PtyEmulator

VERSION = "1.1h"
WELCOME = f"\r\nGrbl {VERSION} ['$' for help]\r\n"
BOOT_S = 0.1  # [s] wall time from opening the port to the welcome (a real Arduino takes ~1 s)
LINE_MAX = 79  # [characters] GRBL's line buffer, after spaces and comments are dropped
MAX_STEP_RATE = 30000  # [steps/s] the step rate GRBL refuses settings beyond (error:12)
AXIS_LETTERS = "XYZABC"

_POLL_MS = 2  # the thread's period [ms]
_RESET, _STATUS, _HOLD, _RESUME = 0x18, ord("?"), ord("!"), ord("~")
_NUMBER = re.compile(r"[+-]?(?:\d+\.?\d*|\.\d+)")
_SETTING = re.compile(r"\$(" + _NUMBER.pattern + r")(?:(=)(" + _NUMBER.pattern + r")?)?(.*)")

# The settings GRBL 1.1 has, with its defaults; axis settings ($100+i ...) are added per axis.
_DEFAULTS: dict[int, float] = {0: 10, 1: 25, 2: 0, 3: 0, 4: 0, 5: 0, 6: 0, 10: 1, 11: 0.010, 12: 0.002,
                               13: 0, 20: 0, 21: 0, 22: 0, 23: 0, 24: 25.0, 25: 500.0, 26: 250, 27: 1.0,
                               30: 1000, 31: 0, 32: 0}
_AXIS_DEFAULTS = {100: 250.0, 110: 500.0, 120: 10.0, 130: 200.0}  # steps/unit, units/min, units/s^2, units
_BOOLS = {4, 5, 6, 13, 20, 21, 22, 32}
_INTEGERS = {0, 1, 2, 3, 10, 23, 26} | _BOOLS
_G_GROUPS = {0: "motion", 1: "motion", 80: "motion", 4: "non-modal", 53: "non-modal", 17: "plane", 18: "plane",
             19: "plane", 20: "units", 21: "units", 40: "cutter", 49: "tool length", 54: "wcs", 55: "wcs",
             56: "wcs", 57: "wcs", 58: "wcs", 59: "wcs", 61: "control", 90: "distance", 91: "distance",
             94: "feed mode"}
_M_GROUPS = {3: "spindle", 4: "spindle", 5: "spindle", 8: "coolant", 9: "coolant"}


def _round_steps(x: float) -> int:
    """C's lround: to the nearest integer, halves away from zero (GRBL's rounding of targets to steps)."""
    return int(math.copysign(math.floor(abs(x) + 0.5), x))


@dataclass
class _Block:
    """A planned straight move: to ``target`` [steps], ``length`` [units] at ``rate`` [units/min]."""

    target: list[int]
    length: float
    rate: float
    accel: float  # [units/s^2] the deceleration a feed hold uses


@dataclass
class _Modal:
    """The G-code parser's modal state, as after a reset."""

    motion: int = 0
    absolute: bool = True
    inches: bool = False
    feed: float = 0.0  # [units/min]
    spindle: int = 5
    speed: float = 0.0  # [rpm]
    coolant: int = 9
    tool: int = 0


class GrblEmulator(PtyEmulator):
    """A GRBL 1.1 controller on a pseudo-terminal: ``start()`` it, open ``port`` with pyserial."""

    name = "grbl-emulator"
    keep_slave = False  # a client's open shows as the hang-up clearing: the Arduino resets then

    def __init__(self, *, axes: str = "XYZ", rx_buffer: int = 128, planner_blocks: int = 15,
                 time_scale: float = 1.0, clock: Callable[[], float] = time.monotonic) -> None:
        """``axes``: the axis letters (from XYZABC), in report order; ``rx_buffer`` [bytes] and
        ``planner_blocks``: GRBL's buffer sizes; ``time_scale``: machine seconds per clock second
        (10 runs motion and dwells 10 times as fast); ``clock`` [s]: drives motion and dwells."""
        super().__init__()
        axes = axes.upper()
        if not axes or len(set(axes)) != len(axes) or any(a not in AXIS_LETTERS for a in axes):
            raise ValueError(f"axes must be distinct letters of {AXIS_LETTERS}, not {axes!r}")
        if rx_buffer < 1 or planner_blocks < 1 or time_scale <= 0:
            raise ValueError("rx_buffer, planner_blocks and time_scale must be positive")
        self.axes = axes
        self.rx_buffer = rx_buffer
        self.planner_blocks = planner_blocks
        self.time_scale = time_scale
        self._clock = clock
        self.settings: dict[int, float] = dict(_DEFAULTS)
        for base, value in _AXIS_DEFAULTS.items():
            self.settings.update({base + i: value for i in range(len(axes))})
        self.lines: list[str] = []  # every line the parser took, as received without its end
        self.overflows = 0  # [bytes] lost to a full receive buffer
        self.max_rx_used = 0  # [bytes] the most ever waiting in the receive buffer
        self.responding = True  # False: read and drop everything, answer nothing
        self._lock = threading.RLock()
        self._tx = bytearray()
        self._inject_error: int | None = None
        self._power_up()
        self._boot_until: float | None = None  # [wall s] the welcome is due then; input is lost till then

    # -- the public side -----------------------------------------------------------------------

    def position(self) -> dict[str, float]:
        """The machine position now, per axis [units]: ``steps() / $10x``."""
        with self._lock:
            self._advance()
            return dict(zip(self.axes, self._units(self._steps_now()), strict=True))

    def steps(self) -> dict[str, int]:
        """The machine position now, per axis [steps]: ``round(position * $10x)``."""
        with self._lock:
            self._advance()
            return dict(zip(self.axes, self._steps_now(), strict=True))

    @property
    def state(self) -> str:
        """``"Idle"``, ``"Run"``, ``"Hold"`` or ``"Alarm"``, now."""
        with self._lock:
            self._advance()
            return self._state()

    def inject_alarm(self, code: int) -> None:
        """Raise ``ALARM:<code>``: motion stops, the planner empties, G-code is locked until ``$X``."""
        with self._lock:
            self._advance()
            if (self._waiting or self._dwell_left is not None) and code not in (1, 2):
                self._reply(9)  # the line the parser was waiting with is dropped with the planner
            self._abort_motion()
            self._alarm = True
            self._send(f"ALARM:{code}")
            if code in (1, 2):  # hard and soft limits: GRBL reads nothing more until a reset
                self._send("[MSG:Reset to continue]")
                self._critical = True

    def inject_error_on_next_line(self, code: int) -> None:
        """Answer the next G-code line (not ``$``, not empty) ``error:<code>``, and drop it."""
        with self._lock:
            self._inject_error = code

    # -- the machine ----------------------------------------------------------------------------

    def _power_up(self) -> None:
        """The Arduino's reset, as opening the port does: position 0, empty buffers (settings kept)."""
        self._steps_done = [0] * len(self.axes)  # [steps] where the running block started
        self._blocks: deque[_Block] = deque()
        self._s = 0.0  # [units] travelled along the running block
        self._v = 0.0  # [units/s] speed while a feed hold decelerates
        self._hold = 0  # 0 none, 1 decelerating (Hold:1), 2 stopped (Hold:0)
        self._last = self._clock()
        self._alarm = self.settings[22] != 0  # with homing enabled, GRBL starts locked
        self._reset_parser()
        self._gc_pos = [0.0] * len(self.axes)

    def _reset_parser(self) -> None:
        """What a soft reset clears: buffers, the line being read, modal state, the report counters."""
        self._rx: deque[int] = deque()
        self._line: list[str] = []
        self._raw = bytearray()
        self._comment = ""  # "(" or ";" while in a comment
        self._line_overflow = False
        self._waiting: tuple[list[int], float] | None = None  # a move waiting for planner room: target, rate
        self._dwell_left: float | None = None  # [machine s] a sync (G4, M3...) waiting, then dwelling
        self._critical = False
        self._modal = _Modal()
        self._wco_count = 0
        self._ovr_count = 0

    def _spu(self, i: int) -> float:
        """Axis i's steps per unit ($100+i)."""
        return self.settings[100 + i]

    def _units(self, steps: list[int]) -> list[float]:
        """Steps to units, per axis (0 steps/unit counts as 1)."""
        return [s / (self._spu(i) or 1.0) for i, s in enumerate(steps)]

    def _state(self) -> str:
        if self._alarm:
            return "Alarm"
        if self._hold:
            return "Hold"
        return "Run" if self._blocks else "Idle"

    def _steps_now(self) -> list[int]:
        if not self._blocks or self._s <= 0.0:
            return list(self._steps_done)
        b = self._blocks[0]
        f = min(self._s / b.length, 1.0)
        return [s + int(f * (t - s)) for s, t in zip(self._steps_done, b.target, strict=True)]

    def _rate_now(self) -> float:
        """The current feed rate [units/min]."""
        if self._hold == 1:
            return self._v * 60.0
        return self._blocks[0].rate if self._blocks and not self._hold and not self._alarm else 0.0

    def _advance(self) -> None:
        """Move the machine on to the clock's now."""
        now = self._clock()
        dt = (now - self._last) * self.time_scale
        self._last = now
        while dt > 0.0 and self._blocks and self._hold != 2:
            b = self._blocks[0]
            if self._hold == 1:
                dt = self._decelerate(b, dt)
                continue
            t_end = (b.length - self._s) / (b.rate / 60.0)
            if dt < t_end:
                self._s += b.rate / 60.0 * dt
                dt = 0.0
                break
            dt -= t_end
            self._finish_block()
        if self._hold == 1 and not self._blocks:
            self._hold, self._v = 2, 0.0
        if self._dwell_left is not None and not self._blocks and not self._hold:
            self._dwell_left -= max(dt, 0.0)

    def _decelerate(self, b: _Block, dt: float) -> float:
        """Feed hold: slow down at ``b.accel`` for up to ``dt`` [s] along ``b``; return the time left."""
        v = min(self._v, b.rate / 60.0)
        rest = b.length - self._s
        if v * v / (2.0 * b.accel) <= rest:  # stops in this block
            t = v / b.accel
            if dt >= t:
                self._s += v * v / (2.0 * b.accel)
                self._hold, self._v = 2, 0.0
                return dt - t
        else:
            t = (v - math.sqrt(v * v - 2.0 * b.accel * rest)) / b.accel
            if dt >= t:
                self._v = v - b.accel * t
                self._finish_block()
                return dt - t
        self._s += v * dt - b.accel * dt * dt / 2.0
        self._v = v - b.accel * dt
        return 0.0

    def _finish_block(self) -> None:
        self._steps_done = self._blocks.popleft().target
        self._s = 0.0

    def _abort_motion(self) -> None:
        """Stop dead where the machine is, empty the planner and sync the parser to the position."""
        self._steps_done = self._steps_now()
        self._blocks.clear()
        self._s, self._v, self._hold = 0.0, 0.0, 0
        self._waiting, self._dwell_left = None, None
        self._gc_pos = self._units(self._steps_done)

    def _queue_move(self, target: list[int], rate: float) -> None:
        start = self._blocks[-1].target if self._blocks else self._steps_done
        delta = [(t - s) / (self._spu(i) or 1.0) for i, (s, t) in enumerate(zip(start, target, strict=True))]
        length = math.sqrt(sum(d * d for d in delta))
        if length == 0.0:
            return  # GRBL drops a block that makes no step
        # GRBL's limit_value_by_axis_maximum: the largest value no axis' share exceeds
        limit = [(i, abs(d) / length) for i, d in enumerate(delta) if d]
        max_rate = min(self.settings[110 + i] / u for i, u in limit)
        accel = min(self.settings[120 + i] / u for i, u in limit)
        rate = max_rate if rate <= 0.0 else min(rate, max_rate)
        self._blocks.append(_Block(target, length, max(rate, 1e-9), max(accel, 1e-9)))

    # -- the serial side ------------------------------------------------------------------------

    def _serve(self) -> None:
        """The thread: read the port, run the machine, answer."""
        poller = select.poll()
        poller.register(self._master, select.POLLIN)
        connected = False
        while not self._stop.is_set():
            events = poller.poll(_POLL_MS)
            hung_up = any(ev & select.POLLHUP for _, ev in events)
            data = b""
            if not hung_up and any(ev & select.POLLIN for _, ev in events):
                try:
                    data = os.read(self._master, 4096)
                except OSError:
                    hung_up = True
            with self._lock:
                if hung_up:
                    connected = False
                elif not connected:  # a client opened the port: the Arduino resets
                    connected = True
                    self._power_up()
                    self._boot_until = time.monotonic() + BOOT_S
                if self._boot_until is not None and time.monotonic() >= self._boot_until:
                    self._boot_until = None
                    self._welcome()
                self._service()
                self._receive(data)
                if not connected:
                    self._tx.clear()
                elif self._tx:
                    with contextlib.suppress(BlockingIOError):
                        del self._tx[: os.write(self._master, self._tx)]
            if hung_up:
                time.sleep(_POLL_MS / 1000)  # the master reports the hang-up at once, every time

    def _receive(self, data: bytes) -> None:
        """Bytes from the host: real-time ones act now, the rest go through the receive buffer."""
        if not self.responding or self._boot_until is not None:
            return
        for c in data:
            if c == _RESET:
                self._soft_reset()
            elif c == _STATUS:
                self._status_report()
            elif c == _HOLD:
                self._feed_hold()
            elif c == _RESUME:
                self._advance()
                if self._hold == 2 and not self._alarm:
                    self._hold = 0
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

    def _unblock(self) -> None:
        """Finish the line the parser waits with, if the machine has made room or synced."""
        if self._dwell_left is not None and self._dwell_left <= 0.0 and not self._blocks:
            self._dwell_left = None
            if self._waiting is None:
                self._reply(0)
        if self._waiting is not None and self._dwell_left is None and len(self._blocks) < self.planner_blocks:
            self._queue_move(*self._waiting)
            self._waiting = None
            self._reply(0)

    def _read_lines(self) -> None:
        """GRBL's protocol loop: take characters from the receive buffer while the parser is free."""
        while self._rx and self._waiting is None and self._dwell_left is None and not self._critical:
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
            self._reply(self._system(line))
        elif self._inject_error is not None:
            code, self._inject_error = self._inject_error, None
            self._reply(code)
        elif self._alarm:
            self._reply(9)
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
        self._send(WELCOME[:-2])
        if self._alarm:
            self._send("[MSG:'$H'|'$X' to unlock]")

    def _soft_reset(self) -> None:
        """Ctrl-X: stop, empty every buffer, keep the position; ALARM:3 if it was moving."""
        self._advance()
        moving = self._state() == "Run" or self._hold == 1
        self._abort_motion()
        self._reset_parser()
        if moving and not self._alarm:
            self._alarm = True
            self._send("ALARM:3")
        self._welcome()

    def _feed_hold(self) -> None:
        self._advance()
        if self._alarm or self._hold:
            return
        if self._blocks:
            self._hold, self._v = 1, self._blocks[0].rate / 60.0
        else:
            self._hold = 2  # GRBL holds when idle too: queued moves wait for ``~``

    def _status_report(self) -> None:
        self._advance()
        mask = int(self.settings[10])
        state = self._state()
        busy = state in ("Run", "Hold")
        if state == "Hold":
            state += ":0" if self._hold == 2 else ":1"
        zeros = ",".join("0.000" for _ in self.axes)
        pos = ",".join(f"{u + 0.0:.3f}" for u in self._units(self._steps_now()))  # + 0.0: no "-0.000"
        fields = [state, f"{'MPos' if mask & 1 else 'WPos'}:{pos}"]
        if mask & 2:
            fields.append(f"Bf:{self.planner_blocks - len(self._blocks)},{self.rx_buffer - len(self._rx)}")
        speed = min(max(self._modal.speed, self.settings[31]), self.settings[30]) if self._modal.spindle != 5 else 0.0
        fields.append(f"FS:{self._rate_now():.0f},{speed:.0f}")
        if self._wco_count > 0:
            self._wco_count -= 1
        else:
            self._wco_count = (30 if busy else 10) - 1
            self._ovr_count = self._ovr_count or 1
            fields.append(f"WCO:{zeros}")
        if self._ovr_count > 0:
            self._ovr_count -= 1
        else:
            self._ovr_count = (20 if busy else 10) - 1
            fields.append("Ov:100,100,100")
            acc = {3: "S", 4: "C"}.get(self._modal.spindle, "") + ("F" if self._modal.coolant == 8 else "")
            if acc:
                fields.append(f"A:{acc}")
        self._send("<" + "|".join(fields) + ">")

    # -- the commands ---------------------------------------------------------------------------

    def _system(self, line: str) -> int:
        """A ``$`` line (GRBL's system_execute_line); return the status code."""
        state = self._state()
        cmd = line[1:]
        if not cmd:
            self._send("[HLP:$$ $# $G $I $N $x=val $Nx=line $J=line $SLP $C $X $H ~ ! ? ctrl-x]")
            return 0
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
            self._send(f"[GC:G{mod.motion} G54 G17 G{20 if mod.inches else 21} G{90 if mod.absolute else 91} G94 "
                       f"M{mod.spindle} M{mod.coolant} T{mod.tool} F{mod.feed / (25.4 if mod.inches else 1):.0f} "
                       f"S{mod.speed:.0f}]")
            return 0
        if cmd == "X":
            if self._alarm:
                self._send("[MSG:Caution: Unlocked]")
                self._alarm = False
            return 0
        if state not in ("Idle", "Alarm"):
            return 8
        if cmd == "I":
            self._send(f"[VER:{VERSION}.20190830:]")
            self._send(f"[OPT:V,{self.planner_blocks},{self.rx_buffer}]")
            return 0
        if cmd == "H":
            return self._home()
        if cmd[0] in "CJ#NRSI":
            return 3  # $C, $J=, $#, $N, $RST=, $SLP, $I=: not emulated
        m = _SETTING.fullmatch(line)
        if not m:
            return 2  # not a setting's number
        if m.group(2) is None:
            return 3
        if m.group(3) is None:
            return 2
        if m.group(4):
            return 3
        return self._store_setting(int(float(m.group(1))), float(m.group(3)))

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
        return 0

    def _home(self) -> int:
        """``$H``: homing at once, without moving (GRBL's position after homing, pull-off included)."""
        if not self.settings[22]:
            return 5
        self._abort_motion()
        mask = int(self.settings[23])
        home = [self.settings[130 + i] + self.settings[27] if mask >> i & 1 else -self.settings[27]
                for i in range(len(self.axes))]
        self._steps_done = [_round_steps(h * self._spu(i)) for i, h in enumerate(home)]
        self._gc_pos = self._units(self._steps_done)
        self._alarm = False
        return 0

    def _gcode(self, line: str) -> int | None:
        """A G-code block (GRBL's gc_execute_line); return the status, or None if it waits for the machine."""
        words: dict[str, float] = {}
        groups: dict[str, int] = {}
        i = 0
        while i < len(line):
            letter = line[i]
            if not "A" <= letter <= "Z":
                return 1
            m = _NUMBER.match(line, i + 1)
            if not m:
                return 2
            i = m.end()
            value = float(m.group())
            if letter in "GM":
                code, mantissa = int(value), round(100 * (value - int(value)))
                table = _G_GROUPS if letter == "G" else _M_GROUPS
                if code != value and code in table and mantissa:
                    return 23
                if code != value or code not in table:
                    return 20
                group = table[code]
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
        if words.get("N", 0.0) > 9999999:
            return 27
        if words.get("T", 0.0) > 255:
            return 38
        if any(w in words for w in "IJKLR") or ("P" in words and groups.get("non-modal") != 4):
            return 36
        mod = self._modal
        inches = {20: True, 21: False}.get(groups.get("units", -1), mod.inches)
        scale = 25.4 if inches else 1.0
        axis = {a: words[a] * scale for a in self.axes if a in words}
        motion = groups.get("motion", mod.motion)
        feed = words["F"] * scale if "F" in words else mod.feed
        if groups.get("non-modal") == 4 and "P" not in words:
            return 28
        if groups.get("non-modal") == 53 and motion not in (0, 1):
            return 30
        if motion == 80 and axis:
            return 31
        if motion == 1 and axis and feed == 0.0:
            return 22
        # the block is valid: apply it, in GRBL's order
        mod.inches, mod.feed, mod.motion = inches, feed, motion
        mod.tool = int(words.get("T", mod.tool))
        if "distance" in groups:
            mod.absolute = groups["distance"] == 90
        sync = groups.get("non-modal") == 4
        spindle, coolant, speed = groups.get("spindle", mod.spindle), groups.get("coolant", mod.coolant), words.get("S")
        if (spindle, coolant) != (mod.spindle, mod.coolant) or (speed not in (None, mod.speed) and spindle != 5):
            sync = sync or not self.settings[32]  # outside laser mode GRBL waits for the planner to empty
        mod.spindle, mod.coolant = spindle, coolant
        mod.speed = mod.speed if speed is None else speed
        if sync:
            self._dwell_left = words.get("P", 0.0)
        if axis and motion in (0, 1):
            absolute = mod.absolute or groups.get("non-modal") == 53
            self._gc_pos = [p if a not in axis else axis[a] if absolute else p + axis[a]
                            for a, p in zip(self.axes, self._gc_pos, strict=True)]
            target = [_round_steps(p * self._spu(i)) for i, p in enumerate(self._gc_pos)]
            self._waiting = (target, 0.0 if motion == 0 else feed)
        return None if sync or self._waiting else 0


def main(argv: list[str] | None = None) -> None:
    """Serve one emulator until Ctrl-C, printing its port."""
    parser = argparse.ArgumentParser(prog="python -m clients.emulators.grbl", description=__doc__.splitlines()[0])
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
