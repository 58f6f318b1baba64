"""Fuzz benchmark: N bad requests (default 10,000) to a service in another process, over Zenoh.

The requests are tests/fuzzing.py's: malformed payloads, and valid requests broken in one
place (unknown keys at every level, booleans, strings and huge numbers where numbers go,
both of two exclusive fields). Any ``internal`` reply is a defect and is listed.
Checks that each gets exactly one structured error reply, that no trajectory or gripper
command is published, that the service's resident memory stays bounded, and that a valid
request afterwards gets the right answer. Prints the counts per error code, the time, the
service's memory before and after, and the round trip of an error reply (p50, p99, max) next
to its peer: a bare Zenoh echo queryable (bench/service.py's), in another process on the same
router, sent the same payload right after each request. The suite runs a 2,000-request
version (tests/test_fuzz.py) against an in-process service.

Run: ``.venv/bin/python bench/fuzz.py [--n 10000]``.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402
import zenoh  # noqa: E402

from armd.clients import ArmClient  # noqa: E402
from armd.service.zconfig import free_endpoint  # noqa: E402
from bench.service import echo_server  # noqa: E402

BLOCK = zenoh.CongestionControl.BLOCK
from tests.fuzzing import bad_requests  # noqa: E402


def rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n", type=int, default=10_000)
    args = ap.parse_args()
    endpoint = free_endpoint()
    proc = subprocess.Popen(
        [sys.executable, "-m", "armd.cli", "serve", "--listen", endpoint], cwd=ROOT, stdout=subprocess.PIPE, text=True
    )
    assert proc.stdout is not None
    proc.stdout.readline()
    ctx = mp.get_context("spawn")
    ready, stop = ctx.Event(), ctx.Event()
    echo = ctx.Process(target=echo_server, args=(endpoint, False, ready, stop))  # a client of the service's router
    echo.start()
    if not ready.wait(30):
        proc.terminate()
        raise SystemExit("the echo queryable did not start within 30 s")
    armd_us: list[float] = []
    echo_us: list[float] = []
    try:
        with ArmClient(endpoint, timeout=10.0) as c:
            published: list[str] = []
            sub = c.session.declare_subscriber(
                "armd/**",
                lambda s: (
                    published.append(str(s.key_expr)) if str(s.key_expr).endswith(("/trajectory", "/gripper")) else None
                ),
            )
            before = rss_mb(proc.pid)
            codes: dict[str, int] = {}
            wrong = 0
            for key, payload in bad_requests(args.n, seed=11):
                t1 = time.perf_counter_ns()
                # BLOCK, as docs/protocol.md asks of clients: under DROP a 1.2 MB request or its
                # echo is dropped when the link is busy, and the get ends with no reply
                replies = list(c.session.get(f"armd/{key}", payload=payload, timeout=10.0, congestion_control=BLOCK))
                t2 = time.perf_counter_ns()
                echoed = list(c.session.get("bench/echo", payload=payload, timeout=10.0, congestion_control=BLOCK))
                t3 = time.perf_counter_ns()
                armd_us.append((t2 - t1) / 1e3)
                echo_us.append((t3 - t2) / 1e3)
                assert len(echoed) == 1 and echoed[0].ok is not None, (key, len(payload), "the echo did not answer")
                if len(replies) != 1 or replies[0].err is None:
                    wrong += 1
                    got = "ok " + replies[0].ok.payload.to_bytes()[:80].decode() if replies and replies[0].ok else ""
                    print(f"  {key}: {len(replies)} replies {got} for {payload[:100]!r}", file=sys.stderr)
                    continue
                body = replies[0].err.payload.to_bytes()
                try:
                    code = str(json.loads(body).get("code", "?"))
                except ValueError:  # not the service's: Zenoh's own error (a timeout)
                    code = f"zenoh:{body[:40]!r}"
                    print(f"  {key}: {code} for {payload[:60]!r}", file=sys.stderr)
                codes[code] = codes.get(code, 0) + 1
                if code == "internal":  # a defect: the request that found it
                    print(f"  internal for {key}: {payload[:200]!r}: {body[:200]!r}", file=sys.stderr)
            elapsed = sum(armd_us) / 1e6  # the bad requests' round trips alone, not the echoes
            time.sleep(0.3)
            after = rss_mb(proc.pid)
            ok = c.ik("insomniac", [0.25, 0.05, 0.12]).status
            sub.undeclare()
        print(
            f"{args.n} bad requests in {elapsed:.1f} s of round trips, one at a time ({args.n / elapsed:.0f}/s): "
            f"{args.n - wrong} answered with exactly one structured error, {wrong} not"
        )
        print("codes:", ", ".join(f"{k} {v}" for k, v in sorted(codes.items())))
        print(f"published trajectories or gripper commands: {len(published)}")
        print(f"service resident memory: {before:.0f} MB before, {after:.0f} MB after")
        print(f"a valid IK request afterwards: {ok}")
        a, e = np.array(armd_us), np.array(echo_us)
        print("\n| round trip, us (client -> embedded router -> server) | p50 | p99 | max |")
        print("|---|---:|---:|---:|")
        print(
            f"| armd error reply to a bad request | {np.median(a):.0f} | {np.percentile(a, 99):.0f} | {a.max():.0f} |"
        )
        print(f"| bare Zenoh echo, same payload | {np.median(e):.0f} | {np.percentile(e, 99):.0f} | {e.max():.0f} |")
        print(
            f"| ratio | {np.median(a) / np.median(e):.2f}x | {np.percentile(a, 99) / np.percentile(e, 99):.2f}x | "
            f"{a.max() / e.max():.2f}x |"
        )
    finally:
        stop.set()
        echo.join(10)
        proc.terminate()
        proc.wait(20)


if __name__ == "__main__":
    main()
