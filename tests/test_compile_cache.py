"""The persistent compilation cache (issue 24): on by default, movable, can be switched off,
and a second process loads what the first compiled instead of compiling again."""

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import jax
import jax.numpy as jnp
import pytest

from fxspace._compile_cache import (
    ENV,
    compile_cache_dir,
    compile_timer,
    configure_compile_cache,
    default_cache_dir,
)


def test_default_dir_follows_xdg(monkeypatch, tmp_path):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    assert default_cache_dir() == tmp_path / "fxspace" / "jax"
    monkeypatch.delenv("XDG_CACHE_HOME")
    assert default_cache_dir() == Path.home() / ".cache" / "fxspace" / "jax"


def test_setting_moves_and_disables_the_cache(monkeypatch, tmp_path):
    before = jax.config.jax_compilation_cache_dir
    try:
        for off in ("off", "0", "False", "none"):
            assert configure_compile_cache(off) is None
            assert compile_cache_dir() is None
        monkeypatch.setenv(ENV, str(tmp_path / "c"))
        assert configure_compile_cache() == tmp_path / "c"
        assert (tmp_path / "c").is_dir() and compile_cache_dir() == tmp_path / "c"
        monkeypatch.setenv(ENV, "off")
        assert configure_compile_cache() is None
    finally:
        jax.config.update("jax_compilation_cache_dir", before)


def test_unwritable_folder_leaves_the_cache_off(tmp_path):
    before = jax.config.jax_compilation_cache_dir
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    try:
        assert configure_compile_cache(blocker / "sub") is None
    finally:
        jax.config.update("jax_compilation_cache_dir", before)


def test_compile_timer_splits_compile_from_compute():
    @jax.jit
    def f(x):
        return jnp.cumsum(jnp.sin(x) * 3.0 + 1.25)

    x = jnp.arange(17.0)
    with compile_timer() as t:
        f(x).block_until_ready()
    first = t.summary()
    assert first["compiles"] >= 1 and first["compile_s"] > 0
    assert first["compile_s"] + first["compute_s"] == pytest.approx(first["wall_s"], abs=1e-3)
    with compile_timer() as t2:
        f(x).block_until_ready()  # already compiled in this process
    assert t2.summary()["compiles"] == 0 and t2.compile_s == 0


_CHILD = textwrap.dedent(
    """
    import json
    import jax, jax.numpy as jnp
    import fxspace as fx
    from fxspace._compile_cache import compile_timer
    geo = fx.LandmarkGeodesics(
        jnp.asarray([[0.0, 1.0, 2.5], [2.5, 1.5, 0.0]]), jnp.asarray([0, 2], jnp.int32)
    )
    y = jnp.asarray([[0.0, 0.0], [1.0, 0.2], [2.4, 0.1]])
    with compile_timer() as t:  # a jitted fxspace kernel (no host callback: cacheable)
        jax.block_until_ready(fx.landmark_score(geo, y))
    print("RESULT", json.dumps(t.summary()))
    """
)


def _child(cache: Path) -> dict:
    env = {
        **os.environ,
        ENV: str(cache),
        "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS": "0",  # store even this tiny kernel
        "JAX_PLATFORMS": "cpu",
    }
    r = subprocess.run(
        [sys.executable, "-c", _CHILD], env=env, capture_output=True, text=True, timeout=300
    )
    assert r.returncode == 0, r.stderr[-2000:]
    line = [ln for ln in r.stdout.splitlines() if ln.startswith("RESULT ")][-1]
    return json.loads(line[len("RESULT ") :])


@pytest.mark.slow
def test_second_process_hits_the_cache(tmp_path):
    cache = tmp_path / "jax-cache"
    first = _child(cache)
    assert first["compile_cache"] == str(cache)
    assert first["cache_misses"] >= 1 and first["cache_hits"] == 0
    assert any(cache.iterdir()), "nothing was written to the cache folder"
    second = _child(cache)
    assert second["cache_hits"] >= 1 and second["cache_misses"] == 0
    assert second["backend_compile_s"] < first["backend_compile_s"]
