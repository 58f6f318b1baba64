"""The Feetech adapter: STS3215 (and other STS) bus servos, the SO-100/SO-101's, on Feetech's
STS protocol through the vendor's SDK, ``feetech-servo-sdk`` (imported as ``scservo_sdk``).

``armd adapter feetech ROBOT --port /dev/ttyACM0 [--baud B]``; what it does on the bus and how it
monitors the arm: :mod:`.bus_servo`.

Why ``feetech-servo-sdk`` 1.0.0 and not the vendor's newer ``ftservo-python-sdk`` 2.0.1 (both
install as ``scservo_sdk``, so only one of them can be installed): the newer one wraps the same
packet layer in per-model classes (``sms_sts``) whose position write sends a negative position
wrongly and whose timeouts are 50 ms; the older one is what LeRobot drives the SO-101 with, and
armd uses only its packet layer (``PacketHandler``: ping, read, write, ``syncReadTx`` and
``readRx``), which the two share. Two of its habits are worked round here: its ``clearPort``
waits for the output instead of dropping stale input (a reply that came after its timeout would
be read as the next one's: the input is reset before every exchange), and its
``GroupSyncRead`` drops each reply's error byte and leaves the data of the servos after a lost
reply as they were (the sync read here reads each reply itself, with its error byte).
"""

from __future__ import annotations

import logging
import math

from .bus_servo import Reading, SdkBus, SdkBusAdapter, Settings

log = logging.getLogger(__name__)

# The STS3215's control table (Feetech's memory table; little-endian words)
TORQUE, ACCELERATION, GOAL_POSITION = 40, 41, 42  # (a goal: position 42/2, time 44/2, speed 46/2)
STATE, STATE_SIZE = 56, 10  # present position 56/2, speed 58/2, load 60/2, voltage 62, temperature 63, 64, status 65
ACCELERATION_UNIT = 100.0  # [counts/s^2] of the acceleration register
ALARMS = {1: "voltage", 2: "angle sensor", 4: "overheat", 8: "overcurrent", 32: "overload"}


def _signed(value: int, bit: int) -> int:
    """A sign-and-magnitude field (the sign in ``bit``): the STS's speed (15) and load (10)."""
    magnitude = value & ((1 << bit) - 1)
    return -magnitude if value & (1 << bit) else magnitude


def alarms(error: int) -> tuple[str, ...]:
    return tuple(name for bit, name in ALARMS.items() if error & bit)


class FeetechBus(SdkBus):
    """STS servos on ``port`` at ``baud``, through ``scservo_sdk``."""

    name = "Feetech"
    module = "scservo_sdk"
    protocol = 0  # the STS's byte order (little-endian)
    torque_address = TORQUE
    ping_bytes, ping_exchanges = 28, 2  # (the SDK's ping reads the model number after it: 6 + 6, 8 + 8)

    def read(self, ids: list[int]) -> dict[int, Reading]:
        out: dict[int, Reading] = {}
        for i, (data, error) in self._sync_read(STATE, STATE_SIZE, ids).items():
            position, speed, load = (data[k] | (data[k + 1] << 8) for k in (0, 2, 4))
            out[i] = Reading(
                position=position,
                speed=float(_signed(speed, 15)),
                load=_signed(load, 10) / 1000.0,
                voltage=data[6] / 10.0,
                temperature=float(data[7]),
                alarms=alarms(error | data[9]),
            )
        return out

    def read_settings(self, ids: list[int]) -> dict[int, Settings]:
        return {i: Settings(bool(d[0]), d[1]) for i, (d, _) in self._sync_read(TORQUE, 2, ids).items()}

    def write_goals(self, goals: dict[int, int], speeds: dict[int, int]) -> None:
        params: list[int] = []  # per servo: goal position 42/2, goal time 44/2 (0: by speed), goal speed 46/2
        for i, c in goals.items():
            speed = speeds[i]
            params += [i, c & 0xFF, (c >> 8) & 0xFF, 0, 0, speed & 0xFF, (speed >> 8) & 0xFF]
        self._fresh()
        self.packets.syncWriteTxOnly(self.handler, GOAL_POSITION, 6, params, len(params))

    def set_limits(self, ident: int, acceleration: float) -> int:
        units = max(1, min(254, math.floor(acceleration / ACCELERATION_UNIT)))  # (0 would be the motor's: none)
        self._write(ident, ACCELERATION, 1, units)
        return units

    def clear_alarm(self, ident: int) -> None:
        """An STS latches an overload until its torque is enabled again: the torque off, then on (at set_torque)."""
        self._write(ident, TORQUE, 1, 0)


class FeetechAdapter(SdkBusAdapter):
    """``robot``'s servos on ``port`` (or on ``bus``, opened already): :class:`~.bus_servo.SdkBusAdapter`."""

    kind = "feetech"
    bus_type = FeetechBus
