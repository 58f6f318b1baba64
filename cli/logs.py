"""The one logging set-up of every command (light: the emergency stop's fast path uses it too)."""

from __future__ import annotations

import logging

LOG_FORMAT = "%(asctime)s %(levelname)s %(name)s: %(message)s"
LOG_LEVELS = ("debug", "info", "warning", "error")


def set_up_logging(level: str) -> None:
    """The one logging set-up of every command: ``level`` one of :data:`LOG_LEVELS`."""
    logging.basicConfig(level=getattr(logging, level.upper()), format=LOG_FORMAT)
