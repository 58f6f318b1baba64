"""GRBL's fault table of bench/adapters.py: each fault mid-move at full speed on gupta3, the GRBL
emulator (its planner, written from GRBL 1.1's sources), the adapter and the service in this
process.

Per fault: when it was noticed (from its injection to the adapter's ``fault`` or ``aborted``
event; for the operator's ``stop``, the row to compare with, to its ``accepted``), how far the
actuator that ran farthest went on after it, how far any went back against its way, the hardest
change of speed against its acceleration limit (GRBL's exact motion before its whole steps,
+-10 ms differences), and the state's rate meanwhile. An ``ALARM`` stops GRBL by its own rule (a
hard limit kills the motion at once, which no command can soften; a soft limit holds first),
and the table says what it did. (An ``error:N`` answers a line, and the adapter stops with a feed
hold as for ``stop``; the lines of a move are all in GRBL's buffer soon after it starts, so none
is left mid-move to answer so: tests/test_adapter_grbl.py tries it at the start of a move.)
"""

from __future__ import annotations

import socket
import time
from collections.abc import Callable
from typing import Any

import numpy as np
import zenoh
from fault_watch import ArmWatch

from armd import robots
from armd.adapters.emulators.grbl import GrblEmulator
from armd.adapters.emulators.measure import actuator_limits_deg, grbl_exact_motion
from armd.clients import ArmClient
from armd.service.server import Service
from armd.service.zconfig import network_config

ARM = "gupta3"
START, GOAL = [-1.0, 1.0, -1.6], [1.5, 1.9, -0.8]
AFTER = 1.5  # [s] watched after the fault
H = 0.01  # [s] the finite differences' half-width

FAULTS: dict[str, Callable[[GrblEmulator, ArmClient], None]] = {
    "stop (an operator's)": lambda emu, c: c.stop(ARM) and None,
    "ALARM:2 (soft limit)": lambda emu, c: emu.inject_alarm(2),
    "ALARM:1 (hard limit)": lambda emu, c: emu.inject_alarm(1),
}


def grbl_fault_rows(runs: int) -> list[dict[str, Any]]:
    from armd.adapters.grbl import GrblAdapter

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
                with GrblEmulator() as emu:
                    adapter = GrblAdapter(session, arm, emu.port, assume_rest=True)
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
    emu: GrblEmulator,
    inject: Callable[[GrblEmulator, ArmClient], None],
    rig: tuple[Service, ArmClient],
) -> None:
    service, client = rig

    watch = ArmWatch(client.session, arm.name)
    try:
        end = time.monotonic() + 10
        while service._adapter_count(arm) != 1 and time.monotonic() < end:
            time.sleep(0.01)
        client.move(ARM, START, wait=True, wait_timeout=30)
        emu.clear_trace()
        r = client.move(ARM, GOAL)
        time.sleep(0.45 * r.duration)
        t_fault = time.monotonic()
        inject(emu, client)
        time.sleep(AFTER)
        until = time.monotonic()
        said = watch.first(t_fault, ("fault", "aborted", "accepted"))
        rate = watch.state_rate(t_fault + 0.2, until)
        t = np.arange(t_fault - 0.05, until, 0.0005)
        q = np.radians(grbl_exact_motion(arm, emu, t))  # [rad] of each actuator
        k0 = round(0.05 / 0.0005)
        k = round(H / 0.0005)
        speed = (q[k0 + k] - q[k0 - k]) / (2 * H)
        way = np.sign(speed)
        ahead = way * (q[k0:] - q[k0])
        acc = (q[2 * k :] - 2.0 * q[k:-k] + q[: -2 * k]) / H**2
        row.setdefault("noticed", []).append(1000.0 * (said - t_fault) if said is not None else float("nan"))
        row.setdefault("ran", []).append(float(np.max(ahead)))
        row.setdefault("back", []).append(float(np.max(np.maximum.accumulate(ahead, axis=0) - ahead)))
        row.setdefault("accel", []).append(float(np.max(np.abs(acc) / np.radians(actuator_limits_deg(arm)[1]))))
        row.setdefault("rate", []).append(rate)
    finally:
        watch.close()


def print_grbl_fault_table(rows: list[dict[str, Any]]) -> None:
    def cell(values: list[float], f: str) -> str:
        return f"{np.nanmedian(values):{f}} / {np.nanmax(values):{f}}"

    print(
        f"\n| GRBL ({ARM}) | fault mid-move, full speed | noticed in, ms | ran on after it, rad "
        "| back against its way, rad | change of speed / acceleration limit (+-10 ms) | state rate meanwhile, Hz |"
    )
    print("|---|---|---|---|---|---|---|")
    for r in rows:
        print(
            f"| grbl | {r['fault']} | {cell(r['noticed'], '.0f')} | {cell(r['ran'], '.3f')} "
            f"| {cell(r['back'], '.4f')} | {cell(r['accel'], '.2f')} | {np.min(r['rate']):.0f} (least) |"
        )
    print("\n(median / worst over the runs; GRBL's exact motion in the emulator, before its whole steps)")
