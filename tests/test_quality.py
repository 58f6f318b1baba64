"""The package's shape: the layers' one-way imports (robots -> solvers -> planning -> service ->
clients, the adapters beside the client, the tools and the CLI on top), no import cycle between
files, one package in site-packages, a client library without Pinocchio. (Lint, formatting and
types are not tests: .ci/lint runs ruff, ruff format and mypy.)"""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
LAYERS = ["robots", "solvers", "planning", "service", "clients", "adapters", "tools", "cli"]
# What each layer may import (besides itself): the data flow, one way.
ALLOWED = {
    "robots": set(),
    "solvers": {"robots"},
    "planning": {"robots", "solvers"},
    "service": {"robots", "solvers", "planning"},
    "clients": {"robots", "service"},  # (the wire: service.protocol's encoding, service.zconfig's sessions)
    "adapters": {"robots", "planning", "service"},  # (not the client: adapters speak the keys themselves)
    "tools": {"robots", "solvers", "planning", "service", "clients", "adapters"},
    "cli": {"robots", "solvers", "planning", "service", "clients", "adapters", "tools"},
}


def _imports(path: Path) -> list[str]:
    """Every module ``path`` imports, anywhere in it (inside functions too), as absolute names;
    ``from X import name`` counts as X.name (a submodule, or a name of X: the caller resolves)."""
    rel = path.relative_to(ROOT).with_suffix("")
    dotted = ["armd", *rel.parts] if rel.parts[0] in LAYERS else list(rel.parts)
    package = dotted[:-1]  # (a package's __init__: the package itself)
    out = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            out += [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package[: len(package) - (node.level - 1)]
                module = ".".join([*base, *([node.module] if node.module else [])])
            else:
                module = node.module or ""
            out += [f"{module}.{a.name}" for a in node.names]
    return out


def test_layers_import_one_way() -> None:
    """A layer may import only the layers :data:`ALLOWED` for it."""
    assert set(ALLOWED) == set(LAYERS)
    problems = []
    for layer in LAYERS:
        for path in (ROOT / layer).rglob("*.py"):
            for name in _imports(path):
                parts = name.split(".")
                if parts[0] in LAYERS:
                    problems.append(f"{path.relative_to(ROOT)} imports {name}: import armd.{name} instead")
                elif (
                    parts[0] == "armd"
                    and len(parts) >= 2
                    and parts[1] in LAYERS
                    and parts[1] != layer
                    and parts[1] not in ALLOWED[layer]
                ):
                    problems.append(f"{path.relative_to(ROOT)} imports {'.'.join(parts[:3])}")
    assert not problems, "\n".join(problems)


def _modules() -> dict[str, Path]:
    """Every module of the package: its name and its file."""
    found = {}
    for layer in LAYERS:
        for path in (ROOT / layer).rglob("*.py"):
            rel = path.relative_to(ROOT).with_suffix("")
            parts = ["armd", *rel.parts]
            if parts[-1] == "__init__":
                parts = parts[:-1]
            found[".".join(parts)] = path
    return found


def test_no_import_cycles_between_files() -> None:
    """No file imports one that imports it back, directly or round a loop (a package's
    ``__init__``, which only gathers its files' names, does not count as an importer)."""
    modules = _modules()
    graph: dict[str, set[str]] = {}
    for name, path in modules.items():
        if path.name == "__init__.py":
            continue
        targets = set()
        for imported in _imports(path):
            while imported and imported not in modules:  # X.name: the module X
                imported = imported.rpartition(".")[0]
            if imported and imported != name and modules[imported].name != "__init__.py":
                targets.add(imported)
        graph[name] = targets
    cycles = []
    state: dict[str, int] = {}  # 1: on the path, 2: done

    def visit(node: str, trail: list[str]) -> None:
        state[node] = 1
        for nxt in sorted(graph.get(node, ())):
            if state.get(nxt) == 1:
                cycles.append(" -> ".join([*trail[trail.index(nxt) :], nxt]))
            elif nxt not in state:
                visit(nxt, [*trail, nxt])
        state[node] = 2

    for node in sorted(graph):
        if node not in state:
            visit(node, [node])
    assert not cycles, "\n".join(cycles)


def test_one_package_at_the_top_of_site_packages(tmp_path: Path) -> None:
    """Installed, armd is one package: its layers import as armd.robots and the rest, and none
    of the five generic names (all taken on PyPI) is importable on its own."""
    script = (
        "import importlib.util, json; import armd.robots, armd.clients; "
        "print(json.dumps([importlib.util.find_spec(n) is not None for n in "
        "('robots', 'solvers', 'planning', 'service', 'clients')]))"
    )
    out = subprocess.run([sys.executable, "-c", script], cwd=tmp_path, capture_output=True, text=True)  # (not the repo)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "[false, false, false, false, false]", out.stdout


def test_the_client_library_loads_no_pinocchio(tmp_path: Path) -> None:
    """A client needs Zenoh, orjson and NumPy: importing armd.clients loads no Pinocchio, no
    Numba, no Ruckig (the models, the solver's compiled code and the planner are the service's)."""
    script = (
        "import sys, json; import armd.clients; "
        "print(json.dumps(sorted(m for m in ('pinocchio', 'numba', 'ruckig') if m in sys.modules)))"
    )
    out = subprocess.run([sys.executable, "-c", script], cwd=tmp_path, capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "[]", out.stdout
