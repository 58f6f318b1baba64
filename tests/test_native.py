"""The compiled code, built ahead of time at install (armd.solvers._native): used, the same
answers as Numba's JIT to the last bits, and a service that never loads Numba. The JIT's
cache is filed by module, not by the checkout's path."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from armd import planning, robots, solvers
from armd.solvers import jit
from armd.solvers.arm import arm_state
from armd.solvers.packed import Packed, pack

ROOT = Path(__file__).resolve().parent.parent

PARITY = """
import json, sys
import numpy as np
from armd import planning, robots, solvers
from armd.solvers import jit
out = {"native": jit.NATIVE is not None}
for name in robots.names():
    arm = robots.load(name)
    rng = np.random.default_rng(7)
    qs = rng.uniform(arm.limits.lower, arm.limits.upper, size=(40, arm.nq))
    targets = [arm.fk(q) for q in qs] + [10.0 * arm.fk(arm.neutral) + 1.0]  # (and one out of reach)
    one = [solvers.solve_ik(arm, t) for t in targets]
    many = solvers.solve_ik_batch(arm, np.array(targets[:-1]))
    clear = arm.limits.contains(qs[0]) and arm.collision.first_contact(qs[0]) is None
    traj = planning.plan(arm, arm.neutral, qs[0] if clear else arm.neutral)
    out[name] = {"q": [r.q.tolist() for r in one], "status": [r.status for r in one],
                 "pitch": [r.pitch for r in one], "batch_q": many.q.tolist(), "plan": traj.position.tolist()}
print(json.dumps(out))
"""


def _run(code: str, **env: str) -> dict[str, object]:
    done = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, timeout=600, env={**os.environ, **env}
    )
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout.strip().splitlines()[-1])  # type: ignore[no-any-return]


def test_the_native_build_is_there_and_used() -> None:
    assert jit.NATIVE is not None, (
        "armd.solvers._native is missing or stale: reinstall armd (pip install -e '.[dev]') to build it"
    )
    assert jit.built_from(jit.NATIVE, jit.source_digest()) and not jit.built_from(jit.NATIVE, "0" * 16)
    # what the solver and the planner call (the compiled modules' own names may have been switched
    # to Numba's by a test that calls an inner function itself; under the tests, each is wrapped
    # in the signature check)
    for caller, name in (
        (solvers.ik, "solve_point"),
        (solvers.batch, "solve_many"),
        (planning.trajectory, "all_clear"),
    ):
        given = getattr(caller, name)
        assert getattr(given, "__wrapped__", given) is getattr(jit.NATIVE, name)


def test_a_call_with_the_wrong_arrays_is_refused_under_the_tests() -> None:
    """The native build reads what it is given as what its signature says; the tests' check
    refuses anything else (here an int array for a float one, a 2-D one for a 1-D one, an arm
    not packed, packed as another bundle, or in arrays not contiguous or of another type), and
    packing refuses a bundle whose arrays are of another type."""
    assert jit.CHECK
    pose = solvers.arm.arm_pose  # (a module Numba never switches: see jit._switch_to_numba)
    arm = robots.load("insomniac")
    state = arm_state(arm)
    packed, arrays = state.packed_arm, state.arrays
    assert packed is not None and arrays is not None and state.packed_family is not None
    out = np.empty(5)
    pose(packed, arm.neutral, out[:3])
    pose(packed, np.zeros((5, 2)).T[0], out[:3])  # (any strides: a column of a transposed array)
    with pytest.raises(TypeError, match="argument 1"):
        pose(packed, np.zeros(5, dtype=np.int64), out)
    with pytest.raises(TypeError, match="argument 2"):
        pose(packed, arm.neutral, np.empty((1, 3)))
    with pytest.raises(TypeError, match=r"argument 0 \(Arm\): an Arm, not a Packed"):
        pose(arrays, arm.neutral, out[:3])
    with pytest.raises(TypeError, match=r"argument 0 \(Arm\): a packed Family, should be a packed Arm"):
        pose(state.packed_family, arm.neutral, out[:3])
    with pytest.raises(TypeError, match=r"argument 0 \(Arm\): F is float32"):
        pose(Packed(packed.F.astype(np.float32), packed.I), arm.neutral, out[:3])
    with pytest.raises(TypeError, match=r"argument 0 \(Arm\): I is int64\[1d\], not a C-contiguous"):
        pose(Packed(packed.F, np.repeat(packed.I, 2)[::2]), arm.neutral, out[:3])
    short = packed.I.copy()
    short[1] -= 1
    with pytest.raises(TypeError, match=r"argument 0 \(Arm\): its header has 17 leaves, a packed Arm 18"):
        pose(Packed(packed.F, short), arm.neutral, out[:3])
    with pytest.raises(TypeError, match=r"family\.J is float64\[1d\], should be int64\[1d\]"):
        pack(arrays._replace(family=arrays.family._replace(J=np.zeros(4))))
    with pytest.raises(TypeError, match=r"sign is float64\[2d\]"):
        pack(arrays._replace(sign=np.ones((5, 2))))
    assert jit.parse_signature("Tuple((i8, f8))(f8[:], i8, f8[:, ::1], b1, f8[::1])") == [
        ("float64", 1, False),
        ("int64", 0, False),
        ("float64", 2, True),
        ("bool", 0, False),
        ("float64", 1, True),
    ]


def test_a_service_never_loads_numba() -> None:
    code = (
        "import sys, json; from armd import robots; from armd.service import server; "
        "[server._warm_arm(robots.load(n)) for n in robots.names()]; "
        "print(json.dumps(sorted(m for m in ('numba', 'llvmlite') if m in sys.modules)))"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, timeout=300)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip().splitlines()[-1] == "[]"


@pytest.mark.slow
def test_native_and_jit_give_the_same_answers() -> None:
    native = _run(PARITY)
    jitted = _run(PARITY, ARMD_NATIVE="0")
    assert native.pop("native") is True and jitted.pop("native") is False
    for name, got in native.items():
        want = jitted[name]
        assert got["status"] == want["status"], name  # type: ignore[index]
        for key in ("q", "pitch", "batch_q", "plan"):
            assert np.allclose(
                np.array(got[key], dtype=float),
                np.array(want[key], dtype=float),  # type: ignore[index]
                rtol=0,
                atol=1e-9,
            ), (name, key)


@pytest.mark.slow
def test_the_jit_cache_is_filed_by_module_not_by_checkout_path(tmp_path: Path) -> None:
    code = (
        "import json; from armd.solvers import analytic; "
        "impl = analytic.solve_point._cache._impl; "
        "print(json.dumps([impl.locator.get_cache_path(), type(impl.locator).root]))"
    )
    path, root = _run(code, ARMD_NATIVE="0", ARMD_CACHE_DIR=str(tmp_path))  # type: ignore[misc]
    assert path == os.path.join(root, "solvers") and root.startswith(str(tmp_path))
    assert str(ROOT) not in path
