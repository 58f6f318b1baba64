"""``armd demo`` end to end, as a user runs it: a separate process that ends by itself."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from armd import robots

pytestmark = pytest.mark.slow  # (seconds: processes, routers, emulated boards; `pytest -m "not slow"` skips it)

ROOT = Path(__file__).resolve().parent.parent
CASES = ["ik parallel", "ik perpendicular", "ik free", "ik unreachable", "joint move", "line move", "stop"]
SEED000 = ["seed000 detect", "seed000 pick", "seed000 place"]  # the insomniac's: seed 000's scenario


def test_demo_runs_every_case_on_every_arm(tmp_path: Path) -> None:
    out = tmp_path / "demo"
    r = subprocess.run(
        [sys.executable, "-m", "armd.cli", "demo", "--out", str(out), "--time-scale", "4"],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=120,
    )
    assert r.returncode == 0, r.stderr
    assert "Traceback" not in r.stderr
    rows = json.loads((out / "demo.json").read_text())
    arms = robots.names()
    lines = r.stdout.splitlines()
    for arm in arms:
        cases = {row["case"]: row for row in rows if row["arm"] == arm}
        assert set(cases) == set(CASES) | (set(SEED000) if arm == "insomniac" else set()), (arm, sorted(cases))
        for case in CASES:  # one table row per arm and case, as printed
            assert any(line.startswith(arm) and case in line for line in lines), (arm, case)
        assert cases["ik free"]["status"] == "ok" and cases["ik free"]["error_m"] < 1e-9
        assert cases["ik unreachable"]["status"] == "unreachable" and cases["ik unreachable"]["error_m"] > 0.1
        assert cases["joint move"]["status"] == "done" and cases["joint move"]["error_m"] < 1e-6
        assert cases["line move"]["status"] == "done" and cases["line move"]["error_m"] < 1e-6
        assert cases["stop"]["status"] == "stopped"
        for png in (f"{arm}-joint-move.png", f"{arm}-line-move.png", f"{arm}-workspace.png"):
            assert (out / png).stat().st_size > 10_000, png
    arm_of = {row["arm"]: robots.load(row["arm"]) for row in rows}
    for row in rows:  # an approach an arm cannot take is refused with the protocol's code, not faked
        wrist = arm_of[row["arm"]].geometry.wrist is not None  # type: ignore[union-attr]
        if row["case"] in ("ik parallel", "ik perpendicular") and not wrist and row["arm"] == "gupta3":
            assert row["status"] == "bad_request"
        elif row["case"] in ("ik parallel", "ik perpendicular") and wrist:
            assert row["status"] == "ok", row
    assert f"{len(rows)} requests on {len(arms)} arms" in r.stdout
    # seed 000's scenario: the scanners found the can where it stood, the arm picked it and put it
    # down on its left, and there it stands (the simulator's floor)
    seed = {row["case"]: row for row in rows if row["case"] in SEED000}
    assert seed["seed000 detect"]["status"] == "stable" and seed["seed000 detect"]["error_m"] < 0.005
    assert seed["seed000 pick"]["status"] == "done"
    assert seed["seed000 place"]["status"] == "done" and seed["seed000 place"]["error_m"] < 0.005
    x, y = json.loads(seed["seed000 place"]["request"])
    assert y > 0.2 and abs(x) < 0.1  # (a quarter turn to the arm's left)


def test_demo_unknown_arm_is_an_error(tmp_path: Path) -> None:
    r = subprocess.run(
        [sys.executable, "-m", "armd.cli", "demo", "nosuch", "--out", str(tmp_path / "d")],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=60,
    )
    assert r.returncode == 1 and "unknown robot" in r.stderr
    assert not (tmp_path / "d").exists()
