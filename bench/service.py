"""Service benchmark: IK round trips over Zenoh, next to a bare echo queryable, and throughput.

Processes, all on 127.0.0.1: the service (``armd serve``), an echo queryable (a bare Zenoh
session that replies with the request's payload, the floor under any service) and the
clients, in two topologies, one after the other (``--topology``):

* embedded: as ``armd serve`` runs by default, the service opens its own router and its
  clients connect straight to it; the echo likewise is a router of its own that its clients
  connect to. One hop.
* routed: a standalone router (``armd router``) with the service (``armd serve --connect``)
  and the echo as its clients, as on several machines (docs/deployment.md). Two hops.

Either way the service and the echo sit in the same place, so a request takes the same
path to either.

* latency: one client process interleaves IK requests (targets from FK of random in-limit
  configurations) through ``ArmClient.ik`` and as a bare Zenoh get whose reply is parsed
  with ``json.loads`` (what a client in any language does), and echo requests of the same
  payload; p50 and p99 of each, and the ratios to the echo. The bare gets are a
  ``session.get`` per request, for the IK and the echo alike; ``ArmClient`` keeps a querier
  per key (docs/protocol.md), which costs its process less per request.
* throughput: 4 client processes send IK requests back to back for ``--seconds``; replies
  per second, and requests that got no reply (lost); then the same against the echo (the
  peer: what this machine's Zenoh and Python clients can carry at all).

Run: ``.venv/bin/python bench/service.py [--n 2000] [--seconds 5] [--topology both|embedded|routed]``.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import multiprocessing as mp
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from armd.service.zconfig import free_port  # noqa: E402


def targets(n: int, seed: int = 0) -> list[list[float]]:
    """Tool points of ``n`` random configurations within every limit and clear of collisions
    (with the arm itself and its floor): targets the IK answers ``ok`` (a point only a
    colliding configuration reaches is answered ``collision``)."""
    from armd import robots

    arm = robots.load("insomniac")
    rng = np.random.default_rng(seed)
    world = arm.collision
    out: list[list[float]] = []
    while len(out) < n:
        q = rng.uniform(arm.limits.lower, arm.limits.upper)
        if not arm.limits.contains(q):
            continue
        p = arm.fk(q)
        if world is not None and (
            world.first_contact(q) is not None or (world.ground is not None and p[2] < world.ground)
        ):
            continue
        out.append(p.tolist())
    return out


def echo_server(endpoint: str, embedded: bool, ready: mp.Event, stop: mp.Event) -> None:  # type: ignore[valid-type]
    """The bare echo queryable: a client of the router at ``endpoint``, or (``embedded``) its own
    router listening there, placed on the network exactly as the service is."""
    import zenoh

    from armd.service.zconfig import network_config

    conf = network_config(listen=[endpoint]) if embedded else network_config(connect=[endpoint])
    with zenoh.open(conf) as session:
        q = session.declare_queryable(
            "bench/echo",
            lambda query: query.reply(
                query.key_expr,
                query.payload.to_bytes() if query.payload else b"",
                encoding=zenoh.Encoding.APPLICATION_JSON,
            ),
            complete=True,
        )
        ready.set()  # type: ignore[attr-defined]
        stop.wait()  # type: ignore[attr-defined]
        q.undeclare()


def latency(endpoint: str, echo_endpoint: str, n: int, out: mp.Queue) -> None:  # type: ignore[type-arg]
    import zenoh

    from armd.clients import ArmClient
    from armd.service.zconfig import client_config

    ts = targets(n)
    ik_us, raw_us, echo_us = [], [], []
    with ArmClient(endpoint, timeout=10.0) as c, contextlib.ExitStack() as stack:
        echo = (
            c.session
            if echo_endpoint == endpoint
            else stack.enter_context(zenoh.open(client_config([echo_endpoint], None)))
        )
        for t in ts[:20]:  # warm-up
            c.ik("insomniac", t)
        for t in ts:  # the three interleaved, so that the machine's noise falls on all of them alike
            payload = json.dumps({"target": t}).encode()
            t0 = time.perf_counter_ns()
            c.ik("insomniac", t)
            ik_us.append((time.perf_counter_ns() - t0) / 1e3)
            t0 = time.perf_counter_ns()
            replies = list(c.session.get("armd/insomniac/ik", payload=payload, timeout=10.0))
            reply = json.loads(replies[0].ok.payload.to_bytes())  # type: ignore[union-attr]
            raw_us.append((time.perf_counter_ns() - t0) / 1e3)
            assert len(replies) == 1 and reply["status"] == "ok"
            t0 = time.perf_counter_ns()
            replies = list(echo.get("bench/echo", payload=payload, timeout=10.0))
            echo_us.append((time.perf_counter_ns() - t0) / 1e3)
            assert len(replies) == 1 and replies[0].ok is not None
    out.put((ik_us, raw_us, echo_us))  # type: ignore[attr-defined]


def hammer_raw(endpoint: str, seconds: float, seed: int, out: mp.Queue, key: str) -> None:  # type: ignore[type-arg]
    """A Zenoh get and ``json.loads`` of the reply, back to back: against ``armd/insomniac/ik``,
    or against the bare echo (the peer), the same client work either way."""
    import zenoh

    from armd.service.zconfig import client_config

    payloads = [json.dumps({"target": t}).encode() for t in targets(500, seed)]
    done = lost = errors = 0
    with zenoh.open(client_config([endpoint], None)) as session:
        end = time.monotonic() + seconds
        i = 0
        while time.monotonic() < end:
            replies = list(session.get(key, payload=payloads[i % len(payloads)], timeout=5.0))
            if len(replies) == 1 and replies[0].ok is not None:
                reply = json.loads(replies[0].ok.payload.to_bytes())
                done += 1
                errors += key.endswith("/ik") and reply["status"] != "ok"
            else:
                lost += 1
            i += 1
    out.put((done, lost, errors))  # type: ignore[attr-defined]


def hammer(endpoint: str, seconds: float, seed: int, out: mp.Queue) -> None:  # type: ignore[type-arg]
    from armd.clients import ArmClient
    from armd.errors import NoReply

    ts = targets(500, seed)
    done = lost = errors = 0
    with ArmClient(endpoint, timeout=5.0) as c:
        c.ik("insomniac", ts[0])
        end = time.monotonic() + seconds
        i = 0
        while time.monotonic() < end:
            try:
                r = c.ik("insomniac", ts[i % len(ts)])
                done += 1
                errors += r.status != "ok"
            except NoReply:
                lost += 1
            i += 1
    out.put((done, lost, errors))  # type: ignore[attr-defined]


def start_servers(embedded: bool, stack: contextlib.ExitStack) -> tuple[str, str]:
    """The router (routed only), the service and the echo, each stopped when ``stack`` closes:
    (the service's endpoint, the echo's endpoint)."""
    cli = [sys.executable, "-m", "armd.cli"]

    def process(cmd: list[str]) -> None:
        proc = subprocess.Popen([*cli, *cmd], cwd=ROOT, stdout=subprocess.PIPE, text=True)
        stack.callback(lambda: (proc.terminate(), proc.wait(20)))
        assert proc.stdout is not None
        proc.stdout.readline()  # "listening" / "armd serving ..." once warmed up

    ctx = mp.get_context("spawn")
    ready, stop = ctx.Event(), ctx.Event()
    if embedded:  # as `armd serve` runs by default: the service is the router its clients reach
        endpoint, echo_endpoint = f"tcp/127.0.0.1:{free_port()}", f"tcp/127.0.0.1:{free_port()}"
        process(["serve", "--listen", endpoint])
    else:  # a standalone router between the clients and the servers (docs/deployment.md)
        endpoint = echo_endpoint = f"tcp/127.0.0.1:{free_port()}"
        process(["router", "--listen", endpoint])
        process(["serve", "--connect", endpoint])
    echo = ctx.Process(target=echo_server, args=(echo_endpoint, embedded, ready, stop))
    echo.start()
    stack.callback(lambda: (stop.set(), echo.join(10)))
    if not ready.wait(30):
        raise RuntimeError("the echo server did not start")
    return endpoint, echo_endpoint


def measure(embedded: bool, args: argparse.Namespace) -> None:
    title = (
        "the service's own router (the default `armd serve`): client process -> server process"
        if embedded
        else "a standalone router between them: client process -> router -> server process"
    )
    with contextlib.ExitStack() as stack:
        endpoint, echo_endpoint = start_servers(embedded, stack)
        ctx = mp.get_context("spawn")
        q = ctx.Queue()
        p = ctx.Process(target=latency, args=(endpoint, echo_endpoint, args.n, q))
        p.start()
        ik_us, raw_us, echo_us = q.get(timeout=600)
        p.join()
        ik, raw, ec = np.array(ik_us), np.array(raw_us), np.array(echo_us)
        print(f"### Through {title}")
        print()
        print("| round trip | p50 us | p99 us | p50 / echo | p99 / echo |")
        print("|---|---:|---:|---:|---:|")
        for label, a in (
            ("armd ik, a Zenoh get + json.loads (any language's client)", raw),
            ("armd ik, ArmClient.ik (typed reply, NumPy arrays)", ik),
            ("bare Zenoh echo, same payload (the floor)", ec),
        ):
            print(
                f"| {label} | {np.median(a):.0f} | {np.percentile(a, 99):.0f} | "
                f"{np.median(a) / np.median(ec):.2f}x | {np.percentile(a, 99) / np.percentile(ec, 99):.2f}x |"
            )
        print()
        print(f"| throughput, {args.clients} client processes, {args.seconds:g} s each | replies/s | lost | not ok |")
        print("|---|---:|---:|---:|")
        runs: list[tuple[str, Any, str, tuple[Any, ...]]] = [
            ("armd ik, a Zenoh get + json.loads", hammer_raw, endpoint, ("armd/insomniac/ik",)),
            ("bare Zenoh echo, a Zenoh get + json.loads (the peer)", hammer_raw, echo_endpoint, ("bench/echo",)),
            ("armd ik, ArmClient.ik", hammer, endpoint, ()),
        ]
        for label, target, where, extra in runs:
            q = ctx.Queue()
            procs = [ctx.Process(target=target, args=(where, args.seconds, k, q, *extra)) for k in range(args.clients)]
            for pr in procs:
                pr.start()
            results = [q.get(timeout=args.seconds + 300) for _ in procs]
            for pr in procs:
                pr.join()
            done = sum(r[0] for r in results)
            print(
                f"| {label} | {done / args.seconds:.0f} | {sum(r[1] for r in results)} | {sum(r[2] for r in results)} |"
            )
        print()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n", type=int, default=2000, help="latency samples")
    ap.add_argument("--seconds", type=float, default=5.0, help="throughput run length")
    ap.add_argument("--clients", type=int, default=4)
    ap.add_argument(
        "--topology",
        choices=("both", "embedded", "routed"),
        default="both",
        help="embedded: the service's own router, as `armd serve` runs by default; routed: a "
        "standalone `armd router` between clients and servers (default: both, in turn)",
    )
    args = ap.parse_args()
    for embedded in (True, False):
        if args.topology in ("both", "embedded" if embedded else "routed"):
            measure(embedded, args)


if __name__ == "__main__":
    main()
