"""The insomniac's range sensors wired to its SSC-32U (seed 000): the SSC-32 adapter steps the
scanners' servos through their sweeps, reads the GP2D12s and the gripper's GP2D120 on the board's
analog inputs, and streams the readings; the service's ``detect`` finds the objects in them.

The board is the emulator (its ``V*`` reads as the SSC-32U guide has them); the sensors on its
pins are :class:`AnalogWorld`: each beam cast into a world of objects along the scanning servo's
angle as the board outputs it, through the datasheets' curves, measured once a period."""

from __future__ import annotations

import json
import math
import time
from typing import Any

import numpy as np
import pytest
import zenoh

from armd import robots
from armd.adapters.emulators.ssc32 import SSC32Emulator
from armd.adapters.sim_sensors import AnalogWorld, objects_of
from armd.adapters.ssc32 import SSC32Adapter
from armd.clients import ArmClient
from armd.errors import RobotFileError
from tests.conftest import wait_for

CAN = {"name": "can", "shape": "cylinder", "size": [0.03, 0.12], "position": [0.40, 0.10]}
POST = {"name": "post", "shape": "cylinder", "size": [0.02, 0.20], "position": [0.30, -0.25]}


def test_the_adapter_scans_and_detect_finds_the_objects(
    client: ArmClient, service: object, adapter_session: zenoh.Session
) -> None:
    arm = robots.load("insomniac")
    world = AnalogWorld(arm, objects_of([CAN, POST]), seed=3)
    readings: list[dict[str, Any]] = []
    sub = adapter_session.declare_subscriber(
        "armd/insomniac/sensors/*", lambda s: readings.append(json.loads(s.payload.to_bytes()))
    )
    with SSC32Emulator() as emu:
        emu.analog = world.volts
        adapter = SSC32Adapter(adapter_session, arm, emu.port)
        try:
            wait_for(lambda: service._adapter_count(arm) == 1, what="the adapter's token")  # type: ignore[attr-defined]
            found = client.detect("insomniac", sweeps=2, wait=60.0)["objects"]  # (a sweep: about 8 s)
            assert [round(o["position"][1], 1) for o in found] == [-0.2, 0.1]  # the post, then the can
            for o, truth in zip(found, (POST, CAN), strict=True):
                err = math.dist(o["position"][:2], truth["position"])
                assert o["stable"] and err <= 3 * o["uncertainty"], (o, err)
            # the scanners' servos went through their sweeps on channels 6 and 7, never elsewhere
            for ch in (6, 7):
                pulses = [p for t0, t1, p0, p1 in emu.segments(ch) for p in (p0, p1) if p > 0]  # (0: before the first)
                assert min(pulses) == pytest.approx(1500 - 636.6, abs=1) and max(pulses) == pytest.approx(2136.6, abs=1)
            arm_channels = {a.channel for a in arm.actuators.actuators}  # type: ignore[union-attr]
            assert all(set(m.pulses) <= arm_channels or set(m.pulses) <= {6, 7} for m in emu.history)
        finally:
            adapter.close()
            sub.undeclare()
    scans = [r for r in readings if r["sensor"] == "et_left"]
    gripper = [r for r in readings if r["sensor"] == "gripper_et"]
    assert gripper and all(r["bearing"] is None for r in gripper)
    # a reading a step: bearings 2 degrees apart, in order, reversing at the ends
    steps = np.diff([r["bearing"] for r in scans if r["sweep"] == scans[-1]["sweep"] - 1])
    assert np.allclose(np.abs(steps), arm.sensors["et_left"].sweep_step, atol=1e-6)
    # the volts are the board's whole counts of 5/256 V; a reading of the can near its bearing
    assert all(abs(r["volts"] * 256 / 5 - round(r["volts"] * 256 / 5)) < 0.01 for r in scans)  # (to 4 decimals)
    bearing = math.atan2(0.10 - 0.10, 0.40 - 0.12)  # et_left at (0.12, 0.10): the can straight ahead
    near = min(scans, key=lambda r: abs(r["bearing"] - bearing))
    assert near["range"] == pytest.approx(0.28 - 0.03, abs=0.02)


@pytest.mark.parametrize(
    ("edit", "field", "said"),
    [
        (('pin = "B"', 'pin = "A"'), "pin", "already 'et_left'"),
        (('pin = "B"', 'pin = "J"'), "pin", "A to H"),
        (("channel = 7", "channel = 3"), "channel", "already 'wrist'"),
        (("channel = 7", "channel = 7\nsweep = [-2.0, 2.0]"), None, "outside [500.0, 2500.0] us"),
        (("channel = 7", "centre_pulse = 1400"), "channel", "needs both"),
    ],
)
def test_wiring_that_cannot_be_is_refused_at_load(
    arm_copy: Any, edit: tuple[str, str], field: str | None, said: str
) -> None:
    folder = arm_copy("insomniac", toml_edits=[edit])
    with pytest.raises(RobotFileError) as e:
        robots.load_dir(folder)
    assert (e.value.field or "").startswith("sensors[") and said in e.value.problem, e.value
    if field:
        assert e.value.field.endswith(field)  # type: ignore[union-attr]


@pytest.mark.slow
def test_by_hand_emulator_serve_adapter_and_detect_as_processes(tmp_path: Any) -> None:
    """What docs/sensors.md tells a user to run: the emulated board with the insomniac's
    sensors wired to it (``--robot``, ``--objects``), ``armd serve``, ``armd adapter ssc32``,
    then ``armd detect``, which keeps asking while the sweeps come (``--wait``)."""
    import signal
    import subprocess
    import sys
    from pathlib import Path

    from armd.service.zconfig import free_endpoint

    root = Path(__file__).resolve().parent.parent
    objects = tmp_path / "objects.json"
    objects.write_text(json.dumps({"insomniac": [CAN]}))
    endpoint = free_endpoint()

    def start(*args: str) -> subprocess.Popen[str]:
        return subprocess.Popen(
            [sys.executable, "-m", *args], cwd=root, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
        )

    board = start("armd.adapters.emulators.ssc32", "--robot", "insomniac", "--objects", str(objects))
    serve = start("armd.cli", "serve", "--listen", endpoint)
    procs = [board, serve]
    try:
        assert board.stdout is not None and serve.stdout is not None
        port = board.stdout.readline().strip()
        assert port.startswith("/dev/"), board.stderr.read() if board.poll() is not None else port
        while "armd serving" not in serve.stdout.readline():
            assert serve.poll() is None, serve.stderr.read()  # type: ignore[union-attr]
        procs.append(start("armd.cli", "adapter", "ssc32", "insomniac", "--port", port, "--connect", endpoint))
        with ArmClient(endpoint) as c:
            wait_for(lambda: c.call("insomniac/info", {})["adapters"] == 1, timeout=60, what="the adapter")
        out = subprocess.run(
            [sys.executable, "-m", "armd.cli", "detect", "insomniac", "--wait", "60", "--connect", endpoint],
            cwd=root,
            capture_output=True,
            text=True,
            timeout=120,
        )
        assert out.returncode == 0, out.stderr
        lines = out.stdout.splitlines()
        assert lines[0] == "1 object(s) seen by et_left, et_right over 2 sweep(s)", out.stdout
        x, y = (float(v) for v in lines[1].split("[")[1].split("]")[0].split(",")[:2])
        assert math.dist((x, y), CAN["position"]) < 0.015 and "stable" in lines[1], lines[1]
    finally:
        for p in reversed(procs):
            p.send_signal(signal.SIGINT if p is not serve else signal.SIGTERM)
            try:
                p.wait(timeout=20)
            except subprocess.TimeoutExpired:
                p.kill()


def test_a_reset_board_or_a_late_answer_publishes_nothing_false(
    client: ArmClient, service: object, adapter_session: zenoh.Session
) -> None:
    """Found by a review. A board power-cycled under the adapter: no reading is published from it
    (its scanners' servos are not where they were sent, its arm's pulses are off: a fault).
    An answer held past the timeout: its late bytes are not taken for the next one (the adapter
    waits for the link to go quiet), so it recovers from where the board truly is."""
    arm = robots.load("insomniac")
    world = AnalogWorld(arm, objects_of([CAN]), seed=1)
    got: list[tuple[float, dict[str, Any]]] = []
    sub = adapter_session.declare_subscriber(
        "armd/insomniac/sensors/*", lambda s: got.append((time.monotonic(), json.loads(s.payload.to_bytes())))
    )
    with SSC32Emulator() as emu:
        emu.analog = world.volts
        adapter = SSC32Adapter(adapter_session, arm, emu.port)
        try:
            wait_for(lambda: len(got) >= 6, timeout=10, what="readings")
            # an answer held 0.7 s on its way (past the 0.5 s timeout), sensors' bytes and all
            emu.delay_input(0.7)
            wait_for(lambda: adapter.fault is not None, timeout=5, what="the timeout's fault")
            wait_for(lambda: adapter.fault is None, timeout=10, what="the recovery")
            assert np.allclose(adapter.measure().position, arm.neutral, atol=0.02)
            client.move("insomniac", [0.3, 1.2, -1.0, -0.2, 0.1], wait=True, wait_timeout=15)
            # the board powered off and on: nothing published from it
            emu.power_cycle()
            cycled = time.monotonic()
            wait_for(lambda: adapter.fault is not None, timeout=5, what="the reset's fault")
            time.sleep(0.5)
            assert not [r for t, r in got if t > cycled + 0.05], "a reading from a board just reset"
        finally:
            adapter.close()
            sub.undeclare()
