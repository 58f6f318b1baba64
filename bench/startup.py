"""Start-up benchmark: how long ``armd serve`` takes to say it is serving, and what it holds.

Each run starts ``python -m armd serve`` (the four catalogue arms, an embedded router on a free
loopback port) and times it from launch to the line ``armd serving ...`` (printed after the
warm-up, once it answers); then reads its resident memory (``VmRSS``) and stops it. Cases:

* native: the compiled code built ahead of time at install (armd.solvers._native), as a
  fresh install runs; ``--runs`` times;
* jit cold: ``ARMD_NATIVE=0`` with an empty compiled-code cache: Numba compiles everything
  (the peer: what every start of a fresh clone cost before the native build, and what a
  machine without a C compiler pays once);
* jit warm: the same again, the cache full; ``--runs`` times;
* jit, another checkout: the sources copied to another folder and run from there with the
  same cache (a second clone, a CI run): the cache is filed by module, not by path.

Run: ``.venv/bin/python bench/startup.py [--runs 5]``.
"""

from __future__ import annotations

import argparse
import os
import shutil
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
LAYERS = ("robots", "solvers", "planning", "service", "clients", "adapters", "tools", "cli")


def _port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def serve_once(env: dict[str, str], path: Path | None = None) -> tuple[float, float]:
    """Seconds to ``armd serving``, and the resident memory then [MB]."""
    env = {**os.environ, **env}
    if path is not None:  # (the package from another folder: before the installed one on sys.path)
        env["PYTHONPATH"] = str(path)
    started = time.monotonic()
    proc = subprocess.Popen(
        [sys.executable, "-m", "armd", "serve", "--listen", f"tcp/127.0.0.1:{_port()}"],
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
        env=env,
        cwd=path or ROOT,
    )
    try:
        assert proc.stdout is not None
        for line in proc.stdout:
            if line.startswith("armd serving"):
                break
        else:
            raise RuntimeError("armd serve exited before serving")
        ready = time.monotonic() - started
        status = Path(f"/proc/{proc.pid}/status").read_text()
        rss = int(next(x for x in status.splitlines() if x.startswith("VmRSS")).split()[1]) / 1024
    finally:
        proc.terminate()
        proc.wait(timeout=30)
    return ready, rss


def _checkout(where: Path) -> Path:
    """The package laid out as installed (armd/robots ...), copied (not linked) under ``where``."""
    pkg = where / "armd"
    shutil.copytree(ROOT / "src" / "armd", pkg, ignore=shutil.ignore_patterns("__pycache__"))
    for layer in LAYERS:
        shutil.copytree(ROOT / layer, pkg / layer, ignore=shutil.ignore_patterns("__pycache__", "*.so"))
    return where


def _show(name: str, runs: list[tuple[float, float]]) -> None:
    t = [r[0] for r in runs]
    m = [r[1] for r in runs]
    print(
        f"{name:<26} ready median {statistics.median(t):6.2f} s  max {max(t):6.2f} s   "
        f"RSS median {statistics.median(m):5.0f} MB  max {max(m):5.0f} MB   ({len(runs)} runs)",
        flush=True,
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--runs", type=int, default=5)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        cache = Path(tmp) / "cache"
        native = [serve_once({"ARMD_CACHE_DIR": str(cache)}) for _ in range(args.runs)]
        _show("native", native)
        jit = {"ARMD_NATIVE": "0", "ARMD_CACHE_DIR": str(cache)}
        cold = [serve_once(jit)]
        _show("jit, cold cache (peer)", cold)
        warm = [serve_once(jit) for _ in range(args.runs)]
        _show("jit, warm cache", warm)
        other = _checkout(Path(tmp) / "other")
        _show("jit, another checkout", [serve_once(jit, other) for _ in range(args.runs)])
    t, m = statistics.median(r[0] for r in native), statistics.median(r[1] for r in native)
    print(
        f"native vs jit cold: {t / cold[0][0]:.3f}x the time, {m / cold[0][1]:.2f}x the memory; "
        f"vs jit warm: {t / statistics.median(r[0] for r in warm):.2f}x the time, "
        f"{m / statistics.median(r[1] for r in warm):.2f}x the memory",
        flush=True,
    )


if __name__ == "__main__":
    main()
