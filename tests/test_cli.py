"""The armd command line, run as a user runs it: a separate process."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path


def armd(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "clients.cli", *args], capture_output=True, text=True,
                          cwd=Path(__file__).resolve().parent.parent, timeout=120)


def test_catalogue_lists_every_arm() -> None:
    out = armd("catalogue")
    assert out.returncode == 0, out.stderr
    for name in ("insomniac", "sg5ut", "gupta3", "desk4"):
        assert f"{name}:" in out.stdout
    assert "coupled linkage" in out.stdout


def test_catalogue_json() -> None:
    out = armd("catalogue", "--json")
    data = json.loads(out.stdout)
    assert data["gupta3"]["joints"][2]["name"] == "elbow"
    assert data["desk4"]["coupled_limits"][0]["upper"] == 0.9


def test_bad_robots_dir_is_a_clear_error(tmp_path: Path) -> None:
    out = armd("catalogue", "--robots-dir", str(tmp_path / "nowhere"))
    assert out.returncode == 2
    assert "armd: error:" in out.stderr and "is not a folder" in out.stderr
    assert "Traceback" not in out.stderr
