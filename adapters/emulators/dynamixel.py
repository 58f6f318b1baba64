"""An emulator of a bus of ROBOTIS Dynamixel X-series servos (XM430-W350, the OpenManipulator-X's)
on Protocol 2.0, for tests: not a driver.

It speaks Protocol 2.0 on a pseudo-terminal at the bus's rate, so that ROBOTIS's SDK
(``dynamixel-sdk``) opens it as it opens a U2D2's ``/dev/ttyUSB0``. Written from the ROBOTIS
e-Manual (Protocol 2.0; the XM430-W350's control table) and the SDK's source. The bus, the
motion model and the faults: :mod:`.bus`. Run one by hand with ``python -m armd.adapters.emulators.dynamixel``.

Packets: ``FF FF FD 00 ID LEN_L LEN_H INST P.. CRC_L CRC_H`` with ``LEN = n + 3`` and a CRC-16
(polynomial 0x8005, initial value 0) over everything before it; a status packet's INST is
``0x55`` followed by an error byte. Byte stuffing: after the header, ``FF FF FD`` is sent as
``FF FF FD FD`` (taken out on arrival, put in the replies). ID 254 is the broadcast id.
Covered: ``PING`` (model and firmware), ``READ``, ``WRITE``, ``REG_WRITE``/``ACTION``,
``REBOOT`` (clears a hardware error; the torque off), ``SYNC_READ`` (each servo listed answers
in turn) and ``SYNC_WRITE``.

Status return level (68): 2 (the factory's) answers everything, 1 ``PING`` and ``READ``, 0
``PING`` only. Errors in the status's error byte: 2 an unknown instruction, 3 a bad CRC (the
servo addressed answers so), 4 data out of range, 5 a data length error, 7 an access error
(the EEPROM, addresses below 64, written with the torque on; a read-only address); bit 7 (the
alert) whenever the hardware error status (70) is not 0.

The control table (the XM430-W350's; little-endian, signed where the manual says so): model 0/2
(1020), id 7, baud 8, return delay 9 (x 2 us, factory 250: 500 us), operating mode 11 (3:
position), homing offset 20/4 (added to what the servo reports), temperature limit 31 (80 C),
voltage limits 32/2 and 34/2 (x 0.1 V: 160 and 95), velocity limit 44/4, position limits 48/4
and 52/4, shutdown 63 (factory 52: overheating, electrical shock, overload turn the torque
off); torque enable 64, status return level 68, hardware error status 70, profile
acceleration 108/4 (x 214.577 rev/min^2, 0: the motor's), profile velocity 112/4 (x 0.229
rev/min, 0: the motor's), goal position 116/4, moving 122, present current 126/2 (x 2.69 mA),
present velocity 128/4, present position 132/4, present input voltage 144/2 (x 0.1 V),
present temperature 146. Hardware error bits: 0 input voltage, 2 overheating, 5 overload;
one in the shutdown's mask turns the torque off, and the torque cannot be enabled again until
a ``REBOOT``.

Where the real servo differs, or may: its position loop and its profile generator are its
own (:mod:`.bus` models a position loop with the profile's speed and acceleration); the baud
rate and operating mode written take no effect here (position mode only); ``BULK_READ``,
``BULK_WRITE``, the fast sync read, ``FACTORY_RESET`` and ``CLEAR`` are not covered (no
answer, recorded in ``errors``); the current is the load's share of the stall current.
"""

from __future__ import annotations

from .bus import BusEmulator, Motor, serve

BROADCAST = 0xFE
PING, READ, WRITE, REG_WRITE, ACTION, REBOOT, STATUS = 0x01, 0x02, 0x03, 0x04, 0x05, 0x08, 0x55
SYNC_READ, SYNC_WRITE = 0x82, 0x83
MODEL_XM430_W350 = 1020
TABLE_SIZE = 147
EEPROM_END = 64

MODEL, FIRMWARE, ID, BAUD, RETURN_DELAY, MODE, HOMING_OFFSET = 0, 6, 7, 8, 9, 11, 20
TEMPERATURE_LIMIT, MAX_VOLTAGE, MIN_VOLTAGE, VELOCITY_LIMIT, MAX_POSITION, MIN_POSITION, SHUTDOWN = (
    31,
    32,
    34,
    44,
    48,
    52,
    63,
)
TORQUE, STATUS_LEVEL, HARDWARE_ERROR = 64, 68, 70
PROFILE_ACCELERATION, PROFILE_VELOCITY, GOAL_POSITION, MOVING = 108, 112, 116, 122
PRESENT_CURRENT, PRESENT_VELOCITY, PRESENT_POSITION, PRESENT_VOLTAGE, PRESENT_TEMPERATURE = 126, 128, 132, 144, 146
READ_ONLY = (range(0, 7), range(HARDWARE_ERROR, HARDWARE_ERROR + 1), range(120, TABLE_SIZE))

VOLTAGE_ALARM, OVERHEAT_ALARM, OVERLOAD_ALARM = 1, 4, 32
ALERT = 0x80
VELOCITY_UNIT = 0.229 * 4096 / 60  # [counts/s] of a velocity unit (0.229 rev/min)
ACCELERATION_UNIT = 214.577 * 4096 / 3600  # [counts/s^2] of an acceleration unit (214.577 rev/min^2)
STALL_CURRENT = 2300.0 / 2.69  # [units] the XM430-W350's stall current at 12 V (2.3 A)

# The XM430-W350 at 12 V: 46 rev/min unloaded (3140 counts/s); the acceleration and loop figures are this model's
XM430_W350 = Motor(top_speed=46 * 4096 / 60, top_acceleration=50_000.0, time_constant=0.02, error_at_full_load=100.0)


def crc16(data: bytes) -> int:
    """Protocol 2.0's CRC-16: polynomial 0x8005, initial value 0, no reflection."""
    crc = 0
    for byte in data:
        crc ^= byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x8005) if crc & 0x8000 else (crc << 1)
            crc &= 0xFFFF
    return crc


def stuff(body: bytes) -> bytes:
    """Byte stuffing: ``FF FF FD`` -> ``FF FF FD FD`` (after the header)."""
    out = bytearray()
    for b in body:
        out.append(b)
        if len(out) >= 3 and out[-3:] == b"\xff\xff\xfd":
            out.append(0xFD)
    return bytes(out)


def unstuff(body: bytes) -> bytes:
    out = bytearray()
    k = 0
    while k < len(body):
        out.append(body[k])
        if len(out) >= 3 and out[-3:] == b"\xff\xff\xfd" and k + 1 < len(body) and body[k + 1] == 0xFD:
            k += 1  # (the stuffed FD)
        k += 1
    return bytes(out)


def packet(ident: int, inst: int, params: bytes = b"") -> bytes:
    """An instruction packet (or, with ``inst`` = STATUS and the error byte first in ``params``, a status)."""
    body = stuff(bytes([inst]) + params)
    head = b"\xff\xff\xfd\x00" + bytes([ident, (len(body) + 2) & 0xFF, (len(body) + 2) >> 8]) + body
    crc = crc16(head)
    return head + bytes([crc & 0xFF, crc >> 8])


class DynamixelEmulator(BusEmulator):
    """XM430-W350 servos with ``ids`` on a bus at ``baud`` (1 Mbaud here; the factory's is
    57600) on a pseudo-terminal; ``start()`` (or ``with``) returns the path to open."""

    name = "dynamixel-emulator"
    motor = XM430_W350

    def __init__(self, ids: tuple[int, ...] | list[int] = (11, 12, 13, 14, 15), **kwargs: object) -> None:
        self._pending: dict[int, tuple[int, bytes]] = {}
        self._pending_crc: int | None = None  # a servo to answer a bad CRC (see _frame)
        self._renamed = 0  # the id of the servo _write wrote to, after it
        super().__init__(ids, **kwargs)  # type: ignore[arg-type]

    # -- the control table -------------------------------------------------------------------

    def value(self, ident: int, address: int, size: int, signed: bool = False) -> int:
        raw = int.from_bytes(self.tables[ident][address : address + size], "little", signed=signed)
        return raw

    def _put(self, ident: int, address: int, size: int, value: int) -> None:
        self.tables[ident][address : address + size] = int(value).to_bytes(size, "little", signed=value < 0)

    def register(self, ident: int, address: int, size: int = 1, signed: bool = False) -> int:
        """A register's value, for tests."""
        with self._lock:
            return self.value(ident, address, size, signed)

    def _factory_table(self, ident: int) -> bytearray:
        t = bytearray(TABLE_SIZE)
        self.tables[ident] = t
        self._put(ident, MODEL, 2, MODEL_XM430_W350)
        t[FIRMWARE], t[ID], t[BAUD], t[RETURN_DELAY], t[MODE] = 45, ident, 1, 250, 3
        t[TEMPERATURE_LIMIT] = 80
        self._put(ident, MAX_VOLTAGE, 2, 160)
        self._put(ident, MIN_VOLTAGE, 2, 95)
        self._put(ident, VELOCITY_LIMIT, 4, 200)
        self._put(ident, MAX_POSITION, 4, 4095)
        self._put(ident, MIN_POSITION, 4, 0)
        t[SHUTDOWN] = 52
        self.servos[ident].voltage = 12.0  # (the supply's, as the X series runs on: a power cycle keeps it)
        self._reset_ram(ident)
        return t

    def _reset_ram(self, ident: int) -> None:
        t = self.tables[ident]
        t[EEPROM_END:] = bytes(TABLE_SIZE - EEPROM_END)
        t[STATUS_LEVEL] = 2
        s = self.servos[ident]
        self._put(ident, GOAL_POSITION, 4, round(s.position + self._offset(ident)))
        self._pending.pop(ident, None)

    def _offset(self, ident: int) -> int:
        return self.value(ident, HOMING_OFFSET, 4, signed=True)

    def _goal(self, ident: int) -> tuple[bool, float, float, float]:
        t = self.tables[ident]
        lo, hi = self.value(ident, MIN_POSITION, 4), self.value(ident, MAX_POSITION, 4)
        goal = min(max(self.value(ident, GOAL_POSITION, 4, signed=True), lo), hi)
        return (
            bool(t[TORQUE]),
            float(goal - self._offset(ident)),
            self.value(ident, PROFILE_VELOCITY, 4) * VELOCITY_UNIT,
            self.value(ident, PROFILE_ACCELERATION, 4) * ACCELERATION_UNIT,
        )

    def _protection(self, ident: int) -> tuple[float, float, bool]:
        return 0.95, 1.0, bool(self.tables[ident][SHUTDOWN] & OVERLOAD_ALARM)

    def _overloaded(self, ident: int) -> None:
        self._alarm(ident, OVERLOAD_ALARM)

    def _alarm(self, ident: int, bit: int) -> None:
        t = self.tables[ident]
        t[HARDWARE_ERROR] |= bit
        if t[SHUTDOWN] & bit:
            t[TORQUE] = 0

    def _update_table(self, ident: int) -> None:
        s, t = self.servos[ident], self.tables[ident]
        if s.temperature > t[TEMPERATURE_LIMIT]:
            self._alarm(ident, OVERHEAT_ALARM)
        if not self.value(ident, MIN_VOLTAGE, 2) <= round(s.voltage * 10) <= self.value(ident, MAX_VOLTAGE, 2):
            self._alarm(ident, VOLTAGE_ALARM)
        self._put(ident, PRESENT_POSITION, 4, round(s.position + self._offset(ident)))
        self._put(ident, PRESENT_VELOCITY, 4, round(s.velocity / VELOCITY_UNIT))
        self._put(ident, PRESENT_CURRENT, 2, round(s.load * STALL_CURRENT))
        self._put(ident, PRESENT_VOLTAGE, 2, round(s.voltage * 10))
        t[PRESENT_TEMPERATURE] = max(0, min(255, round(s.temperature)))
        t[MOVING] = 1 if abs(s.velocity) > VELOCITY_UNIT else 0

    def _return_delay(self, ident: int) -> float:
        return 2e-6 * self.tables[ident][RETURN_DELAY]

    # -- packets -------------------------------------------------------------------------------

    def _frame(self, buffer: bytearray) -> tuple[bytes | None, int]:
        start = buffer.find(b"\xff\xff\xfd\x00")
        if start < 0:
            keep = next((k for k in (3, 2, 1) if b"\xff\xff\xfd\x00"[:k] == bytes(buffer[-k:])), 0)
            return None, len(buffer) - keep
        if start > 0:
            return None, start
        if len(buffer) < 7:
            return None, 0
        length = buffer[5] | (buffer[6] << 8)
        total = 7 + length
        if length < 3:
            return None, 4
        if len(buffer) < total:
            return None, 0
        raw = bytes(buffer[:total])
        if crc16(raw[:-2]) != (raw[-2] | (raw[-1] << 8)):
            self.errors.append(f"bad CRC: {raw.hex(' ')}")
            ident = raw[4]
            if ident in self.servos and not self.servos[ident].silent and self.tables[ident][STATUS_LEVEL] >= 2:
                self._pending_crc = ident  # (answered with a CRC error by _execute)
                return raw[:7] + b"\x00" + raw[-2:], total  # (an instruction 0: see _execute)
            return None, total
        return raw[:7] + unstuff(raw[7:-2]) + raw[-2:], total

    def _status(self, ident: int, error: int = 0, data: bytes = b"") -> tuple[int, bytes]:
        alert = ALERT if self.tables[ident][HARDWARE_ERROR] else 0
        return ident, packet(ident, STATUS, bytes([error | alert]) + data)

    def _here(self, ident: int) -> bool:
        return ident in self.servos and not self.servos[ident].silent

    def _execute(self, pkt: bytes, t: float) -> list[tuple[int, bytes]]:
        ident, inst, params = pkt[4], pkt[7], pkt[8:-2]
        self.instructions.append((t, ident, inst))
        if inst == 0x00 and self._pending_crc == ident:  # a bad CRC, for a servo that answers
            self._pending_crc = None
            return [self._status(ident, 3)]
        if ident == BROADCAST:
            if inst == SYNC_WRITE and len(params) >= 4:
                address, size = params[0] | (params[1] << 8), params[2] | (params[3] << 8)
                k = 4
                while k + 1 + size <= len(params):
                    if self._here(params[k]):
                        self._write(params[k], address, params[k + 1 : k + 1 + size])
                    k += size + 1
                return []
            if inst == SYNC_READ and len(params) >= 4:
                address, size = params[0] | (params[1] << 8), params[2] | (params[3] << 8)
                return [self._read(i, address, size) for i in params[4:] if self._here(i)]
            if inst == PING:
                return [self._ping(i) for i in sorted(self.servos) if self._here(i)]
            if inst == ACTION:
                for i in list(self._pending):
                    if self._here(i):
                        self._write(i, *self._pending.pop(i))
                return []
            self.errors.append(f"broadcast instruction {inst:#04x} not covered")
            return []
        if not self._here(ident):
            return []
        level = self.tables[ident][STATUS_LEVEL]
        if inst == PING:
            return [self._ping(ident)]
        if inst == READ and len(params) == 4:
            if level < 1:
                return []
            return [self._read(ident, params[0] | (params[1] << 8), params[2] | (params[3] << 8))]
        reply: tuple[int, bytes]
        if inst == WRITE and len(params) >= 3:
            error = self._write(ident, params[0] | (params[1] << 8), params[2:])
            reply = self._status(self._renamed, error)  # (an id written: the servo answers as its new one)
        elif inst == REG_WRITE and len(params) >= 3:
            self._pending[ident] = (params[0] | (params[1] << 8), bytes(params[2:]))
            reply = self._status(ident)
        elif inst == ACTION:
            if ident in self._pending:
                self._write(ident, *self._pending.pop(ident))
            reply = self._status(ident)
        elif inst == REBOOT:
            self.tables[ident][HARDWARE_ERROR] = 0
            self._reset_ram(ident)
            reply = self._status(ident)
        else:
            self.errors.append(f"instruction {inst:#04x} to {ident} not covered ({pkt.hex(' ')})")
            reply = self._status(ident, 2)
        return [reply] if level >= 2 else []

    def _ping(self, ident: int) -> tuple[int, bytes]:
        t = self.tables[ident]
        return self._status(ident, 0, bytes([t[0], t[1], t[FIRMWARE]]))

    def _read(self, ident: int, address: int, size: int) -> tuple[int, bytes]:
        if address + size > TABLE_SIZE or size == 0:
            return self._status(ident, 4)
        return self._status(ident, 0, bytes(self.tables[ident][address : address + size]))

    def _write(self, ident: int, address: int, data: bytes) -> int:
        """Write ``data`` at ``address``; the error number (0: written)."""
        t = self.tables[ident]
        self._renamed = ident
        if address + len(data) > TABLE_SIZE:
            return 4
        if any(address <= a < address + len(data) for r in READ_ONLY for a in r):
            return 7
        if address < EEPROM_END and t[TORQUE]:
            return 7  # (the EEPROM is locked while the torque is on)
        if address <= TORQUE < address + len(data) and data[TORQUE - address] and t[HARDWARE_ERROR]:
            return 7  # (a hardware error: the torque stays off until a reboot)
        t[address : address + len(data)] = data
        if t[ID] != ident:
            new = t[ID]
            if new in self.servos or new > 252:
                t[ID] = ident
                return 4
            self.servos[new] = self.servos.pop(ident)
            self.servos[new].id = new
            self.tables[new] = self.tables.pop(ident)
            self._renamed = new
        return 0


def main(argv: list[str] | None = None) -> int:
    return serve(
        DynamixelEmulator,
        "python -m armd.adapters.emulators.dynamixel",
        "Emulated Dynamixel X servos on a pseudo-terminal.",
        "11,12,13,14,15",
        argv,
    )


if __name__ == "__main__":
    raise SystemExit(main())
