"""The codebase's own checks: ruff (lint, import order) and mypy, as configured in pyproject.toml,
and the layers' one-way imports (robots -> solvers -> planning -> service -> clients)."""

from __future__ import annotations

import ast
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
LAYERS = ["robots", "solvers", "planning", "service", "clients"]


def _tool(name: str) -> list[str]:
    exe = Path(sys.executable).parent / name
    if exe.exists():
        return [str(exe)]
    found = shutil.which(name)
    if not found:
        pytest.fail(f"{name} is not installed: install the dev extra, pip install -e '.[dev]'")
    return [found]


def test_ruff_is_clean() -> None:
    out = subprocess.run([*_tool("ruff"), "check", "."], cwd=ROOT, capture_output=True, text=True)
    assert out.returncode == 0, out.stdout + out.stderr


def test_mypy_is_clean(tmp_path: Path) -> None:
    """mypy over the armd package. mypy does not follow the editable install's finder (armd.robots
    is robots/), so it reads the package through a tree of links laid out as it is installed."""
    tree = tmp_path / "armd"
    tree.mkdir()
    (tree / "__init__.py").symlink_to(ROOT / "src" / "armd" / "__init__.py")
    for layer in LAYERS:
        (tree / layer).symlink_to(ROOT / layer, target_is_directory=True)
    env = {**os.environ, "MYPYPATH": str(tmp_path)}
    out = subprocess.run([*_tool("mypy"), "-p", "armd"], cwd=ROOT, capture_output=True, text=True, env=env)
    assert out.returncode == 0, out.stdout + out.stderr


def test_layers_import_one_way() -> None:
    """A layer may import only the layers before it in the data flow."""
    problems = []
    for rank, layer in enumerate(LAYERS):
        allowed = set(LAYERS[: rank + 1])
        for path in (ROOT / layer).rglob("*.py"):
            tree = ast.parse(path.read_text(), str(path))
            for node in ast.walk(tree):
                names = []
                if isinstance(node, ast.Import):
                    names = [a.name for a in node.names]
                elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module == "armd":
                    names = [f"armd.{a.name}" for a in node.names]  # from armd import robots
                elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                    names = [node.module]
                for name in names:
                    parts = name.split(".")
                    if parts[0] in LAYERS:
                        problems.append(f"{path.relative_to(ROOT)} imports {name}: import armd.{name} instead")
                    elif parts[0] == "armd" and len(parts) > 1 and parts[1] in LAYERS and parts[1] not in allowed:
                        problems.append(f"{path.relative_to(ROOT)} imports {name}")
    assert not problems, "\n".join(problems)


def test_one_package_at_the_top_of_site_packages(tmp_path: Path) -> None:
    """Installed, armd is one package: its layers import as armd.robots and the rest, and none
    of the five generic names (all taken on PyPI) is importable on its own."""
    script = ("import importlib.util, json; import armd.robots, armd.clients; "
              "print(json.dumps([importlib.util.find_spec(n) is not None for n in "
              "('robots', 'solvers', 'planning', 'service', 'clients')]))")
    out = subprocess.run([sys.executable, "-c", script], cwd=tmp_path, capture_output=True, text=True)  # (not the repo)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "[false, false, false, false, false]", out.stdout


def test_the_client_library_loads_no_pinocchio(tmp_path: Path) -> None:
    """A client needs Zenoh, orjson and NumPy: importing armd.clients loads no Pinocchio, no
    Numba, no Ruckig (the models, the solver's compiled code and the planner are the service's)."""
    script = ("import sys, json; import armd.clients; "
              "print(json.dumps(sorted(m for m in ('pinocchio', 'numba', 'ruckig') if m in sys.modules)))")
    out = subprocess.run([sys.executable, "-c", script], cwd=tmp_path, capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "[]", out.stdout
