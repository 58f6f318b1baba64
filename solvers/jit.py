"""armd's compiled code: built ahead of time at install, else compiled by Numba on first use.

The solver's closed-form stage and the planner's per-sample loops are Numba code (``@jit``).
The functions Python calls (``@entry``, each with the signature it is called with) are
compiled ahead of time when armd is installed, into the extension module
``armd.solvers._native`` (``setup.py``, :mod:`armd.solvers.build`): a service then starts in a
second or two and never loads Numba or LLVM (about 130 MB of memory). The module carries the
digest of the sources it was built from; if they changed since (a developer's edit), or it
was not built (no C compiler), or ``ARMD_NATIVE=0``, the same functions are compiled by Numba
on first use instead, and cached.

A bundle (a named tuple of an arm's arrays: :class:`~armd.solvers.arrays.Arm`,
:class:`~armd.solvers.collide.Shapes` ...) crosses packed into two arrays
(:mod:`armd.solvers.packed`), and the entry point unpacks it into views of them: the native
wrapper unboxes every array of an argument on its own, about 57 ns an array (measured), and the
IK's common call passed 38 of them, 2.2 us of its 5.4. A signature's bundle name means the
packed form. The views are made by a Numba extension (:func:`extension`: made where Numba
compiles, built into the native module), not by slices, whose reference counts and reshapes
cost 0.24 us to unpack an Arm.

Unlike the JIT's (``nogil``), the native functions hold the interpreter while they run: a
caller with a long call splits it (batch IK: :data:`armd.solvers.batch.CHUNK` targets a call),
so that a move or a stop never waits behind a batch (tests/test_flood.py).

The JIT's cache lives in a per-user folder (``$ARMD_CACHE_DIR``, else
``$XDG_CACHE_HOME/armd/numba``, else ``~/.cache/armd/numba``) under a hash of every compiled
module's source and Numba's version, filed by module name rather than by the checkout's path:
a second clone, a CI run or a reinstall of the same sources reuses it, and any change to any
compiled module starts afresh. (Numba's own cache, keyed on each file's path and on that file
alone, would keep a caller's machine code after its callee's file changed: a stale cache once
ran an out-of-bounds write here.)
"""

from __future__ import annotations

import functools
import hashlib
import logging
import os
import sys
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

log = logging.getLogger(__name__)

HERE = Path(__file__).resolve().parent
# every file with compiled code, relative to solvers/; with the file that compiles them (build
# for the native module, this one for the JIT), what a build or a cache is of
COMPILED_MODULES = (
    "activeset",
    "arrays",
    "analytic",
    "atlas",
    "closest",
    "collide",
    "family",
    "geometric",
    "kinematics",
    "limits",
    "lm",
    "narrowphase",
    "packed",
    "pitch",
    "tree",
    "../planning/compiled",
    "../robots/angles",
)

F = TypeVar("F", bound=Callable[..., Any])
T = TypeVar("T")

ENTRIES: dict[str, tuple[Callable[..., Any], str]] = {}  # name: (function, signature): what the build exports


def source_digest(compiler: str = "build") -> str:
    """A hash of every compiled module's source and of ``compiler``'s (``build``: the native
    module's, ``jit``: the JIT's)."""
    digest = hashlib.sha256()
    for name in (*COMPILED_MODULES, compiler):
        digest.update((HERE / f"{name}.py").read_bytes())
    return digest.hexdigest()[:16]


def native_digest_number(digest: str) -> int:
    """The digest as the int64 the native module returns (an export cannot return a string)."""
    return int(digest[:15], 16)


def _load_native() -> Any:
    """The ahead-of-time module, if it is there, wanted and built from these sources."""
    if os.environ.get("ARMD_NATIVE", "1") == "0":
        return None
    try:
        from armd.solvers import _native  # type: ignore[attr-defined]
    except ImportError:
        log.info("no ahead-of-time build of the compiled code (armd.solvers._native): compiling with Numba")
        return None
    if not built_from(_native, source_digest()):
        log.warning(
            "armd.solvers._native was built from other sources than these: compiling with Numba "
            "instead (reinstall armd, pip install -e ., to rebuild it)"
        )
        return None
    return _native


def built_from(native: Any, digest: str) -> bool:
    """Whether ``native`` was built from the sources of ``digest``."""
    return bool(native.source_digest() == native_digest_number(digest))


NATIVE = _load_native()


def _compiler() -> Callable[[F], F]:
    """Numba's nopython compiler with armd's cache (imports Numba: only when it is needed)."""
    import numba
    from numba.core import caching

    def cache_root() -> str:
        base = os.environ.get("ARMD_CACHE_DIR") or os.path.join(
            os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache"), "armd", "numba"
        )
        key = f"{numba.__version__} {source_digest('jit')}"
        return os.path.join(base, hashlib.sha256(key.encode()).hexdigest()[:16])

    class ByModuleLocator(caching._SourceFileBackedLocatorMixin, caching._CacheLocator):
        """armd's files, cached under the cache root by their folder's name (not by the
        checkout's path); the stamp is the file's content hash (Numba's mixin)."""

        root = cache_root()

        def __init__(self, py_func: Any, py_file: str) -> None:
            self._py_file = py_file
            self._lineno = py_func.__code__.co_firstlineno
            self._cache_path = os.path.join(self.root, Path(py_file).resolve().parent.name)

        def get_cache_path(self) -> str:
            return self._cache_path

        @classmethod
        def from_function(cls, py_func: Any, py_file: str) -> Any:
            if Path(py_file).resolve().parent.parent != HERE.parent:
                return None
            return super().from_function(py_func, py_file)

    class Impl(caching.CompileResultCacheImpl):
        _locator_classes = [ByModuleLocator]  # noqa: RUF012 (numba's own attribute)

    class Cache(caching.FunctionCache):
        _impl_class = Impl

    njit = numba.njit(nogil=True)

    def compile_(fn: F) -> F:
        dispatcher = njit(fn)
        setattr(dispatcher, "_cache", Cache(dispatcher.py_func))  # noqa: B010 (what enable_caching does, ours)
        return dispatcher  # type: ignore[return-value]

    return compile_


if NATIVE is None:
    _compile = _compiler()

    def jit(fn: F) -> F:
        """Numba nopython code, cached (see the module's doc)."""
        return _compile(fn)

    def entry(signature: str) -> Callable[[F], F]:
        """A function Python calls: compiled by the JIT here; ``signature`` is what the
        ahead-of-time build exports it with (Numba's notation)."""

        def decorate(fn: F) -> F:
            if fn.__name__ in ENTRIES:
                raise ValueError(f"two compiled entry points named {fn.__name__}")
            compiled = jit(fn)
            ENTRIES[fn.__name__] = (compiled, signature)
            return compiled

        return decorate

    def extension(make: Callable[[], T]) -> T:
        """A Numba extension that compiled code calls (``make`` builds it, with Numba's extension
        API): made here, where Numba compiles."""
        return make()

else:
    # Python calls the entry points, which are the native module's. The other compiled functions
    # run only inside them, except where a test calls one itself: then, and only then, Numba
    # compiles them all (every compiled module's names are switched to Numba's dispatchers
    # first, as Numba resolves a callee by its module's global at compile time).
    _LAZY: list[_Lazy] = []
    _PYTHON: dict[str, Callable[..., Any]] = {}  # an entry point's name: its Python function
    _GIVEN: dict[str, Callable[..., Any]] = {}  # ... and what @entry gave its module for it
    _MODULES = (
        "armd.solvers.activeset",
        "armd.solvers.arrays",
        "armd.solvers.analytic",
        "armd.solvers.atlas",
        "armd.solvers.closest",
        "armd.solvers.collide",
        "armd.solvers.family",
        "armd.solvers.geometric",
        "armd.solvers.kinematics",
        "armd.solvers.limits",
        "armd.solvers.lm",
        "armd.solvers.narrowphase",
        "armd.solvers.packed",
        "armd.solvers.pitch",
        "armd.solvers.tree",
        "armd.planning.compiled",
    )
    _lock = threading.Lock()

    class _Lazy:
        """A compiled function that is not an entry point: compiled by Numba if Python calls it."""

        def __init__(self, fn: Callable[..., Any]) -> None:
            functools.update_wrapper(self, fn)
            self.py_func = fn
            self.compiled: Callable[..., Any] | None = None
            _LAZY.append(self)

        def __call__(self, *args: Any) -> Any:
            if self.compiled is None:
                _switch_to_numba()
            assert self.compiled is not None
            return self.compiled(*args)

    def _switch_to_numba() -> None:
        with _lock:
            if _LAZY and _LAZY[0].compiled is not None:
                return
            log.info("a compiled function was called from Python: compiling armd's compiled code with Numba")
            compile_ = _compiler()
            for lazy in _LAZY:
                lazy.compiled = compile_(lazy.py_func)
            natives = {id(_GIVEN[name]): compile_(fn) for name, fn in _PYTHON.items()}
            for name in _MODULES:
                module = sys.modules.get(name)
                for key, value in list(vars(module).items()) if module is not None else ():
                    if isinstance(value, _Lazy):
                        setattr(module, key, value.compiled)
                    elif isinstance(value, _Extension):
                        setattr(module, key, value.made())
                    elif id(value) in natives:
                        setattr(module, key, natives[id(value)])

    class _Extension:
        """A Numba extension, made (importing Numba) only if Python calls compiled code itself."""

        def __init__(self, make: Callable[[], Any]) -> None:
            self.make = make
            self.value: Any = None

        def made(self) -> Any:
            if self.value is None:
                self.value = self.make()
            return self.value

    def extension(make: Callable[[], T]) -> T:
        """A Numba extension that compiled code calls (``make`` builds it, with Numba's extension
        API): the native module has it built in; made only if a test calls compiled code itself."""
        return _Extension(make)  # type: ignore[return-value]

    def jit(fn: F) -> F:
        """Compiled into the native module with the entry points that call it (see above)."""
        return _Lazy(fn)  # type: ignore[return-value]

    def entry(signature: str) -> Callable[[F], F]:
        """The native module's build of the function (``signature``: what it was built with)."""

        def decorate(fn: F) -> F:
            native = getattr(NATIVE, fn.__name__)
            given = _checked(native, signature) if CHECK else native
            _PYTHON[fn.__name__], _GIVEN[fn.__name__] = fn, given
            return given  # type: ignore[return-value]

        return decorate


# The native module trusts its caller: an argument of another dtype or number of dimensions than
# the signature says is read as if it were right (garbage, or a crash). Every caller is armd's
# own and passes arrays it made; ARMD_NATIVE_CHECK=1 (the test suite sets it) checks every call
# against the signature, so that a caller that would not is caught by the tests. (Strides are
# read from the array: any layout is fine, except where a signature says ``::1``; a bundle is
# passed packed, solvers.packed, its two arrays C-contiguous and its header naming it.)
CHECK = os.environ.get("ARMD_NATIVE_CHECK") == "1"
_DTYPES = {"f8": "float64", "i8": "int64", "b1": "bool"}
# the named tuples a signature may name (solvers.arrays registers its own): name -> (class, fields)
TUPLES: dict[str, tuple[type, tuple[tuple[str, Any], ...]]] = {}
# how a bundle crosses (solvers.packed registers it): the class, and what is wrong with a value
# as the bundle of a name packed (None: nothing)
PACKING: list[tuple[type, Callable[[Any, str], str | None]]] = []


def register_tuples(classes: dict[str, type], fields: dict[str, tuple[tuple[str, Any], ...]]) -> None:
    """Named tuples (bundles) that signatures name, with each field's (dtype, number of
    dimensions) or the name of a nested tuple: how :func:`solvers.packed.pack` lays them out."""
    for name, cls in classes.items():
        TUPLES[name] = (cls, fields[name])


def register_packing(cls: type, problem: Callable[[Any, str], str | None]) -> None:
    """The class a bundle crosses packed as (a named tuple of a float64 and an int64 array,
    C-contiguous), and its check: what the build's signatures and the call checks use."""
    PACKING[:] = [(cls, problem)]


def parse_signature(signature: str) -> list[tuple[str, int, bool]]:
    """The arguments of a signature in Numba's notation (``void(f8[:], i8, f8[:, ::1])``), each
    as (dtype name, number of dimensions (0 for a scalar), whether it must be C-contiguous); a
    registered bundle as (its name, 0, True)."""
    inner = signature[signature.rindex("(") + 1 : -1]  # (the last parenthesis opens the arguments)
    args, depth, cur = [], 0, ""
    for ch in inner:
        depth += (ch == "[") - (ch == "]")
        if ch == "," and depth == 0:
            args.append(cur.strip())
            cur = ""
        else:
            cur += ch
    if cur.strip():
        args.append(cur.strip())
    out = []
    for arg in args:
        if arg in TUPLES:
            out.append((arg, 0, True))
            continue
        name, _, dims = arg.partition("[")
        out.append((_DTYPES[name], dims.count(",") + 1 if dims else 0, "::1" in dims))
    return out


def numba_types() -> dict[str, Any]:
    """The registered bundles' names as the build's signatures read them: each the Numba type of
    :class:`solvers.packed.Packed` (a bundle crosses packed; the entry point unpacks it)."""
    from numba import types

    cls, _ = PACKING[0]
    packed = types.NamedTuple((types.Array(types.float64, 1, "C"), types.Array(types.int64, 1, "C")), cls)
    return dict.fromkeys(TUPLES, packed)


def _checked(native: Callable[..., Any], signature: str) -> Callable[..., Any]:
    import numpy as np

    spec = parse_signature(signature)
    scalars = {"float64": (float, int, np.floating, np.integer), "int64": (int, np.integer), "bool": (bool, np.bool_)}

    @functools.wraps(native)
    def call(*args: Any) -> Any:
        if len(args) != len(spec):
            raise TypeError(f"{native.__name__}: {len(args)} arguments for {signature}")
        for i, (arg, (dtype, ndim, contiguous)) in enumerate(zip(args, spec, strict=True)):
            if dtype in TUPLES:
                problem = PACKING[0][1](arg, dtype)
                if problem is not None:
                    raise TypeError(f"{native.__name__}: argument {i} ({dtype}): {problem}")
                continue
            if ndim:
                ok = (
                    isinstance(arg, np.ndarray)
                    and arg.dtype == dtype
                    and arg.ndim == ndim
                    and (arg.flags.c_contiguous or not contiguous)
                )
            else:
                ok = isinstance(arg, scalars[dtype]) and not (dtype == "int64" and isinstance(arg, bool))
            if not ok:
                got = f"{arg.dtype}[{arg.ndim}d]" if isinstance(arg, np.ndarray) else type(arg).__name__
                raise TypeError(
                    f"{native.__name__}: argument {i} is {got}; {signature} wants {dtype}"
                    f"{f'[{ndim}d]' if ndim else ''}{' (C-contiguous)' if contiguous else ''}"
                )
        return native(*args)

    return call
