"""Load benchmark: armd under several clients at once, and a stop in the middle of it.

Processes, all on 127.0.0.1:

* the service: ``armd serve --sim`` (embedded router, a simulated arm for every arm),
  started by this script (or ``--endpoint`` to drive one already running);
* ``--clients`` load processes (default 4), each with ``--threads`` threads (default 4) sending
  requests back to back for ``--seconds`` (default 20): 16 requests in flight at once, against
  the service's 4 workers. The mix: ik 35%, fk 20%, plan 15% (joint 10, line 5), ik batch of
  200 targets (20 of them out of reach) 10%, info 5%, robots 5%, bad requests 10% (from
  tests/fuzzing.py);
* one stopper process: moves insomniac (a slow move of several seconds), waits 0.4 s, sends
  ``stop`` and times it, then checks the arm came to rest short of the goal. It runs alone
  first (``--idle-stops`` cycles: the peer, the stop's latency on an idle service), then
  during the load.

Every request is a raw Zenoh ``get`` (not ``ArmClient``, which asks again after a timeout):
it must get exactly one reply. No reply, or more than one, or Zenoh's own timeout error, is
*lost*. Reported: replies per second, p50 / p99 / max latency per verb, error codes, lost,
wrong (a bad request answered ok, a good one answered ``internal``), and the stop's latency
idle and under load.

Run: ``.venv/bin/python bench/load.py [--seconds 20] [--clients 4] [--threads 4] [--out FILE]``.
The suite runs a short version (tests/test_load.py).
"""

from __future__ import annotations

import argparse
import json
import os
import random
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from armd.service.zconfig import free_endpoint  # noqa: E402

TIMEOUT = 15.0  # [s] a client's wait for one reply; the service's deadline (4 s) comes first
STOP_ARM = "insomniac"
STOP_GOALS = ([1.2, 1.0, -1.2, 0.5, 1.0], [-1.2, 2.2, -2.2, -0.5, -1.0])  # far apart: a move of seconds
VERB_ORDER = ["ik", "fk", "plan", "line", "batch", "info", "robots", "bad", "move", "stop"]


# -- one request ----------------------------------------------------------------------------

LOST: list[str] = []  # what each lost request saw (printed by the load processes)


def ask(session: Any, key: str, payload: bytes) -> tuple[str, dict[str, Any] | None, float]:
    """('ok' | 'err' | 'lost', reply object, seconds)."""
    import zenoh

    t0 = time.perf_counter()
    replies = list(
        session.get(
            key,
            payload=payload,
            encoding=zenoh.Encoding.APPLICATION_JSON,
            timeout=TIMEOUT,
            congestion_control=zenoh.CongestionControl.BLOCK,
        )
    )
    dt = time.perf_counter() - t0
    if len(replies) != 1:
        LOST.append(f"{key}: {len(replies)} replies after {dt:.2f} s")
        return "lost", None, dt
    r = replies[0]
    if r.ok is not None:
        return "ok", json.loads(r.ok.payload.to_bytes()), dt
    try:
        body = json.loads(r.err.payload.to_bytes())
    except ValueError:  # Zenoh's own error (a timeout): not the service's reply
        LOST.append(f"{key}: Zenoh error {r.err.payload.to_bytes()[:200]!r} after {dt:.2f} s")
        return "lost", None, dt
    return ("err", body, dt) if isinstance(body, dict) and "code" in body else ("lost", None, dt)


# -- the load -------------------------------------------------------------------------------


class Mix:
    """Requests drawn from the verb mix, with targets every arm can reach (FK of random
    configurations inside the limits)."""

    def __init__(self, seed: int) -> None:
        from armd import robots
        from tests.fuzzing import bad_requests

        self.rng = random.Random(seed)
        nrng = np.random.default_rng(seed)
        self.arms = {}
        for name in robots.names():
            arm = robots.load(name)
            qs = []
            while len(qs) < 200:
                q = nrng.uniform(arm.limits.lower, arm.limits.upper)
                if arm.limits.contains(q):
                    qs.append(q)
            self.arms[name] = (np.array(qs), np.array([arm.fk(q) for q in qs]))
        # (not a stop's: a stop is never refused, it stops the arm whatever its request says)
        self.bad = [(k, p) for k, p in bad_requests(2000, seed=seed, oversized=0) if not k.endswith("/stop")]
        d = nrng.normal(size=(20, 3))
        self.far = (1.0 * d / np.linalg.norm(d, axis=1)[:, None]).tolist()  # beyond every arm's reach

    def draw(self) -> tuple[str, str, bytes]:
        """(verb label, key, payload)."""
        rng = self.rng
        name = rng.choice(list(self.arms))
        qs, ps = self.arms[name]
        i = rng.randrange(len(qs))
        r = rng.random()
        if r < 0.35:
            return "ik", f"armd/{name}/ik", _j({"target": ps[i].tolist(), "seed": qs[(i + 1) % len(qs)].tolist()})
        if r < 0.55:
            return "fk", f"armd/{name}/fk", _j({"q": qs[i].tolist()})
        if r < 0.65:
            return "plan", f"armd/{name}/plan", _j({"start": qs[i].tolist(), "goal": {"target": ps[i - 1].tolist()}})
        if r < 0.70:
            goal = ps[i] + np.array([rng.uniform(-0.02, 0.02) for _ in range(3)])
            return (
                "line",
                f"armd/{name}/plan",
                _j({"start": qs[i].tolist(), "goal": {"target": goal.tolist()}, "path": "line"}),
            )
        if r < 0.80:
            k = rng.randrange(len(qs) - 180)
            targets = ps[k : k + 180].tolist() + self.far
            return "batch", f"armd/{name}/ik", _j({"targets": targets})
        if r < 0.85:
            return "info", f"armd/{name}/info", b"{}"
        if r < 0.90:
            return "robots", "armd/robots", b""
        key, payload = rng.choice(self.bad)
        return "bad", f"armd/{key}", payload


def _j(obj: object) -> bytes:
    return json.dumps(obj).encode()


class Tally:
    """Per verb: latencies [ms], replies ok, error codes, lost, wrong."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.verbs: dict[str, dict[str, Any]] = {}

    def add(self, verb: str, kind: str, body: dict[str, Any] | None, seconds: float) -> None:
        wrong = (verb == "bad" and kind == "ok") or (kind == "err" and body is not None and body["code"] == "internal")
        with self.lock:
            v = self.verbs.setdefault(verb, {"ms": [], "ok": 0, "codes": {}, "lost": 0, "wrong": 0})
            if kind == "lost":
                v["lost"] += 1
            else:
                v["ms"].append(seconds * 1e3)
                if kind == "ok":
                    v["ok"] += 1
                else:
                    assert body is not None
                    v["codes"][body["code"]] = v["codes"].get(body["code"], 0) + 1
            v["wrong"] += wrong


def worker_load(endpoint: str, threads: int, seed: int) -> None:
    """A load process: ready, then on 'go <seconds>' from stdin, threads send the mix back to back."""
    import zenoh

    from armd.service.zconfig import client_config

    mixes = [Mix(seed * 100 + k) for k in range(threads)]
    tally = Tally()
    with zenoh.open(client_config([endpoint])) as session:
        print("ready", flush=True)
        seconds = float(sys.stdin.readline().split()[1])
        end = time.monotonic() + seconds

        def run(mix: Mix) -> None:
            while time.monotonic() < end:
                verb, key, payload = mix.draw()
                kind, body, dt = ask(session, key, payload)
                tally.add(verb, kind, body, dt)

        ts = [threading.Thread(target=run, args=(m,)) for m in mixes]
        for t in ts:
            t.start()
        for t in ts:
            t.join()
    print(json.dumps({"verbs": tally.verbs, "lost_detail": LOST[:20]}), flush=True)


# -- the stopper ----------------------------------------------------------------------------


def worker_stopper(endpoint: str) -> None:
    """On 'go <seconds> <cycles>': move, wait 0.4 s, stop (timed), wait for rest; repeat until
    the time is up or the cycles are done (0: no limit)."""
    import zenoh

    from armd.service.zconfig import client_config

    tally = Tally()
    stops: list[float] = []
    honoured = 0
    failures: list[str] = []
    with zenoh.open(client_config([endpoint])) as session:
        print("ready", flush=True)
        words = sys.stdin.readline().split()
        end, cycles = time.monotonic() + float(words[1]), int(words[2])
        k = 0
        while time.monotonic() < end and (cycles == 0 or k < cycles):
            goal = STOP_GOALS[k % 2]
            k += 1
            kind, body, dt = ask(session, f"armd/{STOP_ARM}/move", _j({"goal": goal, "speed": 0.3}))
            tally.add("move", kind, body, dt)
            if kind != "ok":
                failures.append(f"move: {kind} {body}")
                time.sleep(0.2)
                continue
            time.sleep(0.4)
            kind, body, dt = ask(session, f"armd/{STOP_ARM}/stop", b"{}")
            tally.add("stop", kind, body, dt)
            if kind != "ok":
                failures.append(f"stop: {kind} {body}")
                continue
            stops.append(dt * 1e3)
            rest = _wait_for_rest(session)
            if rest is not None and float(np.max(np.abs(np.array(rest) - goal))) > 1e-3:
                honoured += 1  # at rest, short of the goal: the stop, not the move, ended it
            else:
                failures.append(f"stop not honoured: rest {rest}, goal {goal}")
    print(json.dumps({"verbs": tally.verbs, "stops_ms": stops, "honoured": honoured, "failures": failures}), flush=True)


def _wait_for_rest(session: Any, timeout: float = 10.0) -> list[float] | None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        kind, body, _ = ask(session, f"armd/{STOP_ARM}/info", b"{}")
        if kind == "ok" and body is not None and not body["state"]["moving"]:
            return list(body["state"]["position"])
        time.sleep(0.05)
    return None


# -- the run --------------------------------------------------------------------------------


def _spawn(*args: str) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [sys.executable, __file__, *args], cwd=ROOT, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True
    )


def _ready(procs: list[subprocess.Popen[str]]) -> None:
    for p in procs:
        assert p.stdout is not None
        line = p.stdout.readline()
        if line.strip() != "ready":
            raise RuntimeError(f"a worker did not start: {line!r}")


def _go(procs: list[subprocess.Popen[str]], words: str) -> None:
    for p in procs:
        assert p.stdin is not None
        p.stdin.write(f"go {words}\n")
        p.stdin.flush()


def _result(p: subprocess.Popen[str], timeout: float) -> dict[str, Any]:
    out, _ = p.communicate(timeout=timeout)
    if p.returncode != 0:
        raise RuntimeError(f"a worker failed (exit {p.returncode})")
    out_lines = out.strip().splitlines()
    result: dict[str, Any] = json.loads(out_lines[-1])
    return result


def _merge(results: list[dict[str, Any]]) -> dict[str, dict[str, Any]]:
    merged: dict[str, dict[str, Any]] = {}
    for r in results:
        for verb, v in r["verbs"].items():
            m = merged.setdefault(verb, {"ms": [], "ok": 0, "codes": {}, "lost": 0, "wrong": 0})
            m["ms"] += v["ms"]
            m["ok"] += v["ok"]
            m["lost"] += v["lost"]
            m["wrong"] += v["wrong"]
            for c, n in v["codes"].items():
                m["codes"][c] = m["codes"].get(c, 0) + n
    return merged


def run(
    endpoint: str, *, clients: int = 4, threads: int = 4, seconds: float = 20.0, idle_stops: int = 10
) -> dict[str, Any]:
    """Stops on the idle service, then the load with stops during it: every figure, as a dict."""
    stopper = _spawn("--worker", "stopper", "--endpoint", endpoint)
    _ready([stopper])
    _go([stopper], f"{idle_stops * 10.0} {idle_stops}")
    idle = _result(stopper, idle_stops * 15.0 + 60)

    loaders = [
        _spawn("--worker", "load", "--endpoint", endpoint, "--threads", str(threads), "--seed", str(k))
        for k in range(clients)
    ]
    stopper = _spawn("--worker", "stopper", "--endpoint", endpoint)
    _ready([*loaders, stopper])
    _go(loaders, f"{seconds}")
    time.sleep(min(1.0, seconds / 4))  # the load first, then the moves and stops within it
    _go([stopper], f"{max(seconds - 2.0, 0.5)} 0")
    load = [_result(p, seconds + 120) for p in loaders]
    under = _result(stopper, seconds + 120)
    verbs = _merge([*load, under])
    return {
        "endpoint": endpoint,
        "clients": clients,
        "threads": threads,
        "seconds": seconds,
        "verbs": verbs,
        "replies": sum(v["ok"] + sum(v["codes"].values()) for v in verbs.values()),
        "lost": sum(v["lost"] for v in verbs.values()),
        "wrong": sum(v["wrong"] for v in verbs.values()),
        "stop_idle_ms": idle["stops_ms"],
        "stop_load_ms": under["stops_ms"],
        "stops_honoured": {"idle": idle["honoured"], "load": under["honoured"]},
        "stop_failures": idle["failures"] + under["failures"],
        "lost_detail": [d for r in load for d in r.get("lost_detail", [])],
    }


# -- report ---------------------------------------------------------------------------------


def _pct(ms: list[float]) -> tuple[float, float, float]:
    a = np.array(ms) if ms else np.array([np.nan])
    return float(np.median(a)), float(np.percentile(a, 99)), float(np.max(a))


def report(r: dict[str, Any]) -> str:
    lines = [
        f"{r['clients']} client processes x {r['threads']} threads, {r['seconds']:g} s, service at {r['endpoint']}",
        "",
        "| verb | replies | per s | p50 ms | p99 ms | max ms | ok | error codes | lost | wrong |",
        "|---|---:|---:|---:|---:|---:|---:|---|---:|---:|",
    ]
    verbs = r["verbs"]
    for verb in sorted(verbs, key=lambda v: VERB_ORDER.index(v) if v in VERB_ORDER else 99):
        v = verbs[verb]
        n = len(v["ms"])
        p50, p99, mx = _pct(v["ms"])
        codes = ", ".join(f"{c} {k}" for c, k in sorted(v["codes"].items())) or "-"
        lines.append(
            f"| {verb} | {n:,} | {n / r['seconds']:.0f} | {p50:.1f} | {p99:.1f} | {mx:.1f} | {v['ok']:,} | "
            f"{codes} | {v['lost']} | {v['wrong']} |"
        )
    lines.append(
        f"| all | {r['replies']:,} | {r['replies'] / r['seconds']:.0f} | | | | | | {r['lost']} | {r['wrong']} |"
    )
    i50, i99, imx = _pct(r["stop_idle_ms"])
    l50, l99, lmx = _pct(r["stop_load_ms"])
    lines += [
        "",
        "| stop round trip | n | p50 ms | p99 ms | max ms | came to rest short of the goal |",
        "|---|---:|---:|---:|---:|---:|",
        f"| idle service | {len(r['stop_idle_ms'])} | {i50:.1f} | {i99:.1f} | {imx:.1f} | "
        f"{r['stops_honoured']['idle']}/{len(r['stop_idle_ms'])} |",
        f"| under load | {len(r['stop_load_ms'])} | {l50:.1f} | {l99:.1f} | {lmx:.1f} | "
        f"{r['stops_honoured']['load']}/{len(r['stop_load_ms'])} |",
        f"| ratio load / idle | | {l50 / i50:.1f}x | {l99 / i99:.1f}x | {lmx / imx:.1f}x | |",
    ]
    if r["stop_failures"]:
        lines += ["", "stopper failures: " + "; ".join(r["stop_failures"][:5])]
    return "\n".join(lines)


def main() -> None:
    from bench.fuzz import rss_mb  # (one reader of /proc for both benchmarks)

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seconds", type=float, default=20.0, help="length of the load (default 20)")
    ap.add_argument("--clients", type=int, default=4, help="load processes (default 4)")
    ap.add_argument("--threads", type=int, default=4, help="requests in flight per load process (default 4)")
    ap.add_argument("--idle-stops", type=int, default=10, help="move-stop cycles on the idle service first")
    ap.add_argument("--endpoint", help="drive a service already running there (with simulated arms)")
    ap.add_argument("--serve-args", default="", help="extra arguments for armd serve (e.g. '--workers 2')")
    ap.add_argument("--out", help="write every figure as JSON")
    ap.add_argument("--worker", choices=["load", "stopper"], help=argparse.SUPPRESS)
    ap.add_argument("--seed", type=int, default=0, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.worker == "load":
        return worker_load(args.endpoint, args.threads, args.seed)
    if args.worker == "stopper":
        return worker_stopper(args.endpoint)

    service = None
    endpoint = args.endpoint
    if endpoint is None:
        endpoint = free_endpoint()
        service = subprocess.Popen(
            [sys.executable, "-m", "armd.cli", "serve", "--listen", endpoint, "--sim", *args.serve_args.split()],
            cwd=ROOT,
            stdout=subprocess.PIPE,
            text=True,
        )
        assert service.stdout is not None
        line = service.stdout.readline()
        if "armd serving" not in line:
            raise RuntimeError(f"armd serve did not start: {line!r}")
    try:
        before = rss_mb(service.pid) if service else float("nan")
        t0 = time.monotonic()
        r = run(endpoint, clients=args.clients, threads=args.threads, seconds=args.seconds, idle_stops=args.idle_stops)
        r["wall_s"] = time.monotonic() - t0
        if service:
            r["service_rss_mb"] = {"before": before, "after": rss_mb(service.pid)}
        r["load_avg"] = os.getloadavg()
        print(report(r))
        if service:
            print(
                f"\nservice resident memory: {before:.0f} MB before, {r['service_rss_mb']['after']:.0f} MB after; "
                f"load average {r['load_avg'][0]:.2f}"
            )
        if args.out:
            Path(args.out).write_text(json.dumps(r, indent=1))
    finally:
        if service:
            service.terminate()
            service.wait(20)


if __name__ == "__main__":
    main()
