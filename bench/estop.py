"""Emergency-stop latency: from asking to the adapter having the stop.

A router and a simulated adapter in this process; the estop's arrival is stamped by a subscriber
on ``armd/<robot>/estop`` in this process (the adapter's own subscription sees it at the same
moment). Three ways of asking, each ``--runs`` times, in the same run:

* ``armd estop ROBOT``, the command line as a user types it (a new process: Python's start,
  the fast path's imports, a Zenoh session, the put);
* the peer: a new process that does what the command line did before its fast path, importing
  the client library (NumPy with it) and stopping through ``ArmClient.estop``;
* a resident program with its session open (a teleop, the web page): ``ArmClient.estop``.

Run: ``.venv/bin/python bench/estop.py [--runs 20]``. Prints a Markdown table (median and p99, ms).
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import zenoh

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from armd import robots  # noqa: E402
from armd.adapters.sim import SimAdapter  # noqa: E402
from armd.clients import ArmClient  # noqa: E402
from armd.service.zconfig import free_endpoint, network_config  # noqa: E402

ARM = "gupta3"
PEER = "import sys; from armd.clients import ArmClient\nwith ArmClient(sys.argv[1]) as c: c.estop(sys.argv[2])\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=20)
    args = parser.parse_args()
    endpoint = free_endpoint()
    router = zenoh.open(network_config(listen=[endpoint], mode="router"))
    session = zenoh.open(network_config(connect=[endpoint]))
    adapter = SimAdapter(session, robots.load(ARM))
    arrived = threading.Event()
    stamp: list[float] = []

    def on_estop(_: zenoh.Sample) -> None:
        stamp.append(time.monotonic())
        arrived.set()

    sub = session.declare_subscriber(f"armd/{ARM}/estop", on_estop)
    armd = str(Path(sys.executable).with_name("armd"))
    ways = {
        "armd estop (a new process)": lambda: subprocess.run(
            [armd, "estop", ARM, "--connect", endpoint, "--wait", "0"], check=True, capture_output=True
        ),
        "peer: a new process through ArmClient": lambda: subprocess.run(
            [sys.executable, "-c", PEER, endpoint, ARM], check=True, capture_output=True
        ),
    }
    times: dict[str, list[float]] = {name: [] for name in (*ways, "ArmClient.estop, its session open")}
    try:
        with ArmClient(endpoint) as resident:
            time.sleep(0.5)
            for _ in range(args.runs):
                for name, way in ways.items():
                    arrived.clear()
                    asked = time.monotonic()
                    way()
                    arrived.wait(5.0)
                    times[name].append(1000.0 * (stamp[-1] - asked))
                    time.sleep(0.1)
                arrived.clear()
                asked = time.monotonic()
                resident.estop(ARM)
                arrived.wait(5.0)
                times["ArmClient.estop, its session open"].append(1000.0 * (stamp[-1] - asked))
                time.sleep(0.1)
    finally:
        sub.undeclare()
        adapter.close()
        session.close()
        router.close()
    print("| how the estop is asked | to the adapter: median ms | p99 ms |")
    print("|---|---|---|")
    for name, t in times.items():
        print(f"| {name} | {np.median(t):.1f} | {np.percentile(t, 99):.1f} |")
    print(f"\n({args.runs} runs each, interleaved; a simulated {ARM} adapter and the router in this process)")


if __name__ == "__main__":
    main()
