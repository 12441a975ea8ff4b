"""Issue 45: the fused FCM loop (centres only, (c, n) layout) against the plain loop, and
k-means++-extend / the level split compiling once for every level with the same draws."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import fxspace as fx
from fxspace.cluster._kmeanspp import _kpp_draws, kmeanspp_extend, squared_distances
from fxspace.navigation._hierarchy import _split, _split_dirs, split_centers


def _blobs(rng, n=240, k=5):
    c = rng.normal(scale=4.0, size=(k, 2))
    return jnp.asarray(c[rng.integers(0, k, n)] + rng.normal(scale=0.5, size=(n, 2)))


@pytest.mark.parametrize("m", [2.0, 1.7])
@pytest.mark.parametrize("criterion", ["max", "fro"])
@pytest.mark.parametrize("start", ["centers", "memberships", "kmeans++"])
def test_fused_loop_equals_plain_loop(rng, m, criterion, start):
    x = _blobs(rng)
    kw = {"centers": {"init_centers": x[:6]},
          "memberships": {"init_memberships": jnp.asarray(rng.uniform(size=(240, 6)))},
          "kmeans++": {"key": jax.random.PRNGKey(3)}}[start]  # fmt: skip
    # tol = 0: both run every step; 40 steps in blocks of 4 (fused) or one at a time (plain)
    fused = fx.fuzzy_cmeans(x, 6, m, tol=0.0, max_steps=40, criterion=criterion, **kw)
    plain = fx.fuzzy_cmeans(x, 6, m, tol=0.0, max_steps=40, criterion=criterion,
                            check_every=1, **kw)  # fmt: skip
    assert int(fused.num_steps) == int(plain.num_steps) == 40
    np.testing.assert_allclose(fused.centers, plain.centers, rtol=1e-10, atol=1e-10)
    np.testing.assert_allclose(fused.memberships, plain.memberships, atol=1e-12)
    np.testing.assert_allclose(float(fused.objective), float(plain.objective), rtol=1e-12)


def test_fused_loop_stops_at_the_same_fixed_point(rng):
    x = _blobs(rng)
    a = fx.fuzzy_cmeans(x, 5, key=jax.random.PRNGKey(0), tol=1e-8, max_steps=400)
    b = fx.fuzzy_cmeans(x, 5, key=jax.random.PRNGKey(0), tol=1e-8, max_steps=401)  # plain
    assert bool(a.converged) and bool(b.converged)
    assert abs(int(a.num_steps) - int(b.num_steps)) <= 4
    np.testing.assert_allclose(a.centers, b.centers, atol=1e-6)
    assert float(a.stats["delta"]) < 1e-8


def test_fused_loop_zero_steps_and_jit_vmap(rng):
    x = _blobs(rng, n=60)
    r0 = fx.fuzzy_cmeans(x, 3, init_centers=x[:3], max_steps=0)
    assert int(r0.num_steps) == 0
    np.testing.assert_array_equal(r0.centers, x[:3])
    one = jax.jit(lambda v: fx.fuzzy_cmeans(x, 3, init_centers=v, max_steps=20).centers)
    starts = jnp.stack([x[:3], x[3:6]])
    np.testing.assert_allclose(jax.vmap(one)(starts), jnp.stack([one(s) for s in starts]),
                               atol=1e-12)  # fmt: skip


def _extend_reference(x, centers, n_new, key):
    """k-means++-extend as first written (centre rows carried in the loop)."""
    closest = jnp.min(squared_distances(x, centers), axis=1)
    out = []
    for _ in range(n_new):
        key, sub = jax.random.split(key)
        logits = jnp.where(jnp.sum(closest) > 0, jnp.log(closest), jnp.zeros_like(closest))
        c = x[jax.random.categorical(sub, logits)]
        closest = jnp.minimum(closest, jnp.sum(jnp.square(x - c[None, :]), axis=1))
        out.append(c)
    return jnp.concatenate([centers, jnp.stack(out)])


@pytest.mark.parametrize("n_new", [1, 7, 90])
def test_kmeanspp_extend_draws_as_before(rng, n_new):
    x = _blobs(rng, n=80)
    key = jax.random.PRNGKey(n_new)
    got = kmeanspp_extend(x, x[:4] + 0.1, n_new, key)
    np.testing.assert_array_equal(got, _extend_reference(x, x[:4] + 0.1, n_new, key))
    under_jit = jax.jit(lambda k: kmeanspp_extend(x, x[:4] + 0.1, n_new, k))(key)
    np.testing.assert_array_equal(under_jit, got)


def test_kmeanspp_extend_compiles_once_for_every_level(rng):
    x = _blobs(rng, n=100)
    before = _kpp_draws._cache_size()
    for c in (3, 6, 12):
        assert kmeanspp_extend(x, x[:c], c, jax.random.PRNGKey(c)).shape == (2 * c, 2)
    assert _kpp_draws._cache_size() - before <= 1
    bad = x.at[0, 0].set(jnp.nan)
    assert bool(jnp.all(jnp.isnan(kmeanspp_extend(bad, x[:3], 2, jax.random.PRNGKey(0)))))


def test_split_compiles_once_and_matches_under_jit(rng):
    x = _blobs(rng, n=150)
    before = _split_dirs._cache_size()
    for c in (4, 8, 16):
        fit = fx.fuzzy_cmeans(x, c, key=jax.random.PRNGKey(c), max_steps=50)
        eager = split_centers(x, fit.centers, fit.memberships, 2 * c - 1)
        traced = jax.jit(lambda v, u, c=c: split_centers(x, v, u, 2 * c - 1))(
            fit.centers, fit.memberships)
        assert eager.shape == (2 * c - 1, 2)
        np.testing.assert_allclose(eager, traced, rtol=1e-12, atol=1e-12)
        # the children straddle their parents: each split pair's midpoint is the old centre
        kept = np.isin(np.asarray(eager[:c]), np.asarray(fit.centers)).all(axis=1)
        assert int((~kept).sum()) == c - 1
    assert _split_dirs._cache_size() - before <= 1


def test_padded_centres_give_the_same_iterates(rng):
    # few centres on a small set run padded (one kernel for every c up to 80): as unpadded
    from fxspace.cluster._fcm import _fcm_jit, _padded_size

    x = _blobs(rng, n=300)
    assert _padded_size(300, 7) == 80 and _padded_size(10**6, 7) == 7
    for c in (3, 7):
        got = fx.fuzzy_cmeans(x, c, init_centers=x[:c], tol=0.0, max_steps=40)
        want = _fcm_jit(x, c, 2.0, jnp.asarray(0.0), 40, 1, jax.random.PRNGKey(0), x[:c], None,
                        "max", 4)  # fmt: skip
        assert got.centers.shape == (c, 2) and got.memberships.shape == (300, c)
        np.testing.assert_allclose(got.centers, want.centers, rtol=1e-10, atol=1e-10)
        np.testing.assert_allclose(got.memberships, want.memberships, atol=1e-12)
        np.testing.assert_allclose(got.memberships.sum(1), 1.0, rtol=1e-12)
        assert int(got.num_steps) == 40 and float(got.objective) == pytest.approx(
            float(want.objective), rel=1e-12)


def test_padding_depends_on_the_centres_not_the_points():
    """The shared-compile padding is a ladder of centre counts (80, 320, 1280, …): never
    the number of points, so 3 × 10⁵ points' k-means++-extend and split stay O(n·c)."""
    assert [fx.cluster.pad_rows(c) for c in (1, 80, 81, 320, 321, 1280, 5000)] == [
        80, 80, 320, 320, 1280, 1280, 5120]
    rng = np.random.default_rng(0)
    x = jnp.asarray(rng.normal(size=(300_000, 2)), jnp.float32)  # n × n would be 360 GB
    got = kmeanspp_extend(x, x[:4], 4, jax.random.PRNGKey(0))
    assert got.shape == (8, 2) and bool(jnp.all(jnp.isfinite(got)))
    lab = jnp.zeros(300_000, jnp.int32).at[::2].set(1)
    w = jnp.ones(300_000, jnp.float32)
    v = jnp.asarray([[0.0, 0.0], [0.5, 0.5]], jnp.float32)
    assert _split(x, v, lab, w, 1).shape == (3, 2)
