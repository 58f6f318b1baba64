"""The Numba decorator of armd's compiled solver stage, with a cache that cannot go stale.

Numba caches compiled code per function, keyed on the timestamp of the function's own file
only: a function in one file that calls a compiled function in another keeps the old
callee's machine code after the callee's file changes (a stale cache once ran an
out-of-bounds write here). So the cache lives in a directory named after a hash of every
compiled module's source: any change to any of them starts a fresh cache.
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

import numba

COMPILED_MODULES = ("activeset", "analytic", "closest", "family", "geometric", "jit", "limits", "pitch",
                    "../planning/compiled")  # every file with compiled functions, relative to solvers/


def _cache_dir() -> str:
    here = Path(__file__).resolve().parent
    digest = hashlib.sha256()
    digest.update(numba.__version__.encode())
    for name in COMPILED_MODULES:
        digest.update((here / f"{name}.py").read_bytes())
    base = os.environ.get("ARMD_CACHE_DIR") or os.path.join(
        os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache"), "armd", "numba")
    return os.path.join(base, digest.hexdigest()[:16])


setattr(numba.config, "CACHE_DIR", _cache_dir())  # noqa: B010 (no stub for the attribute)

jit = numba.njit(cache=True, nogil=True)
