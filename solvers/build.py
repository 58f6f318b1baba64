"""Build ``armd.solvers._native``: the compiled entry points (``@entry``), ahead of time.

Run by ``setup.py`` when armd is installed (``python solvers/build.py TARGET.so``), in pip's
build environment, which has Numba and NumPy but not armd nor Pinocchio: the compiled modules
are imported from the source tree through a tree of links laid out as the package, with
empty ``__init__`` files (the real ones import the rest of armd). Numba's ``pycc`` compiles
every entry point with the signature it declares, and every function it calls, for this
machine's CPU, and exports ``source_digest()``: the digest of the sources it was built from,
which :mod:`armd.solvers.jit` compares before it uses the module.
"""

from __future__ import annotations

import os
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
COMPILED = {
    "solvers": (
        "activeset",
        "analytic",
        "arrays",
        "atlas",
        "closest",
        "collide",
        "family",
        "geometric",
        "jit",
        "kinematics",
        "limits",
        "lm",
        "narrowphase",
        "packed",
        "pitch",
        "tree",
    ),
    "planning": ("compiled",),
    "robots": ("angles", "types"),
}


def _import_tree(where: Path) -> None:
    """``where/armd``: the compiled modules (links to the sources), under empty packages."""
    pkg = where / "armd"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    for layer, modules in COMPILED.items():
        (pkg / layer).mkdir()
        (pkg / layer / "__init__.py").write_text("")
        for name in modules:
            (pkg / layer / f"{name}.py").symlink_to(ROOT / layer / f"{name}.py")
    sys.path.insert(0, str(where))


def build(target: Path) -> None:
    os.environ["ARMD_NATIVE"] = "0"  # (the decorators make Numba dispatchers, and list the entry points)
    started = time.monotonic()
    with tempfile.TemporaryDirectory() as tmp:
        _import_tree(Path(tmp))
        import importlib

        import numba
        from numba.pycc import CC

        jit = importlib.import_module("armd.solvers.jit")
        for layer, modules in COMPILED.items():
            for name in modules:
                importlib.import_module(f"armd.{layer}.{name}")
        names = {**vars(numba.types), **jit.numba_types()}  # (a signature may name a named tuple)
        cc = CC(target.name.split(".")[0], source_module=jit)
        cc.output_dir = str(target.parent)
        cc.output_file = target.name
        cc.target_cpu = "host"  # (built where it runs: pip builds it on the machine it installs on)
        for name, (dispatcher, signature) in sorted(jit.ENTRIES.items()):
            cc.export(name, eval(signature, {}, names))(dispatcher.py_func)
        digest = jit.native_digest_number(jit.source_digest())

        def source_digest() -> int:
            return digest

        cc.export("source_digest", "i8()")(source_digest)
        target.parent.mkdir(parents=True, exist_ok=True)
        cc.compile()
    print(
        f"armd: built {target.name} ({len(jit.ENTRIES)} entry points) in {time.monotonic() - started:.0f} s",
        file=sys.stderr,
    )


if __name__ == "__main__":
    build(Path(sys.argv[1]).resolve())
