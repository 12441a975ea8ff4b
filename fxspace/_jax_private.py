"""The one place fxspace reads a private part of JAX, and why there is no public way.

No other module of fxspace imports a private module of another package
(``tests/test_private_imports.py`` holds that); what JAX offers no public answer for is
asked here, and ``tests/test_jax_private.py`` imports every symbol in `PRIVATE` and checks
its behaviour, so a JAX release that moves or changes one fails that test by name instead
of changing what fxspace does without a word.

- **Has this process started JAX's backends?** Two choices must be made before the first
  backend client exists: ``XLA_FLAGS`` (``--xla_force_host_platform_device_count``,
  `fxspace.cli.use_all_cpu_cores`) is read once when the CPU client is created, and forking
  a process whose XLA runtime is running is unsafe (`fxspace.pipelines._sweep` starts its
  local workers by ``fork`` only before that). Every public way to ask
  (``jax.devices()``, ``jax.extend.backend.backends()``, ``get_backend()``) *starts* the
  backends, which is what the question must not do. JAX's own
  ``jax._src.xla_bridge.backends_are_initialized`` answers without starting them.
- **LAPACK's function pointers in a process that never lowered a LAPACK call.** JAX sets
  them when it first lowers one; an executable read back with
  ``jax.experimental.serialize_executable`` skips lowering and would call a null pointer
  (`fxspace._compile_cache.cached_executable`). jaxlib's ``lapack.prepare_lapack_call``
  sets them; JAX documents no public way.
"""

from __future__ import annotations

__all__ = ["PRIVATE", "backends_started", "prepare_lapack"]

#: every private JAX symbol fxspace uses: ``(module, name)``
PRIVATE = (
    ("jax._src.xla_bridge", "backends_are_initialized"),
    ("jaxlib.lapack", "prepare_lapack_call"),
)


def backends_started() -> bool | None:
    """Whether JAX has started its backends in this process, without starting them.

    **Returns:** ``True`` / ``False``; ``None`` when the private test is gone from this
    JAX (callers then take their safe choice; ``tests/test_jax_private.py`` fails loudly
    on such a release).
    """
    try:
        from jax._src import xla_bridge

        return bool(xla_bridge.backends_are_initialized())
    except (ImportError, AttributeError):  # a JAX release moved it: see the module docstring
        return None


def prepare_lapack() -> bool:
    """Make LAPACK's custom calls callable in this process (see the module docstring).

    **Returns:** ``True`` when done; ``False`` when this jaxlib has no such entry (callers
    then do not deserialise an executable that calls LAPACK: they compile it).
    """
    try:
        import numpy as np
        from jaxlib import lapack

        lapack.prepare_lapack_call("syevd_ffi", np.dtype(np.float32))
    except Exception:  # noqa: BLE001 - another jaxlib layout: see the module docstring
        return False
    return True
