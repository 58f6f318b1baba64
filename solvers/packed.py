"""How a bundle crosses into compiled code: packed, two contiguous arrays instead of one a field.

The native module's wrapper unboxes every array of an argument on its own, about 57 ns an
array (measured: a named tuple of 15 arrays took 1.0 us to pass, one array 0.16 us; the IK's
common call, :func:`armd.solvers.analytic.solve_point_clear`, passed 38 arrays, 2.2 us of its
5.4). An entry point therefore takes each bundle (a named tuple registered with
:func:`armd.solvers.jit.register_tuples`: :class:`~armd.solvers.arrays.Arm`,
:class:`~armd.solvers.collide.Shapes` ...) as a :class:`Packed`, made once per bundle by
:func:`pack`, and its body rebuilds the named tuple from views of the two arrays (each
bundle's module has its unpacker, e.g. :func:`armd.solvers.arrays.arm_of`), which costs a few
nanoseconds a field.

The layout: every leaf of the bundle (its fields depth-first, a nested tuple's leaves in its
place), in field order; float arrays and float scalars in ``F``; int arrays, int scalars and
bools (0 or 1) in ``I``, after a header: ``I[0]`` the bundle's code (:func:`code_of`, which
the native calls' check compares), ``I[1]`` the number of leaves, then four ints a leaf
(:data:`PER_LEAF`): its offset into ``F`` or ``I`` and up to three dimensions. The compiled
accessors below read leaf ``k`` of it as a scalar or as a view (C-contiguous, as the registered
types say; borrowed, as :func:`numba.carray`'s are: no reference counted, valid for the call).
:func:`unpacked` gives Python the same named tuple on views of the same buffers.
"""

from __future__ import annotations

import functools
import zlib
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from armd.robots.types import FloatArray

from .jit import TUPLES, extension, jit, register_packing

IntArray = NDArray[np.int64]

HEADER = 2  # I[0]: the bundle's code, I[1]: its number of leaves
PER_LEAF = 4  # a leaf's offset into F or I, and up to three dimensions (0 past its own)
_SCALARS = {"f8": float, "i8": int, "b1": bool}
# the types a scalar leaf may be (for "i8" and "f8" not a bool, which Python counts an int: _flat)
_ACCEPTED = {"f8": (float, np.floating), "i8": (int, np.integer), "b1": (bool, np.bool_)}


class Packed(NamedTuple):
    """A bundle's leaves in two arrays (see the module's doc)."""

    F: FloatArray  # float64, 1-d, C-contiguous: the float arrays and scalars
    I: IntArray  # int64, 1-d, C-contiguous: the header, the int arrays, int scalars and bools  # noqa: E741


def code_of(name: str) -> int:
    """The code of the registered bundle ``name`` in a packed header (31 bits of its CRC-32)."""
    return zlib.crc32(name.encode()) & 0x7FFFFFFF


@functools.cache
def leaves(name: str) -> tuple[tuple[str, str, int], ...]:
    """The leaves of the registered bundle ``name`` in packed order: (path, dtype, number of
    dimensions), a nested tuple's leaves in its place (path ``family.P``)."""
    out: list[tuple[str, str, int]] = []
    for field, spec in TUPLES[name][1]:
        if isinstance(spec, str):
            out.extend((f"{field}.{path}", dtype, ndim) for path, dtype, ndim in leaves(spec))
        else:
            out.append((field, spec[0], spec[1]))
    return tuple(out)


def _names() -> dict[Any, str]:
    """Each registered bundle's name, by its class and by its code (made anew: a module with
    compiled code registers its bundles when it is imported)."""
    out: dict[Any, str] = {}
    for name, (cls, _) in TUPLES.items():
        out[cls] = out[code_of(name)] = name
    return out


def bundle_name(p: Packed) -> str | None:
    """The registered bundle ``p``'s header names, or None."""
    return _names().get(int(p.I[0])) if len(p.I) >= HEADER else None


def _flat(bundle: Any, name: str, path: str = "") -> list[Any]:
    """``bundle``'s leaves in packed order, each checked against its registered kind."""
    cls, fields = TUPLES[name]
    if type(bundle) is not cls:
        raise TypeError(f"{path or 'the bundle'} is a {type(bundle).__name__}, should be a {name}")
    out: list[Any] = []
    for field, spec in fields:
        item = getattr(bundle, field)
        where = f"{path}{field}"
        if isinstance(spec, str):
            out.extend(_flat(item, spec, where + "."))
            continue
        dtype, ndim = spec
        if ndim:
            want = {"f8": np.float64, "i8": np.int64}[dtype]
            if not (isinstance(item, np.ndarray) and item.dtype == want and item.ndim == ndim):
                got = f"{item.dtype}[{item.ndim}d]" if isinstance(item, np.ndarray) else type(item).__name__
                raise TypeError(f"{where} is {got}, should be {np.dtype(want).name}[{ndim}d]")
        elif not isinstance(item, _ACCEPTED[dtype]) or (dtype != "b1" and isinstance(item, bool)):
            raise TypeError(f"{where} is a {type(item).__name__}, should be a {_SCALARS[dtype].__name__}")
        out.append(item)
    return out


def pack(bundle: Any) -> Packed:
    """``bundle`` (a registered named tuple) packed: every leaf copied into the two arrays.
    TypeError if a field is not of its registered dtype and number of dimensions."""
    name = _names().get(type(bundle))
    if name is None:
        raise TypeError(f"a {type(bundle).__name__} is not a registered bundle")
    kinds = leaves(name)
    items = _flat(bundle, name)
    n_float = n_int = 0
    for (_, dtype, ndim), item in zip(kinds, items, strict=True):
        size = int(np.size(item)) if ndim else 1
        if dtype == "f8":
            n_float += size
        else:
            n_int += size
    head = HEADER + PER_LEAF * len(kinds)
    floats = np.zeros(n_float)
    ints = np.zeros(head + n_int, dtype=np.int64)
    ints[0], ints[1] = code_of(name), len(kinds)
    f, i = 0, head
    for k, ((_, dtype, ndim), item) in enumerate(zip(kinds, items, strict=True)):
        h = HEADER + PER_LEAF * k
        buffer, at = (floats, f) if dtype == "f8" else (ints, i)
        size = int(item.size) if ndim else 1
        if ndim:
            buffer[at : at + size] = item.reshape(-1)
            ints[h + 1 : h + 1 + ndim] = item.shape
        else:
            buffer[at] = item
        ints[h] = at
        if dtype == "f8":
            f += size
        else:
            i += size
    return Packed(floats, ints)


def problem(value: Any, name: str) -> str | None:
    """What is wrong with ``value`` as the bundle ``name`` packed, or None: the native calls'
    check (:mod:`solvers.jit`; the native module would read anything else as if it were one)."""
    if type(value) is not Packed:
        kind = type(value).__name__
        return f"{'an' if kind[0] in 'AEIOU' else 'a'} {kind}, not a Packed (solvers.packed.pack it)"
    for field, dtype in (("F", "float64"), ("I", "int64")):
        a = getattr(value, field)
        if not (isinstance(a, np.ndarray) and a.dtype == dtype and a.ndim == 1 and a.flags.c_contiguous):
            got = f"{a.dtype}[{a.ndim}d]" if isinstance(a, np.ndarray) else type(a).__name__
            return f"{field} is {got}, not a C-contiguous {dtype}[1d]"
    ints = value.I
    if len(ints) < HEADER or int(ints[0]) != code_of(name):
        return f"a packed {bundle_name(value) or 'unknown bundle'}, should be a packed {name}"
    want = len(leaves(name))
    if int(ints[1]) != want or len(ints) < HEADER + PER_LEAF * want:
        return f"its header has {int(ints[1])} leaves, a packed {name} {want}"
    return None


register_packing(Packed, problem)


def unpacked(p: Packed) -> Any:
    """The bundle ``p`` holds, as its named tuple on views of ``p``'s arrays (the memory the
    compiled code reads); its scalars as Python's."""
    name = bundle_name(p)
    if name is None:
        raise TypeError("not a packed bundle (its header names none)")
    values = []
    for k, (_, dtype, ndim) in enumerate(leaves(name)):
        h = HEADER + PER_LEAF * k
        at = int(p.I[h])
        buffer = p.F if dtype == "f8" else p.I
        if ndim:
            shape = tuple(int(d) for d in p.I[h + 1 : h + 1 + ndim])
            values.append(buffer[at : at + int(np.prod(shape))].reshape(shape))
        else:
            values.append(_SCALARS[dtype](buffer[at]))
    return _build(name, values, 0)[0]


def _build(name: str, values: list[Any], k: int) -> tuple[Any, int]:
    """The named tuple ``name`` of ``values`` from leaf ``k`` on, and the leaf after it."""
    cls, fields = TUPLES[name]
    items = []
    for _, spec in fields:
        if isinstance(spec, str):
            item, k = _build(spec, values, k)
            items.append(item)
        else:
            items.append(values[k])
            k += 1
    return cls(*items), k


# -- compiled accessors: leaf k of a packed bundle -------------------------------------------


def _make_view() -> Any:
    """``view(buffer, offset, shape)``: the C-contiguous array ``shape`` (a tuple of ints) at
    element ``offset`` of ``buffer`` (1-d, C-contiguous), borrowed as :func:`numba.carray`'s are
    (no reference to ``buffer``'s memory is counted: the view is valid while the buffer lives, as
    an entry point's argument does for the call). Numba's extension API (``@intrinsic``): a slice
    and a reshape instead cost 10-35 ns a leaf, two atomic reference counts and the reshape's
    checks (measured: 370 ns to unpack a Shapes, 240 ns an Arm), most of what packing saves."""
    from numba.core import cgutils, types
    from numba.extending import intrinsic
    from numba.np.arrayobj import make_array, populate_array

    @intrinsic
    def view(typingctx: Any, buffer: Any, offset: Any, shape: Any) -> Any:
        ndim = len(shape)
        out_type = types.Array(buffer.dtype, ndim, "C")

        def codegen(context: Any, builder: Any, signature: Any, args: Any) -> Any:
            source = make_array(buffer)(context, builder, value=args[0])
            out = make_array(out_type)(context, builder)
            dims = cgutils.unpack_tuple(builder, args[2], ndim)
            itemsize = context.get_constant(types.intp, context.get_abi_sizeof(context.get_data_type(buffer.dtype)))
            strides: list[Any] = []
            step = itemsize
            for d in reversed(dims):  # (C order: the last dimension's stride is the item's size)
                strides.insert(0, step)
                step = builder.mul(step, d)
            populate_array(
                out,
                data=builder.gep(source.data, [args[1]]),
                shape=dims,
                strides=strides,
                itemsize=itemsize,
                meminfo=cgutils.get_null_value(source.meminfo.type),
                parent=cgutils.get_null_value(source.parent.type),
            )
            return out._getvalue()

        return out_type(buffer, offset, shape), codegen

    return view


_view = extension(_make_view)


@jit
def floats1(p: Packed, k: int) -> FloatArray:
    """Leaf ``k``: a float array (d0,), a view (borrowed: see :func:`_make_view`)."""
    h = HEADER + PER_LEAF * k
    return _view(p.F, p.I[h], (p.I[h + 1],))


@jit
def floats2(p: Packed, k: int) -> FloatArray:
    """Leaf ``k``: a float array (d0, d1), a view."""
    h = HEADER + PER_LEAF * k
    return _view(p.F, p.I[h], (p.I[h + 1], p.I[h + 2]))


@jit
def floats3(p: Packed, k: int) -> FloatArray:
    """Leaf ``k``: a float array (d0, d1, d2), a view."""
    h = HEADER + PER_LEAF * k
    return _view(p.F, p.I[h], (p.I[h + 1], p.I[h + 2], p.I[h + 3]))


@jit
def ints1(p: Packed, k: int) -> IntArray:
    """Leaf ``k``: an int array (d0,), a view."""
    h = HEADER + PER_LEAF * k
    return _view(p.I, p.I[h], (p.I[h + 1],))


@jit
def ints2(p: Packed, k: int) -> IntArray:
    """Leaf ``k``: an int array (d0, d1), a view."""
    h = HEADER + PER_LEAF * k
    return _view(p.I, p.I[h], (p.I[h + 1], p.I[h + 2]))


@jit
def float_at(p: Packed, k: int) -> float:
    """Leaf ``k``: a float."""
    return p.F[p.I[HEADER + PER_LEAF * k]]


@jit
def int_at(p: Packed, k: int) -> int:
    """Leaf ``k``: an int."""
    return p.I[p.I[HEADER + PER_LEAF * k]]


@jit
def bool_at(p: Packed, k: int) -> bool:
    """Leaf ``k``: a bool."""
    return p.I[p.I[HEADER + PER_LEAF * k]] != 0
