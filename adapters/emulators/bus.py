"""What the bus-servo emulators share: a half-duplex serial bus at its baud rate, servos on it
that move by their own position loop, and the faults a real bus shows.

A subclass speaks one vendor's protocol (:mod:`.feetech`, :mod:`.dynamixel`): it frames the
bytes that reach the bus into instruction packets (``_frame``), executes one (``_execute``,
returning the status packets the servos send, in order) and keeps each servo's control table
(the registers its protocol reads and writes). This module times the bytes and moves the
servos.

The link (all times on ``clock``, like the SSC-32 emulator's):

- The bus runs at ``baud`` (8N1: 10 bits a byte), both ways, one way at a time. Byte ``i`` of a
  write the emulator reads at ``t`` reaches the servos at ``max(t, end of the previous byte) +
  (i + 1) * 10 / baud``; an instruction is executed when its last byte has arrived.
- A servo's status packet leaves ``return_delay`` after the instruction's last byte (its
  control table's return delay time) plus ``processing`` (the servo's firmware, 50 us here),
  and travels back at the same rate; replies of several servos (a sync read) follow one another
  in the order the instruction lists them, each no sooner than the previous one ended.
- Nothing is ever sent that no instruction asked for.
- ``latency`` [s] (0: none): the USB-serial chip between the bus and the host holds what the
  servos send, as an FTDI chip does until its latency timer runs out (16 ms from the factory)
  or a USB packet (62 bytes) fills: a batch leaves ``latency`` after its first byte arrived.

A servo (the motion model; the vendors publish no closed form of their firmware's loop, so
this is the documented behaviour of a position servo, with each vendor's numbers):

- With torque on, it drives toward its goal with a speed ``(goal - position) / time_constant``
  (a proportional position loop), at most the goal speed (or profile velocity) its control
  table sets, else the motor's own top speed, and at most what it can brake from before the
  goal (``sqrt(2 a |goal - position|)``: it arrives, it does not overshoot), and changes that
  speed by at most ``a``, the acceleration its control table sets, else the motor's own;
  integrated at ``STEP`` [s]. A goal that keeps moving ahead of it (a trajectory streamed)
  is tracked with the loop's lag; with a low acceleration set, it lags much more (it must be
  able to brake before each goal as it comes).
- With torque off it stays where it is, unless moved by hand (:meth:`BusEmulator.move_by_hand`).
- ``hold(id, position)``: something in the way at ``position`` (the servo cannot pass it): its
  load rises with the error its loop sees, and a load above its protection threshold for longer
  than its protection time is an overload: the overload bit in every status packet and the
  torque off (as the STS3215 and the X series do by default).
- Load: the loop's effort, ``error / error_at_full_load``, as a fraction of full torque (the
  motor's top speed, and the acceleration, take nothing here: an unloaded arm).
- Voltage and temperature are set by the test (:meth:`set_voltage`, :meth:`set_temperature`);
  outside the control table's limits they set the voltage or overheat bit.

Faults, for tests: ``drop_replies(id, n, after=0)`` (the next ``n`` status packets of that
servo are lost on the wire, once ``after`` more have gone through), ``silence(id)`` (it never
answers again: a cable off), ``trip_overload(id)`` (its overload protection trips, as a payload
too heavy would make it), ``power_cycle()`` (RAM registers back to their defaults: torque off;
the EEPROM and the horn's position stay).
"""

from __future__ import annotations

import contextlib
import math
import os
import select
import threading
import time
from abc import abstractmethod
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

from .pty import PtyEmulator

BITS_PER_BYTE = 10  # 8N1
STEP = 0.001  # [s] the motion model's integration step
PROCESSING = 50e-6  # [s] a servo's firmware: from an instruction's last byte to its reply's first
USB_PACKET = 62  # [bytes] of data in a USB-serial chip's packet to the host (an FTDI's 64, less 2 of status)


@dataclass
class Motor:
    """One servo's mechanics, in counts: ``top_speed`` [counts/s], ``top_acceleration``
    [counts/s^2], the loop's ``time_constant`` [s], and the error [counts] at which the loop
    asks for full torque."""

    top_speed: float
    top_acceleration: float
    time_constant: float
    error_at_full_load: float


@dataclass
class ServoState:
    """A servo's physical state and what the tests inject; the control table is the protocol's."""

    id: int
    position: float  # [counts] the horn, raw (before any offset the control table applies)
    velocity: float = 0.0  # [counts/s]
    load: float = 0.0  # [-1, 1] of full torque, signed
    voltage: float = 7.4  # [V]
    temperature: float = 30.0  # [deg C]
    blocked_at: float | None = None  # [counts] something in the way (hold())
    overloaded_for: float = 0.0  # [s] how long the load has been above the protection threshold
    drop: int = 0  # status packets still to lose
    drop_after: int = 0  # ... once this many more have gone through
    silent: bool = False
    # (time [s], position [counts]) at every step it moved, for tests (the last ten minutes at most)
    moved: deque[tuple[float, float]] = field(default_factory=lambda: deque(maxlen=600_000))


class BusEmulator(PtyEmulator):
    """A bus of servos on a pseudo-terminal. ``ids``: the servos on it; ``baud``: the bus's
    rate [bit/s] (None: instant); ``clock`` [s]; ``positions``: each servo's raw position at
    power-up [counts] (default: the middle of its turn)."""

    keep_slave = True  # opening the port resets nothing
    motor: Motor  # (the subclass's servo model)
    counts_per_rev = 4096

    def __init__(
        self,
        ids: tuple[int, ...] | list[int],
        *,
        baud: int | None = 1_000_000,
        clock: Callable[[], float] = time.monotonic,
        positions: dict[int, float] | None = None,
        latency: float = 0.0,
    ) -> None:
        super().__init__()
        if len(set(ids)) != len(ids) or not ids:
            raise ValueError(f"ids must be distinct and not empty, got {ids}")
        self.baud = baud
        self.latency = float(latency)
        self.clock = clock
        self.servos: dict[int, ServoState] = {}
        for i in ids:
            at = (positions or {}).get(i, self.counts_per_rev / 2)
            self.servos[i] = ServoState(i, float(at))
        self.tables: dict[int, bytearray] = {}
        for i in ids:
            self.tables[i] = self._factory_table(i)
        self.errors: list[str] = []  # what was not understood (bad checksum, unknown instruction...)
        self.instructions: list[tuple[float, int, int]] = []  # (time, id, instruction), executed
        self.transactions = 0  # instructions executed
        self._rx: deque[tuple[float, int]] = deque()
        self._rx_free = -math.inf
        self._tx: deque[tuple[float, int]] = deque()
        self._tx_free = -math.inf
        self._buffer = bytearray()  # bytes arrived, not yet a whole packet
        self._now = clock()  # [s] the motion model's time
        self._lock = threading.Lock()

    # -- for tests -----------------------------------------------------------------------------

    def position(self, ident: int) -> float:
        """The servo's raw position now [counts]."""
        with self._lock:
            self._advance()
            return self.servos[ident].position

    def positions(self) -> dict[int, float]:
        with self._lock:
            self._advance()
            return {i: s.position for i, s in self.servos.items()}

    def trace(self, ident: int) -> list[tuple[float, float]]:
        """The servo's raw position [counts] over time, at every model step it moved."""
        with self._lock:
            self._advance()
            return list(self.servos[ident].moved)

    def move_by_hand(self, ident: int, position: float) -> None:
        """Someone turns the horn to ``position`` [raw counts] (with torque on, the loop drives
        it back to its goal: as on the real servo)."""
        with self._lock:
            self._advance()
            s = self.servos[ident]
            s.position, s.velocity = float(position), 0.0
            s.moved.append((self._now, s.position))

    def hold(self, ident: int, position: float | None) -> None:
        """Something in the way at ``position`` [raw counts] (None: taken away)."""
        with self._lock:
            self._advance()
            self.servos[ident].blocked_at = None if position is None else float(position)

    def set_voltage(self, volts: float) -> None:
        with self._lock:
            for s in self.servos.values():
                s.voltage = float(volts)

    def set_temperature(self, ident: int, celsius: float) -> None:
        with self._lock:
            self.servos[ident].temperature = float(celsius)

    def drop_replies(self, ident: int, n: int, after: int = 0) -> None:
        """Lose the next ``n`` status packets of servo ``ident`` (noise on the wire), once
        ``after`` more have gone through."""
        with self._lock:
            self.servos[ident].drop += int(n)
            self.servos[ident].drop_after = int(after)

    def trip_overload(self, ident: int) -> None:
        """The servo's overload protection trips now (a load the motion model cannot make: a
        payload too heavy): its overload bit, and its torque off where its table says so."""
        with self._lock:
            self._advance()
            self._overloaded(ident)

    def silence(self, ident: int, silent: bool = True) -> None:
        """The servo hears nothing and answers nothing (its cable off), or again."""
        with self._lock:
            self.servos[ident].silent = silent

    def power_cycle(self) -> None:
        """Power off and on: the RAM registers back to their defaults (torque off), the EEPROM
        kept, the horns where they are; bytes on their way and replies not yet sent are lost."""
        with self._lock:
            self._advance()
            for i in self.servos:
                self._reset_ram(i)
                self.servos[i].velocity = 0.0
            self._buffer.clear()
            self._tx.clear()
            self._tx_free = -math.inf

    # -- what a protocol provides ----------------------------------------------------------------

    @abstractmethod
    def _factory_table(self, ident: int) -> bytearray:
        """The control table of a servo as shipped (with id ``ident``)."""

    @abstractmethod
    def _reset_ram(self, ident: int) -> None:
        """Power-up: the RAM area back to its defaults."""

    @abstractmethod
    def _frame(self, buffer: bytearray) -> tuple[bytes | None, int]:
        """The first whole packet in ``buffer`` and how many bytes it (and any garbage before
        it) takes; ``(None, k)``: ``k`` bytes of garbage to drop, or ``(None, 0)``: wait for more."""

    @abstractmethod
    def _execute(self, packet: bytes, t: float) -> list[tuple[int, bytes]]:
        """Execute one instruction packet at time ``t``; the status packets, as (servo id, bytes), in order."""

    @abstractmethod
    def _goal(self, ident: int) -> tuple[bool, float, float, float]:
        """From the control table: (torque on, goal [raw counts], speed limit [counts/s, 0: the
        motor's], acceleration limit [counts/s^2, 0: the motor's])."""

    @abstractmethod
    def _update_table(self, ident: int) -> None:
        """Write the servo's state (position, speed, load, voltage, temperature, moving, error) into its table."""

    @abstractmethod
    def _protection(self, ident: int) -> tuple[float, float, bool]:
        """(load threshold [0..1], time [s], whether an overload turns the torque off)."""

    @abstractmethod
    def _overloaded(self, ident: int) -> None:
        """Set the overload bit (and turn the torque off, if the table says so)."""

    # -- the motion model ------------------------------------------------------------------------

    def _step(self, s: ServoState, dt: float) -> None:
        on, goal, vlim, alim = self._goal(s.id)
        m = self.motor
        before = s.position
        if on:
            vmax = vlim if vlim > 0 else m.top_speed
            amax = alim if alim > 0 else m.top_acceleration
            error = goal - s.position
            # the loop's speed, and no more than it can brake from before the goal (no overshoot)
            want = math.copysign(min(vmax, abs(error) / m.time_constant, math.sqrt(2.0 * amax * abs(error))), error)
            dv = max(-amax * dt, min(amax * dt, want - s.velocity))
            v = s.velocity + dv
            p = s.position + v * dt
            wall = s.blocked_at
            if wall is not None and (before - wall) * (p - wall) <= 0.0:  # it cannot pass what is in the way
                p, v = wall, 0.0
            s.position, s.velocity = float(p), float(v)
            s.load = max(-1.0, min(1.0, (goal - s.position) / m.error_at_full_load))
            threshold, hold_time, _unload = self._protection(s.id)
            s.overloaded_for = s.overloaded_for + dt if abs(s.load) >= threshold else 0.0
            if s.overloaded_for >= hold_time:
                self._overloaded(s.id)
                s.overloaded_for = 0.0
        else:
            s.velocity, s.load, s.overloaded_for = 0.0, 0.0, 0.0
        if s.position != before:
            s.moved.append((self._now + dt, s.position))

    def _advance_motion(self, until: float) -> None:
        while self._now + STEP <= until:
            for s in self.servos.values():
                self._step(s, STEP)
            self._now += STEP

    # -- the link --------------------------------------------------------------------------------

    def _byte_time(self) -> float:
        return 0.0 if self.baud is None else BITS_PER_BYTE / self.baud

    def _receive(self, chunk: bytes, now: float) -> None:
        dt, start = self._byte_time(), max(self._rx_free, now)
        self._rx.extend((start + (i + 1) * dt, b) for i, b in enumerate(chunk))
        self._rx_free = start + len(chunk) * dt

    def _transmit(self, data: bytes, ready: float) -> None:
        dt, start = self._byte_time(), max(self._tx_free, ready)
        self._tx.extend((start + (i + 1) * dt, b) for i, b in enumerate(data))
        self._tx_free = start + len(data) * dt

    def _return_delay(self, ident: int) -> float:
        """[s] the servo's return delay time (its control table's)."""
        return 0.0

    def _advance(self) -> float:
        """Execute every instruction arrived by now (the servos moved up to its time first),
        write every reply byte due; return now."""
        now = self.clock()
        while self._rx and self._rx[0][0] <= now:
            t, byte = self._rx.popleft()
            self._buffer.append(byte)
            while True:
                packet, used = self._frame(self._buffer)
                if used == 0:
                    break
                del self._buffer[:used]
                if packet is None:
                    continue
                self._advance_motion(t)
                for i in self.servos:
                    self._update_table(i)
                self.transactions += 1
                for ident, reply in self._execute(packet, t):
                    s = self.servos[ident]
                    if s.drop > 0 and s.drop_after > 0:
                        s.drop_after -= 1
                    elif s.drop > 0:
                        s.drop -= 1
                        continue
                    self._transmit(reply, t + self._return_delay(ident) + PROCESSING)
        self._advance_motion(now)
        for i in self.servos:
            self._update_table(i)
        out = bytearray()
        while self._tx and (leave := self._released(0)) <= now:  # a batch at a time (a byte, with no latency)
            for _ in range(USB_PACKET if self.latency else 1):
                if not self._tx or self._tx[0][0] > leave:
                    break
                out.append(self._tx.popleft()[1])
        if out and self._master >= 0:
            with contextlib.suppress(BlockingIOError):  # the host's input buffer full: lost, as on a UART
                os.write(self._master, out)
        return now

    def _released(self, k: int) -> float:
        """When the reply byte waiting ``k``-th reaches the host [s]: at once, or through a
        USB-serial chip's buffer (``latency``: its latency timer), in a batch that leaves
        ``latency`` after its first byte arrived, or when ``USB_PACKET`` bytes fill it."""
        first = self._tx[k][0]
        if not self.latency:
            return first
        full = k + USB_PACKET - 1
        return min(first + self.latency, self._tx[full][0]) if full < len(self._tx) else first + self.latency

    def _serve(self) -> None:
        master = self._master
        while not self._stop.is_set():
            with self._lock:
                due = min(self._rx[0][0] if self._rx else math.inf, self._released(0) if self._tx else math.inf)
                wait = due - self.clock()
            timeout = 0.005 if wait == math.inf else min(max(wait, 0.0), 0.005)
            if select.select([master], [], [], timeout)[0]:
                try:
                    chunk = os.read(master, 4096)
                except (BlockingIOError, InterruptedError):
                    chunk = b""
                except OSError:
                    break
                with self._lock:
                    self._receive(chunk, self.clock())
            with self._lock:
                self._advance()


def serve(cls: type[BusEmulator], prog: str, description: str, ids: str, argv: list[str] | None = None) -> int:
    """``python -m armd.adapters.emulators.<vendor>``: a bus of ``cls`` servos until Ctrl-C, its port printed."""
    import argparse

    parser = argparse.ArgumentParser(prog=prog, description=description)
    parser.add_argument("--ids", default=ids, help=f"the servos' ids, comma-separated (default {ids})")
    parser.add_argument("--baud", type=int, default=1_000_000, help="the bus's rate, bit/s (0: instant)")
    args = parser.parse_args(argv)
    with cls([int(x) for x in args.ids.split(",")], baud=args.baud or None) as emu:
        print(emu.port, flush=True)
        try:
            while True:
                time.sleep(1.0)
        except KeyboardInterrupt:
            pass
    return 0
