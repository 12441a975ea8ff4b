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
import numpy as np
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


# ------------------------------------------------------------------ serialised executables
@jax.jit
def _horn_like(A, b):
    """A small program with a LAPACK custom call (eigh), like the motion step's Horn fit."""
    w, v = jnp.linalg.eigh(A @ A.T)
    return v[:, -1] * w[-1] + b.sum(), jnp.cumsum(b)


def _inputs(n=4):
    A = jnp.arange(float(n * n)).reshape(n, n) / 7.0 + jnp.eye(n)
    return A, jnp.linspace(0.0, 1.0, 5)


@pytest.fixture
def exe_cache(tmp_path):
    from fxspace import _compile_cache as cc

    before = jax.config.jax_compilation_cache_dir
    cc._MEMO.clear()
    cc.configure_compile_cache(tmp_path / "jax")
    try:
        yield cc
    finally:
        cc._MEMO.clear()
        cc.configure_compile_cache("off")
        jax.config.update("jax_compilation_cache_dir", before)


def test_cached_executable_round_trip_and_fallback(exe_cache):
    """Written by the first call, read back (as a new process would: memo cleared) with the
    jitted function's results; another shape falls back to the jitted function; another
    structure or static configuration gets another key (never the wrong executable)."""
    cc = exe_cache
    A, b = _inputs()
    ref = _horn_like(A, b)
    first = cc.cached_executable(_horn_like, A, b)
    assert first.source == "compiled"
    files = list(cc.executable_cache_dir().glob("*.exe"))
    assert len(files) == 1 and cc.executable_cache_dir().parent == cc.compile_cache_dir().parent
    cc._MEMO.clear()
    again = cc.cached_executable(_horn_like, A, b)
    assert again.source == "disk" and again.compiled is not None
    for got, want in zip(again(A, b), ref, strict=True):
        np.testing.assert_allclose(np.asarray(got), np.asarray(want), rtol=1e-6)
    A5, b5 = _inputs(5)  # another shape: the jitted function answers, correctly
    for got, want in zip(again(A5, b5), _horn_like(A5, b5), strict=True):
        np.testing.assert_allclose(np.asarray(got), np.asarray(want), rtol=1e-6)
    assert cc._executable_key(_horn_like, (A5, b5)) != cc._executable_key(_horn_like, (A, b))
    assert cc._executable_key(_horn_like, ((A,), b)) != cc._executable_key(_horn_like, (A, b))
    assert cc._executable_key(_horn_like, (A, b)) == cc._executable_key(_horn_like, (A + 1, b))


def test_cached_executable_torn_file_is_recompiled(exe_cache):
    cc = exe_cache
    A, b = _inputs()
    cc.cached_executable(_horn_like, A, b)
    (path,) = cc.executable_cache_dir().glob("*.exe")
    path.write_bytes(path.read_bytes()[:1000])  # torn / foreign content
    cc._MEMO.clear()
    again = cc.cached_executable(_horn_like, A, b)
    assert again.source == "compiled"
    np.testing.assert_allclose(np.asarray(again(A, b)[0]), np.asarray(_horn_like(A, b)[0]))


def test_cached_executable_that_fails_its_first_run_is_dropped(exe_cache):
    """XLA can write an executable without the code of fusions its process compiled
    earlier: it loads, then fails on its first run ("Function ... not found"). The first
    run of a loaded executable is awaited; on failure the answer comes from the jitted
    function, the file is removed and its key marked, so no later process loads it."""
    cc = exe_cache
    A, b = _inputs()
    cc.cached_executable(_horn_like, A, b)
    (path,) = cc.executable_cache_dir().glob("*.exe")
    cc._MEMO.clear()
    loaded = cc.cached_executable(_horn_like, A, b)
    assert loaded.source == "disk"

    class _Broken:  # what a loaded executable without its code returns
        def block_until_ready(self):
            raise jax.errors.JaxRuntimeError("NOT_FOUND: Function fusion.3 not found")

    loaded.compiled = lambda *a: (_Broken(), _Broken())
    got = loaded(A, b)
    for g, w in zip(got, _horn_like(A, b), strict=True):
        np.testing.assert_allclose(np.asarray(g), np.asarray(w), rtol=1e-6)
    assert loaded.source == "jit" and loaded.compiled is None
    assert not path.exists() and path.with_suffix(".noexe").exists()
    cc._MEMO.clear()
    assert cc.cached_executable(_horn_like, A, b).source == "jit"


def test_cached_executable_off_without_the_compile_cache():
    from fxspace import _compile_cache as cc

    assert cc.compile_cache_dir() is None  # the suite runs with the cache off
    A, b = _inputs()
    out = cc.cached_executable(_horn_like, A, b)
    assert out.source == "jit" and out.compiled is None
    np.testing.assert_allclose(np.asarray(out(A, b)[1]), np.cumsum(np.linspace(0, 1, 5)))


_EXE_CHILD = textwrap.dedent(
    """
    import json, sys
    sys.path.insert(0, sys.argv[1])
    import jax.numpy as jnp, numpy as np
    from fxspace._compile_cache import cached_executable
    from test_compile_cache import _horn_like, _inputs
    A, b = _inputs()
    exe = cached_executable(_horn_like, A, b)
    out = exe(A, b)  # a deserialised LAPACK call in a fresh process: must not crash
    print("RESULT", json.dumps({"source": exe.source, "v": np.asarray(out[0]).tolist()}))
    """
)


def test_executable_read_by_a_fresh_process(tmp_path):
    """A second process reads the executable the first wrote and runs it (LAPACK's
    function pointers prepared first: without that a deserialised eigh crashes)."""
    env = {**os.environ, ENV: str(tmp_path / "jax"), "JAX_PLATFORMS": "cpu"}
    here = str(Path(__file__).resolve().parent)
    got = []
    for _ in range(2):
        r = subprocess.run([sys.executable, "-c", _EXE_CHILD, here], env=env,
                           capture_output=True, text=True, timeout=300)  # fmt: skip
        assert r.returncode == 0, r.stderr[-2000:]
        line = [ln for ln in r.stdout.splitlines() if ln.startswith("RESULT ")][-1]
        got.append(json.loads(line[len("RESULT ") :]))
    assert [g["source"] for g in got] == ["compiled", "disk"]
    assert got[1]["v"] == got[0]["v"]  # the same executable: the same bits
    np.testing.assert_allclose(got[1]["v"], np.asarray(_horn_like(*_inputs())[0]), rtol=1e-5)
