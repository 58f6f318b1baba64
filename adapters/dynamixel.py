"""The Dynamixel adapter: ROBOTIS X-series bus servos (XM430, XL430: the OpenManipulator-X, the
Koch arm) on Protocol 2.0, through ROBOTIS's SDK, ``dynamixel-sdk``.

``armd adapter dynamixel ROBOT --port /dev/ttyUSB0 [--baud B]``; what it does on the bus and how
it monitors the arm: :mod:`.bus_servo`. Each cycle is one sync write of every servo's profile
velocity and goal position (112/4 and 116/4, one block) and one sync read of its current,
velocity, position, voltage and temperature (126 to 146); a status whose alert bit is set is
followed by a read of that servo's hardware error status (70), to name the alarm (its reply
lost: read again, so that the fault, said once, is said with its cause). As with
Feetech's SDK, the input is reset before every exchange (the SDK's ``clearPort`` waits for the
output), and each sync-read reply is read with its error byte (``readRx``).
"""

from __future__ import annotations

import logging
import math
import time

from armd.errors import ControllerFault

from .bus_servo import Reading, SdkBus, SdkBusAdapter, Settings

log = logging.getLogger(__name__)

# The X series' control table (the ROBOTIS e-Manual)
TORQUE, HARDWARE_ERROR, PROFILE_ACCELERATION, PROFILE_VELOCITY = 64, 70, 108, 112
STATE, STATE_SIZE = 126, 21  # current 126/2, velocity 128/4, position 132/4, .., voltage 144/2, temperature 146
VELOCITY_UNIT = 0.229 * 4096 / 60  # [counts/s] of a velocity unit (0.229 rev/min)
ACCELERATION_UNIT = 214.577 * 4096 / 3600  # [counts/s^2] of a profile acceleration unit (214.577 rev/min^2)
STALL_CURRENT = 2300.0 / 2.69  # [current units] the XM430-W350's stall current (2.3 A at 12 V)
ALARMS = {1: "input voltage", 4: "overheating", 8: "motor encoder", 16: "electrical shock", 32: "overload"}
ALERT = 0x80
ALARM_READS = 3  # reads of a servo's hardware error status before it is named only "hardware error"
REBOOT_TIME = 0.5  # [s] a servo rebooted answers again after this (the e-Manual: within a few hundred ms)


def _signed(data: list[int], k: int, size: int) -> int:
    return int.from_bytes(bytes(data[k : k + size]), "little", signed=True)


class DynamixelBus(SdkBus):
    """X-series servos on ``port`` at ``baud``, through ``dynamixel_sdk`` (Protocol 2.0)."""

    name = "Dynamixel"
    module = "dynamixel_sdk"
    protocol = 2.0
    torque_address = TORQUE
    write_errors = 0x7F  # (bit 7 is the alert: a hardware error, not the write's)
    sync_read_extra = (False,)  # (not the fast sync read)
    ping_bytes = 24  # (a ping 10, its answer 14)

    def read(self, ids: list[int]) -> dict[int, Reading]:
        out: dict[int, Reading] = {}
        alerted = []
        for i, (data, error) in self._sync_read(STATE, STATE_SIZE, ids).items():
            if error & ALERT:
                alerted.append(i)
            out[i] = Reading(
                position=_signed(data, 6, 4),
                speed=_signed(data, 2, 4) * VELOCITY_UNIT,
                load=_signed(data, 0, 2) / STALL_CURRENT,
                voltage=(data[18] | (data[19] << 8)) / 10.0,
                temperature=float(data[20]),
            )
        for i in alerted:  # name the alarm: the servo's hardware error status
            r = out[i]
            out[i] = Reading(r.position, r.speed, r.load, r.voltage, r.temperature, self._alarms(i))
        return out

    def _alarms(self, ident: int) -> tuple[str, ...]:
        """The names of the servo's hardware error bits; its reply lost, asked again (up to
        ``ALARM_READS`` times: a fault is said once, so it is said with its cause, not as a
        "hardware error" first and again once named), else ``("hardware error",)``."""
        for _ in range(ALARM_READS):
            self._fresh()
            bits, result, _ = self.packets.read1ByteTxRx(self.handler, ident, HARDWARE_ERROR)
            if self._ok(result):
                return tuple(n for b, n in ALARMS.items() if bits & b) or ("hardware error",)
        return ("hardware error",)

    def write_goals(self, goals: dict[int, int], speeds: dict[int, int]) -> None:
        params: list[int] = []  # per servo: profile velocity 112/4, goal position 116/4
        for i, c in goals.items():
            units = max(1, math.floor(speeds[i] / VELOCITY_UNIT))  # (0 would be no limit)
            params += [i, *units.to_bytes(4, "little"), *int(c).to_bytes(4, "little", signed=True)]
        self._fresh()
        self.packets.syncWriteTxOnly(self.handler, PROFILE_VELOCITY, 8, params, len(params))

    def read_settings(self, ids: list[int]) -> dict[int, Settings]:
        torque = self._sync_read(TORQUE, 1, ids)
        accel = self._sync_read(PROFILE_ACCELERATION, 4, ids)
        both = [i for i in ids if i in torque and i in accel]
        return {i: Settings(bool(torque[i][0][0]), _signed(accel[i][0], 0, 4)) for i in both}

    def set_limits(self, ident: int, acceleration: float) -> int:
        units = max(1, math.floor(acceleration / ACCELERATION_UNIT))  # (0 would be the motor's: none)
        self._write(ident, PROFILE_ACCELERATION, 4, units)
        return units

    def clear_alarm(self, ident: int) -> None:
        """A hardware error holds the torque off until a reboot (the servo's RAM back to its defaults)."""
        self._fresh()
        bits, result, _ = self.packets.read1ByteTxRx(self.handler, ident, HARDWARE_ERROR)
        if self._ok(result) and bits == 0:
            return
        self._fresh()
        result, _ = self.packets.reboot(self.handler, ident)
        if not self._ok(result):
            raise ControllerFault(
                f"servo id {ident} on {self.port} did not reboot: {self.packets.getTxRxResult(result)}"
            )
        time.sleep(REBOOT_TIME)  # (its RAM back to its defaults: the adapter sets it up again)


class DynamixelAdapter(SdkBusAdapter):
    """``robot``'s servos on ``port`` (or on ``bus``, opened already): :class:`~.bus_servo.SdkBusAdapter`."""

    kind = "dynamixel"
    bus_type = DynamixelBus
