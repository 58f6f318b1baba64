"""An emulator of the Lynxmotion SSC-32 / SSC-32U servo controller, for tests: not a driver.

It speaks the board's ASCII serial protocol on a pseudo-terminal, so that an adapter opens
``serial.Serial(emulator.port, 115200, timeout=...)`` exactly as it opens ``/dev/ttyUSB0``,
and records what it received (``history``, ``out_of_range``, ``errors``) and what it output
(``segments``) for tests to check. Run one by hand with ``python -m armd.adapters.emulators.ssc32``:
it prints the port and serves until Ctrl-C.

Covered (SSC-32U user guide, "Commands"); a command ends with a carriage return (``\\r``, ASCII 13)
and only then takes effect:

- ``#<ch>P<pw>[S<spd>] ... [T<time>]<cr>``: a group move. Channels 0-31, pulse widths [us],
  speeds [us/s], time [ms] (65535 max). Every servo of the group starts and ends together; the
  move lasts T, or longer if a servo's S needs it; with neither, it is immediate. Pulses change
  linearly in time. A servo never commanded (or turned off, or since a ``power_cycle()``) has no
  known position: it jumps at once to its pulse.
  Pulses outside 500-2500 us are clamped (as users measured on the board) and recorded in ``out_of_range``;
  ``P0`` turns the channel's pulses off (the real board's undocumented behaviour), and is recorded too.
- ``Q<cr>``: ``+`` while a move is in progress, ``.`` when done; no carriage return.
- ``QP<ch><cr>`` (also ``QP<ch>QP<ch>...``): one binary byte per channel, pulse width / 10 (0 if off):
  the guide's "single byte ... indicating the pulse width of the selected servo with a resolution of
  10uS". The board outputs a channel's pulse once every 20 ms (the guide: an R/C pulse "repeated every
  20ms"), and a pulse has one width: ``QP`` answers the width of the frame in progress when the query
  is executed (its ``\\r`` has arrived): the board's interpolation at that frame's start (frames every
  ``frame`` s from the board's start), or where the channel jumped to since (a first command, an
  immediate move: at once). A servo moving at 1910 us/s (3 rad/s on an AL5 arm) answers up to 38 us
  behind the interpolation, and the 10 us of the byte more.
- ``VER<cr>``: the version string and a carriage return.
- ``STOP<ch><cr>`` (SSC-32U): stops that servo where it is. As the guide says, ``Q`` still answers
  ``+`` until the original move's time has elapsed.
- ``VA<cr>`` .. ``VH<cr>`` (also ``VAVB...``): the analog inputs on pins A to H, one binary byte
  each, the voltage times 256/5 (255: 4.98 V and above), as the guide says. The pins' voltages
  are ``analog(pin, t, pulse)`` [V], where ``pulse(channel, t)`` is a channel's output then (a
  sensor on a scanning servo: :class:`armd.adapters.sim_sensors.AnalogWorld`; none: 0 V). The
  board filters its inputs digitally, settling "within 8 mS of a change": here a read gives the
  voltage ``ANALOG_SETTLE`` before it is executed. A pin is a digital input with a pull-up at
  power-up; "the first time a V* command is used, the pin will be converted to analog without
  pullup. The result of this first read will not return valid data": here it returns the
  pull-up's 255. A power cycle makes every pin digital again.

Spaces, tabs and line feeds are ignored, as the guide says, and letters may be either case: only
``\\r`` ends a command, so ``#0P1500\\n`` waits for a ``\\r`` and ``#0P15\\n00\\r`` is ``#0P1500``.
Anything else (offsets ``PO``, digital outputs ``L``/``H``, digital inputs ``A``-``F``, registers, ``#<ch>P``
with a channel above 31, ...) is ignored and recorded in ``errors``.

The link and the board's timing (``baud``, ``query_delay``; all times on ``clock``):

- The serial link runs at ``baud`` (8N1: 10 bits a byte), both ways. The SSC-32U ships at 9600; its
  button selects 9600, 38400 or 115200, and register R4 any other rate (57600, ...). The default here
  is 115200, the rate the project's adapter opens at. The host's writes return at once (the USB-serial
  chip and the OS buffer them); byte ``i`` of a write the emulator reads at ``t`` reaches the board's
  parser at ``max(t, end of the previous byte) + (i + 1) * 10 / baud``, so a host that writes faster than
  the link gets its commands executed late, in order (``link_backlog()``). A command is executed at the
  arrival of its ``\\r``: that is the time ``history`` records and the board's state changes, exactly,
  whenever the emulator's thread gets to it. The host must open the port at ``baud`` (below).
  ``baud=None`` is an ideal link (instant, at any rate the host sets), for exact tests on a frozen clock.
- Replies to ``Q``, ``QP``, ``V*`` and ``VER`` leave the board ``query_delay`` after the query has been executed
  (the guide: 50 us to 5 ms, "typically within 100 us"; the default is 100 us), then travel back at the
  same rate: each byte is written to the terminal when its last bit would have reached the host.
- Opening and closing the port does not reset the board (the terminal's other end stays open): it keeps
  its pulses across an adapter's restart. ``power_cycle()`` turns every channel off, as a board just powered.
- ``segments(channel)`` is the exact pulse output over time, piecewise linear: the board's interpolation,
  holds, and jumps (zero-length segments: a first move, an immediate move, ``P0``, a power cycle).
- ``delay_input(seconds)``: the host holds the next bytes written that long before the board has them
  (a USB-serial link's or a terminal's latency, now and then: the host's timing, for tests).
- ``hold_input(shortest, longest)``: from then on a slow host (a busy machine's kernel thread that
  carries the terminal's bytes, a USB-serial link that waits to fill its packets): each time bytes
  are written while none are held, they are held a time drawn evenly from ``shortest`` to
  ``longest`` [s] (a fixed seed: the same draws every run), and bytes written meanwhile go with
  them; then they cross the link as ever. Every line then reaches the board late, by a varying
  delay, and a query written soon after a line is delayed less than the line. ``hold_input(0)`` ends it.
  The emulator's thread never waits for a hold: replies leave on time.

Where the real board differs, or may:

- It drives real servos, which have their own maximum speed and lag; here the pulse *is* the position.
- It outputs each channel's pulse once every 20 ms (the guide: an R/C pulse "repeated every 20ms"), so a
  servo sees the interpolation at each frame; here the output (``segments``) is the interpolation itself,
  continuous in time (stricter: a change of speed between two frames counts as it happens), and only
  ``QP`` sees the frames. The output's resolution is not documented. ``QP`` here truncates the pulse to
  10 us (whether the board rounds is not documented). When in a frame the board's interpolation steps,
  and whether a command received during a frame changes that frame's pulse, are not documented: here the
  interpolation is exact, a command takes effect when its ``\\r`` arrives, and ``QP`` sees a move from the
  next frame, a jump at once.
- Whether the board parses further commands while it waits to answer a query is not documented: here it
  does (the reply is delayed, the parser is not). Its own receive buffer is not modelled: it never overflows.
- A host that opens the port at another rate than ``baud`` (pyserial sets it on the terminal) gets
  nothing executed and no answer; ``errors`` records each lost write. On the board the bytes become
  garbage, which may by chance parse as something, and its replies would reach the host as garbage.
- The exact ``VER`` string depends on the firmware (the guide does not document it).
- Whether ``S0``, or a ``T`` on a servo's first move, mean anything on the board is not documented:
  here ``S0`` is no limit, and a first move jumps while ``Q`` answers ``+`` for the group's time.
  A ``T`` above 65535 is cut to 65535 here.
- ``power_cycle()`` loses the partly received command and the replies not yet sent; bytes still on
  their way from the host (in the USB-serial chip, which the USB powers) arrive afterwards.
"""

from __future__ import annotations

import argparse
import bisect
import contextlib
import math
import os
import random
import re
import select
import termios
import threading
import time
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

from .pty import PtyEmulator

PULSE_MIN = 500  # [us], the manual's range
PULSE_MAX = 2500  # [us]
CHANNELS = 32
TIME_MAX = 65535  # [ms], the longest T the board takes
ANALOG_PINS = "ABCDEFGH"  # the SSC-32U's analog inputs
FRAME = 0.02  # [s] the guide: a servo's pulse is "repeated every 20ms"
ANALOG_SETTLE = 0.008  # [s] the guide: filtered values "settle to their final values within 8 mS of a change"
BITS_PER_BYTE = 10  # 8N1: a start bit, 8 data bits, a stop bit
FACTORY_BAUD = 9600  # the SSC-32U as shipped
DEFAULT_BAUD = 115200  # what the project's adapter opens at
BOARD_BAUDS = (9600, 38400, 57600, 115200)  # the rates an SSC-32U is commonly set to (R4 takes others)

_GROUP = re.compile(r"(?:#\d+P\d+(?:S\d+)?)+(?:T\d+)?")
_ITEM = re.compile(r"#(\d+)P(\d+)(?:S(\d+))?")
_QUERY_PULSES = re.compile(r"(?:QP\d+)+")
_STOP = re.compile(r"STOP(\d+)")
_ANALOG = re.compile(r"(?:V[A-H])+")
_TERMIOS_BAUDS = {
    getattr(termios, f"B{r}"): r
    for r in (1200, 2400, 4800, 9600, 19200, 38400, 57600, 115200, 230400)
    if hasattr(termios, f"B{r}")
}
_IGNORED = b"\n"  # dropped as they arrive; spaces and tabs are dropped when a command is parsed

Segment = tuple[float, float, float, float]  # (t0 [s], t1 [s], p0 [us], p1 [us]), linear between


@dataclass(frozen=True)
class GroupMove:
    """One group move as executed: ``time`` [s, emulator clock: the arrival of its carriage return],
    ``pulses`` {channel: us} (before clamping), ``speeds`` {channel: us/s} (channels with an S only),
    ``duration_ms`` (T, None if absent)."""

    time: float
    pulses: dict[int, int]
    speeds: dict[int, int]
    duration_ms: int | None


@dataclass
class _Servo:
    """One channel's motion: linear from ``start`` [us] at ``t0`` [s] to ``target`` [us] at ``t1`` [s], then held."""

    start: float
    target: float
    t0: float
    t1: float

    def at(self, now: float) -> float:
        """Pulse width [us] at time ``now`` [s]."""
        if now >= self.t1:
            return self.target
        if now <= self.t0:
            return self.start
        return self.start + (self.target - self.start) * (now - self.t0) / (self.t1 - self.t0)


class SSC32Emulator(PtyEmulator):
    """An SSC-32 on a pseudo-terminal; ``start()`` (or ``with``) returns the path to open with pyserial.

    ``baud``: the link's rate [bit/s] (None: instant); ``frame`` [s]: how often the board outputs a
    pulse (the width ``QP`` answers is the frame's; 0: ``QP`` answers the interpolation itself, for
    exact tests); ``query_delay`` [s]: how long after a query is
    executed its reply leaves the board; ``clock`` [s]: the emulator's time, for every timestamp.
    """

    name = "ssc32-emulator"
    keep_slave = True  # the board does not reset when its port is opened

    def __init__(
        self,
        *,
        version: str = "SSC32-V2.50USB",
        clock: Callable[[], float] = time.monotonic,
        baud: int | None = DEFAULT_BAUD,
        query_delay: float = 100e-6,
        frame: float = FRAME,
    ) -> None:
        if baud is not None and baud <= 0:
            raise ValueError(f"baud must be positive or None, not {baud}")
        if not query_delay >= 0:
            raise ValueError(f"query_delay must be >= 0 s, not {query_delay}")
        if not frame >= 0:
            raise ValueError(f"frame must be >= 0 s, not {frame}")
        super().__init__()
        self.version = version
        self.clock = clock  # [s]
        self.baud = baud
        self.query_delay = query_delay  # [s]
        self.frame = frame  # [s]
        self._frame0 = clock()  # [s] the board's frames start every ``frame`` from here
        self.history: list[GroupMove] = []
        self.out_of_range: list[tuple[int, int]] = []  # (channel, pulse [us]) received outside 500..2500
        self.errors: list[str] = []  # lines not understood, as received
        self.responding = True  # False: reads and discards everything, answers and executes nothing
        # (pin A..H, time [s], a channel's pulse [us] at a time) -> the volts on the pin
        self.analog: Callable[[str, float, Callable[[int, float], float]], float] | None = None
        self._analog_pins: set[str] = set()  # pins a V* read has made analog (until a power cycle)
        self._input_delay = 0.0  # [s] how long the host holds the next bytes written (delay_input)
        self._hold = (0.0, 0.0)  # [s] the shortest and longest a slow host holds bytes (hold_input)
        self._held_until = -math.inf  # [s] when the bytes held now reach the link
        self._hold_draws = random.Random(0)
        self._servos: dict[int, _Servo] = {}  # channels with pulses
        self._off_since: dict[int, float] = {}  # channels turned off (P0, power cycle): since when [s]
        self._trace: dict[int, list[Segment]] = {}  # closed segments, per channel
        self._busy_until = -math.inf  # [s] end of the latest move, for Q
        self._rx: deque[tuple[float, int]] = deque()  # (arrival at the board [s], byte), not yet parsed
        self._rx_free = -math.inf  # [s] when the host-to-board link has sent all it was given
        self._tx: deque[tuple[float, int]] = deque()  # (arrival at the host [s], byte), not yet written
        self._tx_free = -math.inf  # [s] when the board-to-host link has sent all it was given
        self._line = bytearray()  # the command being received
        self._lock = threading.Lock()

    # -- state, for tests --------------------------------------------------------------------

    def pulse(self, channel: int) -> float:
        """Current pulse width of ``channel`` [us], interpolated now; 0.0 if never commanded or off."""
        with self._lock:
            now = self._advance()
            return self._pulse_at(channel, now)

    def pulses(self) -> dict[int, float]:
        """Current pulse width [us] of every channel that has one (commanded, not off)."""
        with self._lock:
            now = self._advance()
            return {ch: servo.at(now) for ch, servo in sorted(self._servos.items())}

    def target(self, channel: int) -> int | None:
        """The pulse width [us] ``channel`` is moving to (or stays at); None if never commanded or off."""
        with self._lock:
            self._advance()
            servo = self._servos.get(channel)
            return None if servo is None else round(servo.target)

    def moving(self) -> bool:
        """Whether a move is in progress: what ``Q`` answers (``+``)."""
        with self._lock:
            return self._advance() < self._busy_until

    def host_baud(self) -> int | None:
        """The rate [bit/s] the host set on its end of the terminal (None: unknown, or not started)."""
        if self._slave < 0:
            return None
        try:
            return _TERMIOS_BAUDS.get(termios.tcgetattr(self._slave)[5])
        except termios.error:
            return None

    def link_backlog(self) -> float:
        """How far behind the host the link is [s]: until the last byte received reaches the board's parser."""
        with self._lock:
            now = self._advance()
            return max(0.0, self._rx_free - now)

    def segments(self, channel: int, until: float | None = None) -> list[Segment]:
        """The exact pulse output of ``channel``: ``(t0, t1, p0, p1)`` [s, us], linear from ``p0`` at ``t0``
        to ``p1`` at ``t1``, each starting where the previous one ended, from the channel's first command
        up to ``until`` (default now). Zero-length segments are jumps; 0 us is no pulse (off)."""
        with self._lock:
            now = self._advance()
            end = now if until is None else min(until, now)
            return [*self._trace.get(channel, []), *self._open_segments(channel, end)]

    def power_cycle(self) -> None:
        """Switch the board off and on: every channel off (no pulses, no known position: the next command
        of each channel jumps), no move in progress; the partly received command and unsent replies are lost."""
        with self._lock:
            now = self._advance()
            for ch in list(self._servos):
                self._set(ch, None, now)
            self._busy_until = -math.inf
            self._analog_pins.clear()
            self._line.clear()
            self._tx.clear()
            self._tx_free = -math.inf

    def delay_input(self, seconds: float) -> None:
        """The host holds the next bytes written to the port ``seconds`` before they reach the
        board, as a USB-serial link or the kernel thread that carries a terminal's bytes does now
        and then (a host's timing, not the board's: for tests of what a late command does)."""
        with self._lock:
            self._input_delay = float(seconds)

    def hold_input(self, shortest: float, longest: float | None = None) -> None:
        """From now on the host holds the bytes written to the port before the board has them,
        as a busy host's kernel thread or a slow USB-serial link does: each time bytes are
        written while none are held, they are held a time drawn evenly from ``shortest`` to
        ``longest`` [s] (``shortest`` if None), and bytes written meanwhile go with them.
        ``hold_input(0)`` ends it. (The host's timing, not the board's: for tests of late lines.)"""
        longest = shortest if longest is None else longest
        if not 0.0 <= shortest <= longest:
            raise ValueError(f"need 0 <= shortest <= longest [s], not {shortest}, {longest}")
        with self._lock:
            self._hold = (float(shortest), float(longest))
            self._held_until = -math.inf

    # -- the link ------------------------------------------------------------------------------

    def _held(self, now: float) -> float:
        """When bytes the emulator reads at ``now`` leave the host (after a slow host's hold)."""
        if self._hold[1] <= 0.0:
            return now
        if now >= self._held_until:  # none held: these start a hold, and what comes during it joins them
            self._held_until = now + self._hold_draws.uniform(*self._hold)
        return self._held_until

    def _byte_time(self) -> float:
        return 0.0 if self.baud is None else BITS_PER_BYTE / self.baud

    def _receive(self, chunk: bytes, now: float) -> None:
        """Queue bytes the host wrote (read from the terminal at ``now``) at their arrival times."""
        dt, start = self._byte_time(), max(self._rx_free, now)
        self._rx.extend((start + (i + 1) * dt, byte) for i, byte in enumerate(chunk))
        self._rx_free = start + len(chunk) * dt

    def _transmit(self, data: bytes, ready: float) -> None:
        """Queue a reply that leaves the board at ``ready``."""
        dt, start = self._byte_time(), max(self._tx_free, ready)
        self._tx.extend((start + (i + 1) * dt, byte) for i, byte in enumerate(data))
        self._tx_free = start + len(data) * dt

    def _advance(self) -> float:
        """Parse and execute every byte arrived by now, write every reply byte due; return now [s]."""
        now = self.clock()
        while self._rx and self._rx[0][0] <= now:
            t, byte = self._rx.popleft()
            if byte == 13:
                if self._line:
                    reply = self._execute(self._line.decode("ascii", "replace"), t)
                    if reply:
                        self._transmit(reply, t + self.query_delay)
                self._line.clear()
            elif byte not in _IGNORED:
                self._line.append(byte)
        out = bytearray()
        while self._tx and self._tx[0][0] <= now:
            out.append(self._tx.popleft()[1])
        if out and self._master >= 0:
            with contextlib.suppress(BlockingIOError):  # the opener's input buffer is full: lost, as on a UART
                os.write(self._master, out)
        return now

    def _next_due(self) -> float:
        return min(self._rx[0][0] if self._rx else math.inf, self._tx[0][0] if self._tx else math.inf)

    def _serve(self) -> None:
        master = self._master
        while not self._stop.is_set():
            with self._lock:
                wait = self._next_due() - self.clock()
            # an idle link: check the stop flag now and then; a pending byte: wake for it (at most 5 ms
            # later, so that a clock that is not time.monotonic, a test's, is seen to move)
            timeout = 0.05 if wait == math.inf else min(max(wait, 0.0), 0.005)
            if select.select([master], [], [], timeout)[0]:
                with self._lock:
                    held, self._input_delay = self._input_delay, 0.0
                if held > 0.0:
                    time.sleep(held)
                try:
                    chunk = os.read(master, 4096)
                except (BlockingIOError, InterruptedError):
                    chunk = b""
                except OSError:  # EIO: no one holds the terminal open (cannot happen while we hold the slave)
                    break
                host_baud = self.host_baud()
                with self._lock:
                    if not self.responding:
                        self._line.clear()
                    elif chunk and self.baud is not None and host_baud not in (None, self.baud):
                        # framing errors: the board reads garbage, executes nothing of it, answers nothing
                        self.errors.append(f"<{len(chunk)} bytes sent at {host_baud} baud to a board at {self.baud}>")
                        self._line.clear()
                    else:
                        now = self.clock()
                        self._receive(chunk, self._held(now) if chunk else now)
            with self._lock:
                self._advance()

    # -- the board -----------------------------------------------------------------------------

    def _execute(self, text: str, now: float) -> bytes:
        """Execute one command (without its carriage return) at time ``now``; return the reply (b"" for none)."""
        cmd = text.replace(" ", "").replace("\t", "").upper()
        if cmd == "":
            return b""
        if cmd == "VER":
            return self.version.encode("ascii") + b"\r"
        if cmd == "Q":
            return b"+" if now < self._busy_until else b"."
        if _QUERY_PULSES.fullmatch(cmd):
            channels = [int(c) for c in re.findall(r"\d+", cmd)]
            if all(ch < CHANNELS for ch in channels):
                return bytes(min(255, int(self._frame_pulse(ch, now)) // 10) for ch in channels)
        elif _ANALOG.fullmatch(cmd):
            return bytes(self._analog_read(pin, now) for pin in cmd[1::2])
        elif (m := _STOP.fullmatch(cmd)) and int(m[1]) < CHANNELS:
            self._stop_servo(int(m[1]), now)
            return b""
        elif _GROUP.fullmatch(cmd) and self._group_move(cmd, now):
            return b""
        self.errors.append(text)
        return b""

    def _analog_read(self, pin: str, now: float) -> int:
        """Pin ``pin``'s byte: its voltage as the board's filter has it, times 256/5."""
        if pin not in self._analog_pins:  # its first read: made analog, the pull-up's level read
            self._analog_pins.add(pin)
            return 255
        volts = self.analog(pin, now - ANALOG_SETTLE, self._pulse_at) if self.analog is not None else 0.0
        return max(0, min(255, math.floor(volts * 256.0 / 5.0)))

    def _pulse_at(self, channel: int, now: float) -> float:
        servo = self._servos.get(channel)
        return 0.0 if servo is None else servo.at(now)

    def _frame_pulse(self, channel: int, now: float) -> float:
        """The width [us] of ``channel``'s pulse in the frame in progress at ``now`` [s]: its
        output at the frame's start, or where it last jumped since (a jump shows at once); its
        pulse now if it had none."""
        servo = self._servos.get(channel)
        if servo is None:
            return 0.0
        if self.frame <= 0.0:
            return servo.at(now)
        start = self._frame0 + math.floor((now - self._frame0) / self.frame + 1e-9) * self.frame
        if start >= servo.t0:
            return servo.at(start)
        if servo.t1 == servo.t0:  # (a jump: a first command, an immediate move)
            return servo.target
        trace = self._trace.get(channel, [])
        k = bisect.bisect_right(trace, start, key=lambda seg: seg[0]) - 1
        width = 0.0
        if k >= 0:
            t0, t1, p0, p1 = trace[k]
            width = p1 if t1 <= t0 or start >= t1 else p0 + (p1 - p0) * (start - t0) / (t1 - t0)
        for t0, t1, _, p1 in trace[k + 1 :]:  # (since the frame's start: a jump sets the pulse at once)
            if t1 == t0:
                width = p1
        return width if width > 0.0 else servo.at(now)

    def _open_segments(self, channel: int, now: float) -> list[Segment]:
        """The output of ``channel`` since its last change, up to ``now``: the move's part done, the hold."""
        servo = self._servos.get(channel)
        if servo is None:
            since = self._off_since.get(channel)
            return [] if since is None or now <= since else [(since, now, 0.0, 0.0)]
        out: list[Segment] = []
        if servo.t1 > servo.t0 and now > servo.t0:
            end = min(now, servo.t1)
            out.append((servo.t0, end, servo.start, servo.at(end)))
        if now > servo.t1:
            out.append((servo.t1, now, servo.target, servo.target))
        return out

    def _set(self, channel: int, servo: _Servo | None, now: float) -> None:
        """Change ``channel``'s motion at ``now`` to ``servo`` (None: off), closing its trace so far."""
        trace = self._trace.setdefault(channel, [])
        trace.extend(self._open_segments(channel, now))
        here = self._pulse_at(channel, now)
        start = 0.0 if servo is None else servo.start
        if start != here:
            trace.append((now, now, here, start))
        if servo is None:
            self._servos.pop(channel, None)
            self._off_since[channel] = now
        else:
            self._servos[channel] = servo
            self._off_since.pop(channel, None)

    def _stop_servo(self, channel: int, now: float) -> None:
        if channel in self._servos:
            here = self._servos[channel].at(now)
            self._set(channel, _Servo(here, here, now, now), now)

    def _group_move(self, cmd: str, now: float) -> bool:
        """Start the group move ``cmd`` (normalised); False (nothing done) if a channel is above 31."""
        items = [(int(m[1]), int(m[2]), None if m[3] is None else int(m[3])) for m in _ITEM.finditer(cmd)]
        if any(ch >= CHANNELS for ch, _, _ in items):
            return False
        t = re.search(r"T(\d+)$", cmd)
        duration_ms = None if t is None else int(t[1])
        self.history.append(
            GroupMove(now, {ch: pw for ch, pw, _ in items}, {ch: s for ch, _, s in items if s is not None}, duration_ms)
        )
        duration = min(duration_ms or 0, TIME_MAX) / 1000.0  # [s]
        moves: dict[int, tuple[float | None, int]] = {}  # channel: (pulse now or None, clamped target)
        for ch, pw, speed in items:
            if not PULSE_MIN <= pw <= PULSE_MAX:
                self.out_of_range.append((ch, pw))
            if pw == 0:
                self._set(ch, None, now)
                moves.pop(ch, None)
                continue
            target = min(max(pw, PULSE_MIN), PULSE_MAX)
            here = self._servos[ch].at(now) if ch in self._servos else None
            moves[ch] = (here, target)
            if here is not None and speed:
                duration = max(duration, abs(target - here) / speed)
        for ch, (here, target) in moves.items():
            if here is None or duration == 0:  # no known position, or no time: jump
                self._set(ch, _Servo(float(target), float(target), now, now), now)
            else:
                self._set(ch, _Servo(here, float(target), now, now + duration), now)
        self._busy_until = max(self._busy_until, now + duration)
        return True


def main(argv: list[str] | None = None) -> int:
    """Serve an emulated SSC-32 until Ctrl-C, printing its port and what it receives."""
    parser = argparse.ArgumentParser(
        prog="python -m armd.adapters.emulators.ssc32",
        description="An emulated SSC-32 servo controller on a pseudo-terminal.",
    )
    parser.add_argument("--ver", default="SSC32-V2.50USB", help="what VER answers")
    parser.add_argument(
        "--baud",
        type=int,
        default=DEFAULT_BAUD,
        help=f"the link's rate, bit/s (the SSC-32U ships at {FACTORY_BAUD}); open the port at"
        " the same rate, or nothing is executed; 0: an instant link that takes any rate",
    )
    parser.add_argument("--query-delay", type=float, default=100e-6, help="seconds before a query's reply leaves")
    parser.add_argument(
        "--robot", help="an arm whose wired range sensors (robot.toml [[sensors]] pin) put out voltages on the pins"
    )
    parser.add_argument(
        "--objects", metavar="FILE", help="with --robot: the objects its sensors see, as armd serve --objects takes"
    )
    args = parser.parse_args(argv)
    with SSC32Emulator(version=args.ver, baud=args.baud or None, query_delay=args.query_delay) as emu:
        if args.robot:
            emu.analog = _analog_world(args.robot, args.objects).volts
        print(emu.port, flush=True)
        logs: dict[str, Sequence[object]] = {
            "move": emu.history,
            "out of range": emu.out_of_range,
            "not understood": emu.errors,
        }
        seen = dict.fromkeys(logs, 0)
        try:
            while True:
                time.sleep(0.1)
                for label, items in logs.items():
                    for item in items[seen[label] :]:
                        print(f"{label}: {item}", flush=True)
                    seen[label] = len(items)
        except KeyboardInterrupt:
            pass
    return 0


def _analog_world(robot: str, objects: str | None) -> Any:
    """``robot``'s wired sensors in the world of ``objects`` (a file: ``{"<robot>": [objects]}``)."""
    import json
    from pathlib import Path

    from armd import robots
    from armd.adapters.sim_sensors import AnalogWorld, objects_of

    specs = json.loads(Path(objects).read_text(encoding="utf-8")).get(robot, []) if objects else []
    return AnalogWorld(robots.load(robot), objects_of(specs))


if __name__ == "__main__":
    raise SystemExit(main())
