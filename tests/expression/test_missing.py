"""Issue 10, cases 1–2: occluded markers never become numbers; accurate float32 distances."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.spatial.distance import cdist

import fxspace as fx
from fxspace.datasets import FaceData, load_face
from fxspace.expression import require_complete


def _smooth(rng, T=60, M=5):
    t = np.linspace(0, 2 * np.pi, T)[:, None, None]
    phase = rng.uniform(0, np.pi, (1, M, 3))
    return 50 * np.sin(t + phase) + 10 * np.cos(2 * t + 2 * phase)


# --- NaN propagates, never zeroed ---------------------------------------------------------


def test_distance_features_keep_nan(rng):
    X = rng.standard_normal((4, 5, 3))
    X[1, 2] = np.nan
    F = np.asarray(fx.distance_features(X))
    i, j = np.triu_indices(5, 1)
    touches = (i == 2) | (j == 2)
    assert np.all(np.isnan(F[1, touches])) and np.all(np.isfinite(F[1, ~touches]))
    assert np.all(np.isfinite(F[[0, 2, 3]]))


def test_pairwise_nan_row_only(rng):
    F = rng.standard_normal((6, 4))
    F[2, 1] = np.nan
    for dtype in (np.float32, np.float64):
        P = np.asarray(fx.pairwise_distances(F.astype(dtype)))
        assert np.all(np.isnan(P[2])) and np.all(np.isnan(P[:, 2]))
        keep = [0, 1, 3, 4, 5]
        ref = cdist(F[keep], F[keep])
        np.testing.assert_allclose(P[np.ix_(keep, keep)], ref, rtol=1e-5, atol=1e-6)


def test_inf_marker_rejected(rng):
    X = rng.standard_normal((4, 5, 3))
    X[0, 0, 0] = np.inf
    with pytest.raises(fx.FxspaceError, match="inf"):
        fx.distance_features(X)


def test_expression_space_names_missing_markers(rng):
    X = _smooth(rng, 80, 6)
    X[20:31, 3] = np.nan
    with pytest.raises(fx.FxspaceError, match=r"marker 3 frames 20–30"):
        fx.expression_space(X, 100.0)


def test_classical_mds_nonfinite():
    D = np.abs(np.subtract.outer(np.arange(6.0), np.arange(6.0)))
    D[1, 2] = D[2, 1] = np.nan
    with pytest.raises(fx.FxspaceError, match="NaN/inf"):
        fx.classical_mds(D)
    res = jax.jit(lambda d: fx.classical_mds(d, 2))(jnp.asarray(D))
    assert not bool(res.converged)
    ok = fx.classical_mds(np.nan_to_num(D, nan=1.0))
    assert bool(ok.converged) and ok.num_steps.shape == ()


@pytest.mark.parametrize(
    "x, match",
    [
        (np.zeros((3, 4, 3), np.complex64), "complex"),
        (np.zeros((3, 4, 3), np.float16), "float16"),
        (np.zeros((0, 4, 3)), "empty"),
        (np.zeros((3, 4)), "positions"),
    ],
)
def test_feature_inputs_rejected(x, match):
    with pytest.raises(fx.FxspaceError, match=match):
        fx.distance_features(x)


def test_int_positions_converted():
    X = np.arange(24).reshape(2, 4, 3)
    F = np.asarray(fx.distance_features(X))
    assert F.dtype.kind == "f"
    ref = np.sqrt(2) * cdist(X[0], X[0])[np.triu_indices(4, 1)]  # the full-matrix weight
    np.testing.assert_allclose(F[0], ref, rtol=1e-6)


# --- fill_gaps -------------------------------------------------------------------------


def test_fill_gaps_linear_matches_numpy_interp(rng):
    X = _smooth(rng)
    Y = X.copy()
    Y[10:15, 1] = np.nan  # 5 frames: filled
    Y[30:50, 2] = np.nan  # 20 frames: too long
    Y[0:3, 4] = np.nan  # touches the start: never extrapolated
    res = fx.fill_gaps(Y, max_gap=10)
    assert res.positions.shape == X.shape and res.filled.shape == (60, 5)
    assert res.filled.sum() == 5 and res.filled[10:15, 1].all()
    t = np.arange(60)
    known = np.isfinite(Y[:, 1, 0])
    for k in range(3):
        np.testing.assert_allclose(
            res.positions[10:15, 1, k], np.interp(t[10:15], t[known], Y[known, 1, k]), rtol=1e-12
        )
    assert np.isnan(res.positions[30:50, 2]).all() and np.isnan(res.positions[0:3, 4]).all()
    assert ("marker 2", 30, 49) in res.unfilled and ("marker 4", 0, 2) in res.unfilled
    np.testing.assert_array_equal(res.positions[~np.isnan(Y)], Y[~np.isnan(Y)])


def test_fill_gaps_cubic_is_closer_on_smooth_motion(rng):
    X = _smooth(rng, 120)
    Y = X.copy()
    Y[40:48, 0] = np.nan
    lin = fx.fill_gaps(Y, 10).positions
    cub = fx.fill_gaps(Y, 10, method="cubic").positions
    e_lin = np.abs(lin[40:48, 0] - X[40:48, 0]).max()
    e_cub = np.abs(cub[40:48, 0] - X[40:48, 0]).max()
    assert e_cub < e_lin


def test_fill_gaps_arguments(rng):
    X = _smooth(rng)
    with pytest.raises(fx.FxspaceError, match="max_gap"):
        fx.fill_gaps(X, max_gap=-1)
    with pytest.raises(fx.FxspaceError, match="method"):
        fx.fill_gaps(X, method="spline")
    res = fx.fill_gaps(X, max_gap=0)
    assert not res.filled.any() and res.unfilled == []


def test_require_complete_names_markers(rng):
    X = _smooth(rng)
    X[5:9, 1] = np.nan
    with pytest.raises(fx.FxspaceError, match="b frames 5–8"):
        require_complete(X, ["a", "b", "c", "d", "e"])


# --- accurate float32 distances ------------------------------------------------------------


def test_float32_distances_accurate_on_near_pairs(rng):
    # far from the origin, tiny separations: the float32 Gram expansion loses these
    base = rng.standard_normal(300) * 50 + 400
    F = (base[None, :] + rng.standard_normal((40, 300)) * 1e-2).astype(np.float32)
    P = np.asarray(fx.pairwise_distances(jnp.asarray(F)))
    assert P.dtype == np.float32
    ref = cdist(F.astype(np.float64), F.astype(np.float64))
    off = ~np.eye(40, dtype=bool)
    assert np.max(np.abs(P - ref)[off] / ref[off]) <= 1e-5
    np.testing.assert_allclose(jax.jit(fx.pairwise_distances)(jnp.asarray(F)), P, rtol=1e-6)


def test_float32_distances_grad_and_vmap(rng):
    F = jnp.asarray(rng.standard_normal((8, 5)), jnp.float32)
    v = jnp.asarray(rng.standard_normal((8, 5)), jnp.float32)

    def f(x):
        return jnp.sum(fx.pairwise_distances(x) ** 2 * 0.5 + fx.pairwise_distances(x))

    g = jax.grad(f)(F)
    F64 = F.astype(jnp.float64)
    g64 = jax.grad(f)(F64)  # float64 path: plain Gram autodiff, an independent reference
    np.testing.assert_allclose(g, g64, rtol=1e-4, atol=1e-4)
    eps = 1e-3
    fd = (f(F64 + eps * v) - f(F64 - eps * v)) / (2 * eps)
    np.testing.assert_allclose(jnp.sum(g * v), fd, rtol=1e-3)
    batched = jax.vmap(fx.pairwise_distances)(jnp.stack([F, 2 * F]))
    np.testing.assert_allclose(batched[1], 2 * fx.pairwise_distances(F), rtol=1e-5)


@pytest.mark.data
def test_float32_distances_real_capture(data_dir):
    seq = fx.io.read_markers(data_dir / "face" / "animface_cheeks.c3d")
    pos = np.asarray(seq.positions)[::2]
    F = fx.distance_features(pos.astype(np.float32))
    P = np.asarray(fx.pairwise_distances(F))
    Fn = np.asarray(F, np.float64)
    ref = cdist(Fn, Fn)
    off = ~np.eye(len(Fn), dtype=bool)
    assert np.max(np.abs(P - ref)[off] / ref[off]) <= 1e-5


# --- a real capture with occluded markers -----------------------------------------------


def _cut_gaps(pos):
    """Gaps of 1, 4, 9 (fillable) and 40, 120 (not) frames on several markers at once."""
    cut = pos.copy()
    gaps = [(3, 100, 1), (7, 200, 4), (7, 400, 9), (12, 200, 9), (20, 600, 40), (30, 300, 120)]
    for m, a, n in gaps:
        cut[a : a + n, m] = np.nan
    return cut, gaps


@pytest.mark.data
def test_real_capture_with_gaps_fill_close_to_uncut(tmp_path, data_dir):
    seq = fx.io.read_markers(data_dir / "face" / "animface_cheeks.c3d").to_units("mm")
    pos = np.asarray(seq.positions)[:900]
    cut, _ = _cut_gaps(pos)
    path = tmp_path / "cut.trc"
    fx.io.write_trc(path, fx.io.MarkerSequence(cut, seq.names, seq.rate, "mm"))
    raw = fx.io.read_markers(path)
    assert np.isnan(np.asarray(raw.positions)).any()

    # raise: names the markers and the frames
    with pytest.raises(fx.FxspaceError, match=r"frames 300–419"):
        load_face(FaceData(source="files", paths=(str(path),), missing="raise"))

    face = load_face(FaceData(source="files", paths=(str(path),), missing="fill", max_gap=10))
    # 1-, 4- and 9-frame gaps filled; the 40- and 120-frame gaps dropped (160 frames)
    # frames with a filled marker: 100, 200–208 (two markers), 400–408
    assert face.missing["dropped_frames"] == 160 and face.missing["filled_frames"] == 1 + 9 + 9
    assert face.missing["filled_samples"] == 1 + 4 + 9 + 9
    assert len(face.missing["unfilled_gaps"]) == 2
    kept = face.frame
    assert not np.isin(np.arange(300, 420), kept).any() and np.isin(np.arange(200, 209), kept).all()

    stride = 3
    A = face.positions[::stride]
    B = pos[kept][::stride]
    eps = 1.5 * fx.connecting_threshold(fx.pairwise_distances(fx.distance_features(B)))
    ea = fx.expression_space(A, float(eps), paths=False)
    eb = fx.expression_space(B, float(eps), paths=False)
    # measure: Procrustes disparity of the two 2-D embeddings of the same frames
    from scipy.spatial import procrustes

    _, _, disparity = procrustes(np.asarray(eb.embedding), np.asarray(ea.embedding))
    assert disparity < 1e-3, disparity
    assert abs(float(ea.score) - float(eb.score)) < 1e-3
