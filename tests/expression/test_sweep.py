import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.sparse.csgraph import shortest_path as sp_shortest
from scipy.spatial.distance import cdist
from scipy.stats import pearsonr

import fxspace as fx


def _curve(rng, n=120):
    """Points on a noisy spiral: geodesics are arc lengths."""
    s = np.sort(rng.random(n)) * 3 * np.pi
    X = np.c_[s * np.cos(s), s * np.sin(s), 0.05 * rng.standard_normal(n)]
    return cdist(X, X)


def _reference_score(P, thr):
    W = np.where(P <= thr, P, 0)
    D = sp_shortest(W, directed=False)
    if not np.isfinite(D).all():
        return np.nan
    n = len(D)
    J = np.eye(n) - 1 / n
    w, V = np.linalg.eigh(-0.5 * J @ (D**2) @ J)
    Y = V[:, ::-1][:, :2] * np.sqrt(np.maximum(w[::-1][:2], 0))
    iu = np.triu_indices(n, 1)
    return pearsonr(D[iu], cdist(Y, Y)[iu])[0]


def test_sweep_matches_scipy_reference(rng):
    P = _curve(rng)
    th = fx.threshold_grid(P, num=6, upper_quantile=0.3, lower_factor=0.9)
    sw = fx.threshold_sweep(P, th)
    assert not bool(sw.connected[0])  # starts just below the connecting threshold
    assert np.isnan(sw.scores[0]) and int(sw.n_components[0]) >= 2
    for k, t in enumerate(th):
        ref = _reference_score(P, t)
        if np.isnan(ref):
            assert np.isnan(sw.scores[k])
        else:
            np.testing.assert_allclose(sw.scores[k], ref, rtol=1e-8)


def test_sweep_vmap_equals_loop(rng):
    P = jnp.asarray(_curve(rng, 80))
    th = fx.threshold_grid(P, num=5)
    a = fx.threshold_sweep(P, th, batch_size=None)
    b = fx.threshold_sweep(P, th, batch_size=5)
    np.testing.assert_allclose(a.scores, b.scores, rtol=1e-10, equal_nan=True)
    loop = [fx.threshold_sweep(P, th[k : k + 1]).scores[0] for k in range(5)]
    np.testing.assert_allclose(a.scores, loop, rtol=1e-10, equal_nan=True)


def test_sweep_under_jit(rng):
    P = jnp.asarray(_curve(rng, 60))
    th = jnp.asarray(fx.threshold_grid(P, num=4))
    f = jax.jit(lambda p, t: fx.threshold_sweep(p, t).scores)
    np.testing.assert_allclose(
        f(P, th), fx.threshold_sweep(P, th).scores, rtol=1e-10, equal_nan=True
    )


def test_geodesic_curve_known_answer(rng):
    """On a spiral the geodesic embedding unrolls the curve: r close to 1 at small ε."""
    P = _curve(rng, 150)
    t0 = float(fx.connecting_threshold(P))
    sw = fx.threshold_sweep(P, [t0 * 1.05])
    assert float(sw.scores[0]) > 0.99


def test_choose_threshold_criteria(rng):
    P = _curve(rng)
    sw = fx.threshold_sweep(P, fx.threshold_grid(P, num=8, upper_quantile=0.9))
    best = fx.choose_threshold(sw, "max_r")
    # the highest r among connected ε not held together by a bridge (issue 44)
    held = np.asarray(sw.bridge_part) >= max(2, np.ceil(0.05 * sw.num_frames))
    assert best["score"] == np.nanmax(np.where(held, np.nan, np.asarray(sw.scores)))
    skipped = [d["threshold"] for d in best["skipped_bridged"]]
    assert skipped == np.asarray(sw.thresholds)[held].tolist()
    bd = fx.choose_threshold(sw, "bounded_degree", max_mean_degree=10)
    first = int(np.flatnonzero(np.asarray(sw.connected) & ~held)[0])
    assert bd["mean_degree"] <= 10 or bd["index"] == first
    el = fx.choose_threshold(sw, "elbow")
    assert bool(sw.connected[el["index"]])
    with pytest.raises(ValueError, match="criterion"):
        fx.choose_threshold(sw, "best")


def test_all_disconnected_is_reported(rng):
    P = _curve(rng, 50)
    t0 = float(fx.connecting_threshold(P))
    sw = fx.threshold_sweep(P, [t0 * 0.5, t0 * 0.9])
    assert not np.any(np.asarray(sw.connected))
    with pytest.raises(ValueError, match="components"):
        fx.choose_threshold(sw)


def test_bad_thresholds():
    with pytest.raises(fx.FxspaceError, match="> 0"):
        fx.threshold_sweep(np.zeros((4, 4)), [-1.0])
    with pytest.raises(fx.FxspaceError, match="square"):
        fx.threshold_sweep(np.zeros((4, 3)), [1.0])
    for bad in ("230", ["230"], [np.nan]):
        with pytest.raises(fx.FxspaceError, match="thresholds"):
            fx.threshold_sweep(np.ones((4, 4)) - np.eye(4), bad)
    P = np.ones((4, 4)) - np.eye(4)
    for num in (2.5, "8", 1):
        with pytest.raises(fx.FxspaceError, match="num"):
            fx.threshold_grid(P, num)
    with pytest.raises(fx.FxspaceError, match="threshold"):
        fx.expression_space(None, "230", pairwise=P)


def test_grid_spans_connecting_to_largest_distance(rng):
    """The default grid covers the whole meaningful range (Kim & Jung §2.2): from the
    connecting threshold to the largest distance, where the graph is complete."""
    P = _curve(rng, 90)
    th = fx.threshold_grid(P, 7)
    assert th[0] == pytest.approx(float(fx.connecting_threshold(P)))
    assert th[-1] == P.max() and np.all(np.diff(th) > 0)
    sw = fx.threshold_sweep(P, th)
    assert bool(np.all(np.asarray(sw.connected)))
    assert float(sw.mean_degree[-1]) == pytest.approx(89.0)  # complete graph
    best = fx.choose_threshold(sw)  # max_r is the default (the paper's)
    assert best["criterion"] == "max_r"
    held = np.asarray(sw.bridge_part) >= max(2, np.ceil(0.05 * sw.num_frames))  # issue 44
    assert best["score"] == np.nanmax(np.where(held, np.nan, np.asarray(sw.scores)))


def test_expression_space_on_synthetic_face():
    face = fx.synthetic.synthetic_face(n_markers=24, n_frames=150, seed=1)
    pos = face.sequence.positions
    P = fx.pairwise_distances(fx.distance_features(pos))
    t0 = float(fx.connecting_threshold(P))
    es = fx.expression_space(pos, 1.1 * t0)
    assert es.embedding.shape == (150, 2) and 0.9 < float(es.score) <= 1.0
    path = fx.shortest_path(es.geodesics, 0, 149)
    assert path[0] == 0 and path[-1] == 149
    with pytest.raises(fx.DisconnectedGraphError, match="connected components"):
        fx.expression_space(pos, 0.5 * t0)
