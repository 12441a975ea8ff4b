"""Issue 33: one test per example of "Silent wrong", "Raw tracebacks", "Hangs" and "Wrong
cause named" (each failed before its fix): bad arguments raise a `FxspaceError` naming the
argument, overflow is never "successful", NaN in gives NaN out."""

from __future__ import annotations

import os

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import fxspace as fx
from fxspace import motion as M
from fxspace.errors import FxspaceError

RNG = np.random.default_rng(0)


def _dist(n=10, d=3, seed=0):
    P = np.random.default_rng(seed).normal(size=(n, d))
    return np.linalg.norm(P[:, None] - P[None], axis=-1)


# -- silent wrong ---------------------------------------------------------------------------
def test_fused_lasso_all_zero_weights_refused():
    Y = RNG.normal(size=(16, 2))
    with pytest.raises(FxspaceError, match="weights"):
        fx.fused_lasso(Y, 0, 1, weights=np.zeros((16, 2)))
    # a channel with one weighted frame is fine: the known answer is that frame's value
    w = np.zeros((16, 2))
    w[3] = 1.0
    out = np.asarray(fx.fused_lasso(Y, 0, 1e-3, weights=w))
    np.testing.assert_allclose(out[3], Y[3], atol=1e-2)


def test_dtw_huge_scale_is_finite_or_not_successful():
    A = RNG.normal(size=(10, 2))
    B = RNG.normal(size=(12, 2))
    ref = fx.dtw(jnp.asarray(A), jnp.asarray(B))
    big = fx.dtw(jnp.asarray(A * 1e30), jnp.asarray(B * 1e30))
    if big.result == fx.RESULTS.successful:
        assert np.isfinite(float(big.cost))
        np.testing.assert_allclose(float(big.cost) / 1e30, float(ref.cost), rtol=1e-4)
        np.testing.assert_array_equal(np.asarray(big.path), np.asarray(ref.path))
    else:
        assert not bool(big.converged)


def test_dtw_overflowing_cost_reported():
    A = np.full((4, 1), 3e38, np.float32)
    B = np.full((4, 1), -3e38, np.float32)
    res = fx.dtw(jnp.asarray(A), jnp.asarray(B))
    assert res.result == fx.RESULTS.nonfinite_output
    with pytest.raises(FxspaceError, match="dtw"):
        fx.dtw(jnp.asarray(A), jnp.asarray(B), throw=True)


def test_fit_control_points_huge_scale_refused():
    X = (RNG.normal(size=(5, 60, 3)) * 1e30).astype(np.float32)  # squares overflow float32
    with pytest.raises(FxspaceError, match="X is too large"):
        fx.fit_control_points(X, 4, key=jax.random.PRNGKey(0), n_init=2)


def test_distance_matrix_checks():
    D = _dist()
    asym = D.copy()
    asym[0, 1] += 1.0
    for bad, word in ((asym, "symmetric"), (-D, "non-negative")):
        with pytest.raises(FxspaceError, match=word):
            fx.classical_mds(jnp.asarray(bad))
        with pytest.raises(FxspaceError, match=word):
            fx.threshold_sweep(jnp.asarray(bad), jnp.asarray([1.0, 2.0]))
    # the valid matrix still embeds exactly (known answer: 3-D points need 3 dims)
    res = fx.classical_mds(jnp.asarray(D), dim=3)
    E = np.linalg.norm(
        np.asarray(res.embedding)[:, None] - np.asarray(res.embedding)[None], axis=-1
    )
    np.testing.assert_allclose(E, D, atol=1e-3)


def test_kernel_kmeans_labels_out_of_range_refused():
    X = RNG.normal(size=(20, 2))
    with pytest.raises(FxspaceError, match="init labels"):
        fx.kernel_kmeans(X, 2, key=jax.random.PRNGKey(0), init=np.full((1, 20), 5))


def test_navigate_float_centres_refused():
    xy = RNG.normal(size=(30, 2))
    P = fx.pairwise_distances(jnp.asarray(xy))
    geo = fx.geodesic_distances(fx.epsilon_graph(P, float(fx.connecting_threshold(P)) * 1.3))
    h = fx.build_hierarchy(xy, geo, c0=4, key=jax.random.PRNGKey(0), restarts=0)
    with pytest.raises(FxspaceError, match="centres"):
        fx.navigate(h, geo, [0.9, 2.2])
    with pytest.raises(FxspaceError, match="centres"):
        fx.navigate(h, geo, [0.0, 2.0])  # an index is never a float
    with pytest.raises(FxspaceError, match="h must be a Hierarchy"):
        fx.navigate(None, geo, [0, 2])  # checked before the body, from the annotation


def test_advance_clock_nan_and_signs():
    warps = jnp.array([[0.0, 1, 2, 3], [0, 2, 4, 6]])
    w = jnp.array([0.5, 0.5])
    assert np.isnan(float(M.advance_clock(jnp.nan, warps, w)))
    assert np.isnan(float(M.advance_clock_duration(jnp.nan, warps, w)))
    # known answer of the docstring: slopes 1 and 2 → (0.5·1 + 0.5·0.5) = 0.75
    np.testing.assert_allclose(float(M.advance_clock(1.0, warps, w)), 0.75, rtol=1e-6)
    with pytest.raises(FxspaceError, match="w must be >= 0"):
        M.advance_clock(1.0, warps, jnp.array([-0.5, 0.5]))
    with pytest.raises(FxspaceError, match="dt must be > 0"):
        M.advance_clock(1.0, warps, w, dt=-1.0)
    # under jit the value checks are skipped but NaN still propagates
    assert np.isnan(float(jax.jit(M.advance_clock)(jnp.nan, warps, w)))


def test_align_clocks_alpha_range():
    lam = jnp.arange(5.0) * 2
    with pytest.raises(FxspaceError, match="alpha"):
        M.align_clocks(1.0, 2.0, lam, alpha=5.0)
    tl, tu = M.align_clocks(3.0, 4.0, jnp.arange(10.0) * 2, alpha=0.5)  # docstring example
    np.testing.assert_allclose([float(tl), float(tu)], [2.5, 5.0], rtol=1e-6)


# -- raw tracebacks -------------------------------------------------------------------------
def test_mds_lobpcg_tiny_matrix():
    with pytest.raises(FxspaceError, match="lobpcg"):
        fx.classical_mds(jnp.asarray(_dist()), method="lobpcg")


def test_fuzzy_cmeans_batch_of_keys():
    X = jnp.asarray(RNG.normal(size=(20, 2)))
    with pytest.raises(FxspaceError, match="key"):
        fx.fuzzy_cmeans(X, 3, key=jax.random.split(jax.random.PRNGKey(0), 2))


def test_rest_pose_of_ik_model_like():
    class _Model:
        ancestors = np.zeros((4, 4))

    p = fx.rest_pose(_Model())
    assert p.angles.shape == (4, 3)
    with pytest.raises(FxspaceError, match="num_joints"):
        fx.rest_pose("x")


@pytest.mark.parametrize(
    "schedule,seconds,word",
    [
        ([], 0.001, "one frame"),
        ([("1s", {})], 1.0, "schedule"),
        ([(1.0,)], 1.0, "schedule"),
        (None, 1.0, "schedule"),
        ([], 1e8, "GiB"),
    ],
)
def test_session_arguments(schedule, seconds, word):
    from fxspace.motion._session_checks import check_session_args

    with pytest.raises(FxspaceError, match=word):
        check_session_args(schedule, seconds, 120.0, 31)


def test_session_arguments_valid():
    from fxspace.motion._session_checks import check_session_args

    assert check_session_args([(0, {"alpha": 1})], 1.0, 30.0, 5) == [(0.0, {"alpha": 1})]


def test_playback_huge_duration_refused():
    emb = RNG.normal(size=(5, 2))
    pos = RNG.normal(size=(5, 3, 3))
    with pytest.raises(FxspaceError, match="GiB"):
        fx.playback([0, 1, 2], emb, pos, duration=1e9)


def _square():
    V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0.0]])
    F = np.array([[0, 2, 1], [1, 2, 3]])
    return V, F


def test_place_markers_arguments():
    V, F = _square()
    with pytest.raises(FxspaceError, match="seed"):
        fx.place_markers(V, F, 1, seed=-1)
    with pytest.raises(FxspaceError, match="num_markers"):
        fx.place_markers(V, F, 1.5)
    Vn = V.copy()
    Vn[0, 0] = np.nan
    with pytest.raises(FxspaceError, match="vertices"):
        fx.place_markers(Vn, F, 1)


# -- hangs ----------------------------------------------------------------------------------
@pytest.mark.parametrize("port", [70000, -5, 2.5])
def test_studio_port_checked_first(port, tmp_path):
    from fxspace.studio import serve

    with pytest.raises(FxspaceError, match="port"):
        serve(tmp_path, port=port)


def test_read_markers_named_pipe_does_not_block(tmp_path):
    fifo = tmp_path / "x.trc"
    os.mkfifo(fifo)
    with pytest.raises(FxspaceError, match="named pipe"):
        fx.io.read_markers(fifo)


# -- wrong cause named ----------------------------------------------------------------------
def test_segment_motion_constant_take_not_called_nan():
    seg = fx.segment_motion(np.ones((50, 3)))
    assert seg is not None  # a still take: no "NaN/inf" error


def test_symlink_loop_named(tmp_path):
    a = tmp_path / "a.trc"
    a.symlink_to(tmp_path / "a.trc")
    with pytest.raises(FxspaceError, match="symlink loop"):
        fx.io.read_markers(a)


def test_fxspace_data_pointing_at_file(tmp_path, monkeypatch):
    f = tmp_path / "data"
    f.write_text("x")
    monkeypatch.setenv("FXSPACE_DATA", str(f))
    from fxspace.data import data_path

    with pytest.raises(FileNotFoundError, match="is a file"):
        data_path("face")


def test_max_points_zero_named():
    X = RNG.normal(size=(5, 30, 3))
    with pytest.raises(FxspaceError, match="max_points"):
        fx.fit_control_points(X, 2, key=jax.random.PRNGKey(0), max_points=0)


def test_every_clock_and_time_warp_helper_gives_nan_for_nan():
    """Issue 33.4: NaN in gives NaN out in every clock and time-warp helper (a NaN time,
    weight, step or α is never turned into a plausible clock)."""
    import fxspace.motion as M

    nan = float("nan")
    warps = np.stack([np.linspace(0, 9, 10), np.linspace(0, 12, 10)])
    lam = np.linspace(0, 18, 10)
    w = np.array([0.5, 0.5])
    outs = [
        M.warp_slopes(warps, nan),
        M.interp_curve(lam, nan),
        M.invert_curve(lam, nan),
        M.advance_clock(nan, warps, w),
        M.advance_clock(1.0, warps, np.array([nan, 0.5])),
        M.advance_clock(1.0, warps, w, nan),
        M.advance_clock_duration(nan, warps, w),
        M.advance_clock_duration(1.0, warps, np.array([nan, 0.5])),
        *M.align_clocks(nan, 2.0, lam),
        *M.align_clocks(2.0, nan, lam),
        *M.align_clocks(2.0, 3.0, lam, nan),
    ]
    for i, o in enumerate(outs):
        assert np.all(np.isnan(np.asarray(o))), i
    assert np.all(np.isfinite(np.asarray(M.warp_slopes(warps, 2.5))))  # and finite for finite
