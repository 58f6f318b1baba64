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

``--attacks``: after the idle peer, each of the red team's attacks of issue 34 in turn
(:func:`attack`: ``flood``, the IK batches above; ``world``, requests of 10,000 obstacles and
64-obstacle changes; ``huge``, 40 MB and 2 MB requests; ``junk``, deeply nested control puts,
1 MB states and events, forged readings; ``sessions``, 1,000 sessions asking at once), the
operator's move and stop timed under each. Issue 34's bar: a stop within 50 ms p99 under every one.

Run: ``.venv/bin/python bench/flood.py [--batches 80] [--targets 10000] [--cycles 10] [--secure] [--attacks]``.
"""

from __future__ import annotations

import argparse
import contextlib
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


def _junk_payloads() -> list[tuple[str, bytes]]:
    """What the red team put on other arms' keys: deep nesting, huge states and events, forged readings."""
    deep = b"[" * 2000 + b"]" * 2000
    state = json.dumps({"adapter": "forged", "seq": 1, "epoch": 0, "position": [0, 0, 0], "pad": "p" * 1_000_000})
    reading = json.dumps(
        {"sensor": "scan", "adapter": "forged", "seq": 1, "time": time.time(), "range": 0.1, "bearing": 0.0}
    )
    return [
        ("armd/gupta3/estop", deep),
        ("armd/gupta3/gripper", deep),
        ("armd/gupta3/unlock", deep),
        ("armd/gupta3/state", state.encode()),
        ("armd/gupta3/events", state.encode()),
        ("armd/insomniac/sensors/scan", reading.encode()),
    ]


def attack(name: str, endpoint: str | None, seconds: float, config: str | None = None) -> None:
    """One of the red team's attacks (issue 34), for ``seconds``, from this process: ``world``
    (requests of 10,000 obstacles, and 64 added and cleared, 4 at a time), ``huge`` (40 MB and
    2 MB requests), ``junk`` (deeply nested control puts, 1 MB states and events, forged
    readings, as fast as they go), ``sessions`` (1,000 sessions, each asking ``robots``)."""
    import zenoh

    from armd.service.zconfig import network_config

    conf = lambda: network_config(connect=[endpoint] if endpoint else None, config_file=config)  # noqa: E731
    sessions = []
    for _ in range(1000 if name == "sessions" else 1):
        try:
            sessions.append(zenoh.open(conf()))
        except zenoh.ZError:  # (the router's max_sessions: as many as it lets in)
            break
    print(f"{len(sessions)} sessions open", file=sys.stderr, flush=True)
    session = sessions[0]
    end = time.monotonic() + seconds
    done = [0]
    lock = threading.Lock()
    many = json.dumps(
        {"add": [{"name": f"o{i}", "shape": "sphere", "size": [0.01], "position": [1, 1, 1]} for i in range(10_000)]}
    ).encode()
    cap = json.dumps(
        {"add": [{"name": f"c{i}", "shape": "sphere", "size": [0.01], "position": [1, 1, 1.0 + i]} for i in range(64)]}
    ).encode()
    junk = _junk_payloads()

    def ask(key: str, body: bytes | None, s: Any = None) -> None:
        for _ in (s or session).get(key, payload=body, timeout=10.0):
            pass
        with lock:
            done[0] += 1

    def one(k: int) -> None:
        while time.monotonic() < end:
            if name == "world":
                ask("armd/gupta3/world", many)
                ask("armd/gupta3/world", cap)
                ask("armd/gupta3/world", b'{"clear": true}')
            elif name == "huge":
                ask("armd/gupta3/ik", b" " * (40_000_000 if k % 2 else 2_000_000))
            elif name == "junk":
                for key, body in junk:
                    session.put(key, body)
                with lock:
                    done[0] += len(junk)
            else:  # sessions
                for s in sessions[k::4]:
                    ask("armd/robots", None, s)

    threads = [threading.Thread(target=one, args=(k,), daemon=True) for k in range(4)]
    for t in threads:
        t.start()
    print("ready", flush=True)
    for t in threads:
        t.join(seconds + 30)
    print(json.dumps({"answered": done[0]}), flush=True)
    for s in sessions:
        s.close()


ATTACKS = ("flood", "world", "huge", "junk", "sessions")


def operator(
    endpoint: str | None, cycles: int, config: str | None = None, client: Any = None
) -> dict[str, list[float]]:
    """Move, stop 0.3 s in, ``cycles`` times: each reply's latency [ms]. With ``client``, on
    that session (an operator's, open before the attack); else on a new one."""
    from armd.clients import ArmClient
    from armd.errors import ServiceError

    out: dict[str, list[float]] = {"move": [], "stop": [], "refused": []}
    own = client is None
    with ArmClient(endpoint, config=config, timeout=30.0) if own else contextlib.nullcontext(client) as c:
        for k in range(cycles):
            t = time.monotonic()
            try:
                c.move("insomniac", GOALS[k % 2])
            except ServiceError as e:  # (counted: the stop is timed all the same)
                out["refused"].append(1.0)
                print(f"move refused: {e.code}: {e.message}", file=sys.stderr, flush=True)
            out["move"].append((time.monotonic() - t) * 1e3)
            time.sleep(0.3)
            t = time.monotonic()
            c.stop("insomniac")
            out["stop"].append((time.monotonic() - t) * 1e3)
            time.sleep(0.5)
    return out


def fresh_stop(where: dict[str, Any]) -> str:
    """A stop from a session opened for it (as ``armd stop`` is): connect and stop [ms], or why not."""
    from armd.clients import ArmClient
    from armd.errors import ArmdError

    t = time.monotonic()
    try:
        with ArmClient(where["endpoint"], config=where.get("config"), timeout=10.0) as c:
            c.stop("insomniac")
    except ArmdError as e:
        return f"failed: {e.message[:60]}"
    return f"{(time.monotonic() - t) * 1e3:.0f}"


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
    ap.add_argument(
        "--attacks",
        nargs="?",
        const=",".join(ATTACKS),
        metavar="NAMES",
        help=f"the red team's attacks in turn (default all: {','.join(ATTACKS)}): a stop's latency under each",
    )
    ap.add_argument("--worker", choices=["flood", *ATTACKS[1:]], help=argparse.SUPPRESS)
    ap.add_argument("--endpoint", help=argparse.SUPPRESS)
    ap.add_argument("--config", help=argparse.SUPPRESS)
    ap.add_argument("--seconds", type=float, default=60.0, help=argparse.SUPPRESS)
    ap.add_argument("--secure", action="store_true", help="through a router with logins and the ACL (guests flood)")
    args = ap.parse_args()
    if args.worker == "flood":
        flood(args.endpoint, args.batches, args.targets, args.seconds, args.config)
        return
    if args.worker is not None:
        attack(args.worker, args.endpoint, args.seconds, args.config)
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
    stack = contextlib.ExitStack()
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
        held = ArmClient(where["endpoint"], config=where.get("config"), timeout=30.0) if args.attacks else None
        stack.callback(lambda: held.close() if held is not None else None)
        results["idle"] = operator(where["endpoint"], args.cycles, where.get("config"), held)
        results["idle fresh"] = fresh_stop(where)
        seconds = (args.cycles * 1.5 + 20.0) if args.attacks else (args.cycles * 4.0 + 20.0)
        attacks = args.attacks.split(",") if args.attacks else ["flood"]
        for name in attacks:
            sized = ["--batches", str(args.batches), "--targets", str(args.targets)] if name == "flood" else []
            fl = subprocess.Popen(
                [sys.executable, __file__, "--worker", name, *guest, *sized, "--seconds", str(seconds)],
                cwd=ROOT,
                stdout=subprocess.PIPE,
                text=True,
            )
            assert fl.stdout is not None
            assert fl.stdout.readline().strip() == "ready"
            time.sleep(5.0)  # the attack in full
            results[name] = operator(where["endpoint"], args.cycles, where.get("config"), held)
            results[f"{name} fresh"] = fresh_stop(where) if args.attacks else "-"
            out, _ = fl.communicate(timeout=seconds + 120)
            results[f"{name} answered"] = json.loads(out.strip().splitlines()[-1])["answered"]
    finally:
        stack.close()
        for d in reversed(daemons):
            d.terminate()
            d.wait(20)
        shutil.rmtree(tmp, ignore_errors=True)
    how = "through the secure setup (guests attack, an operator moves)" if args.secure else "on the default setup"
    if not args.attacks:
        print(
            f"{args.batches} IK batches of {args.targets} targets in flight {how} "
            f"({results.get('flood answered', '?')} answered during the run); latency [ms], median / p99 / max:\n"
        )
        print("| request | idle | flooded |")
        print("|---|---|---|")
        for verb in ("stop", "move"):
            print(f"| {verb} | {_cell(results['idle'][verb])} | {_cell(results['flood'][verb])} |")
        return
    print(f"The red team's attacks, each in turn, {how}; latency [ms], median / p99 / max:\n")
    print("| while | stop | move | moves refused | a new session's stop | the attack's requests or puts |")
    print("|---|---|---|---|---|---|")
    idle = results["idle"]
    print(
        f"| nothing (the peer) | {_cell(idle['stop'])} | {_cell(idle['move'])} | {len(idle['refused'])} "
        f"| {results['idle fresh']} | - |"
    )
    for name in attacks:
        r, n, f = results[name], results[f"{name} answered"], results[f"{name} fresh"]
        print(f"| {name} | {_cell(r['stop'])} | {_cell(r['move'])} | {len(r['refused'])} | {f} | {n} |")


if __name__ == "__main__":
    main()
