"""The tracking stream's figures (issue 35): a program streaming targets at 100 Hz, followed.

Processes, all on 127.0.0.1: a Zenoh router, the client and the arm's adapter in this process
(the adapter's commands are stamped where they leave it: the simulated arm's positions, the
Feetech bus's goal writes); the service, ``armd serve --connect``, in a process of its own (its
CPU measured from /proc); for the so101, its servos on the Feetech emulator in a process of its
own. Per arm (``--arms``, default ``insomniac`` on the simulated arm and ``so101`` on its bus):

* **latency**: the stream holds the arm still at 100 Hz; every 0.3 s a put steps one joint's
  target by 0.05 rad; from that put (this clock) to the first command that moves the arm toward
  it, leaving the adapter (the simulated arm's position, the servos' goal and speed written);
* **circle**: targets on a circle 0.1 m across (in the vertical plane across the reach) at
  0.2 m/s, put at 100 Hz for ``--seconds``: every splice-joined sample the adapter ran (its
  finite-difference velocity, acceleration and jerk over the limits), the tool's distance from
  the latest target after the first second (where the adapter has the arm: the simulated arm's
  position, the servos' present positions), the service's CPU over the circle less its CPU idle
  over as long (adapter connected, states flowing), and per cycle;
* **deadman**: the puts stop mid-circle (deadman 0.25 s): how long until the adapter's arm rests,
  against 0.25 s plus the time a stop from the circle's fastest (each joint's) takes;
* **the peer**: a bare Python loop of Ruckig's online generation (``Ruckig.update``) for the
  arm's joints at 100 Hz with a new target every cycle, its CPU per cycle: the floor.

``--flood``: the latency again while a guest keeps 80 IK batches of 10,000 targets in flight
(bench/flood.py's flood): the operator's stream keeps its p99?

Run: ``.venv/bin/python bench/track.py [--arms insomniac,so101] [--seconds 6] [--steps 40] [--flood]``.
Prints a Markdown table (medians, p99, ratios); docs/benchmarks.md has a run.
"""

from __future__ import annotations

import argparse
import contextlib
import math
import os
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import zenoh

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from armd import planning, robots  # noqa: E402
from armd.adapters.sim import SimAdapter  # noqa: E402
from armd.adapters.trajectory_message import Command  # noqa: E402
from armd.clients import ArmClient, NoReply  # noqa: E402
from armd.service.zconfig import free_endpoint, network_config  # noqa: E402

RATE = 100.0  # [Hz] the client's puts
STEP = 0.05  # [rad] a latency step
DEADMAN = 0.25  # [s] the service's default


class Stamps:
    """What the adapter ran (each trajectory once, in order, splices joined) and what it sent,
    stamped on this clock."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.ran: list[Command] = []
        self.sent: list[tuple[float, np.ndarray]] = []  # (when, the joints it sent toward)
        self.moving: list[tuple[float, bool]] = []  # (when, whether what it sent moves)

    def command(self, cmd: Command) -> None:
        with self.lock:
            if not self.ran or self.ran[-1] is not cmd:
                self.ran.append(cmd)

    def spliced(self, before: Command, cmd: Command) -> None:
        with self.lock:
            if not self.ran or self.ran[-1] is not before:
                self.ran.append(before)
            self.ran.append(cmd)

    def joined(self) -> np.ndarray:
        with self.lock:
            ran = list(self.ran)
        parts = []
        for i, cmd in enumerate(ran):
            nxt = ran[i + 1] if i + 1 < len(ran) else None
            parts.append(cmd.position[: round(nxt.at * cmd.rate_hz)] if nxt and nxt.after == cmd.id else cmd.position)
        return np.vstack(parts)


def sim_adapter(session: zenoh.Session, arm: robots.Robot, stamps: Stamps) -> Any:
    class Stamped(SimAdapter):
        def execute(self, cmd: Command, t: float, first: bool) -> bool:
            done = super().execute(cmd, t, first)
            stamps.command(cmd)
            with stamps.lock:
                stamps.sent.append((time.monotonic(), self.position.copy()))
            return done

        def spliced(self, before: Command, cmd: Command) -> None:
            stamps.spliced(before, cmd)

    return Stamped(session, arm)


@contextlib.contextmanager
def feetech_adapter(session: zenoh.Session, arm: robots.Robot, stamps: Stamps) -> Iterator[Any]:
    from armd.adapters.emulators.feetech import FeetechEmulator
    from armd.adapters.emulators.process import EmulatorProcess
    from armd.adapters.feetech import FeetechAdapter

    class Stamped(FeetechAdapter):
        def execute(self, cmd: Command, t: float, first: bool) -> bool:
            stamps.command(cmd)
            return super().execute(cmd, t, first)

        def spliced(self, before: Command, cmd: Command) -> None:
            stamps.spliced(before, cmd)

        def _send(self, q: Any, v: Any) -> None:
            super()._send(q, v)
            with stamps.lock:
                stamps.sent.append((time.monotonic(), np.array(q, dtype=float)))
                stamps.moving.append((time.monotonic(), bool(np.any(np.abs(v) > 1e-6))))

    with EmulatorProcess(FeetechEmulator, ids=[1, 2, 3, 4, 5, 6]) as emu:
        adapter = Stamped(session, arm, emu.port)
        try:
            yield adapter, emu
        finally:
            adapter.close()


def cpu_seconds(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def across(centre: np.ndarray) -> np.ndarray:
    side = np.array([-centre[1], centre[0], 0.0])
    return side / np.linalg.norm(side)


def on_circle(centre: np.ndarray, radius: float, a: float) -> np.ndarray:
    return centre + radius * (math.cos(a) * across(centre) + math.sin(a) * np.array([0.0, 0.0, 1.0]))


def paced(seconds: float, put: Any) -> None:
    t0 = time.monotonic()
    k = 0
    while time.monotonic() - t0 < seconds:
        put(k)
        k += 1
        time.sleep(max(0.0, t0 + k / RATE - time.monotonic()))


def latency(track: Any, stamps: Stamps, q0: np.ndarray, steps: int, feetech: bool) -> list[float]:
    """Per step (one joint, by ``STEP``, there and back): from the put to the adapter's first
    command that moves the arm toward it [ms]."""
    out = []
    step = STEP * np.eye(len(q0))[0]
    for k in range(steps):
        here, there = (q0, q0 + step) if k % 2 == 0 else (q0 + step, q0)
        paced(0.4, lambda _, here=here: track.send(joints=here.tolist()))  # (at rest there)
        with stamps.lock:
            mark = len(stamps.moving if feetech else stamps.sent)
            held = stamps.sent[-1][1].copy() if stamps.sent else here
        asked = time.monotonic()
        seen = None
        while seen is None and time.monotonic() < asked + 1.0:
            track.send(joints=there.tolist())
            time.sleep(1.0 / RATE)
            with stamps.lock:
                if feetech:
                    seen = next((t for t, moves in stamps.moving[mark:] if moves and t >= asked), None)
                else:
                    seen = next(
                        (t for t, q in stamps.sent[mark:] if t >= asked and np.max(np.abs(q - held)) > 1e-9), None
                    )
        if seen is not None:
            out.append(1000.0 * (seen - asked))
    return out


PEER = """
import math, sys, time, ruckig
n, seconds = int(sys.argv[1]), float(sys.argv[2])
v, a, j = (list(map(float, s.split(","))) for s in sys.argv[3:6])
otg = ruckig.Ruckig(n, 0.01)
inp, out = ruckig.InputParameter(n), ruckig.OutputParameter(n)
inp.max_velocity, inp.max_acceleration, inp.max_jerk = v, a, j
inp.current_position = [0.0] * n
cycles, c0, t0 = 0, time.process_time(), time.monotonic()
while time.monotonic() - t0 < seconds:
    inp.target_position = [0.2 * math.sin(cycles / 50.0)] * n
    otg.update(inp, out)
    out.pass_to_input(inp)
    cycles += 1
    time.sleep(max(0.0, t0 + cycles / 100.0 - time.monotonic()))
print(1e6 * (time.process_time() - c0) / cycles)
"""


def peer(arm: robots.Robot, seconds: float) -> float:
    """A bare Python loop of Ruckig's online generation at 100 Hz, a new target every cycle, in a
    process of its own: its CPU per cycle [us]."""
    lim = arm.limits
    limits = [",".join(f"{x:g}" for x in values) for values in (lim.velocity, lim.acceleration, lim.jerk)]
    run = subprocess.run(
        [sys.executable, "-c", PEER, str(arm.nq), str(seconds), *limits], capture_output=True, text=True, check=True
    )
    return float(run.stdout.strip())


def one_arm(name: str, endpoint: str, service: subprocess.Popen[bytes], args: argparse.Namespace) -> dict[str, Any]:
    arm = robots.load(name)
    stamps = Stamps()
    session = zenoh.open(network_config(connect=[endpoint]))
    feetech = name == "so101"
    with contextlib.ExitStack() as stack:
        if feetech:
            adapter, emu = stack.enter_context(feetech_adapter(session, arm, stamps))

            def where() -> np.ndarray:
                at = emu.positions()
                return arm.actuators.joints_from_commands(
                    np.array([at[a.id] for a in arm.actuators.actuators]), tol=np.inf
                )
        else:
            adapter = sim_adapter(session, arm, stamps)
            stack.callback(adapter.close)

            def where() -> np.ndarray:
                return adapter.position.copy()

        client = stack.enter_context(ArmClient(endpoint, timeout=10.0))
        time.sleep(1.0)
        bent = {"so101": [0.3, -1.0, 1.2, 0.8, 0.0]}.get(name, arm.neutral)
        q0 = np.array(bent, dtype=float)
        with client.track(name, session=f"bench-latency-{name}") as t:
            paced(1.5, lambda _: t.send(joints=q0.tolist()))
            lat = latency(t, stamps, q0, args.steps, feetech)
            paced(0.5, lambda _: t.send(joints=q0.tolist()))

        time.sleep(0.5)
        idle0 = cpu_seconds(service.pid)
        time.sleep(args.seconds)
        idle = cpu_seconds(service.pid) - idle0
        # the circle
        centre = arm.fk(q0)
        w = 0.2 / 0.05
        with stamps.lock:
            stamps.ran.clear()
        tool: list[tuple[float, np.ndarray]] = []
        sent: list[tuple[float, np.ndarray]] = []
        with client.track(name, session=f"bench-circle-{name}") as t:
            paced(1.5, lambda _: t.send(target=on_circle(centre, 0.05, 0.0).tolist()))
            with stamps.lock:
                stamps.ran.clear()
            cpu0 = cpu_seconds(service.pid)

            def put(k: int) -> None:
                p = on_circle(centre, 0.05, w * k / RATE)
                sent.append((time.monotonic(), p))
                t.send(target=p.tolist())
                if k % 2 == 0:
                    tool.append((time.monotonic(), arm.fk(where())))

            paced(args.seconds, put)
            cpu = cpu_seconds(service.pid) - cpu0
            stopped = time.monotonic()  # the deadman: no more puts
            last_move = stopped
            moving_at = where()
            while time.monotonic() - stopped < 3.0:
                time.sleep(0.005)
                now = where()
                if np.max(np.abs(now - moving_at)) > 1e-6:
                    last_move, moving_at = time.monotonic(), now
        statuses = [e.status for e in t.events]
        joined = stamps.joined()
        flooded: list[float] = []
        if args.flood:  # a guest's 80 IK batches of 10,000 targets in flight all the while (bench/flood.py)
            flood = subprocess.Popen(
                [
                    *(sys.executable, str(ROOT / "bench" / "flood.py"), "--worker", "flood", "--endpoint", endpoint),
                    *("--seconds", str(args.steps * 0.5 + 10), "--batches", "80", "--targets", "10000"),
                ],
                stdout=subprocess.PIPE,
                stderr=subprocess.DEVNULL,
                text=True,
            )
            try:
                assert flood.stdout is not None and flood.stdout.readline().strip() == "ready"
                with client.track(name, session=f"bench-flood-{name}") as t:
                    paced(2.0, lambda _: t.send(joints=q0.tolist()))
                    flooded = latency(t, stamps, q0, args.steps, feetech)
            finally:
                flood.kill()
                flood.wait(10)
    session.close()
    dt = 1.0 / 200.0
    v = np.diff(joined, axis=0) / dt
    a = np.diff(v, axis=0) / dt
    j = np.diff(a, axis=0) / dt
    lim = arm.limits
    S = np.array([s[0] for s in sent])
    X = np.array([s[1] for s in sent])
    err = [np.linalg.norm(p - X[max(0, np.searchsorted(S, when) - 1)]) for when, p in tool if when > S[0] + 1.0]
    fastest = np.max(np.abs(v), axis=0) if len(v) else np.zeros(arm.nq)  # (each joint's, over the circle)
    brake = planning.plan_stop(
        arm, planning.JointState(q0, np.minimum(fastest, lim.velocity), np.zeros(arm.nq))
    ).duration
    cycles = len(stamps.ran) or 1
    return {
        "arm": name + (" (Feetech bus, emulated)" if feetech else " (simulated)"),
        "latency": lat,
        "flooded": flooded,
        "v": float(np.max(np.abs(v) / lim.velocity)),
        "a": float(np.max(np.abs(a) / lim.acceleration)),
        "j": float(np.max(np.abs(j) / lim.jerk)),
        "err": err,
        "cpu": 100.0 * (cpu - idle) / args.seconds,
        "cycle_us": 1e6 * (cpu - idle) / cycles,
        "rest": last_move - stopped,
        "rest_bar": DEADMAN + brake,
        "peer_us": peer(arm, 3.0),
        "events": sorted(set(statuses)),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--arms", default="insomniac,so101")
    parser.add_argument("--seconds", type=float, default=6.0)
    parser.add_argument("--steps", type=int, default=40)
    parser.add_argument("--flood", action="store_true", help="the latency again under a guest's flood of IK batches")
    args = parser.parse_args()
    endpoint = free_endpoint()
    router = zenoh.open(network_config(listen=[endpoint], mode="router"))
    armd = str(Path(sys.executable).with_name("armd"))
    service = subprocess.Popen(
        [armd, "serve", "--connect", endpoint], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
    )
    rows = []
    try:
        with ArmClient(endpoint, timeout=60.0) as c:
            for _ in range(120):  # (the service warmed up and serving: seconds)
                try:
                    c.robots()
                    break
                except NoReply:
                    time.sleep(0.5)
        for name in args.arms.split(","):
            rows.append(one_arm(name, endpoint, service, args))
    finally:
        service.terminate()
        service.wait(10)
        router.close()
    print(
        "| arm | put -> controller p50 / p99 [ms] | max v, a, j / limit | tool error after 1 s, median / p99 [mm] "
        "| service CPU [% of a core] | cycle [us] / peer (Ruckig.update) [us] | rest after the last put [s] / bar |"
    )
    print("|---|---|---|---|---|---|---|")
    for r in rows:
        lat = np.array(r["latency"]) if r["latency"] else np.array([np.nan])
        err = 1000.0 * np.array(r["err"]) if r["err"] else np.array([np.nan])
        print(
            f"| {r['arm']} | {np.median(lat):.1f} / {np.percentile(lat, 99):.1f} (n={len(r['latency'])}) "
            f"| {r['v']:.2f}, {r['a']:.2f}, {r['j']:.2f} | {np.median(err):.1f} / {np.percentile(err, 99):.1f} "
            f"| {r['cpu']:.1f} | {r['cycle_us']:.0f} / {r['peer_us']:.0f} ({r['cycle_us'] / r['peer_us']:.0f}x) "
            f"| {r['rest']:.2f} / {r['rest_bar']:.2f} |"
        )
    for r in rows:
        if r["flooded"]:
            f = np.array(r["flooded"])
            print(
                f"| {r['arm']}, under a flood of IK batches | {np.median(f):.1f} / {np.percentile(f, 99):.1f} "
                f"(n={len(f)}) | | | | | |"
            )
    print()
    print("events said:", {r["arm"]: r["events"] for r in rows})


if __name__ == "__main__":
    main()
