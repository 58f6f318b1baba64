"""The lifecycle the emulators share: a pseudo-terminal served by a thread.

A subclass writes the controller (``_serve``: the thread's loop, until ``_stop`` is set,
reading and writing ``_master``); this class opens the terminal, starts and stops the thread,
and gives the path a client opens with pyserial, exactly as it opens ``/dev/ttyUSB0``.
"""

from __future__ import annotations

import os
import threading
import tty
from abc import ABC, abstractmethod
from types import TracebackType
from typing import TypeVar

E = TypeVar("E", bound="PtyEmulator")


class PtyEmulator(ABC):
    """A controller on a pseudo-terminal: ``start()`` (or ``with``) it, open ``port``.

    Class attributes for subclasses: ``name`` (the thread's name), and ``keep_slave``: hold the
    terminal's other end open, so that reads never see a hang-up (True), or close it, so that a
    client's open and close show as the master's hang-up clearing and setting (False: a
    controller that resets when its port is opened, like an Arduino).
    """

    name = "emulator"
    keep_slave = True

    def __init__(self) -> None:
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._master = -1  # our end of the terminal, non-blocking; -1 when not started
        self._slave = -1
        self._port = ""

    def start(self) -> str:
        """Open the pseudo-terminal and serve it from a thread; return the path to open. Idempotent."""
        if self._thread is not None:
            return self._port
        master, slave = os.openpty()
        tty.setraw(slave)  # no echo, no CR/LF translation or line editing before a client sets its own modes
        self._port = os.ttyname(slave)
        if self.keep_slave:
            self._slave = slave
        else:
            os.close(slave)
        os.set_blocking(master, False)  # a reply nobody reads never blocks the thread
        self._master = master
        self._stop.clear()
        self._thread = threading.Thread(target=self._serve, name=f"{self.name} {self._port}", daemon=True)
        self._thread.start()
        return self._port

    def stop(self) -> None:
        """Stop serving and close the pseudo-terminal. Idempotent."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
            self._thread = None
        for fd in (self._master, self._slave):
            if fd >= 0:
                os.close(fd)
        self._master = self._slave = -1

    def unplug(self) -> None:
        """The cable pulled, the board still powered: its terminal closed (the client's port
        fails: EIO, and its path is gone), the controller's state kept for :meth:`plug`."""
        self.stop()

    def plug(self) -> str:
        """The cable back in: a new terminal to the same controller; its path (a new one, as a
        USB serial device may come back under another name)."""
        return self.start()

    def __enter__(self: E) -> E:
        self.start()
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.stop()

    @property
    def port(self) -> str:
        """The pseudo-terminal's path (like ``/dev/pts/3``), for ``serial.Serial(port, 115200)``."""
        if not self._port:
            raise RuntimeError(f"the {type(self).__name__} is not started")
        return self._port

    @abstractmethod
    def _serve(self) -> None:
        """The thread: the controller itself, reading and answering ``_master`` until ``_stop`` is set."""
