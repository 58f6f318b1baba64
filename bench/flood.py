"""Flood benchmark: an operator's stop and move while guests keep the service full of IK batches.

Processes, all on 127.0.0.1: the service (``armd serve --sim``: embedded router, simulated
arms), started by this script; a flood process holding ``--batches`` (default 80) IK requests
of ``--targets`` (default 10,000) targets each in flight at once, each sent again as soon as it
is answered; and the operator, in this process: an ``ArmClient`` that moves insomniac (a long
move), sends ``stop`` 0.3 s in, and times both replies, ``--cycles`` times, first on the idle
service (the peer), then during the flood.

Reported: median / p99 / max of each, idle and flooded, and the flood's batches answered.
Issue 14's bars: under the flood a stop answered within 0.3 s and a move within 2 s.

Run: ``.venv/bin/python bench/flood.py [--batches 80] [--targets 10000] [--cycles 10]``.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

GOALS = ([1.2, 2.0, -1.8, 1.0, 1.0], [-0.9, 1.0, -0.6, -1.0, -1.0])  # insomniac, far apart: seconds each


def flood(endpoint: str, batches: int, targets: int, seconds: float) -> None:
    """The flood process: ``batches`` IK batches in flight for ``seconds``; prints how many were answered."""
    import zenoh

    from armd import robots
    from armd.service.zconfig import network_config

    arm = robots.load("desk4")
    rng = np.random.default_rng(0)
    qs = rng.uniform(arm.limits.lower, arm.limits.upper, size=(targets, arm.nq))
    body = json.dumps({"targets": [arm.fk(q).tolist() for q in qs]}).encode()
    session = zenoh.open(network_config(connect=[endpoint]))
    end = time.monotonic() + seconds
    answered = [0]
    lock = threading.Lock()

    def keep_one() -> None:
        while time.monotonic() < end:
            for _ in session.get("armd/desk4/ik", payload=body, timeout=60.0):
                pass
            with lock:
                answered[0] += 1

    threads = [threading.Thread(target=keep_one, daemon=True) for _ in range(batches)]
    for t in threads:
        t.start()
    print("ready", flush=True)
    for t in threads:
        t.join(seconds + 70)
    print(json.dumps({"answered": answered[0]}), flush=True)
    session.close()


def operator(endpoint: str, cycles: int) -> dict[str, list[float]]:
    """Move, stop 0.3 s in, ``cycles`` times: each reply's latency [ms]."""
    from armd.clients import ArmClient

    out: dict[str, list[float]] = {"move": [], "stop": []}
    with ArmClient(endpoint, timeout=30.0) as c:
        for k in range(cycles):
            t = time.monotonic()
            c.move("insomniac", GOALS[k % 2])
            out["move"].append((time.monotonic() - t) * 1e3)
            time.sleep(0.3)
            t = time.monotonic()
            c.stop("insomniac")
            out["stop"].append((time.monotonic() - t) * 1e3)
            time.sleep(0.5)
    return out


def _cell(ms: list[float]) -> str:
    if not ms:
        return "-"
    a = np.array(ms)
    return f"{np.median(a):.0f} / {np.percentile(a, 99):.0f} / {a.max():.0f}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--batches", type=int, default=80, help="IK batches in flight (default 80)")
    ap.add_argument("--targets", type=int, default=10_000, help="targets per batch (default 10,000)")
    ap.add_argument("--cycles", type=int, default=10, help="move-stop cycles, idle and flooded (default 10)")
    ap.add_argument("--worker", choices=["flood"], help=argparse.SUPPRESS)
    ap.add_argument("--endpoint", help=argparse.SUPPRESS)
    ap.add_argument("--seconds", type=float, default=60.0, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.worker == "flood":
        flood(args.endpoint, args.batches, args.targets, args.seconds)
        return
    from armd.service.zconfig import free_endpoint

    endpoint = free_endpoint()
    serve = subprocess.Popen(
        [sys.executable, "-m", "armd.cli", "serve", "--sim", "--listen", endpoint],
        cwd=ROOT,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    results: dict[str, Any] = {}
    try:
        from armd.clients import ArmClient

        deadline = time.monotonic() + 180
        while True:  # (a first start compiles: a minute)
            try:
                with ArmClient(endpoint, timeout=2.0) as c:
                    if c.state("insomniac")["source"] == "adapter":
                        break
            except Exception:  # not up yet
                pass
            if time.monotonic() > deadline:
                raise RuntimeError("the service did not come up")
            time.sleep(0.5)
        results["idle"] = operator(endpoint, args.cycles)
        seconds = args.cycles * 4.0 + 20.0
        fl = subprocess.Popen(
            [
                sys.executable,
                __file__,
                "--worker",
                "flood",
                "--endpoint",
                endpoint,
                "--batches",
                str(args.batches),
                "--targets",
                str(args.targets),
                "--seconds",
                str(seconds),
            ],
            cwd=ROOT,
            stdout=subprocess.PIPE,
            text=True,
        )
        assert fl.stdout is not None
        assert fl.stdout.readline().strip() == "ready"
        time.sleep(5.0)  # the flood in full
        results["flood"] = operator(endpoint, args.cycles)
        out, _ = fl.communicate(timeout=seconds + 120)
        results["answered"] = json.loads(out.strip().splitlines()[-1])["answered"]
    finally:
        serve.terminate()
        serve.wait(20)
    print(
        f"{args.batches} IK batches of {args.targets} targets in flight "
        f"({results.get('answered', '?')} answered during the run); latency [ms], median / p99 / max:\n"
    )
    print("| request | idle | flooded |")
    print("|---|---|---|")
    for verb in ("stop", "move"):
        print(f"| {verb} | {_cell(results['idle'][verb])} | {_cell(results['flood'][verb])} |")


if __name__ == "__main__":
    main()
