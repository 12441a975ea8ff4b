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

`compile_timer` splits a block's wall time into compile time (tracing, lowering and
backend compilation or cache retrieval, from `jax.monitoring`'s duration events) and the
rest (compute); pipelines record it in ``meta.json`` under ``"timing"``.
"""

from __future__ import annotations

import os
import threading
import time
from pathlib import Path
from typing import Any

__all__ = [
    "ENV",
    "MIN_COMPILE_TIME_S",
    "MAX_SIZE_BYTES",
    "default_cache_dir",
    "configure_compile_cache",
    "compile_cache_dir",
    "CompileTimer",
    "compile_timer",
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
