"""Compiled inner loops: numba's `njit`, compiled on first call and cached on disk.

Per-frame work in streamkey is many tiny loops (a banded solve per HP scale, a heap of Ward
merges, a joint chain of 3x3 products) whose cost in numpy is call overhead, not arithmetic.
`kernel` compiles such a loop with numba (no fastmath: IEEE results, the same on every call
path) the first time it runs, so `import streamkey`, `--help` and error paths never import
numba. Compiled code is cached beside the module (`__pycache__`, or `NUMBA_CACHE_DIR`), so a
process pays the compilation once per machine, not per start.

A live process must not compile on its first frame: `warm_up()` runs every registered
warmer (`@warmer`: a function calling its module's kernels on tiny inputs) before the stream
starts. Algorithm modules stay sans-I/O; this module only wraps functions.

`prefetch(a, i)`, callable from kernels only, is a cache hint (LLVM's prefetch, built when
the first kernel calling it compiles): it starts fetching `a[i]`'s cache line early and
changes no result.
"""

from __future__ import annotations

import types
from collections.abc import Callable
from typing import Any, TypeVar, cast

__all__ = ["kernel", "warmer", "warm_up", "cache_is_cold", "prefetch", "watch_compilation",
           "kernel_count"]

F = TypeVar("F", bound=Callable[..., Any])

_WARMERS: list[Callable[[], None]] = []
_KERNELS: list[_Kernel] = []
_WARMED: set[Callable[[], None]] = set()
_WATCHERS: list[Callable[[str, float | None], None]] = []
_LISTENING: list[bool] = []  # [True] once numba's compile events are hooked


class _Kernel:
    """A function compiled by numba on its first call (then called directly)."""

    def __init__(self, fn: Callable[..., Any], options: dict[str, Any]) -> None:
        self.py_func = fn
        self.options = options
        self.compiled: Callable[..., Any] | None = None
        self.__name__ = fn.__name__
        self.__qualname__ = fn.__qualname__
        self.__doc__ = fn.__doc__
        self.__module__ = fn.__module__
        _KERNELS.append(self)

    def compile(self) -> Callable[..., Any]:
        """The numba dispatcher (imports numba on first use)."""
        if self.compiled is None:
            import numba

            if _WATCHERS and not _LISTENING:
                _listen()
            fn = self.py_func
            names = fn.__code__.co_names
            if any(isinstance(fn.__globals__.get(name), _Kernel) for name in names):
                scope = dict(fn.__globals__)  # other kernels it calls: their dispatchers
                for name in names:
                    if isinstance(scope.get(name), _Kernel):
                        scope[name] = scope[name].compile()
                fn = types.FunctionType(fn.__code__, scope, fn.__name__, fn.__defaults__,
                                        fn.__closure__)
                fn.__qualname__ = self.py_func.__qualname__
            self.compiled = numba.njit(cache=True, nogil=True, **self.options)(fn)
        return self.compiled

    def __call__(self, *args: Any) -> Any:
        fn = self.compiled or self.compile()
        return fn(*args)

    def __reduce__(self) -> str:  # pickled by reference (module-level name)
        return self.__qualname__


def kernel(fn: F | None = None, **options: Any) -> Any:
    """Decorator: compile `fn` with numba (`cache=True`, `nogil=True`, no fastmath) on first
    call. Kernels take and return numpy arrays, tuples and scalars; a kernel may call other
    module-level kernels by name."""
    if fn is None:
        return lambda f: _Kernel(f, options)
    return _Kernel(fn, options)


def warmer(fn: Callable[[], None]) -> Callable[[], None]:
    """Register `fn` (no arguments) to compile/load its module's kernels in `warm_up()`."""
    _WARMERS.append(fn)
    return fn


def cache_is_cold(kernels: list[Any] | None = None) -> bool:
    """True when some kernel (default: every one imported so far) has nothing in numba's
    on-disk cache, so the next `warm_up()` compiles (tens of seconds on a new machine, once)
    instead of loading (~0.3 s). False when the cache cannot be read (numba's index API is
    private)."""
    try:
        return any(not cast(Any, k.compile())._cache._cache_file._load_index()
                   for k in (_KERNELS if kernels is None else kernels))
    except Exception:  # another numba version: no notice rather than a wrong one
        return False


def warm_up(*warmers: Callable[[], None]) -> None:
    """Compile or load from the cache the kernels of `warmers` (default: every registered
    one, i.e. of the modules imported so far); call before a live stream starts, so no frame
    waits for the compiler. Each warmer runs once per process."""
    for fn in warmers or list(_WARMERS):
        if fn not in _WARMED:
            fn()
            _WARMED.add(fn)


def watch_compilation(fn: Callable[[str, float | None], None]) -> None:
    """Call `fn(name, None)` when numba starts compiling a kernel (`module.function`) and
    `fn(name, seconds)` when it is done: progress for a cold cache, where compiling every
    kernel takes about a minute. Loading from the cache calls nothing. numba is hooked
    only once a kernel is used, so `--help` and error paths still never import it."""
    _WATCHERS.append(fn)


def kernel_count() -> int:
    """How many kernels the modules imported so far define (the total for progress)."""
    return sum(1 for k in _KERNELS if not isinstance(k, _Intrinsic))


def _listen() -> None:
    """Forward numba's `numba:compile` events to the watchers."""
    import time

    from numba.core import event

    class Forward(event.Listener):
        def __init__(self) -> None:
            self.started: list[float] = []

        def on_start(self, ev: Any) -> None:
            self.started.append(time.monotonic())
            if name := _name(ev):
                for fn in list(_WATCHERS):
                    fn(name, None)

        def on_end(self, ev: Any) -> None:
            seconds = time.monotonic() - self.started.pop() if self.started else 0.0
            if name := _name(ev):
                for fn in list(_WATCHERS):
                    fn(name, seconds)

    def _name(ev: Any) -> str | None:
        """`module.function` of one of our kernels; None for numba's own helpers."""
        py = getattr(ev.data.get("dispatcher"), "py_func", None)
        if py is None or py.__module__ not in {k.__module__ for k in _KERNELS}:
            return None
        return f"{py.__module__.rsplit('.', 1)[-1]}.{py.__name__}"

    event.register("numba:compile", Forward())
    _LISTENING.append(True)


class _Intrinsic(_Kernel):
    """LLVM code that kernels call by name, built by `build()` (importing numba) when the
    first kernel calling it compiles; nothing of its own in numba's cache (not listed in
    `cache_is_cold`)."""

    def __init__(self, build: Callable[[], Any]) -> None:
        self.py_func = build
        self.options = {}
        self.compiled = None
        self.__name__ = self.__qualname__ = build.__name__.removeprefix("_build_")
        self.__doc__ = build.__doc__
        self.__module__ = build.__module__

    def compile(self) -> Callable[..., Any]:
        """The numba intrinsic."""
        if self.compiled is None:
            self.compiled = self.py_func()
        return self.compiled


def _build_prefetch() -> Callable[..., Any]:
    """`prefetch(a, i)` in a kernel: ask the CPU to start fetching the cache line of `a[i]`
    (a 1-D array) into every cache level; a hint, no effect on results. For reads whose
    addresses are known before they are needed but that no hardware prefetcher guesses (a
    block of rows at a data-dependent place)."""
    from llvmlite import ir
    from numba.core import cgutils, types
    from numba.extending import intrinsic

    @intrinsic
    def prefetch(typingctx: Any, array: Any, index: Any) -> Any:
        if not (isinstance(array, types.Array) and array.ndim == 1
                and isinstance(index, types.Integer)):
            return None

        def codegen(context: Any, builder: Any, signature: Any, args: Any) -> Any:
            aryty = signature.args[0]
            ary = context.make_array(aryty)(context, builder, args[0])
            idx = context.cast(builder, args[1], signature.args[1], types.intp)
            ptr = cgutils.get_item_pointer(context, builder, aryty, ary, [idx])
            i8p = ir.IntType(8).as_pointer()
            i32 = ir.IntType(32)
            fn = cgutils.get_or_insert_function(
                builder.module, ir.FunctionType(ir.VoidType(), [i8p, i32, i32, i32]),
                "llvm.prefetch.p0i8")
            # read, keep in every cache level, data cache
            builder.call(fn, [builder.bitcast(ptr, i8p), i32(0), i32(3), i32(1)])
            return context.get_dummy_value()

        return types.void(array, index), codegen

    return prefetch


prefetch = _Intrinsic(_build_prefetch)
