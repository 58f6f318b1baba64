"""Bundles packed for the compiled code (solvers/packed.py): every registered bundle of every
catalogue arm comes back from its hand-written compiled unpacker (arrays.arm_of,
collide.shapes_of ...) exactly as it went in, leaf by leaf, on the packed memory; that guards
the unpackers' leaf indices against the registered fields."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from armd import robots
from armd.solvers import arrays, atlas, collide, kinematics, tree
from armd.solvers.arm import _atlas, arm_state, exact_chain, family_arrays
from armd.solvers.jit import TUPLES
from armd.solvers.packed import HEADER, Packed, code_of, leaves, pack, unpacked
from armd.solvers.world import compile_world, compiled

# each registered bundle: its compiled unpacker, called from Python (Numba compiles it lazily
# under the native build: jit._switch_to_numba)
UNPACKERS = {
    "Arm": lambda p: arrays.arm_of(p),
    "Family": lambda p: arrays.family_at(p, 0),
    "Chain": lambda p: kinematics.chain_of(p),
    "Atlas": lambda p: atlas.atlas_of(p),
    "Shapes": lambda p: collide.shapes_of(p),
    "Tree": lambda p: tree.tree_at(p, 0),
}


def same(got: Any, want: Any, name: str, path: str = "") -> None:
    """``got`` is the bundle ``want`` field by field: each array of the same dtype, shape and
    bits, each scalar of the same type and value."""
    assert type(got) is type(want), path
    for field, spec in TUPLES[name][1]:
        g, w = getattr(got, field), getattr(want, field)
        where = f"{path}{field}"
        if isinstance(spec, str):
            same(g, w, spec, where + ".")
        elif spec[1]:
            assert isinstance(g, np.ndarray) and g.flags.c_contiguous, where
            assert g.dtype == w.dtype and g.shape == w.shape, (where, g.dtype, g.shape, w.dtype, w.shape)
            assert g.tobytes() == w.tobytes(), where
        else:
            assert type(g) is type(w) and g == w, (where, g, w)


def array_leaves(bundle: Any, name: str) -> list[np.ndarray]:
    out = []
    for field, spec in TUPLES[name][1]:
        item = getattr(bundle, field)
        if isinstance(spec, str):
            out += array_leaves(item, spec)
        elif spec[1]:
            out.append(item)
    return out


def bundles(name: str) -> dict[str, tuple[Packed, Any]]:
    """Every registered bundle of the catalogue arm ``name``, packed as the solver and the
    compiled world keep it, with the named tuple it was packed from (built anew)."""
    robot = robots.load(name)
    state = arm_state(robot)
    assert robot.collision is not None
    world = compiled(robot.collision)
    configurations = _atlas(robot)
    points = np.array([robot.fk(q) for q in configurations])
    shapes = compile_world(robot.collision).shapes  # (another build's)
    out: dict[str, tuple[Packed, Any]] = {
        "Chain": (state.packed_chain, exact_chain(robot)),
        "Atlas": (state.packed_atlas, atlas.make_atlas(configurations, points)),
        "Shapes": (world.packed_shapes, shapes),
        "Tree": (pack(shapes.tree), shapes.tree),
    }
    if robot.geometry is not None:
        assert state.packed_arm is not None and state.packed_family is not None
        arm = family_arrays(robot, robot.geometry)
        out["Arm"] = (state.packed_arm, arm)
        out["Family"] = (state.packed_family, arm.family)
    return out


def test_every_registered_bundle_has_an_unpacker_and_its_own_code() -> None:
    assert set(UNPACKERS) == set(TUPLES)
    assert len({code_of(name) for name in TUPLES}) == len(TUPLES)


@pytest.mark.parametrize("name", robots.names())
def test_the_compiled_unpackers_give_back_every_leaf(name: str) -> None:
    for kind, (p, original) in bundles(name).items():
        assert p.I[0] == code_of(kind) and p.I[1] == len(leaves(kind)) and len(p.I) >= HEADER
        assert p.F.flags.c_contiguous and p.I.flags.c_contiguous
        same(unpacked(p), original, kind)  # (Python's views: what the solver reads)
        got = UNPACKERS[kind](p)
        same(got, original, kind)
        for leaf in array_leaves(got, kind):  # views of the packed arrays, not copies
            assert leaf.size == 0 or np.shares_memory(leaf, p.F if leaf.dtype == np.float64 else p.I)


def test_the_python_views_are_the_packed_memory() -> None:
    state = arm_state(robots.load("insomniac"))
    assert state.arrays is not None and state.packed_arm is not None
    assert np.shares_memory(state.arrays.family.P, state.packed_arm.F)
    assert np.shares_memory(state.arrays.family.J, state.packed_arm.I)
    assert np.shares_memory(state.chain.placement, state.packed_chain.F)
    assert np.shares_memory(state.atlas.q, state.packed_atlas.F)


def test_packing_refuses_what_is_not_a_bundle() -> None:
    with pytest.raises(TypeError, match="not a registered bundle"):
        pack((np.zeros(3),))
    with pytest.raises(TypeError, match="header names none"):
        unpacked(Packed(np.zeros(0), np.zeros(2, dtype=np.int64)))
