"""An emulator of a bus of Feetech STS3215 servos (the SO-100/SO-101's), for tests: not a driver.

It speaks Feetech's STS serial protocol on a pseudo-terminal at the bus's rate, so that the
vendor's SDK (``scservo_sdk``) opens it as it opens ``/dev/ttyACM0``. Written from Feetech's
STS3215 memory table and protocol manual, and the SDKs' sources (``feetech-servo-sdk`` 1.0.0 and
``ftservo-python-sdk`` 2.0.1), not from what armd's adapter sends. The bus, the motion model and
the faults: :mod:`.bus`. Run one by hand with ``python -m armd.adapters.emulators.feetech``.

Packets: an instruction is ``FF FF ID LEN INST P1..Pn CHK`` with ``LEN = n + 2`` and
``CHK = ~(ID + LEN + INST + P1 + .. + Pn) & 0xFF``; a status packet is ``FF FF ID LEN ERR
D1..Dn CHK``. ID 254 (``FE``) is the broadcast id. Covered instructions:

- ``PING`` (1): a status packet with no data.
- ``READ`` (2) ``addr, len``: the control table's bytes.
- ``WRITE`` (3) ``addr, data..``: written (EEPROM bytes only while ``Lock`` is 0), a status packet.
- ``REG_WRITE`` (4) and ``ACTION`` (5): a write held until ``ACTION`` (broadcast: no reply).
- ``SYNC_READ`` (0x82, to FE) ``addr, len, id..``: each servo listed and present answers, in
  the order listed, one after the other.
- ``SYNC_WRITE`` (0x83, to FE) ``addr, len, (id, data..)..``: each servo listed writes its data; no reply.

A status packet answers an instruction to one servo (not a broadcast one) when its status
return level (address 8) is 1 (the factory's), else only ``PING`` and ``READ``. A packet with a
bad checksum, an unknown instruction, or for no servo on the bus gets no answer, and is
recorded in ``errors``.

The control table (the STS3215's; little-endian words; ``*``: sign and magnitude, the sign in
bit 15, or bit 11 for the offset, bit 10 for the load):

- EEPROM (kept across ``power_cycle``; written only with ``Lock`` (55) at 0; the factory's
  ``Lock`` is 1): model 3/2 (777), id 5, baud 6 (0 = 1 Mbaud), return delay 7 (x 2 us), status
  return level 8, angle limits 9/2 and 11/2 (0-4095), max temperature 13 (70 C), max and min
  voltage 14 and 15 (x 0.1 V: 80 and 40), unloading condition 19 (bit 5: an overload turns the
  torque off; factory 44: overheat, overcurrent, overload), offset 31/2* (the position the
  servo reports is its raw position less this; a goal is moved by it too), overload torque
  36 (percent: 80), protection time 35 (x 10 ms: 200).
- RAM (back to its defaults at power-up): torque enable 40 (0 at power-up), acceleration 41
  (x 100 counts/s^2, 0: the motor's), goal position 42/2 (the position at power-up), goal time
  44/2, goal speed 46/2 (counts/s, 0: the motor's top speed), lock 55, present position 56/2,
  present speed 58/2*, present load 60/2* (x 0.1 percent), present voltage 62 (x 0.1 V),
  present temperature 63 (C), moving 66, present current 69/2.
- Error bits in every status packet: 0 voltage, 2 overheat, 5 overload (1 the sensor and 3
  the current are never raised here). An overload latches until the torque is enabled again.
  An error whose bit is in the unloading condition (19) turns the torque off (the servo
  "unloads"): with the factory's 44, an overheat and an overload do, a voltage error does not.

Where the real servo differs, or may:

- Its position loop is a PID of its own (coefficients 21-23) on a motor with inertia and load:
  here a proportional loop with speed and acceleration limits (:mod:`.bus`); its tracking lag
  at speed is of the same order (20 ms here), not the same.
- Whether writing a goal with the torque off turns the torque on is not documented: here it
  does not (the torque goes on only by address 40, and then drives to the goal written last:
  a host that does not write the goal first sees the servo jump to an old one).
- The baud rate (6) and the angle resolution (30) written take no effect here; multi-turn
  mode (both angle limits 0) is not modelled: the goal is kept within the angle limits.
- The current (69) is the load's share of 500 mA; the real servo measures it.
"""

from __future__ import annotations

from .bus import BusEmulator, Motor, serve

BROADCAST = 0xFE
PING, READ, WRITE, REG_WRITE, ACTION, SYNC_READ, SYNC_WRITE = 0x01, 0x02, 0x03, 0x04, 0x05, 0x82, 0x83
MODEL_STS3215 = 777
TABLE_SIZE = 256
EEPROM_END = 40  # addresses below: EEPROM (written only unlocked)

# addresses
MODEL, ID, BAUD, RETURN_DELAY, STATUS_LEVEL = 3, 5, 6, 7, 8
MIN_ANGLE, MAX_ANGLE, MAX_TEMPERATURE, MAX_VOLTAGE, MIN_VOLTAGE = 9, 11, 13, 14, 15
UNLOADING, OFFSET, PROTECTION_TIME, OVERLOAD_TORQUE = 19, 31, 35, 36
TORQUE, ACCELERATION, GOAL_POSITION, GOAL_TIME, GOAL_SPEED, LOCK = 40, 41, 42, 44, 46, 55
PRESENT_POSITION, PRESENT_SPEED, PRESENT_LOAD, PRESENT_VOLTAGE, PRESENT_TEMPERATURE = 56, 58, 60, 62, 63
MOVING, PRESENT_CURRENT = 66, 69
READ_ONLY = range(56, 71)

# error bits of a status packet
VOLTAGE_ERROR, SENSOR_ERROR, OVERHEAT_ERROR, CURRENT_ERROR, OVERLOAD_ERROR = 1, 2, 4, 8, 32

# The STS3215 at 7.4 V: 0.222 s / 60 deg unloaded (4.7 rad/s, 3073 counts/s); the acceleration
# and loop figures are this model's (module docstring)
STS3215 = Motor(top_speed=3073.0, top_acceleration=50_000.0, time_constant=0.02, error_at_full_load=100.0)


def checksum(body: bytes) -> int:
    """``~(ID + LEN + INST/ERR + params) & 0xFF`` of a packet's bytes after ``FF FF``."""
    return ~sum(body) & 0xFF


def packet(ident: int, inst: int, params: bytes = b"") -> bytes:
    """An instruction (or, with ``inst`` the error byte, a status) packet."""
    body = bytes([ident, len(params) + 2, inst]) + params
    return b"\xff\xff" + body + bytes([checksum(body)])


def signed(value: int, bit: int) -> int:
    """A sign-and-magnitude field (the sign in ``bit``) as an int."""
    magnitude = value & ((1 << bit) - 1)
    return -magnitude if value & (1 << bit) else magnitude


def sign_magnitude(value: int, bit: int) -> int:
    return (1 << bit) | min(-value, (1 << bit) - 1) if value < 0 else min(value, (1 << bit) - 1)


class FeetechEmulator(BusEmulator):
    """STS3215 servos with ``ids`` on a bus at ``baud`` (the factory's 1 Mbaud) on a
    pseudo-terminal; ``start()`` (or ``with``) returns the path to open."""

    name = "feetech-emulator"
    motor = STS3215

    def __init__(self, ids: tuple[int, ...] | list[int] = (1, 2, 3, 4, 5, 6), **kwargs: object) -> None:
        self._pending: dict[int, tuple[int, bytes]] = {}  # REG_WRITE's, per servo
        self._errors_latched: dict[int, int] = {}
        super().__init__(ids, **kwargs)  # type: ignore[arg-type]

    # -- the control table -------------------------------------------------------------------

    def word(self, ident: int, address: int) -> int:
        t = self.tables[ident]
        return t[address] | (t[address + 1] << 8)

    def _set_word(self, ident: int, address: int, value: int) -> None:
        t = self.tables[ident]
        t[address], t[address + 1] = value & 0xFF, (value >> 8) & 0xFF

    def register(self, ident: int, address: int, size: int = 1) -> int:
        """A register's raw value, for tests."""
        with self._lock:
            return self.tables[ident][address] if size == 1 else self.word(ident, address)

    def _factory_table(self, ident: int) -> bytearray:
        t = bytearray(TABLE_SIZE)
        t[0], t[1] = 3, 10  # firmware 3.10
        t[MODEL], t[MODEL + 1] = MODEL_STS3215 & 0xFF, MODEL_STS3215 >> 8
        t[ID], t[BAUD], t[RETURN_DELAY], t[STATUS_LEVEL] = ident, 0, 0, 1
        t[MIN_ANGLE], t[MIN_ANGLE + 1] = 0, 0
        t[MAX_ANGLE], t[MAX_ANGLE + 1] = 4095 & 0xFF, 4095 >> 8
        t[MAX_TEMPERATURE], t[MAX_VOLTAGE], t[MIN_VOLTAGE] = 70, 80, 40
        t[16], t[17] = 1000 & 0xFF, 1000 >> 8  # max torque
        t[UNLOADING], t[20] = 44, 47  # unloading and LED alarm conditions
        t[21], t[22], t[23] = 32, 32, 0  # P, D, I
        t[PROTECTION_TIME], t[OVERLOAD_TORQUE], t[34] = 200, 80, 20
        self.tables[ident] = t
        self._reset_ram(ident)
        return t

    def _reset_ram(self, ident: int) -> None:
        t = self.tables[ident]
        t[EEPROM_END:] = bytes(TABLE_SIZE - EEPROM_END)
        t[LOCK] = 1
        t[48], t[49] = 1000 & 0xFF, 1000 >> 8  # torque limit
        raw = self.servos[ident].position
        self._set_word(ident, GOAL_POSITION, round(raw - self._offset(ident)) % self.counts_per_rev)
        self._errors_latched[ident] = 0
        self._pending.pop(ident, None)

    def _offset(self, ident: int) -> int:
        return signed(self.word(ident, OFFSET), 11)

    def _goal(self, ident: int) -> tuple[bool, float, float, float]:
        t = self.tables[ident]
        lo, hi = self.word(ident, MIN_ANGLE), self.word(ident, MAX_ANGLE)
        goal = min(max(self.word(ident, GOAL_POSITION), lo), hi) if lo < hi else self.word(ident, GOAL_POSITION)
        return (
            bool(t[TORQUE]),
            float(goal + self._offset(ident)),
            float(self.word(ident, GOAL_SPEED)),
            100.0 * t[ACCELERATION],
        )

    def _protection(self, ident: int) -> tuple[float, float, bool]:
        t = self.tables[ident]
        return t[OVERLOAD_TORQUE] / 100.0, t[PROTECTION_TIME] * 0.01, bool(t[UNLOADING] & OVERLOAD_ERROR)

    def _overloaded(self, ident: int) -> None:
        self._errors_latched[ident] |= OVERLOAD_ERROR
        if self.tables[ident][UNLOADING] & OVERLOAD_ERROR:
            self.tables[ident][TORQUE] = 0

    def _error(self, ident: int) -> int:
        s, t = self.servos[ident], self.tables[ident]
        bits = self._errors_latched[ident]
        if not t[MIN_VOLTAGE] <= round(s.voltage * 10) <= t[MAX_VOLTAGE]:
            bits |= VOLTAGE_ERROR
        if s.temperature > t[MAX_TEMPERATURE]:
            bits |= OVERHEAT_ERROR
        return bits

    def _update_table(self, ident: int) -> None:
        s = self.servos[ident]
        present = round(s.position - self._offset(ident)) % self.counts_per_rev
        self._set_word(ident, PRESENT_POSITION, present)
        self._set_word(ident, PRESENT_SPEED, sign_magnitude(round(s.velocity), 15))
        self._set_word(ident, PRESENT_LOAD, sign_magnitude(round(s.load * 1000), 10))
        t = self.tables[ident]
        t[PRESENT_VOLTAGE] = max(0, min(255, round(s.voltage * 10)))
        t[PRESENT_TEMPERATURE] = max(0, min(255, round(s.temperature)))
        t[MOVING] = 1 if abs(s.velocity) > 1.0 else 0
        self._set_word(ident, PRESENT_CURRENT, round(abs(s.load) * 500 / 6.5))  # (6.5 mA a unit)
        t[65] = self._error(ident)
        if t[65] & t[UNLOADING] & (VOLTAGE_ERROR | OVERHEAT_ERROR):  # (its unloading condition: the torque off)
            t[TORQUE] = 0

    def _return_delay(self, ident: int) -> float:
        return 2e-6 * self.tables[ident][RETURN_DELAY]

    # -- packets -------------------------------------------------------------------------------

    def _frame(self, buffer: bytearray) -> tuple[bytes | None, int]:
        start = buffer.find(b"\xff\xff")
        if start < 0:
            return None, (len(buffer) - 1 if buffer.endswith(b"\xff") else len(buffer))
        if start > 0:
            return None, start
        if len(buffer) > 2 and buffer[2] == 0xFF:  # (FF FF FF ..: the header is the last two)
            return None, 1
        if len(buffer) < 4:
            return None, 0
        length = buffer[3]
        if length < 2:
            self.errors.append(f"a packet of length {length}")
            return None, 4
        total = 4 + length
        if len(buffer) < total:
            return None, 0
        body = bytes(buffer[2 : total - 1])
        if checksum(body) != buffer[total - 1]:
            self.errors.append(f"bad checksum: {bytes(buffer[:total]).hex(' ')}")
            return None, total
        return bytes(buffer[:total]), total

    def _status(self, ident: int, data: bytes = b"") -> tuple[int, bytes]:
        return ident, packet(ident, self._error(ident), data)

    def _here(self, ident: int) -> bool:
        return ident in self.servos and not self.servos[ident].silent

    def _execute(self, pkt: bytes, t: float) -> list[tuple[int, bytes]]:
        ident, inst, params = pkt[2], pkt[4], pkt[5:-1]
        self.instructions.append((t, ident, inst))
        if inst == SYNC_WRITE and ident == BROADCAST and len(params) >= 2:
            address, size = params[0], params[1]
            k = 2
            while k + 1 + size <= len(params):
                if self._here(params[k]):
                    self._write(params[k], address, params[k + 1 : k + 1 + size])
                k += size + 1
            return []
        if inst == SYNC_READ and ident == BROADCAST and len(params) >= 2:
            address, size = params[0], params[1]
            return [
                self._status(i, bytes(self.tables[i][address : address + size])) for i in params[2:] if self._here(i)
            ]
        if inst == ACTION:
            targets = list(self.servos) if ident == BROADCAST else [ident]
            for i in targets:
                if self._here(i) and i in self._pending:
                    self._write(i, *self._pending.pop(i))
            return [] if ident == BROADCAST or not self._here(ident) else self._reply(ident, inst, b"")
        if ident == BROADCAST:
            if inst == WRITE and params:
                for i in self.servos:
                    if self._here(i):
                        self._write(i, params[0], params[1:])
                return []
            if inst == PING:  # each servo answers, by id
                return [self._status(i) for i in sorted(self.servos) if self._here(i)]
            self.errors.append(f"broadcast instruction {inst:#04x} not understood")
            return []
        if not self._here(ident):
            return []  # (no one there: the host's read times out)
        if inst == PING:
            return [self._status(ident)]
        if inst == READ and len(params) == 2:
            address, size = params
            return [self._status(ident, bytes(self.tables[ident][address : address + size]))]
        if inst == WRITE and params:
            ident = self._write(ident, params[0], params[1:])  # (an id written: the servo answers as its new one)
            return self._reply(ident, inst, b"")
        if inst == REG_WRITE and params:
            self._pending[ident] = (params[0], bytes(params[1:]))
            return self._reply(ident, inst, b"")
        self.errors.append(f"instruction {inst:#04x} to {ident} not understood ({pkt.hex(' ')})")
        return []

    def _reply(self, ident: int, inst: int, data: bytes) -> list[tuple[int, bytes]]:
        level = self.tables[ident][STATUS_LEVEL]
        return [self._status(ident, data)] if level >= 1 or inst in (PING, READ) else []

    def _write(self, ident: int, address: int, data: bytes) -> int:
        """Write ``data`` at ``address``; the servo's id after it."""
        t = self.tables[ident]
        locked = t[LOCK] != 0
        enable_before = t[TORQUE]
        for k, byte in enumerate(data):
            a = address + k
            if a >= TABLE_SIZE or a in READ_ONLY or (a < EEPROM_END and locked and a != LOCK):
                continue
            t[a] = byte
        if t[TORQUE] and not enable_before:
            self._errors_latched[ident] &= ~OVERLOAD_ERROR  # (enabling the torque clears an overload)
        if t[ID] != ident and address <= ID < address + len(data):
            return self._renumber(ident, t[ID])
        return ident

    def _renumber(self, old: int, new: int) -> int:
        if new in self.servos or new > 253:
            self.tables[old][ID] = old
            self.errors.append(f"id {old} -> {new} refused (in use or reserved)")
            return old
        self.servos[new] = self.servos.pop(old)
        self.servos[new].id = new
        self.tables[new] = self.tables.pop(old)
        self._errors_latched[new] = self._errors_latched.pop(old)
        return new


def main(argv: list[str] | None = None) -> int:
    return serve(
        FeetechEmulator,
        "python -m armd.adapters.emulators.feetech",
        "Emulated Feetech STS3215 servos on a pseudo-terminal.",
        "1,2,3,4,5,6",
        argv,
    )


if __name__ == "__main__":
    raise SystemExit(main())
