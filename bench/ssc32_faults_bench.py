"""The SSC-32's fault table of bench/adapters.py: each fault mid-move at full speed on insomniac,
the SSC-32 emulator (its 20 ms frames, ``QP`` answering the frame in progress), the adapter and
the service in this process.

Per fault: when it was noticed (from its injection to the adapter's ``fault`` event; for the
operator's ``stop`` and ``estop``, the rows to compare with, to the ``accepted`` of the stop),
how far the joint that ran farthest went on after it, how far any joint went back against its
way (for the servo another program moved: against the way that program sent it), the hardest
change of speed of the board's output against the acceleration limit (over a 20 ms stream
period, the board's own frame; for another program's line, of the joints it did not move), and
the state's rate meanwhile. A power cycle leaves the board with no pulse (the servos limp): the
row counts the lines the adapter sent it after the fault (a line to a channel without a pulse
jumps the servo: none may come) instead of a motion. (Mid-move, the stream's next line to each
channel gives it a pulse again within a period, where the plan is: the board cannot be told
from one that kept its power; docs/adapters.md.)
"""

from __future__ import annotations

import os
import socket
import tempfile
import time
from collections.abc import Callable
from typing import Any

import numpy as np
import zenoh
from fault_watch import ArmWatch

from armd import robots
from armd.adapters.emulators.measure import ratios, ssc32_motion, ssc32_speed_noise
from armd.adapters.emulators.ssc32 import SSC32Emulator
from armd.clients import ArmClient
from armd.service.server import Service
from armd.service.zconfig import network_config

ARM = "insomniac"
START, GOAL = [-1.3, 1.8, -1.6, 1.2, -1.3], [1.3, 1.8, -1.6, -1.2, 1.3]  # (base, wrist, roll at 3 rad/s)
AFTER = 2.5  # [s] watched after the fault
PERIOD = 0.02  # [s] the window of a change of speed: the board's frame


def _other_program(emu: SSC32Emulator, _: ArmClient) -> None:
    """Another program on the port sends the base 300 us on (to the side it moved last) at 600
    us/s: mid-move, the adapter's next line overrides it; at rest, it moves the base 0.5 s."""
    here = emu.pulse(0)
    way = 1.0 if (emu.target(0) or 0) >= here else -1.0
    fd = os.open(emu.port, os.O_WRONLY | os.O_NOCTTY)
    try:
        os.write(fd, f"#0P{round(here + way * 300)}S600\r".encode())
    finally:
        os.close(fd)


FAULTS: dict[str, Callable[[SSC32Emulator, ArmClient], None]] = {
    "stop (an operator's)": lambda emu, c: c.stop(ARM) and None,
    "estop (a put)": lambda emu, c: c.session.put(f"armd/{ARM}/estop", b"{}"),
    "another program's line mid-move": _other_program,
    "another program moves the resting base": _other_program,
    "QP unanswered (the board hangs)": lambda emu, c: setattr(emu, "query_delay", 30.0),
    "power cycle (at rest)": lambda emu, c: emu.power_cycle(),
}


def ssc32_fault_rows(runs: int) -> list[dict[str, Any]]:
    from armd.adapters.ssc32 import SSC32Adapter

    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    endpoint = f"tcp/127.0.0.1:{s.getsockname()[1]}"
    s.close()
    arm = robots.load(ARM)
    router = zenoh.open(network_config(listen=[endpoint], mode="router"))
    session = zenoh.open(network_config(connect=[endpoint]))
    service = Service(session, {ARM: arm})
    client = ArmClient(endpoint, timeout=10.0)
    rows: list[dict[str, Any]] = []
    try:
        for fault, inject in FAULTS.items():
            row: dict[str, Any] = {"fault": fault}
            for _ in range(runs):
                with SSC32Emulator() as emu, tempfile.TemporaryDirectory() as kept:
                    adapter = SSC32Adapter(session, arm, emu.port, state_dir=kept)
                    try:
                        _one(row, arm, emu, inject, (service, client))
                    finally:
                        adapter.close()
            rows.append(row)
    finally:
        client.close()
        service.close()
        session.close()
        router.close()
    return rows


def _one(
    row: dict[str, Any],
    arm: robots.Robot,
    emu: SSC32Emulator,
    inject: Callable[[SSC32Emulator, ArmClient], None],
    rig: tuple[Service, ArmClient],
) -> None:
    service, client = rig
    watch = ArmWatch(client.session, arm.name)
    try:
        end = time.monotonic() + 10
        while service._adapter_count(arm) != 1 and time.monotonic() < end:
            time.sleep(0.01)
        client.move(ARM, START, wait=True, wait_timeout=30)
        time.sleep(0.3)
        resting = "rest" in str(row["fault"])
        r = client.move(ARM, GOAL, wait=resting, wait_timeout=30)
        time.sleep(0.3 if resting else 0.5 * r.duration)
        t_fault = time.monotonic()
        e_fault = emu.clock()
        lines_before = len(emu.history)
        inject(emu, client)
        time.sleep(AFTER)
        until = time.monotonic()
        said = watch.first(t_fault, ("fault", "aborted", "accepted"))
        row.setdefault("noticed", []).append(1000.0 * (said - t_fault) if said is not None else float("nan"))
        row.setdefault("rate", []).append(watch.state_rate(t_fault + 0.2, until))
        if "power" in str(row["fault"]):
            seen = e_fault + (said - t_fault if said is not None else 0.0)
            row.setdefault("lines", []).append(sum(1 for m in emu.history[lines_before:] if m.time > seen))
            return
        m = ssc32_motion(arm, emu, since=e_fault - 0.1)
        k0 = int(np.searchsorted(m.times, e_fault))
        t, q = m.times, m.position
        i = max(k0 - 1, 0)
        way = np.sign(q[min(k0 + 1, len(q) - 1)] - q[i])  # (each joint's way at the fault, or the other program's)
        if "another" in str(row["fault"]):  # (the base's way: where the other program sent it)
            later = q[np.searchsorted(t, e_fault + 0.05) :]
            way[0] = np.sign(later[0, 0] - q[i, 0]) if len(later) else way[0]
        ahead = way * (q[i:] - q[i])
        row.setdefault("ran", []).append(float(np.max(ahead)))
        row.setdefault("back", []).append(float(np.max(np.maximum.accumulate(ahead, axis=0) - ahead)))
        if "another" in str(row["fault"]):  # (the base's changes of speed: the other program's)
            q = q.copy()
            q[:, 0] = q[i, 0]
        after = m.__class__(t[i:], q[i:], 0)
        rr = ratios(arm, after, PERIOD, ssc32_speed_noise(arm, emu, e_fault - 0.1), held=True)
        row.setdefault("accel", []).append(rr.acceleration)
    finally:
        watch.close()


def print_ssc32_fault_table(rows: list[dict[str, Any]]) -> None:
    def cell(values: list[float], f: str) -> str:
        return f"{np.nanmedian(values):{f}} / {np.nanmax(values):{f}}" if values else "-"

    print(
        f"\n| SSC-32 ({ARM}) | fault mid-move, full speed | noticed in, ms | ran on after it, rad "
        "| back against its way, rad | change of speed / acceleration limit (20 ms) | state rate meanwhile, Hz |"
    )
    print("|---|---|---|---|---|---|---|")
    for r in rows:
        if "lines" in r:
            print(
                f"| ssc32 | {r['fault']} | {cell(r['noticed'], '.0f')} | lines sent after it: {max(r['lines'])} "
                f"| (no pulse: limp) | - | {np.min(r['rate']):.0f} (least) |"
            )
            continue
        print(
            f"| ssc32 | {r['fault']} | {cell(r['noticed'], '.0f')} | {cell(r['ran'], '.3f')} "
            f"| {cell(r['back'], '.4f')} | {cell(r['accel'], '.2f')} | {np.min(r['rate']):.0f} (least) |"
        )
    print("\n(median / worst over the runs; the board's output in the emulator, continuous in time)")


if __name__ == "__main__":
    import sys

    print_ssc32_fault_table(ssc32_fault_rows(int(sys.argv[1]) if len(sys.argv) > 1 else 1))
