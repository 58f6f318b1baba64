"""armd's build: everything is in pyproject.toml but the ahead-of-time compiled code.

``armd.solvers._native`` is built by ``solvers/build.py`` (Numba's pycc, for this machine's
CPU: about 40 s) instead of from C sources. If it cannot be built (no C compiler), armd still
installs and runs: its compiled code is then compiled by Numba on first use (armd.solvers.jit).
"""

import os
import subprocess
import sys
from pathlib import Path

from setuptools import Extension, setup
from setuptools.command.build_ext import build_ext

ROOT = Path(__file__).resolve().parent
NATIVE = "armd.solvers._native"


class BuildNative(build_ext):
    def build_extension(self, ext: Extension) -> None:
        if ext.name != NATIVE:
            super().build_extension(ext)
            return
        target = Path(self.get_ext_fullpath(ext.name)).resolve()
        if os.environ.get("ARMD_NATIVE", "1") == "0":
            print("armd: ARMD_NATIVE=0: not building the native module (Numba compiles on first use)", file=sys.stderr)
            return
        done = subprocess.run([sys.executable, str(ROOT / "solvers" / "build.py"), str(target)], cwd=ROOT)
        if done.returncode != 0:
            print(
                "armd: warning: the native module could not be built; armd will compile its code with Numba "
                "on first use (about a minute, once)",
                file=sys.stderr,
            )


setup(ext_modules=[Extension(NATIVE, sources=[], optional=True)], cmdclass={"build_ext": BuildNative})
