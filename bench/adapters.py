"""Adapters benchmark: what reaches the controller, against the limits, when things go wrong.

Per adapter on its emulator (the SSC-32 for insomniac, GRBL for gupta3), the adapter a process
of its own (``armd adapter ...``, as a user runs it) and the service in this one, in four
conditions. The SSC-32 emulator runs in a process of its own too, at real-time priority where
the system allows it (``adapters/emulators/process.py``): a board has its own CPU, and an
emulator starved beside the busy processes would stamp commands late. (GRBL's emulator stays
in this process, where its figures meet their bars.)

* idle: nothing else runs;
* busy: two processes spin beside it (the machine has 2 cores);
* slow board: the SSC-32 answers ``QP`` in 150 ms; GRBL answers ``?`` in 150 ms;
* stall: the adapter's process is stopped (SIGSTOP) for 1.5 s in the middle of a move.

Each run moves the arm far (every joint near its velocity limit) and back, then stops it
mid-move. Reported, per condition: the worst implied speed and acceleration of any joint (SSC-32:
the board's own output, exactly, per group move, its 1 us pulses allowed for; in a stall, the
motion before and after it: the hold at the stall is the one stop at speed an SSC-32 move cannot
soften; GRBL: its trace fitted over 40 ms, on a copy of gupta3 with 256 micro-steps so that the
fit sees the motion, not the steps) as a ratio of the limits; executed vs planned duration; the
stop's latency (from ``stop`` asked to the arm at rest) against the stop's planned duration.
Medians and worst over the runs.

Then the bus servos (bench/bus_servo_bench.py): the Feetech and Dynamixel adapters' bus round
trip against the SDK's own sync read, the bus cycles a second, the tracking error and the
stop's latency; and their fault table (bench/bus_faults_bench.py): each fault injected mid-move
at full speed, when it was noticed, how far the arm ran on and back, how hard it braked, the
state's rate meanwhile. GRBL's fault table (bench/grbl_faults_bench.py) the same, for an
operator's stop and GRBL's alarms; the SSC-32's (bench/ssc32_faults_bench.py) for a stop, an
estop, another program's lines, an unanswered QP and a power cycle.

Run: ``.venv/bin/python bench/adapters.py [--runs 3] [--only ssc32|grbl|bus]``. Prints Markdown tables.
"""

from __future__ import annotations

import argparse
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import zenoh

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from armd import robots  # noqa: E402
from armd.adapters.emulators.grbl import GrblEmulator  # noqa: E402
from armd.adapters.emulators.measure import (  # noqa: E402
    Motion,
    actuator_limits_deg,
    fitted_peaks,
    grbl_motion,
    ratios,
    span,
    ssc32_motion,
    ssc32_speed_noise,
)
from armd.adapters.emulators.process import EmulatorProcess  # noqa: E402
from armd.adapters.emulators.ssc32 import SSC32Emulator  # noqa: E402
from armd.clients import ArmClient  # noqa: E402
from armd.service.server import Service  # noqa: E402
from armd.service.zconfig import free_endpoint, network_config  # noqa: E402

CONDITIONS = ("idle", "busy", "slow board", "stall")
SSC32_GOALS = ([1.2, 2.0, -1.8, 1.0, 1.0], [-0.9, 1.0, -0.6, -1.0, -1.0])
GRBL_GOALS = ([1.5, 1.0, -2.3], [-1.0, 2.0, -0.8])


def wait(pred: Callable[[], bool], timeout: float, what: str) -> None:
    end = time.monotonic() + timeout
    while not pred():
        if time.monotonic() > end:
            raise TimeoutError(f"timed out waiting for {what}")
        time.sleep(0.01)


def burners(n: int) -> list[subprocess.Popen[bytes]]:
    return [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(n)]


def fine_gupta(folder: Path) -> Path:
    """gupta3 with 256 micro-steps (its limits unchanged): a trace fine enough to fit."""
    dst = folder / "gupta3fine"
    shutil.copytree(robots.CATALOGUE_DIR / "gupta3", dst)
    toml = (dst / "robot.toml").read_text().replace("microsteps = 16", "microsteps = 256")
    (dst / "robot.toml").write_text(toml)
    return dst


class Bench:
    def __init__(self, arms_dir: Path) -> None:
        self.endpoint = free_endpoint()
        self.router = zenoh.open(network_config(listen=[self.endpoint], mode="router"))
        self.session = zenoh.open(network_config(connect=[self.endpoint]))
        self.arms_dir = arms_dir
        self.arms = {"insomniac": robots.load("insomniac"), **robots.load_dir(arms_dir)}
        self.service = Service(self.session, self.arms)
        self.client = ArmClient(self.endpoint, timeout=10.0)
        self.logs: list[Path] = []

    def close(self) -> None:
        self.client.close()
        self.service.close()
        self.session.close()
        self.router.close()

    def adapter(self, kind: str, robot: str, port: str, state_dir: str, *extra: str) -> subprocess.Popen[str]:
        env = {**os.environ, "ARMD_STATE_DIR": state_dir}
        log = Path(state_dir) / "adapter.log"  # (a pipe nobody reads would stall the adapter once full)
        with log.open("w") as err:
            proc = subprocess.Popen(
                [
                    sys.executable,
                    "-m",
                    "armd.cli",
                    "adapter",
                    kind,
                    robot,
                    "--port",
                    port,
                    "--connect",
                    self.endpoint,
                    "--robots-dir",
                    str(self.arms_dir),
                    *extra,
                ],
                cwd=ROOT,
                env=env,
                stdout=subprocess.DEVNULL,
                stderr=err,
                text=True,
            )
        wait(lambda: self.service._adapter_count(self.arms[robot]) == 1 or proc.poll() is not None, 30, "the adapter")
        if proc.poll() is not None:
            raise RuntimeError(f"the {kind} adapter exited: {log.read_text()[-2000:]}")
        self.logs.append(log)
        return proc

    def at_rest(self, robot: str, goal: list[float], timeout: float) -> None:
        def there() -> bool:
            s = self.client.state(robot)  # (as the adapter says: what the service last commanded is no proof)
            return (
                s["source"] == "adapter"
                and not s["moving"]
                and bool(np.max(np.abs(np.array(s["position"]) - goal)) < 5e-3)
            )

        try:
            wait(there, timeout, "the arm at its goal")
        except TimeoutError:
            said = [ln for ln in self.logs[-1].read_text().splitlines() if "WARNING" in ln or "ERROR" in ln]
            raise TimeoutError(f"the arm did not reach its goal ({said[-1] if said else 'nothing logged'})") from None


def run_move(
    b: Bench, robot: str, goal: list[float], proc: subprocess.Popen[str], stall: bool
) -> tuple[float, float | None]:
    """One move; returns the planned duration [s] and when the adapter was stopped (stall) [s]."""
    r = b.client.move(robot, goal)
    stopped = None
    if stall:
        time.sleep(0.3 * r.duration)
        proc.send_signal(signal.SIGSTOP)
        stopped = time.monotonic()
        time.sleep(1.5)
        proc.send_signal(signal.SIGCONT)
    b.at_rest(robot, goal, r.duration + 15)
    return r.duration, stopped


def ssc32_runs(b: Bench, condition: str, runs: int) -> dict[str, list[float]]:
    arm = b.arms["insomniac"]
    out: dict[str, list[float]] = {k: [] for k in ("v", "a", "duration", "stop", "held")}
    with (
        tempfile.TemporaryDirectory() as state,
        EmulatorProcess(SSC32Emulator, query_delay=0.15 if condition == "slow board" else 1e-4) as emu,
    ):
        proc = b.adapter("ssc32", "insomniac", emu.port, state)
        hot = burners(2) if condition == "busy" else []
        try:
            time.sleep(0.2)
            for _ in range(runs):
                for goal in SSC32_GOALS:
                    since = emu.clock()
                    planned, stalled = run_move(b, "insomniac", goal, proc, condition == "stall")
                    time.sleep(0.2)
                    m = ssc32_motion(arm, emu, since)
                    t0, t1 = m.moving()
                    # a stall: the motion before it and after it (the board's hold at the stall is the
                    # stop at speed no SSC-32 move can soften: docs/adapters.md)
                    parts = (
                        [m]
                        if stalled is None
                        else [
                            Motion(m.times[m.times <= stalled], m.position[m.times <= stalled], 0),
                            Motion(m.times[m.times >= stalled + 1.0], m.position[m.times >= stalled + 1.0], 0),
                        ]
                    )
                    rs = [ratios(arm, part, 0.02, ssc32_speed_noise(arm, emu, since), held=True) for part in parts]
                    out["held"].append(max(r.held for r in rs))
                    out["v"].append(max(r.velocity for r in rs))
                    out["a"].append(max(r.acceleration for r in rs))
                    if condition != "stall":  # (a stall adds 1.5 s by design)
                        out["duration"].append((t1 - t0) / planned)
                # (the arm is at GOALS[1]: the stop is asked on the way back)
                out["stop"].append(stop_latency(b, "insomniac", SSC32_GOALS[0], lambda: ssc32_still(arm, emu)))
        finally:
            for p in hot:
                p.kill()
            proc.terminate()
            proc.wait(10)
    return out


def ssc32_still(arm: robots.Robot, emu: EmulatorProcess) -> float | None:
    """When the board's output last changed [s], if it has been still for 0.1 s since."""
    m = ssc32_motion(arm, emu, emu.clock() - 5.0)
    end = m.moving()[1]
    return end if emu.clock() - end > 0.1 else None


def grbl_still(emu: GrblEmulator, arm: robots.Robot) -> float | None:
    t, p = grbl_motion(arm, emu)
    if len(t) < 2:
        return None
    end = span(t, p)[1]
    return end if time.monotonic() - end > 0.1 else None


def stop_latency(b: Bench, robot: str, goal: list[float], still: Callable[[], float | None]) -> float:
    """A move, a stop 40% in: how long the arm took to be at rest, over the stop's planned duration."""
    r = b.client.move(robot, goal)
    time.sleep(0.4 * r.duration)
    asked = time.monotonic()
    stopped = b.client.stop(robot)
    wait(lambda: not b.client.state(robot)["moving"], 10, "the adapter done with the stop")
    wait(lambda: still() is not None, 10, "the arm at rest")
    end = still()
    assert end is not None
    return (end - asked) / max(stopped["duration"], 1e-3)


def grbl_runs(b: Bench, condition: str, runs: int) -> dict[str, list[float]]:
    arm = b.arms["gupta3fine"]
    vlim, alim = actuator_limits_deg(arm)
    out: dict[str, list[float]] = {k: [] for k in ("v", "a", "duration", "stop", "held")}
    with (
        tempfile.TemporaryDirectory() as state,
        GrblEmulator(status_delay=0.15 if condition == "slow board" else 0.003) as emu,
    ):
        proc = b.adapter("grbl", "gupta3fine", emu.port, state, "--assume-rest")
        hot = burners(2) if condition == "busy" else []
        try:
            wait(lambda: b.client.state("gupta3fine").get("homed") is True, 10, "homed")
            for _ in range(runs):
                for goal in GRBL_GOALS:
                    emu.clear_trace()
                    planned, _ = run_move(b, "gupta3fine", goal, proc, condition == "stall")
                    wait(lambda: emu.state == "Idle", 10, "GRBL idle")
                    t, p = grbl_motion(arm, emu)
                    v, a = fitted_peaks(t, p, 0.04)
                    out["v"].append(float(np.max(v / vlim)))
                    out["a"].append(float(np.max(a / alim)))
                    if condition != "stall":
                        t0, t1 = span(t, p)
                        out["duration"].append((t1 - t0) / planned)
                emu.clear_trace()
                out["stop"].append(stop_latency(b, "gupta3fine", GRBL_GOALS[0], lambda: grbl_still(emu, arm)))
        finally:
            for burner in hot:
                burner.kill()
            proc.send_signal(signal.SIGCONT)
            proc.terminate()
            proc.wait(10)
    return out


def cell(values: list[float]) -> str:
    if not values:
        return "-"
    a = np.array(values)
    return f"{np.median(a):.2f} / {np.max(a):.2f}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=3, help="move pairs and stops per condition (default 3)")
    parser.add_argument(
        "--only", choices=["ssc32", "grbl", "bus"], help="one adapter only (bus: Feetech and Dynamixel)"
    )
    parser.add_argument("--condition", choices=CONDITIONS, help="one condition only")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as arms:
        fine_gupta(Path(arms))
        b = Bench(Path(arms))
        rows: list[tuple[str, str, dict[str, Any]]] = []
        try:
            for name, runner in (("ssc32", ssc32_runs), ("grbl", grbl_runs)):
                if args.only not in (None, name) or args.only == "bus":
                    continue
                for condition in CONDITIONS:
                    if args.condition not in (None, condition):
                        continue
                    started = time.monotonic()
                    try:
                        res = runner(b, condition, args.runs)
                    except (TimeoutError, RuntimeError) as e:  # said in the table, the rest still measured
                        res = {"failed": str(e)}

                    rows.append((name, condition, res))
                    print(f"{name} {condition}: {time.monotonic() - started:.0f} s", file=sys.stderr, flush=True)
        finally:
            b.close()
    if not rows:
        if args.only in (None, "bus"):
            bus_tables(args.runs)
        return
    print(
        "| adapter | condition | speed / limit | acceleration / limit | executed / planned | stop / planned stop "
        "| lines held (worst) |"
    )
    print("|---|---|---|---|---|---|---|")
    for name, condition, res in rows:
        if "failed" in res:
            print(f"| {name} | {condition} | failed: {res['failed']} | | | | |")
            continue
        print(
            f"| {name} | {condition} | {cell(res['v'])} | {cell(res['a'])} | {cell(res['duration'])} | "
            f"{cell(res['stop'])} | {int(max(res['held'])) if res['held'] else '-'} |"
        )
    print("\n(median / worst over the runs; speed and acceleration: the worst joint of each move)")
    if args.only in (None, "ssc32") and args.condition is None:
        from ssc32_faults_bench import print_ssc32_fault_table, ssc32_fault_rows

        print_ssc32_fault_table(ssc32_fault_rows(args.runs))
    if args.only in (None, "grbl") and args.condition is None:
        from grbl_faults_bench import grbl_fault_rows, print_grbl_fault_table

        print_grbl_fault_table(grbl_fault_rows(args.runs))
    if args.only in (None, "bus"):
        bus_tables(args.runs)


def bus_tables(runs: int) -> None:
    from bus_faults_bench import fault_rows, print_fault_table
    from bus_servo_bench import bus_rows, print_table

    print_table(bus_rows(runs))
    print_fault_table(fault_rows(runs))


if __name__ == "__main__":
    main()
