"""An emulator in a process of its own: a board has its own clock and CPU.

An emulator thread in the test's own interpreter shares its GIL and, on a busy machine, its
share of the CPU: it reads a command when it gets to run, and stamps it then, milliseconds
after the adapter wrote it, although a real board had it at once. Served from a process of its
own, at real-time priority where the system allows it (``SCHED_FIFO``, else the highest nice
it may), it reads each command as it is written, as a board would; the clock it stamps with
(``time.monotonic``) is the system's, the same in every process.

``EmulatorProcess(SSC32Emulator, baud=..., ...)`` takes the emulator's class and its
arguments; it is used like the emulator (``with``, ``port``, ``segments``, ``history``,
``clock``, and the emulator's other methods, forwarded to the process).
"""

from __future__ import annotations

import contextlib
import os
import time
from multiprocessing.managers import BaseManager
from types import TracebackType
from typing import Any

from .pty import PtyEmulator

REALTIME_PRIORITY = 10  # SCHED_FIFO priority of the emulator's process (1-99; the kernel's threads use 50)


def _prioritise() -> None:
    """Run the process ahead of ordinary ones: SCHED_FIFO if permitted, else a lower nice value."""
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(REALTIME_PRIORITY))
    except (PermissionError, OSError, AttributeError):
        with contextlib.suppress(PermissionError, OSError):
            os.nice(-10)


class _Manager(BaseManager):
    pass


class _Host:
    """What runs in the emulator's process: the emulator, its attributes read as methods."""

    def __init__(self, cls: type[PtyEmulator], kwargs: dict[str, Any]) -> None:
        self.emulator = cls(**kwargs)

    def call(self, name: str, *args: Any) -> Any:
        return getattr(self.emulator, name)(*args)

    def get(self, name: str) -> Any:
        value = getattr(self.emulator, name)
        return list(value) if isinstance(value, list) else value

    def policy(self) -> str:
        return {os.SCHED_FIFO: "SCHED_FIFO", os.SCHED_OTHER: f"nice {os.nice(0)}"}.get(
            os.sched_getscheduler(0), "other"
        )


_Manager.register("Host", _Host)


class EmulatorProcess:
    """An emulator of class ``cls`` (with ``kwargs``) served from its own process."""

    clock = staticmethod(time.monotonic)  # (the emulators' default clock; the same in every process)

    def __init__(self, cls: type[PtyEmulator], **kwargs: Any) -> None:
        if "clock" in kwargs:
            raise ValueError("an emulator in its own process keeps the system's clock")
        self._cls, self._kwargs = cls, kwargs
        self._manager: _Manager | None = None
        self._host: Any = None
        self._port = ""

    def start(self) -> str:
        if self._manager is None:
            self._manager = _Manager()
            self._manager.start(initializer=_prioritise)
            self._host = self._manager.Host(self._cls, self._kwargs)  # type: ignore[attr-defined]
            self._port = self._host.call("start")
        return self._port

    def stop(self) -> None:
        if self._manager is not None:
            with contextlib.suppress(Exception):  # (the process may be gone already)
                self._host.call("stop")
            self._manager.shutdown()
            self._manager = None

    def __enter__(self) -> EmulatorProcess:
        self.start()
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.stop()

    @property
    def port(self) -> str:
        if not self._port:
            raise RuntimeError("the emulator's process is not started")
        return self._port

    @property
    def policy(self) -> str:
        """How the emulator's process is scheduled (``SCHED_FIFO``, or its nice value)."""
        return str(self._host.policy())

    @property
    def history(self) -> list[Any]:
        return list(self._host.get("history"))

    def __getattr__(self, name: str) -> Any:
        if name.startswith("_"):
            raise AttributeError(name)
        return lambda *args: self._host.call(name, *args)
