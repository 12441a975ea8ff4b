"""The private JAX symbols fxspace relies on (`fxspace._jax_private`) still exist and still
mean what fxspace takes them to mean: a JAX release that moves or changes one fails here,
naming it, instead of silently changing how the CLI and the sweeps start JAX."""

import importlib
import os
import subprocess
import sys
import textwrap

import pytest

from fxspace._jax_private import PRIVATE


@pytest.mark.parametrize("module,name", PRIVATE, ids=[f"{m}.{n}" for m, n in PRIVATE])
def test_private_symbol_is_where_fxspace_reads_it(module, name):
    try:
        mod = importlib.import_module(module)
    except ImportError as e:
        pytest.fail(f"JAX moved {module} (fxspace._jax_private reads {module}.{name}): {e}")
    assert callable(getattr(mod, name, None)), (
        f"JAX no longer has {module}.{name}: the function of fxspace._jax_private that reads "
        "it now gives its safe answer (None / False); find JAX's new way and update that module"
    )


def test_prepare_lapack_succeeds():
    """jaxlib's LAPACK preparation runs (else cached executables calling LAPACK are never
    read back: `fxspace._compile_cache` compiles them every time)."""
    from fxspace._jax_private import prepare_lapack

    assert prepare_lapack(), "jaxlib.lapack.prepare_lapack_call failed or moved"


_CHILD = textwrap.dedent(
    """
    import jax
    from fxspace._jax_private import backends_started
    before = backends_started()
    from fxspace._jax_private import backends_started as again  # asking twice starts nothing
    still = again()
    jax.devices()
    print(before, still, backends_started())
    """
)


def test_backends_started_tells_before_from_after_without_starting_them():
    """In a fresh process: False after ``import jax`` (asking must not start a backend),
    True once ``jax.devices()`` has."""
    env = {**os.environ, "JAX_PLATFORMS": "cpu"}
    r = subprocess.run([sys.executable, "-c", _CHILD], env=env, capture_output=True,
                       text=True, timeout=120)  # fmt: skip
    assert r.returncode == 0, r.stderr[-2000:]
    assert r.stdout.split() == ["False", "False", "True"], (
        "jax._src.xla_bridge.backends_are_initialized changed meaning: "
        f"before / asked again / after jax.devices() gave {r.stdout.split()}"
    )
