"""Flood benchmark: an operator's stop and move while guests keep the service full of IK batches.

Processes, all on 127.0.0.1: the service (``armd serve --sim``: embedded router, simulated
arms), started by this script; a flood process holding ``--batches`` (default 80) IK requests
of ``--targets`` (default 10,000) targets each in flight at once, each sent again as soon as it
is answered; and the operator, in this process: an ``ArmClient`` that moves insomniac (a long
move), sends ``stop`` 0.3 s in, and times both replies, ``--cycles`` times, first on the idle
service (the peer), then during the flood.

Reported: median / p99 / max of each, idle and flooded, and the flood's batches answered.
Issue 14's bars: under the flood a stop answered within 0.3 s and a move within 2 s.

``--secure``: the same through the secure setup (docs/security.md), as a deployment has it: a
router of its own (``armd router``) with logins and the ACL, written by ``armd.service.
secure_setup`` with fresh passwords; the service logs in as ``armd-service``, insomniac's
simulated arm as its adapter (``armd adapter sim``), the flood as the guest and the operator as
the operator.

Run: ``.venv/bin/python bench/flood.py [--batches 80] [--targets 10000] [--cycles 10] [--secure]``.
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

GOALS = ([1.2, 2.0, -1.8, 1.0, 1.0], [-0.9, 1.0, -0.6, -1.0, -1.0])  # insomniac, far apart: seconds each


def flood(endpoint: str | None, batches: int, targets: int, seconds: float, config: str | None = None) -> None:
    """The flood process: ``batches`` IK batches in flight for ``seconds``; prints how many were answered."""
    import zenoh

    from armd import robots
    from armd.service.zconfig import network_config

    arm = robots.load("desk4")
    rng = np.random.default_rng(0)
    qs = rng.uniform(arm.limits.lower, arm.limits.upper, size=(targets, arm.nq))
    body = json.dumps({"targets": [arm.fk(q).tolist() for q in qs]}).encode()
    session = zenoh.open(network_config(connect=[endpoint] if endpoint else None, config_file=config))
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


def operator(endpoint: str | None, cycles: int, config: str | None = None) -> dict[str, list[float]]:
    """Move, stop 0.3 s in, ``cycles`` times: each reply's latency [ms]."""
    from armd.clients import ArmClient

    out: dict[str, list[float]] = {"move": [], "stop": []}
    with ArmClient(endpoint, config=config, timeout=30.0) as c:
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


def secure(directory: Path, endpoint: str) -> dict[str, Path]:
    """The secure setup for the catalogue in ``directory``, on ``endpoint``, fresh passwords:
    each side's file, by side (``router``, ``service``, ``adapter-<robot>``, ``operator``, ``guest``)."""
    from armd import robots
    from armd.service import secure_setup

    names = robots.names()
    contents = secure_setup.files(
        names, secure_setup.new_passwords(names), str(directory / "users.txt"), endpoint=endpoint
    )
    return {p.name.removesuffix(".json5"): p for p in secure_setup.write(directory, contents)}


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
    ap.add_argument("--config", help=argparse.SUPPRESS)
    ap.add_argument("--seconds", type=float, default=60.0, help=argparse.SUPPRESS)
    ap.add_argument("--secure", action="store_true", help="through a router with logins and the ACL (guests flood)")
    args = ap.parse_args()
    if args.worker == "flood":
        flood(args.endpoint, args.batches, args.targets, args.seconds, args.config)
        return
    from armd.service.zconfig import free_endpoint

    endpoint = free_endpoint()
    tmp = Path(tempfile.mkdtemp(prefix="armd-flood-"))
    sides = secure(tmp, endpoint) if args.secure else None
    cli = [sys.executable, "-m", "armd.cli"]
    quiet = {"cwd": ROOT, "stdout": subprocess.DEVNULL, "stderr": subprocess.DEVNULL}
    if sides is None:
        daemons = [subprocess.Popen([*cli, "serve", "--sim", "--listen", endpoint], **quiet)]  # type: ignore[call-overload]
        where: dict[str, Any] = {"endpoint": endpoint}
        guest: list[str] = ["--endpoint", endpoint]
    else:
        daemons = [subprocess.Popen([*cli, "router", "--config", str(sides["router"])], **quiet)]  # type: ignore[call-overload]
        time.sleep(1.0)
        daemons += [
            subprocess.Popen([*cli, "serve", "--config", str(sides["service"])], **quiet),  # type: ignore[call-overload]
            subprocess.Popen(  # type: ignore[call-overload]
                [*cli, "adapter", "sim", "insomniac", "--config", str(sides["adapter-insomniac"])], **quiet
            ),
        ]
        where = {"endpoint": None, "config": str(sides["operator"])}
        guest = ["--config", str(sides["guest"])]
    results: dict[str, Any] = {}
    try:
        from armd.clients import ArmClient

        deadline = time.monotonic() + 180
        while True:  # (a first start compiles: a minute)
            try:
                with ArmClient(where["endpoint"], config=where.get("config"), timeout=2.0) as c:
                    if c.state("insomniac")["source"] == "adapter":
                        break
            except Exception:  # not up yet
                pass
            if time.monotonic() > deadline:
                raise RuntimeError("the service did not come up")
            time.sleep(0.5)
        results["idle"] = operator(where["endpoint"], args.cycles, where.get("config"))
        seconds = args.cycles * 4.0 + 20.0
        fl = subprocess.Popen(
            [
                sys.executable,
                __file__,
                "--worker",
                "flood",
                *guest,
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
        results["flood"] = operator(where["endpoint"], args.cycles, where.get("config"))
        out, _ = fl.communicate(timeout=seconds + 120)
        results["answered"] = json.loads(out.strip().splitlines()[-1])["answered"]
    finally:
        for d in reversed(daemons):
            d.terminate()
            d.wait(20)
        shutil.rmtree(tmp, ignore_errors=True)
    how = "through the secure setup (guests flood, an operator moves)" if args.secure else "on the default setup"
    print(
        f"{args.batches} IK batches of {args.targets} targets in flight {how} "
        f"({results.get('answered', '?')} answered during the run); latency [ms], median / p99 / max:\n"
    )
    print("| request | idle | flooded |")
    print("|---|---|---|")
    for verb in ("stop", "move"):
        print(f"| {verb} | {_cell(results['idle'][verb])} | {_cell(results['flood'][verb])} |")


if __name__ == "__main__":
    main()
