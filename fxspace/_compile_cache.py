"""Compile once: JAX's persistent compilation cache, on by default, and compile-time accounting.

Every new Python process would otherwise compile every jitted fxspace kernel again (tens
of seconds for a pipeline or an app). Importing `fxspace` points JAX's persistent
compilation cache at a folder in the user's cache directory, so a kernel compiled by one
process is loaded from disk by the next:

- default folder: ``$XDG_CACHE_HOME/fxspace/jax`` (``~/.cache/fxspace/jax`` when
  ``XDG_CACHE_HOME`` is unset);
- ``FXSPACE_COMPILE_CACHE=/some/folder`` moves it, ``FXSPACE_COMPILE_CACHE=off`` (or
  ``0``, ``false``, ``no``, ``none``) disables it;
- the folder is bounded (`MAX_SIZE_BYTES`, least recently used entries evicted), which also
  makes JAX lock it around every read and write, so concurrent fxspace processes never
  read a half-written entry;
- a cache folder the user already gave JAX (``JAX_COMPILATION_CACHE_DIR`` or
  ``jax.config.update("jax_compilation_cache_dir", ...)``) is kept when
  ``FXSPACE_COMPILE_CACHE`` is unset.

JAX only stores programs whose compilation took at least
``jax_persistent_cache_min_compile_time_secs`` (1 s by default, which would skip most of
fxspace's kernels on a CPU); fxspace lowers it to `MIN_COMPILE_TIME_S` unless the user
set it. The cache is an optimisation only: a folder that cannot be created leaves the cache
off, never an error.

`cached_executable` goes one step further for an app's hot per-frame kernel: the compiled
executable itself is serialised to disk (CPU), keyed by the function, fxspace's code, JAX's
version, the device and the arguments' structure and shapes, so a new process skips tracing
and lowering too (seconds for a large step function), not only XLA's compilation. It is
kept by measurement (`experiments/bench_compile_cache.py`: every later start of the motion
app about 2 s shorter than with JAX's cache alone; figures in
``docs/concepts/architecture.md``, "Compilation cache"). Only public JAX is used here; the
one step JAX has no public way for (LAPACK's function pointers) is in `fxspace._jax_private`.

`compile_timer` splits a block's wall time into compile time (tracing, lowering and
backend compilation or cache retrieval, from `jax.monitoring`'s duration events) and the
rest (compute); pipelines record it in ``meta.json`` under ``"timing"``.
"""

from __future__ import annotations

import os
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

from fxspace._jax_private import prepare_lapack

__all__ = [
    "ENV",
    "MIN_COMPILE_TIME_S",
    "MAX_SIZE_BYTES",
    "default_cache_dir",
    "configure_compile_cache",
    "compile_cache_dir",
    "CompileTimer",
    "compile_timer",
    "cached_executable",
    "CachedExecutable",
    "executable_cache_dir",
]

ENV = "FXSPACE_COMPILE_CACHE"
MIN_COMPILE_TIME_S = 0.05
#: size bound of the cache folder (least recently used entries evicted past it)
MAX_SIZE_BYTES = 4 << 30
_OFF = {"off", "0", "false", "no", "none", "disable", "disabled"}

_TRACE = "/jax/core/compile/jaxpr_trace_duration"
_LOWER = "/jax/core/compile/jaxpr_to_mlir_module_duration"
_BACKEND = "/jax/core/compile/backend_compile_duration"
_HIT = "/jax/compilation_cache/cache_hits"
_MISS = "/jax/compilation_cache/cache_misses"
_SAVED = "/jax/compilation_cache/compile_time_saved_sec"


def default_cache_dir() -> Path:
    """``$XDG_CACHE_HOME/fxspace/jax``, or ``~/.cache/fxspace/jax`` without ``XDG_CACHE_HOME``."""
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "fxspace" / "jax"


def compile_cache_dir() -> Path | None:
    """The persistent compilation cache folder JAX uses now (``None`` when it is off)."""
    import jax

    if not jax.config.jax_enable_compilation_cache:
        return None
    path = jax.config.jax_compilation_cache_dir
    return Path(path) if path else None


def configure_compile_cache(
    setting: str | os.PathLike | None = None, min_compile_time_s: float = MIN_COMPILE_TIME_S
) -> Path | None:
    """Turn JAX's persistent compilation cache on (or off) for this process.

    **Arguments:**

    - `setting`: a folder, ``"off"`` to disable, or ``None`` to read ``FXSPACE_COMPILE_CACHE``
      (unset → keep a folder already given to JAX, else `default_cache_dir`).
    - `min_compile_time_s`: programs that compiled faster than this are not stored (JAX's own
      default, 1 s, would skip most kernels on a CPU); kept if the user set their own.

    Call it before the first compilation: JAX opens the cache folder once per process.

    **Returns:** the cache folder, or ``None`` when the cache is off.
    """
    import jax

    if setting is None:
        setting = os.environ.get(ENV)
        if setting is None and jax.config.jax_compilation_cache_dir:
            return compile_cache_dir()  # the user configured JAX directly: keep it
    if setting is not None and str(setting).strip().lower() in _OFF:
        jax.config.update("jax_compilation_cache_dir", None)
        return None
    path = Path(os.path.expanduser(str(setting))) if setting else default_cache_dir()
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError:
        return None  # read-only home, no permission: run without the cache
    try:
        import filelock  # noqa: F401  (JAX needs it for a bounded, locked cache)
    except ImportError:  # pragma: no cover - a declared dependency
        filelock = None
    if filelock is not None and not os.environ.get("JAX_COMPILATION_CACHE_MAX_SIZE"):
        # A bounded cache makes JAX take a file lock around every read and write: without
        # it, a process could read an entry another process is still writing (a torn
        # executable crashed a test run here when several processes shared the folder).
        jax.config.update("jax_compilation_cache_max_size", MAX_SIZE_BYTES)
    if not os.environ.get("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS"):
        jax.config.update("jax_persistent_cache_min_compile_time_secs", float(min_compile_time_s))
    jax.config.update("jax_compilation_cache_dir", str(path))
    jax.config.update("jax_enable_compilation_cache", True)
    return path


class CompileTimer:
    """Compile time and compute time of a block, from `jax.monitoring` duration events.

    Fields (seconds unless counts): ``trace_s``, ``lower_s``, ``backend_compile_s`` (XLA
    compilation, or reading the executable from the persistent cache on a hit),
    ``compiles`` (backend compilations requested), ``cache_hits``, ``cache_misses`` and
    ``saved_s`` (compile time the persistent cache saved). Counts every thread's events
    while the block runs.
    """

    def __init__(self) -> None:
        self.trace_s = self.lower_s = self.backend_compile_s = self.saved_s = 0.0
        self.compiles = self.cache_hits = self.cache_misses = 0
        self.wall_s = 0.0
        self._lock = threading.Lock()
        self._t0 = 0.0
        self._active = False

    def _on_duration(self, event: str, duration: float, **_: Any) -> None:
        if not self._active:
            return
        with self._lock:
            if event == _TRACE:
                self.trace_s += duration
            elif event == _LOWER:
                self.lower_s += duration
            elif event == _BACKEND:
                self.backend_compile_s += duration
                self.compiles += 1
            elif event == _SAVED:
                self.saved_s += duration

    def _on_event(self, event: str, **_: Any) -> None:
        if not self._active:
            return
        with self._lock:
            if event == _HIT:
                self.cache_hits += 1
            elif event == _MISS:
                self.cache_misses += 1

    def __enter__(self) -> CompileTimer:
        import jax.monitoring as mon

        mon.register_event_duration_secs_listener(self._on_duration)
        mon.register_event_listener(self._on_event)
        self._active = True
        self._t0 = time.perf_counter()
        return self

    def __exit__(self, *exc: Any) -> None:
        import jax.monitoring as mon

        self.wall_s = time.perf_counter() - self._t0
        self._active = False
        for unregister, fn in (
            (mon.unregister_event_duration_listener, self._on_duration),
            (mon.unregister_event_listener, self._on_event),
        ):
            try:
                unregister(fn)
            except (AssertionError, ValueError, KeyError):  # pragma: no cover - already gone
                pass

    @property
    def compile_s(self) -> float:
        """Tracing + lowering + backend compilation (or cache retrieval)."""
        return self.trace_s + self.lower_s + self.backend_compile_s

    def summary(self) -> dict[str, Any]:
        """A JSON-ready dict: ``wall_s``, ``compile_s``, ``compute_s`` (= wall − compile) and the
        parts, counts and the cache folder (``None`` when off)."""
        wall = self.wall_s if not self._active else time.perf_counter() - self._t0
        cache = compile_cache_dir()
        return {
            "wall_s": round(wall, 4),
            "compile_s": round(self.compile_s, 4),
            "compute_s": round(max(wall - self.compile_s, 0.0), 4),
            "trace_s": round(self.trace_s, 4),
            "lower_s": round(self.lower_s, 4),
            "backend_compile_s": round(self.backend_compile_s, 4),
            "compiles": self.compiles,
            "cache_hits": self.cache_hits,
            "cache_misses": self.cache_misses,
            "compile_time_saved_s": round(self.saved_s, 4),
            "compile_cache": None if cache is None else str(cache),
        }


def compile_timer() -> CompileTimer:
    """A `CompileTimer` context manager: ``with compile_timer() as t: ...; t.summary()``."""
    return CompileTimer()


# ------------------------------------------------------------------ serialised executables
#: executables kept on disk (the oldest files beyond this are removed when one is written)
MAX_EXECUTABLES = 32
_LAPACK = "lapack_"
_MEMO: dict[str, Any] = {}
_MEMO_LOCK = threading.Lock()
_SWITCH_LOCK = threading.Lock()
_CODE: list[str] = []


def executable_cache_dir() -> Path | None:
    """Where `cached_executable` keeps executables: beside JAX's compilation cache folder
    (``…/fxspace/jax-executables`` by default); ``None`` when the compilation cache is off."""
    base = compile_cache_dir()
    return None if base is None else base.with_name(base.name + "-executables")


def _code_version() -> str:
    if not _CODE:
        from fxspace.runs import code_digest

        _CODE.append(code_digest())
    return _CODE[0]


def _executable_key(fn: Any, args: tuple) -> str:
    import hashlib
    import sys

    import jax
    import jaxlib

    leaves, tree = jax.tree_util.tree_flatten(args)
    dev = jax.devices()[0]
    h = hashlib.sha256()
    for part in (
        getattr(fn, "__module__", ""),
        getattr(fn, "__qualname__", repr(fn)),
        _code_version(),
        jax.__version__,
        jaxlib.__version__,
        sys.version,
        dev.platform,
        getattr(dev, "device_kind", ""),
        str(jax.config.jax_enable_x64),
        str(jax.config.jax_default_matmul_precision),
        os.environ.get("XLA_FLAGS", ""),
        str(tree),
    ):
        h.update(str(part).encode() + b"\0")
    for x in leaves:
        a = jax.typeof(x)
        h.update(f"{a.shape}|{a.dtype}|{getattr(a, 'weak_type', False)};".encode())
    return h.hexdigest()


def _custom_targets(lowered: Any) -> set[str]:
    import re

    text = lowered.as_text()
    found = re.findall(r'custom_call @([\w.]+)|call_target_name = "([\w.]+)"', text)
    return {a or b for a, b in found}


def _prepare_targets(targets: set[str]) -> bool:
    """Make the executable's custom calls callable in this process (LAPACK's function
    pointers are set when JAX first lowers a LAPACK call; a deserialised executable skips
    that and would call a null pointer). False when a target is not one we can prepare."""
    if any(not t.startswith(_LAPACK) for t in targets):
        return False
    return not targets or prepare_lapack()


def _mark_unserialisable(path: Path) -> None:
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.with_suffix(".noexe").touch()
    except OSError:
        pass


def _prune(folder: Path) -> None:
    files = sorted(folder.glob("*.exe"), key=lambda f: f.stat().st_mtime)
    for f in sorted(folder.glob("*.noexe"), key=lambda f: f.stat().st_mtime)[:-MAX_EXECUTABLES]:
        try:
            f.unlink()
        except OSError:
            pass
    for f in files[:-MAX_EXECUTABLES]:
        try:
            f.unlink()
        except OSError:
            pass


class CachedExecutable:
    """A jitted function compiled ahead of time for one argument structure (see
    `cached_executable`). Calling it runs the compiled executable; arguments of another
    structure or shape fall back to the jitted function (correct, compiled as usual).

    ``source`` says where the executable came from: ``"disk"`` (deserialised),
    ``"compiled"`` (lowered and compiled in this process, then written when XLA can
    serialise it), or ``"jit"`` (no executable: the cache is off, not a CPU, or an earlier
    process found that XLA cannot serialise this program).
    """

    def __init__(self, fn: Any, compiled: Any, source: str, path: Path | None = None):
        self.fn = fn
        self.compiled = compiled
        self.source = source
        self._unproved = path if source == "disk" else None  # its first run not yet seen

    def __call__(self, *args: Any) -> Any:
        if self.compiled is not None:
            try:
                out = self.compiled(*args)
            except TypeError:  # another structure, dtype or shape than it was built for
                return self.fn(*args)
            if self._unproved is None:
                return out
            import jax

            # XLA can serialise an executable without the code of fusions its process had
            # compiled before; such a file loads but fails on its first run ("Function …
            # not found"). The first run of a loaded one is awaited: on failure the file
            # is dropped and marked, and this and later calls use the jitted function.
            try:
                jax.block_until_ready(out)
            except Exception:  # noqa: BLE001 - jax.errors.JaxRuntimeError
                _drop_executable(self._unproved)
                self.compiled, self.source, self._unproved = None, "jit", None
                return self.fn(*args)
            self._unproved = None
            return out
        return self.fn(*args)


def _drop_executable(path: Path) -> None:
    """A serialised executable that failed to run: removed, its key marked (see
    `_mark_unserialisable`) so later processes use the jitted function."""
    try:
        path.unlink()
    except OSError:
        pass
    _mark_unserialisable(path)


def _compile_outside_cache(lowered: Any) -> Any:
    """``lowered.compile()`` with JAX's persistent cache switched off meanwhile: an
    executable that was itself read from that cache serialises without its code (its calls
    then fail). The switch is JAX's public ``jax_enable_compilation_cache`` option, which
    is process-wide: it is flipped under a lock and restored, and another thread compiling
    meanwhile only misses the cache (compiles, never a wrong program)."""
    import jax

    with _SWITCH_LOCK:
        before = jax.config.jax_enable_compilation_cache
        jax.config.update("jax_enable_compilation_cache", False)
        try:
            return lowered.compile()
        finally:
            jax.config.update("jax_enable_compilation_cache", before)


def cached_executable(fn: Any, *args: Any) -> CachedExecutable:
    """`fn` (a ``jax.jit`` function) compiled for `args`' structure and shapes, kept on disk.

    The first process lowers and compiles `fn` (through JAX's compilation cache as usual)
    and writes the serialised executable to `executable_cache_dir`; later processes load
    it (no tracing, no lowering). The key covers the function's name, fxspace's source
    (`fxspace.runs.code_digest`), JAX / jaxlib / Python versions, the device, the x64 and
    matmul-precision settings, ``XLA_FLAGS`` and the arguments' tree structure (static
    fields included) and shapes / dtypes: another version or configuration is compiled
    afresh, never served. Only on CPU (elsewhere the function is returned as is) and only
    for programs whose custom calls are LAPACK's; a file that cannot be read is
    recompiled. The executable is compiled outside JAX's persistent cache (one read from it
    serialises without its code). XLA cannot serialise every program (it depends on what
    the process compiled before): such a key is marked, and later processes use the
    jitted function through JAX's cache. Within a process the result is memoised by key.
    """
    import pickle

    import jax

    folder = executable_cache_dir()
    if folder is None or jax.devices()[0].platform != "cpu":
        return CachedExecutable(fn, None, "jit")
    key = _executable_key(fn, args)
    with _MEMO_LOCK:
        if key in _MEMO:
            return _MEMO[key]
    from jax.experimental import serialize_executable as se

    path = folder / f"{key}.exe"
    out = None
    if path.with_suffix(".noexe").exists():  # known not to serialise: the jitted function
        out = CachedExecutable(fn, None, "jit")  # (through JAX's compilation cache)
    elif path.exists():
        try:
            with open(path, "rb") as f:
                payload, in_tree, out_tree, targets = pickle.load(f)
            if _prepare_targets(set(targets)):
                out = CachedExecutable(
                    fn, se.deserialize_and_load(payload, in_tree, out_tree), "disk", path
                )
                os.utime(path)
        except Exception:  # noqa: BLE001 - a torn or foreign file: compile instead
            out = None
    if out is None:
        lowered = fn.lower(*args)
        targets = _custom_targets(lowered)
        compiled = _compile_outside_cache(lowered)
        out = CachedExecutable(fn, compiled, "compiled")
        if not _prepare_targets(targets):
            _mark_unserialisable(path)
        else:
            try:
                blob = pickle.dumps((*se.serialize(compiled), sorted(targets)))
                folder.mkdir(parents=True, exist_ok=True)
                fd, tmp = tempfile.mkstemp(prefix=".fx", suffix=".tmp", dir=folder)
                with os.fdopen(fd, "wb") as f:  # unique temp name beside the target
                    f.write(blob)
                os.replace(tmp, path)
                _prune(folder)
            except Exception:  # noqa: BLE001 - XLA cannot serialise every program
                _mark_unserialisable(path)
    with _MEMO_LOCK:
        _MEMO[key] = out
    return out
