import jax
import jax.numpy as jnp
import numpy as np
import pytest

import fxspace as fx
from fxspace.cluster import fuzzy_cmeans
from fxspace.errors import FxspaceError


def _blobs(rng, n=600, c=6):
    centers = rng.uniform(-10, 10, (c, 2))
    lab = rng.integers(0, c, n)
    return centers[lab] + 0.5 * rng.standard_normal((n, 2)), centers


def test_all_centres_kept_equals_dense_fcm(rng):
    x, _ = _blobs(rng)
    v0 = fx.kmeanspp_init(jnp.asarray(x), 6, jax.random.key(1))
    dense = fx.fuzzy_cmeans(x, 6, init_centers=v0, tol=0.0, max_steps=40, check_every=1)
    sp = fuzzy_cmeans(x, 6, nearest=6, init_centers=v0, tol=0.0, max_steps=40)
    np.testing.assert_allclose(np.asarray(sp.centers), np.asarray(dense.centers), atol=1e-8)
    U = np.zeros((len(x), 6))
    np.put_along_axis(U, np.asarray(sp.indices), np.asarray(sp.memberships), axis=1)
    np.testing.assert_allclose(U, np.asarray(dense.memberships), atol=1e-8)
    assert np.isclose(float(sp.objective), float(dense.objective), rtol=1e-8)


def test_few_nearest_centres_find_the_blobs(rng):
    x, truth = _blobs(rng, 3000, 8)
    sp = fuzzy_cmeans(x, 8, nearest=3, key=jax.random.key(0), max_steps=200)
    assert sp.indices.shape == (3000, 3) and sp.memberships.shape == (3000, 3)  # O(n·p)
    np.testing.assert_allclose(np.asarray(sp.memberships).sum(axis=1), 1.0, rtol=1e-10)
    got = np.asarray(sp.centers)
    err = np.sqrt(((truth[:, None] - got[None]) ** 2).sum(-1)).min(axis=1)
    assert np.all(err < 0.5) and bool(sp.converged) and int(sp.num_steps) < 200
    dense = fx.fuzzy_cmeans(x, 8, init_centers=sp.centers, max_steps=200)
    assert abs(float(sp.objective) - float(dense.objective)) < 0.05 * float(dense.objective)


def test_jit_and_bad_arguments(rng):
    x, _ = _blobs(rng, 200, 3)
    f = jax.jit(lambda v: fuzzy_cmeans(x, 3, nearest=2, init_centers=v).centers)
    v0 = jnp.asarray(x[:3])
    np.testing.assert_allclose(
        np.asarray(f(v0)), np.asarray(fuzzy_cmeans(x, 3, nearest=2, init_centers=v0).centers)
    )
    with pytest.raises(FxspaceError, match="n_clusters"):
        fuzzy_cmeans(x, 0, nearest=2, key=jax.random.key(0))
    with pytest.raises(FxspaceError, match="key"):
        fuzzy_cmeans(x, 3, nearest=2)
    with pytest.raises(FxspaceError, match="fuzzifier"):
        fuzzy_cmeans(x, 3, m=1.0, nearest=2, key=jax.random.key(0))


def test_one_name_full_or_truncated_memberships_and_options_refused_by_name():
    """Issue 29: `fuzzy_cmeans` is one routine; ``nearest`` picks truncated memberships
    (a `SparseFCMResult`), and an option of the other implementation is refused."""
    x = np.random.default_rng(3).normal(size=(120, 2))
    full = fuzzy_cmeans(x, 4, key=jax.random.key(0))
    assert isinstance(full, fx.FCMResult) and full.memberships.shape == (120, 4)
    cut = fuzzy_cmeans(x, 4, nearest=4, init_centers=full.centers, tol=1e-9, max_steps=500)
    assert isinstance(cut, fx.cluster.SparseFCMResult) and cut.memberships.shape == (120, 4)
    # p = c: the truncated FCM is FCM (the same fixed point as the full run)
    np.testing.assert_allclose(np.sort(np.asarray(cut.centers), 0),
                               np.sort(np.asarray(full.centers), 0), atol=1e-3)  # fmt: skip
    with pytest.raises(fx.FxspaceError, match="n_init.*full memberships"):
        fuzzy_cmeans(x, 4, nearest=2, n_init=3, key=jax.random.key(0))
    with pytest.raises(fx.FxspaceError, match="chunk.*nearest"):
        fuzzy_cmeans(x, 4, chunk=64, key=jax.random.key(0))


def _truncated_fcm_reference(x, v, p, steps):
    """Bezdek's truncated steps with every centre looked at on every step (numpy)."""
    x, v = np.asarray(x, np.float64), np.asarray(v, np.float64).copy()
    for _ in range(steps):
        d2 = ((x[:, None, :] - v[None]) ** 2).sum(-1)
        idx = np.argsort(d2, axis=1, kind="stable")[:, :p]
        w = 1.0 / np.maximum(np.take_along_axis(d2, idx, 1), 1e-300)
        um = (w / w.sum(1, keepdims=True)) ** 2
        mass = np.bincount(idx.ravel(), um.ravel(), minlength=len(v))
        num = np.stack([np.bincount(idx.ravel(), (um * x[:, k, None]).ravel(), minlength=len(v))
                        for k in range(x.shape[1])], 1)  # fmt: skip
        v = np.where(mass[:, None] > 0, num / np.where(mass > 0, mass, 1.0)[:, None], v)
    return v


@pytest.mark.parametrize("c, p", [(60, 4), (40, 8), (12, 3)])
def test_candidate_lists_give_the_full_search_steps(rng, c, p):
    """Between full passes each point ranks only its 16 listed centres; the steps must be
    those of the search over every centre (the list is re-made whenever it could miss)."""
    x = rng.normal(size=(3000, 2)) * np.array([3.0, 1.0])
    v0 = x[rng.choice(len(x), c, replace=False)]
    res = fuzzy_cmeans(jnp.asarray(x), c, nearest=p, init_centers=jnp.asarray(v0),
                       tol=0.0, max_steps=40)  # fmt: skip
    assert int(res.num_steps) == 40
    ref = _truncated_fcm_reference(x, v0, p, 40)
    np.testing.assert_allclose(np.asarray(res.centers), ref, rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize(("n", "rows", "sizes"), [
    (100_000, 65536, [50_000, 50_000]), (10, 4, [4, 3, 3]), (12, 4, [4, 4, 4]), (7, 7, [7])])
def test_blocks_are_as_few_as_rows_allow_and_of_equal_size(n, rows, sizes):
    """`rows_per_task` bounds a block: as few blocks as it allows, their sizes within one
    point of each other (the threads finish a step together, one compiled kernel), every
    point in exactly one block, in order."""
    from fxspace.cluster._fcm_blocks import _STATES, _Blocks

    x = np.arange(2 * n, dtype=np.float32).reshape(n, 2)
    b = _Blocks(x, rows, 3, None)
    try:
        parts = [np.asarray(_STATES[b.run, i][0]) for i in b.blocks]
        assert [len(p) for p in parts] == sizes
        np.testing.assert_array_equal(np.concatenate(parts), x)
    finally:
        b.close()


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_precompiled_block_kernels_leave_the_runs_nothing_to_compile(dtype):
    """`precompile` (a hierarchy's later levels, compiled in a thread beside the first)
    compiles exactly the block kernels `blocked_fcm` then calls: the runs for every
    centre count given, with unequal blocks (1001 points in blocks of ≤ 300: 250 and
    251), compile neither `_block_step` nor `_assign`; a count not given does (the check
    can fail)."""
    from fxspace.cluster import _fcm_blocks as FB

    def kernels_compiled(run):
        import jax.monitoring as mon

        names = []

        def heard(event, _duration, **kw):
            if event == "/jax/core/compile/backend_compile_duration":
                names.append(kw.get("fun_name"))

        mon.register_event_duration_secs_listener(heard)
        try:
            run()
        finally:
            mon.unregister_event_duration_listener(heard)
        return [n for n in names if n in ("jit(_block_step)", "jit(_assign)")]

    x = np.random.default_rng(0).normal(size=(1001, 2)).astype(dtype)
    m = 2.0 + 1e-3 * (dtype == np.float64)  # a static argument no other test compiles with
    got = kernels_compiled(lambda: FB.precompile(len(x), 2, dtype, [5, 12], m, 3, 128, 300))
    assert len(got) in (0, 8)  # 2 counts × 2 block sizes × 2 kernels (0: already compiled)
    for c, want in ((5, 0), (12, 0), (7, 4)):
        v0 = x[np.linspace(0, 1000, c).astype(int)]
        with jax.enable_x64(dtype == np.float64):
            got = kernels_compiled(lambda v0=v0: FB.blocked_fcm(x, v0, m, 3, 1e-4, 50, 128, 300))
        assert len(got) == want, (c, got)
