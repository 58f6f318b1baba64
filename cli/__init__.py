"""The ``armd`` command line (``armd --help``; ``python -m armd``): :func:`main`."""

from .main import build_parser, main

__all__ = ["build_parser", "main"]
