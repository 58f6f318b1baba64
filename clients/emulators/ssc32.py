"""An emulator of the Lynxmotion SSC-32 / SSC-32U servo controller, for tests: not a driver.

It speaks the board's ASCII serial protocol on a pseudo-terminal, so that an adapter opens
``serial.Serial(emulator.port, 115200, timeout=...)`` exactly as it opens ``/dev/ttyUSB0``,
and records what it received (``history``, ``out_of_range``, ``errors``) for tests to check.
Run one by hand with ``python -m clients.emulators.ssc32``: it prints the port and serves until Ctrl-C.

Covered (SSC-32U user guide, "Commands"), one command per line:

- ``#<ch>P<pw>[S<spd>] ... [T<time>]<cr>``: a group move. Channels 0-31, pulse widths [us],
  speeds [us/s], time [ms] (65535 max). Every servo of the group starts and ends together; the
  move lasts T, or longer if a servo's S needs it; with neither, it is immediate. Pulses change
  linearly in time. A servo never commanded (or turned off) has no known position: it jumps.
  Pulses outside 500-2500 us are clamped (as users measured on the board) and recorded in ``out_of_range``;
  ``P0`` turns the channel's pulses off (the real board's undocumented behaviour), and is recorded too.
- ``Q<cr>``: ``+`` while a move is in progress, ``.`` when done; no carriage return.
- ``QP<ch><cr>`` (also ``QP<ch>QP<ch>...``): one binary byte per channel, pulse width / 10 (0 if off).
- ``VER<cr>``: the version string and a carriage return.
- ``STOP<ch><cr>`` (SSC-32U): stops that servo where it is. As the guide says, ``Q`` still answers
  ``+`` until the original move's time has elapsed.

Spaces and tabs are ignored, and letters may be either case. Lines end with ``\\r``, ``\\r\\n`` or ``\\n``.
Anything else (offsets ``PO``, digital outputs ``L``/``H``, inputs ``A``-``H``, registers, ``#<ch>P``
with a channel above 31, ...) is ignored and recorded in ``errors``.

Where the real board differs, or may:

- It ignores line feeds: only ``\\r`` ends a command there, so a ``\\n``-only adapter works here but
  not on the board.
- It answers ``Q`` and ``QP`` after 50 us to 5 ms; this emulator answers at once.
- It drives real servos, which have their own maximum speed and lag; here the pulse *is* the position.
- The exact ``VER`` string depends on the firmware (the guide does not document it).
- Whether ``S0``, or a ``T`` on a servo's first move, mean anything on the board is not documented:
  here ``S0`` is no limit, and a first move jumps while ``Q`` answers ``+`` for the group's time.
  A ``T`` above 65535 is cut to 65535 here.
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
from collections.abc import Callable, Sequence
from dataclasses import dataclass

from .pty import PtyEmulator

PULSE_MIN = 500  # [us], the manual's range
PULSE_MAX = 2500  # [us]
CHANNELS = 32
TIME_MAX = 65535  # [ms], the longest T the board takes

_GROUP = re.compile(r"(?:#\d+P\d+(?:S\d+)?)+(?:T\d+)?")
_ITEM = re.compile(r"#(\d+)P(\d+)(?:S(\d+))?")
_QUERY_PULSES = re.compile(r"(?:QP\d+)+")
_STOP = re.compile(r"STOP(\d+)")


@dataclass(frozen=True)
class GroupMove:
    """One group move as received: ``time`` [s, emulator clock], ``pulses`` {channel: us} (before
    clamping), ``speeds`` {channel: us/s} (channels with an S only), ``duration_ms`` (T, None if absent)."""

    time: float
    pulses: dict[int, int]
    speeds: dict[int, int]
    duration_ms: int | None


@dataclass
class _Servo:
    """One channel's motion: linear from ``start`` [us] at ``t0`` [s] to ``target`` [us] at ``t1`` [s]."""

    start: float
    target: int
    t0: float
    t1: float

    def at(self, now: float) -> float:
        """Pulse width [us] at time ``now`` [s]."""
        if now >= self.t1:
            return float(self.target)
        if now <= self.t0:
            return self.start
        return self.start + (self.target - self.start) * (now - self.t0) / (self.t1 - self.t0)


class SSC32Emulator(PtyEmulator):
    """An SSC-32 on a pseudo-terminal; ``start()`` (or ``with``) returns the path to open with pyserial."""

    name = "ssc32-emulator"
    keep_slave = True  # the board does not reset when its port is opened

    def __init__(self, *, version: str = "SSC32-V2.50USB", clock: Callable[[], float] = time.monotonic) -> None:
        super().__init__()
        self.version = version
        self.clock = clock  # [s]
        self.history: list[GroupMove] = []
        self.out_of_range: list[tuple[int, int]] = []  # (channel, pulse [us]) received outside 500..2500
        self.errors: list[str] = []  # lines not understood, as received
        self.responding = True  # False: reads and discards everything, answers and executes nothing
        self._servos: dict[int, _Servo] = {}
        self._busy_until = -math.inf  # [s] end of the latest move, for Q
        self._lock = threading.Lock()

    # -- state, for tests --------------------------------------------------------------------

    def pulse(self, channel: int) -> float:
        """Current pulse width of ``channel`` [us], interpolated now; 0.0 if never commanded or off."""
        with self._lock:
            servo = self._servos.get(channel)
            return 0.0 if servo is None else servo.at(self.clock())

    def pulses(self) -> dict[int, float]:
        """Current pulse width [us] of every channel that has one (commanded, not off)."""
        with self._lock:
            now = self.clock()
            return {ch: servo.at(now) for ch, servo in sorted(self._servos.items())}

    def target(self, channel: int) -> int | None:
        """The pulse width [us] ``channel`` is moving to (or stays at); None if never commanded or off."""
        with self._lock:
            servo = self._servos.get(channel)
            return None if servo is None else servo.target

    def moving(self) -> bool:
        """Whether a move is in progress: what ``Q`` answers (``+``)."""
        with self._lock:
            return self.clock() < self._busy_until

    # -- protocol ----------------------------------------------------------------------------

    def _serve(self) -> None:
        master, line = self._master, bytearray()
        while not self._stop.is_set():
            if not select.select([master], [], [], 0.05)[0]:
                continue
            try:
                chunk = os.read(master, 4096)
            except (BlockingIOError, InterruptedError):
                continue
            except OSError:  # EIO: no one holds the terminal open (cannot happen while we hold the slave)
                break
            if not self.responding:
                line.clear()
                continue
            for byte in chunk:
                if byte in b"\r\n":
                    if line:
                        self._reply(self._execute(line.decode("ascii", "replace")))
                    line.clear()
                else:
                    line.append(byte)

    def _reply(self, data: bytes) -> None:
        if data and self._master >= 0:
            with contextlib.suppress(BlockingIOError):  # the opener's input buffer is full: lost, as on a UART
                os.write(self._master, data)

    def _execute(self, text: str) -> bytes:
        """Execute one line (without its terminator); return the reply (b"" for none)."""
        cmd = text.replace(" ", "").replace("\t", "").upper()
        with self._lock:
            now = self.clock()
            if cmd == "":
                return b""
            if cmd == "VER":
                return self.version.encode("ascii") + b"\r"
            if cmd == "Q":
                return b"+" if now < self._busy_until else b"."
            if _QUERY_PULSES.fullmatch(cmd):
                channels = [int(c) for c in re.findall(r"\d+", cmd)]
                if all(ch < CHANNELS for ch in channels):
                    return bytes(min(255, int(self._pulse_now(ch, now)) // 10) for ch in channels)
            elif (m := _STOP.fullmatch(cmd)) and int(m[1]) < CHANNELS:
                self._stop_servo(int(m[1]), now)
                return b""
            elif _GROUP.fullmatch(cmd) and self._group_move(cmd, now):
                return b""
            self.errors.append(text)
            return b""

    def _pulse_now(self, channel: int, now: float) -> float:
        servo = self._servos.get(channel)
        return 0.0 if servo is None else servo.at(now)

    def _stop_servo(self, channel: int, now: float) -> None:
        servo = self._servos.get(channel)
        if servo is not None:
            here = servo.at(now)
            self._servos[channel] = _Servo(here, round(here), now, now)

    def _group_move(self, cmd: str, now: float) -> bool:
        """Start the group move ``cmd`` (normalised); False (nothing done) if a channel is above 31."""
        items = [(int(m[1]), int(m[2]), None if m[3] is None else int(m[3])) for m in _ITEM.finditer(cmd)]
        if any(ch >= CHANNELS for ch, _, _ in items):
            return False
        t = re.search(r"T(\d+)$", cmd)
        duration_ms = None if t is None else int(t[1])
        self.history.append(GroupMove(now, {ch: pw for ch, pw, _ in items},
                                      {ch: s for ch, _, s in items if s is not None}, duration_ms))
        duration = min(duration_ms or 0, TIME_MAX) / 1000.0  # [s]
        moves: dict[int, tuple[float | None, int]] = {}  # channel: (pulse now or None, clamped target)
        for ch, pw, speed in items:
            if not PULSE_MIN <= pw <= PULSE_MAX:
                self.out_of_range.append((ch, pw))
            if pw == 0:
                self._servos.pop(ch, None)
                moves.pop(ch, None)
                continue
            target = min(max(pw, PULSE_MIN), PULSE_MAX)
            here = self._servos[ch].at(now) if ch in self._servos else None
            moves[ch] = (here, target)
            if here is not None and speed:
                duration = max(duration, abs(target - here) / speed)
        for ch, (here, target) in moves.items():
            if here is None:  # no known position: jump
                self._servos[ch] = _Servo(float(target), target, now, now)
            else:
                self._servos[ch] = _Servo(here, target, now, now + duration)
        self._busy_until = max(self._busy_until, now + duration)
        return True


def main(argv: list[str] | None = None) -> int:
    """Serve an emulated SSC-32 until Ctrl-C, printing its port and what it receives."""
    parser = argparse.ArgumentParser(prog="python -m clients.emulators.ssc32",
                                     description="An emulated SSC-32 servo controller on a pseudo-terminal.")
    parser.add_argument("--ver", default="SSC32-V2.50USB", help="what VER answers")
    args = parser.parse_args(argv)
    with SSC32Emulator(version=args.ver) as emu:
        print(emu.port, flush=True)
        logs: dict[str, Sequence[object]] = {"move": emu.history, "out of range": emu.out_of_range,
                                             "not understood": emu.errors}
        seen = dict.fromkeys(logs, 0)
        try:
            while True:
                time.sleep(0.1)
                for label, items in logs.items():
                    for item in items[seen[label]:]:
                        print(f"{label}: {item}", flush=True)
                    seen[label] = len(items)
        except KeyboardInterrupt:
            pass
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
