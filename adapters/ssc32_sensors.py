"""Range sensors wired to the SSC-32U (robot.toml ``[[sensors]] pin``, a scanner's ``channel``):
the SSC-32 adapter reads their outputs on the board's analog inputs and steps the scanners'
servos, publishing each reading as the simulator does (:mod:`.sensor_stream`, docs/sensors.md).

Per step (the seed's scan: a reading, a turn, a reading):

1. One ``V<pin>...`` read of every wired pin (the guide: a byte each, the voltage times 256/5),
   after a ``QP`` of the scanners' channels, always with the adapter's own ``QP`` of the arm's,
   as one write: it never holds up the arm's stream, and the board answers in order.
2. If the arm's ``QP`` agrees with the adapter's model (else the adapter faults, as ever) and each
   scanner's servo is where it was sent (else the board was reset, or a scanner moved: nothing
   is published and the scanners are sent again), a reading of each wired sensor is published:
   a scanner's at the bearing it has held since its last step; a sensor on the arm's with no
   bearing. Nothing is published while the adapter is faulted.
3. Every scanner turns a step (``#<ch>P<pw>S<SCAN_SPEED>``, one command), and the next read is
   due (``ready_at``, the adapter sets it) once each has arrived, its sensor has measured there
   afresh (a Sharp sensor puts out a measurement at the end of its period, so the one under way
   at the arrival is not it: two of its periods, with the datasheet's slack), and the board's
   input filter has settled (8 ms): :meth:`WiredSensors.settle_time` after the step reaches the board.

The first read of a pin after the board powers up is not valid (the guide): the adapter makes
one at start-up and discards it.
"""

from __future__ import annotations

import json
from collections.abc import Callable

import numpy as np

from armd.robots import Robot
from armd.robots.sensors import RangeSensor

from .sensor_stream import Numbering, Sweep, reading

SCAN_SPEED = 1000  # [us/s] a scanning servo's step (2 degrees: 22 us in 22 ms)
# (a step, then: 22 ms + 2 x 48 ms + 8 ms, and the control loop's 20 ms: about 6 readings a second,
# a sweep of 2 rad in 2-degree steps in 9.5 s, measured)
MEASURE_SLACK = 0.25  # a Sharp sensor's period may run this much longer than typical (38.3 +- 9.6 ms)
FILTER_SETTLE = 0.008  # [s] the board's analog inputs settle within 8 ms of a change (the guide)
VOLTS_PER_COUNT = 5.0 / 256.0  # the guide: "multiply by 5/256"


class WiredSensors:
    """``robot``'s sensors wired to its SSC-32U; ``publish(name, payload)`` sends a reading."""

    def __init__(self, robot: Robot, adapter: str, publish: Callable[[str, bytes], None]) -> None:
        self.sensors = [s for s in robot.sensors.values() if s.pin is not None and s.curve is not None]
        self.adapter = adapter
        self.publish = publish
        self.sweeps = {s.name: Sweep(s) for s in self.sensors if s.servo is not None and s.sweep is not None}
        self.scanners = [s for s in self.sensors if s.name in self.sweeps]
        self.ready_at = 0.0  # [s] when the next read is due (monotonic)
        self.numbers = Numbering()  # (each sensor's readings numbered: the service believes them in order)
        self.readings = 0  # published so far
        self.refused = 0  # reads not published: a scanner's servo not where it was sent (a reset board)

    def __bool__(self) -> bool:
        return bool(self.sensors)

    @property
    def request(self) -> bytes:
        """A ``QP`` of the scanners' channels (each must be where it was sent), then the read of
        every wired pin: :attr:`reply_size` bytes, in that order."""
        qp = "".join(f"QP{s.servo.channel}" for s in self.scanners if s.servo is not None)
        return ((qp + "\r") if qp else "").encode() + ("".join(f"V{s.pin}" for s in self.sensors) + "\r").encode()

    @property
    def reply_size(self) -> int:
        return len(self.scanners) + len(self.sensors)

    def _pulse(self, sensor: RangeSensor) -> int:
        assert sensor.servo is not None
        return round(float(sensor.servo.to_command(np.array(self.sweeps[sensor.name].bearing))))

    def aim(self) -> bytes:
        """The command putting every scanner at its sweep's bearing (b"" if none)."""
        items = [f"#{s.servo.channel}P{self._pulse(s)}S{SCAN_SPEED}" for s in self.scanners if s.servo is not None]
        return ("".join(items) + "\r").encode() if items else b""

    def settle_time(self) -> float:
        """[s] from a step's arrival at the board to the next read: the scanners there, measured
        afresh, the input filter settled."""
        travel = max(
            (s.sweep_step * (s.servo.us_per_rad if s.servo else 0.0) / SCAN_SPEED for s in self.sensors), default=0.0
        )
        period = max(s.curve.period for s in self.sensors if s.curve is not None) * (1.0 + MEASURE_SLACK)
        # the measurement under way at the arrival began before it: the next one's result, two periods on
        return travel + 2.0 * period + FILTER_SETTLE

    def answered(self, reply: bytes) -> bool:
        """The board's :attr:`reply_size` bytes for :attr:`request`: if every scanner's servo is
        where it was sent (``QP``: its pulse / 10, give or take one), each sensor's reading is
        published and the sweeps turn a step (then write :meth:`aim`); else nothing is published
        (the board was reset, or someone moved a scanner: write :meth:`aim` again). Whether
        published."""
        scan, volts = reply[: len(self.scanners)], reply[len(self.scanners) :]
        if any(abs(10 * b - self._pulse(s)) > 10 for s, b in zip(self.scanners, scan, strict=True)):
            self.refused += 1
            return False
        for s, count in zip(self.sensors, volts, strict=True):
            msg = reading(s, count * VOLTS_PER_COUNT, self.adapter, self.numbers.next(s.name), self.sweeps.get(s.name))
            self.publish(s.name, json.dumps(msg).encode())
            self.readings += 1
        for sweep in self.sweeps.values():
            sweep.step()
        return True
