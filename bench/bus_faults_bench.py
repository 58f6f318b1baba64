"""The bus servos' fault table of bench/adapters.py: each fault injected mid-move at full speed on
the emulated bus (a process of its own, 1 Mbaud), the adapter and the service in this process.

Per bus and fault: when the fault was noticed (from its injection to the adapter's ``fault``
event; for the operator's ``stop``, the row to compare with, to its ``accepted``), how far the
arm ran on after it (the joint that ran farthest), how far any joint went back against its way
(the old adapter: 0.27-0.41 rad), the hardest braking of a servo that kept its torque against
its acceleration limit (at the servos, over 10 ms), and the state's rate meanwhile (50 Hz
asked). Medians and worst over the runs.
"""

from __future__ import annotations

import math
import socket
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import zenoh
from fault_watch import ArmWatch

from armd import robots
from armd.adapters.emulators.dynamixel import DynamixelEmulator
from armd.adapters.emulators.feetech import FeetechEmulator
from armd.adapters.emulators.measure import braking, bus_joint_traces
from armd.adapters.emulators.process import EmulatorProcess
from armd.clients import ArmClient
from armd.service.server import Service
from armd.service.zconfig import network_config

ROOT = Path(__file__).resolve().parent.parent
AFTER = 1.5  # [s] watched after the fault

# name: (inject(emulator, client, arm, servo id), which servos lose their torque: none, the one, all)
FAULTS: dict[str, tuple[Callable[[Any, ArmClient, str, int], None], str]] = {
    "stop (an operator's)": (lambda emu, c, name, i: c.stop(name), "none"),
    "alarm (voltage)": (lambda emu, c, name, i: emu.set_voltage(3.0), "none"),
    "overload (lets go)": (lambda emu, c, name, i: emu.trip_overload(i), "one"),
    "30 replies lost": (lambda emu, c, name, i: emu.drop_replies(i, 30), "none"),
    "silent servo": (lambda emu, c, name, i: emu.silence(i), "one"),  # (it hears nothing: braked by none)
    "power cycle": (lambda emu, c, name, i: emu.power_cycle(), "all"),
}


@dataclass(frozen=True)
class Case:
    """One bus: its arm, its emulator and servo ids, its adapter, a start and a far goal, and
    when in the move [s] the goal's fastest joint cruises at its velocity limit."""

    bus: str
    arm: robots.Robot
    emulator: type[Any]
    ids: list[int]
    adapter: Any
    start: list[float]
    goal: list[float]
    cruise: float


def _cases() -> list[Case]:
    from armd.adapters.dynamixel import DynamixelAdapter
    from armd.adapters.feetech import FeetechAdapter

    return [
        Case(
            "feetech",
            robots.load("so101"),
            FeetechEmulator,
            [1, 2, 3, 4, 5, 6],
            FeetechAdapter,
            [-1.0, 0.0, 0.0, -0.6, -1.2],
            [1.0, 0.9, -0.7, 0.6, 1.4],
            0.5,
        ),
        Case(
            "dynamixel",
            robots.load_folder(ROOT / "examples" / "arms" / "openmanipulator-x"),
            DynamixelEmulator,
            [11, 12, 13, 14, 15],
            DynamixelAdapter,
            [-1.5, 0.0, 0.0, 0.0],
            [1.5, 0.4, -0.3, 0.5],
            0.6,
        ),
    ]


def fault_rows(runs: int) -> list[dict[str, Any]]:
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    endpoint = f"tcp/127.0.0.1:{s.getsockname()[1]}"
    s.close()
    router = zenoh.open(network_config(listen=[endpoint], mode="router"))
    rows: list[dict[str, Any]] = []
    try:
        for case in _cases():
            session = zenoh.open(network_config(connect=[endpoint]))
            service = Service(session, {case.arm.name: case.arm})
            client = ArmClient(endpoint, timeout=10.0)
            try:
                for fault in FAULTS:
                    row: dict[str, Any] = {"bus": case.bus, "arm": case.arm.name, "fault": fault}
                    for _ in range(runs):
                        _one(row, case, fault, (session, service, client))
                    rows.append(row)
            finally:
                client.close()
                service.close()
                session.close()
    finally:
        router.close()
    return rows


def _one(row: dict[str, Any], case: Case, fault: str, rig: tuple[zenoh.Session, Service, ArmClient]) -> None:
    """One run of ``fault`` on ``case``'s bus, its figures added to ``row``."""
    session, service, client = rig
    arm = case.arm
    inject, limp = FAULTS[fault]

    with EmulatorProcess(case.emulator, ids=case.ids) as emu:
        adapter = case.adapter(session, arm, emu.port)
        watch = ArmWatch(client.session, arm.name)
        try:
            end = time.monotonic() + 10
            while service._adapter_count(arm) != 1 and time.monotonic() < end:
                time.sleep(0.01)
            client.move(arm.name, case.start, wait=True, wait_timeout=20)
            r = client.move(arm.name, case.goal)
            while not watch.started(r.id):
                time.sleep(0.002)
            time.sleep(case.cruise)
            culprit = arm.actuators.actuators[1].id
            t_fault = time.monotonic()
            inject(emu, client, arm.name, culprit)
            time.sleep(AFTER)
            until = time.monotonic()
            said = watch.first(t_fault, ("fault", "accepted"))
            rate = watch.state_rate(t_fault + 0.2, until)
            row.setdefault("noticed", []).append(1000.0 * (said - t_fault) if said is not None else float("nan"))
            ran = back = accel = 0.0
            for j, trace in enumerate(bus_joint_traces(arm, emu)):
                b = braking(trace, t_fault, until)
                ran, back = max(ran, b.travel), max(back, b.back)
                if limp == "none" or (limp == "one" and j != 1):
                    accel = max(accel, b.acceleration / float(arm.limits.acceleration[j]))
                elif limp == "all":
                    accel = math.nan
            row.setdefault("ran", []).append(ran)
            row.setdefault("back", []).append(back)
            row.setdefault("accel", []).append(accel)
            row.setdefault("rate", []).append(rate)
        finally:
            watch.close()
            adapter.close()


def print_fault_table(rows: list[dict[str, Any]]) -> None:
    def cell(values: list[float], f: str) -> str:
        return f"{np.nanmedian(values):{f}} / {np.nanmax(values):{f}}"

    print(
        "\n| bus (arm) | fault mid-move, full speed | noticed in, ms | ran on after it, rad "
        "| back against its way, rad | braking / acceleration limit (servos with torque) | state rate meanwhile, Hz |"
    )
    print("|---|---|---|---|---|---|---|")
    for r in rows:
        braked = "- (all let go)" if np.all(np.isnan(r["accel"])) else cell(r["accel"], ".2f")
        print(
            f"| {r['bus']} ({r['arm']}) | {r['fault']} | {cell(r['noticed'], '.0f')} | {cell(r['ran'], '.3f')} "
            f"| {cell(r['back'], '.4f')} | {braked} | {np.min(r['rate']):.0f} (least) |"
        )
    print("\n(median / worst over the runs; at the servos, the emulators' model; 50 Hz asked of the state)")
