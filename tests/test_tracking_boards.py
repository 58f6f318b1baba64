"""The tracking stream down to the controllers: the Feetech bus (the so101) on its emulator, with
its adapter as a user runs it, the real service and the client: what the servos did (their own
model) keeps every limit while the stream splices a trajectory in every 10 ms, and the arm
follows. The SSC-32 refuses streams for now (adapters/ssc32.py says why)."""

from __future__ import annotations

import contextlib
import math
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from armd import robots
from armd.adapters.emulators.feetech import FeetechEmulator
from armd.adapters.emulators.process import EmulatorProcess
from armd.clients import ArmClient
from tests.conftest import adapter_process, collect, wait_for
from tests.test_adapter_ssc32 import running_adapter
from tests.test_tracking import keep as hold

pytestmark = pytest.mark.slow  # (seconds: processes, emulated boards)

pytest.importorskip("scservo_sdk")

BENT = [0.3, -1.0, 1.2, 0.8, 0.0]  # the so101 bent, the tool before it: a circle there is far from its singular poses
FEETECH_ACCEL_BAR = 1.02  # (as tests/test_adapter_feetech.py: the servos' own limit, rounded; the measure's)
SSC32_ACCEL_BAR = 1.05  # (as tests/test_adapter_ssc32.py: the board's whole microseconds; the host's timing)


def across(centre: np.ndarray) -> np.ndarray:
    """The horizontal direction across the arm's reach at ``centre`` (a circle in the vertical
    plane across the reach keeps the arm away from its stretched and folded poses)."""
    side = np.array([-centre[1], centre[0], 0.0])
    return side / np.linalg.norm(side)


def on_circle(centre: np.ndarray, radius: float, a: float) -> np.ndarray:
    return centre + radius * (math.cos(a) * across(centre) + math.sin(a) * np.array([0.0, 0.0, 1.0]))


def circle(track: Any, centre: np.ndarray, radius: float, speed: float, seconds: float) -> None:
    """Targets on a circle in the vertical plane across the reach at ``speed`` m/s, put at 100 Hz
    on the test's clock, from angle 0 (where the test put the tool first)."""
    w = speed / radius
    t0 = time.monotonic()
    for k in range(int(seconds * 100)):
        track.send(target=on_circle(centre, radius, w * k / 100).tolist())
        time.sleep(max(0.0, t0 + (k + 1) / 100 - time.monotonic()))


def test_the_ssc32_refuses_a_stream_and_nothing_moves(
    router: str, client: ArmClient, service: Any, tmp_path: Path
) -> None:
    """Not yet on the SSC-32 (adapters/ssc32.py says why): its adapter refuses the stream's
    trajectories, said on the stream's events, and the board gets nothing."""
    arm = robots.load("insomniac")
    centre = arm.fk(arm.neutral) + np.array([0.0, -0.04, -0.05])
    with running_adapter(router, service, tmp_path) as (emu, _):
        since = emu.clock()
        with client.track("insomniac") as t:
            hold(t, 0.5, target=on_circle(centre, 0.04, 0.0).tolist())
            refused = t.wait_for("rejected")
        assert refused is not None and "does not follow a tracking stream" in refused.message
        first = arm.actuators.actuators[0].channel
        assert not [m for m in emu.history if m.time >= since and first in m.pulses]


def _servo_ratios(arm: robots.Robot, emu: Any, since: float) -> tuple[np.ndarray, np.ndarray]:
    """Each joint's fastest speed and hardest acceleration at the servos (the emulator's model,
    over 10 ms windows), over the limits."""
    vmax, amax = np.zeros(arm.nq), np.zeros(arm.nq)
    for j, act in enumerate(arm.actuators.actuators):
        trace = np.array([p for p in emu.trace(act.id) if p[0] >= since])
        if len(trace) < 3:
            continue
        t = np.arange(trace[0, 0], trace[-1, 0], 0.01)
        p = np.interp(t, trace[:, 0], trace[:, 1]) / act.counts_per_rad
        v = np.diff(p) / 0.01
        vmax[j] = np.max(np.abs(v)) / arm.limits.velocity[j]
        amax[j] = np.max(np.abs(np.diff(v) / 0.01)) / arm.limits.acceleration[j]
    return vmax, amax


@contextlib.contextmanager
def feetech_arm(router: str, service: Any, tmp_path: Path) -> Iterator[Any]:
    """The servos on an emulated bus (a process of its own) and ``armd adapter feetech so101`` on
    it as a user runs it (a process of its own, as the bus has its own CPUs), ready."""
    arm = robots.load("so101")
    with EmulatorProcess(FeetechEmulator, ids=[1, 2, 3, 4, 5, 6]) as emu:
        with adapter_process(["feetech", "so101", "--port", emu.port, "--connect", router], tmp_path):
            wait_for(lambda: service._adapter_count(arm) == 1, timeout=30, what="the adapter's token")
            yield emu
        wait_for(lambda: service._adapter_count(arm) == 0, timeout=10, what="the adapter gone")


def servo_joints(arm: robots.Robot, emu: Any) -> np.ndarray:
    at = emu.positions()
    return arm.actuators.joints_from_commands(np.array([at[a.id] for a in arm.actuators.actuators]), tol=np.inf)


def test_a_stream_on_the_feetech_bus_keeps_every_limit_at_the_servos(
    router: str, client: ArmClient, service: Any, tmp_path: Path
) -> None:
    arm = robots.load("so101")
    with feetech_arm(router, service, tmp_path) as emu:
        events, sub = collect(client, "armd/so101/events")
        centre = arm.fk(np.array(BENT))
        start = on_circle(centre, 0.04, 0.0)
        with client.track("so101", deadman=0.5) as t:
            hold(t, 1.5, target=start.tolist())
            since = time.monotonic()  # (the emulator's trace is on the same monotonic clock)
            circle(t, centre, 0.04, 0.15, 2.5)
            hold(t, 1.0, target=start.tolist())
            statuses = {e.status for e in t.events}
        time.sleep(0.3)
        sub.undeclare()  # type: ignore[attr-defined]
        # the promise, whatever happened: every servo within its limits
        vmax, amax = _servo_ratios(arm, emu, since)
        assert np.all(vmax <= 1.01), vmax
        assert np.all(amax <= FEETECH_ACCEL_BAR), amax
        faults = [e for e in events if e.get("event") == "fault"]
        if faults:  # (a busy host can hold a servo's reply past the adapter's patience: a fault, braked; said)
            assert all("does not answer" in str(e.get("reason")) for e in faults), faults
            if any(e.get("event") == "aborted" for e in events):  # (a trajectory of the stream aborted: it ended)
                assert "ended" in {e.status for e in t.events}
            return
        bad = [e for e in events if e.get("event") == "aborted"]
        assert not bad, [(e.get("event"), e.get("reason")) for e in bad]
        assert statuses <= {"started", "deadman"}, "; ".join(e.message for e in t.events)
        there = arm.fk(servo_joints(arm, emu))
        assert np.linalg.norm(there - start) < 0.005  # where it was held (the servos' counts: 1.5 mrad)
