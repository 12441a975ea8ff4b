"""DTW: cost vs dtaidistance, path vs brute force, jit/vmap/grad, padded lengths, warps."""

import itertools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from dtaidistance import dtw_ndim
from helpers import check_grad

import fxspace as fx
from fxspace.motion import dtw_batch, dtw_padded, warp_from_path


def _all_paths(n, m):
    """Every monotone path from (0,0) to (n-1,m-1) with steps (1,0),(0,1),(1,1)."""

    def rec(i, j):
        if (i, j) == (n - 1, m - 1):
            yield [(i, j)]
            return
        for di, dj in ((1, 1), (1, 0), (0, 1)):
            if i + di < n and j + dj < m:
                for rest in rec(i + di, j + dj):
                    yield [(i, j)] + rest

    return list(rec(0, 0))


@pytest.mark.parametrize("shape", [(7, 5, 3), (12, 20, 1), (30, 30, 4), (1, 6, 2)])
def test_cost_and_path_match_dtaidistance(shape, rng):
    n, m, d = shape
    a, b = rng.standard_normal((n, d)), rng.standard_normal((m, d))
    r = fx.dtw(a, b)
    assert float(r.cost) == pytest.approx(dtw_ndim.distance(a, b), rel=1e-12)
    np.testing.assert_array_equal(np.asarray(r.path), np.asarray(dtw_ndim.warping_path(a, b)))
    assert r.path.shape == (int(r.path_length), 2)
    cost, path = r  # DESIGN.md: DTWResult(cost, path)
    assert cost is r.cost and path is r.path


@pytest.mark.parametrize("seed", range(4))
def test_path_is_optimal_by_brute_force(seed):
    rng = np.random.default_rng(seed)
    n, m = rng.integers(1, 5, size=2)
    a, b = rng.standard_normal((n, 2)), rng.standard_normal((m, 2))
    c = ((a[:, None] - b[None]) ** 2).sum(-1)
    costs = {tuple(p): sum(c[i, j] for i, j in p) for p in _all_paths(n, m)}
    best = min(costs.values())
    r = fx.dtw(a, b)
    assert float(r.cost) ** 2 == pytest.approx(best, rel=1e-12)
    path = tuple(map(tuple, np.asarray(r.path).tolist()))
    assert path in costs and costs[path] == pytest.approx(best, rel=1e-12)


def test_scalar_series_and_known_answer():
    # b is a with a repeated sample: the warp absorbs it, cost 0
    a = jnp.asarray([0.0, 1.0, 2.0, 3.0])
    b = jnp.asarray([0.0, 1.0, 1.0, 2.0, 3.0])
    r = fx.dtw(a, b)
    assert float(r.cost) == 0.0
    np.testing.assert_array_equal(r.path, [[0, 0], [1, 1], [1, 2], [2, 3], [3, 4]])


def test_jit_vmap_padded_and_batch(rng):
    A = rng.standard_normal((4, 15, 3))
    B = rng.standard_normal((4, 11, 3))
    loop = [fx.dtw(a, b) for a, b in zip(A, B, strict=True)]
    jitted = jax.jit(fx.dtw)(A[0], B[0])  # padded under jit
    assert int(jitted.path_length) == loop[0].path.shape[0]
    np.testing.assert_array_equal(jitted.path[: int(jitted.path_length)], loop[0].path)
    assert np.all(np.asarray(jitted.path[int(jitted.path_length) :]) == -1)
    for method in ("map", "vmap"):
        res = jax.jit(lambda a, b, m=method: dtw_batch(a, b, method=m))(A, B)
        for k, r in enumerate(loop):
            assert float(res.cost[k]) == pytest.approx(float(r.cost), rel=1e-12)
            np.testing.assert_array_equal(res.path[k, : int(res.path_length[k])], r.path)
    # different lengths in one padded batch
    n = jnp.asarray([15, 9, 4, 12])
    m = jnp.asarray([11, 11, 7, 3])
    res = dtw_batch(A, B, n_valid=n, m_valid=m)
    for k in range(4):
        ref = fx.dtw(A[k, : n[k]], B[k, : m[k]])
        assert float(res.cost[k]) == pytest.approx(float(ref.cost), rel=1e-12)
        np.testing.assert_array_equal(res.path[k, : int(res.path_length[k])], ref.path)


def test_grad_of_cost(rng):
    a = jnp.asarray(rng.standard_normal((6, 2)))
    b = jnp.asarray(rng.standard_normal((8, 2)))
    check_grad(jax.jit(lambda x: dtw_padded(x, b, with_path=False).cost), a, rng)


def test_warp_from_path_monotone(rng):
    a = rng.standard_normal((20, 2)).cumsum(0)
    b = rng.standard_normal((35, 2)).cumsum(0)
    w = np.asarray(warp_from_path(fx.dtw(a, b).path, 20))
    assert w[0] == 0.0 and w[-1] == 34.0 and np.all(np.diff(w) >= 0)
    # the padded path (under jit) gives the same warp
    p = jax.jit(fx.dtw)(a, b).path
    np.testing.assert_allclose(warp_from_path(p, 20), w)


def test_errors():
    with pytest.raises(ValueError, match="same d"):
        fx.dtw(np.zeros((3, 2)), np.zeros((3, 3)))
    with pytest.raises(ValueError, match="at least one frame"):
        fx.dtw(np.zeros((0, 2)), np.zeros((3, 2)))
    with pytest.raises(ValueError, match="method"):
        dtw_batch(np.zeros((1, 3, 2)), np.zeros((1, 3, 2)), method="fast")


def test_paths_helper_counts():
    # sanity of the brute-force enumerator: Delannoy numbers D(2,2)=13
    assert len(_all_paths(3, 3)) == 13
    assert len(list(itertools.islice(_all_paths(1, 4), 5))) == 1
