"""The bus-servo part of bench/adapters.py: the Feetech adapter on the so101, the Dynamixel one
on the OpenManipulator-X, each on its emulated bus at 1 Mbaud (a process of its own), through
the vendor's SDK, the adapter and the service in this process.

Per bus: one sync read of every servo's state, as the adapter reads it (``Bus.read``: each reply
read with its error byte) and as the SDK's own ``GroupSyncRead`` reads it (the peer, the same
bytes, in the same run), against the wire's own time at the baud rate; the bus cycles a second
while a move runs (a sync write and a sync read each); the worst tracking error of a move (the
measured position against the plan, every cycle) against the joints' tolerance; and the stop's
latency, from ``stop`` asked mid-move to every servo still, against the stop's planned duration.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np
import zenoh

from armd import robots
from armd.adapters.emulators.dynamixel import DynamixelEmulator
from armd.adapters.emulators.feetech import FeetechEmulator
from armd.adapters.emulators.process import EmulatorProcess
from armd.clients import ArmClient
from armd.service.server import Service
from armd.service.zconfig import network_config

ROOT = Path(__file__).resolve().parent.parent
BAUD = 1_000_000


def _sdk_peer(kind: str, bus: Any, ids: list[int]) -> Any:
    """The SDK's own sync read of the same block: a callable."""
    if kind == "feetech":
        import scservo_sdk as sdk

        from armd.adapters.feetech import STATE, STATE_SIZE

        group = sdk.GroupSyncRead(bus.handler, bus.packets, STATE, STATE_SIZE)
    else:
        import dynamixel_sdk as sdk

        from armd.adapters.dynamixel import STATE, STATE_SIZE

        group = sdk.GroupSyncRead(bus.handler, bus.packets, STATE, STATE_SIZE)
    for i in ids:
        group.addParam(i)

    def read() -> None:
        bus.handler.ser.reset_input_buffer()
        assert group.txRxPacket() == sdk.COMM_SUCCESS

    return read


def _times(fn: Any, n: int) -> np.ndarray:
    out = []
    for _ in range(n):
        t = time.perf_counter()
        fn()
        out.append(time.perf_counter() - t)
    return np.array(out) * 1e3


def _still(emu: Any, ids: list[int]) -> bool:
    a = emu.positions()
    time.sleep(0.02)
    b = emu.positions()
    return max(abs(a[i] - b[i]) for i in ids) < 0.5


def bus_rows(runs: int) -> list[dict[str, Any]]:
    from armd.adapters.dynamixel import DynamixelAdapter
    from armd.adapters.feetech import FeetechAdapter

    cases = [
        (
            "feetech",
            robots.load("so101"),
            FeetechEmulator,
            [1, 2, 3, 4, 5, 6],
            FeetechAdapter,
            [0.8, 0.9, -0.7, 0.6, 1.2],
        ),
        (
            "dynamixel",
            robots.load_folder(ROOT / "examples" / "arms" / "openmanipulator-x"),
            DynamixelEmulator,
            [11, 12, 13, 14, 15],
            DynamixelAdapter,
            [0.6, 0.4, -0.3, 0.5],
        ),
    ]
    import socket

    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    endpoint = f"tcp/127.0.0.1:{s.getsockname()[1]}"
    s.close()
    router = zenoh.open(network_config(listen=[endpoint], mode="router"))
    rows = []
    try:
        for kind, arm, emulator, ids, adapter_cls, goal in cases:
            session = zenoh.open(network_config(connect=[endpoint]))
            service = Service(session, {arm.name: arm})
            client = ArmClient(endpoint, timeout=10.0)
            adapter_session = zenoh.open(network_config(connect=[endpoint]))
            row: dict[str, Any] = {"bus": kind, "arm": arm.name}
            try:
                with EmulatorProcess(emulator, ids=ids, baud=BAUD) as emu:
                    adapter = adapter_cls(adapter_session, arm, emu.port, baud=BAUD)
                    try:
                        joints = [a.id for a in arm.actuators.actuators]
                        with adapter._io:  # (the control loop waits: the bus is the bench's)
                            ours = _times(lambda: adapter.bus.read(joints), 300)  # noqa: B023
                            peer = _times(_sdk_peer(kind, adapter.bus, joints), 300)
                        state = 10 if kind == "feetech" else 21
                        header = 8 if kind == "feetech" else 14
                        reply = 6 if kind == "feetech" else 11
                        wire = ((header + len(joints)) + len(joints) * (reply + state)) * 10 / BAUD * 1e3
                        row.update(read=ours, peer=peer, wire=wire)
                        rates, worst, stops, planned = [], [], [], []
                        import json

                        accepted: list[float] = []
                        sub = client.session.declare_subscriber(
                            f"armd/{arm.name}/events",
                            lambda sample: accepted.extend(  # noqa: B023
                                [e["duration"]]
                                if (e := json.loads(sample.payload.to_bytes())).get("event") == "accepted"
                                and e.get("trajectory") == "stop"
                                else []
                            ),
                        )
                        home = [0.0] * arm.nq
                        for _ in range(runs):
                            for target in (goal, home):
                                n0, t0 = adapter._cycles, time.monotonic()
                                client.move(arm.name, target, wait=True, wait_timeout=20)
                                rates.append((adapter._cycles - n0) / (time.monotonic() - t0))
                                worst.append(float(np.max(adapter.tracking / arm.tracking_tolerance)))
                                row.setdefault("track_rad", []).append(float(np.max(adapter.tracking)))
                            r = client.move(arm.name, goal)
                            time.sleep(0.4 * r.duration)
                            asked = time.monotonic()
                            client.stop(arm.name)
                            while not _still(emu, joints):
                                pass
                            latency = time.monotonic() - asked - 0.02
                            stops.append(latency)
                            planned.append(accepted[-1] if accepted else float("nan"))
                            time.sleep(0.3)
                            client.move(arm.name, home, wait=True, wait_timeout=20)
                        sub.undeclare()
                        row.update(rate=rates, tracking=worst, stop=stops, planned=planned)
                    finally:
                        adapter.close()
            finally:
                client.close()
                service.close()
                adapter_session.close()
                session.close()
            rows.append(row)
    finally:
        router.close()
    return rows


def print_table(rows: list[dict[str, Any]]) -> None:
    print(
        "\n| bus (arm) | sync read, armd's: median / p99 ms | the SDK's GroupSyncRead (peer) | the wire's time "
        "| cycles a second in a move | worst tracking error / tolerance (rad) | stop: asked to still, s (planned) |"
    )
    print("|---|---|---|---|---|---|---|")
    for r in rows:
        read, peer = r["read"], r["peer"]
        print(
            f"| {r['bus']} ({r['arm']}) | {np.median(read):.2f} / {np.percentile(read, 99):.2f} "
            f"| {np.median(peer):.2f} / {np.percentile(peer, 99):.2f} (x{np.median(read) / np.median(peer):.2f}) "
            f"| {r['wire']:.2f} | {np.median(r['rate']):.0f} (min {np.min(r['rate']):.0f}) "
            f"| {np.median(r['tracking']):.2f} / {np.max(r['tracking']):.2f} ({np.max(r['track_rad']):.3f}) "
            f"| {np.median(r['stop']):.2f} / {np.max(r['stop']):.2f} ({np.median(r['planned']):.2f}) |"
        )
    print("\n(1 Mbaud; the emulators' buses in processes of their own; median / worst over the moves)")
