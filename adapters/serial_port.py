"""The serial side of the adapters whose controller is on a serial port (the SSC-32, GRBL):
the port opened, and the adapter that holds it. pyserial is the ``hardware`` extra
(``pip install 'armd[hardware]'``): the simulated arms and the service do without it."""

from __future__ import annotations

import threading

import serial
import zenoh

from armd.errors import ControllerFault
from armd.robots import Robot

from .base import Adapter


def open_port(
    port: str, baud: int, timeout: float, write_timeout: float, *, exclusive: bool = False
) -> serial.SerialBase:
    """A serial port or pyserial URL, opened; :class:`ControllerFault` naming it if it cannot be
    (missing, or busy: with ``exclusive`` another program's lock on it is refused)."""
    try:
        ser = serial.serial_for_url(port, do_not_open=True, baudrate=baud, timeout=timeout, write_timeout=write_timeout)
        if exclusive and hasattr(ser, "exclusive"):
            ser.exclusive = True
        ser.open()
        return ser
    except (serial.SerialException, ValueError, OSError) as e:
        why = "busy (another program has it open)" if "lock" in str(e).lower() else str(e)
        raise ControllerFault(f"cannot open {port}: {why}") from None


class SerialAdapter(Adapter):
    """An adapter whose controller is on a serial port (or a pyserial URL): the port, opened
    (:func:`open_port`), and the lock its users share (the control loop, gripper requests)."""

    def __init__(
        self,
        session: zenoh.Session,
        robot: Robot,
        port: str,
        *,
        baud: int,
        timeout: float,
        write_timeout: float,
        prefix: str = "armd",
        state_hz: float = 50.0,
        check_period: float = 0.5,
        serial_port: serial.SerialBase | None = None,
    ) -> None:
        self.port = port
        self._io = threading.Lock()
        if serial_port is None:
            self.serial = open_port(port, baud, timeout, write_timeout)
        else:  # opened already (the command line opens the port before joining Zenoh)
            self.serial = serial_port
            self.serial.baudrate, self.serial.timeout, self.serial.write_timeout = baud, timeout, write_timeout
        super().__init__(session, robot, prefix=prefix, state_hz=state_hz, check_period=check_period)
