"""The serial side of the adapters whose controller is on a serial port (the SSC-32, GRBL):
the port opened, and the adapter that holds it. pyserial is the ``hardware`` extra
(``pip install 'armd[hardware]'``): the simulated arms and the service do without it."""

from __future__ import annotations

import contextlib
import logging
import termios
import threading
import time
from collections.abc import Callable

import serial
import zenoh

from armd.errors import ControllerFault
from armd.robots import Robot

from .base import Adapter

log = logging.getLogger(__name__)

# What a port that vanished (a USB adapter pulled, a board's USB power lost) raises: pyserial's
# SerialException is an OSError, and so is its in_waiting's ioctl; reset_input_buffer's tcflush
# raises termios.error, which is not.
PORT_ERRORS = (OSError, termios.error)
REOPEN_FIRST = 0.25  # [s] the first wait before a vanished port is opened again ...
REOPEN_MOST = 5.0  # [s] ... doubled at each failed attempt up to this: a port gone for good costs nothing


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
        self._opening = (baud, timeout, write_timeout)
        self.gone: str | None = None  # the port vanished: why (every access fails with it at once)
        self._reopen_wait, self._reopen_at = REOPEN_FIRST, 0.0
        if serial_port is None:
            self.serial = open_port(port, baud, timeout, write_timeout)
        else:  # opened already (the command line opens the port before joining Zenoh)
            self.serial = serial_port
            self.serial.baudrate, self.serial.timeout, self.serial.write_timeout = baud, timeout, write_timeout
        super().__init__(session, robot, prefix=prefix, state_hz=state_hz, check_period=check_period)

    def port_gone(self, e: BaseException) -> ControllerFault:
        """The port failed under the adapter (``e``: one of :data:`PORT_ERRORS`): the fault to
        raise, one reason until the port is open again (:meth:`reopen`), so that it is said once."""
        if self.gone is None:
            self.gone = (
                f"{self.port} is gone ({type(e).__name__}: {e}): the adapter opens it again every "
                f"{REOPEN_FIRST:g}-{REOPEN_MOST:g} s"
            )
            self._reopen_wait = REOPEN_FIRST
            self._reopen_at = time.monotonic() + REOPEN_FIRST
        return ControllerFault(self.gone)

    def reopen(self, identify: Callable[[], object]) -> bool:
        """The port that vanished, opened again when its back-off allows (each failed attempt
        doubles the wait, up to ``REOPEN_MOST``) and ``identify`` run on it (a
        :class:`ControllerFault` from it, what answers is not the controller: a failed attempt,
        its reason kept): True once it is open and identified (``gone`` cleared)."""
        now = time.monotonic()
        if self.gone is None:
            return True
        if now < self._reopen_at:
            return False
        with contextlib.suppress(Exception):  # (its file descriptor: the device is gone)
            self.serial.close()
        try:
            ser = open_port(self.port, *self._opening, exclusive=True)
            with self._io:
                self.serial = ser
            self.gone = None  # (for identify's questions)
            identify()
        except ControllerFault as e:
            log.debug("%s: %s", self.robot.name, e.message)
            if self.gone is None:  # (opened, and not the controller: closed again)
                with contextlib.suppress(Exception):
                    self.serial.close()
                self.gone = f"{e.message}; the adapter opens {self.port} again every {REOPEN_FIRST:g}-{REOPEN_MOST:g} s"
            self._reopen_wait = min(2.0 * self._reopen_wait, REOPEN_MOST)
            self._reopen_at = now + self._reopen_wait
            return False
        log.warning("%s: %s is there again: opened", self.robot.name, self.port)
        return True
