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


# -- issue 44: ε held together by a bridge -------------------------------------------------
def _bridge_parts_by_removal(P, eps):
    """Reference: remove each edge of the ε-graph in turn and count what it cuts off."""
    from scipy.sparse.csgraph import connected_components

    A = (P <= eps) & ~np.eye(len(P), dtype=bool)
    if connected_components(A, directed=False)[0] > 1:
        return 0
    best = 0
    for i, j in zip(*np.nonzero(np.triu(A)), strict=True):
        B = A.copy()
        B[i, j] = B[j, i] = False
        k, lab = connected_components(B, directed=False)
        if k > 1:
            best = max(best, int(np.bincount(lab).min()))
    return best


def _trajectory(n=240, seed=0):
    """A smooth 8-D trajectory sampled in time: at small ε its graph is the time chain."""
    rng = np.random.default_rng(seed)
    t = np.linspace(0, 1, n)[:, None]
    X = np.sin(2 * np.pi * rng.uniform(0.5, 3.0, 8) * t + rng.uniform(0, 6.3, 8)) * 10
    return np.linalg.norm(X[:, None] - X[None], axis=-1)


def test_bridge_parts_match_edge_removal(rng):
    X = np.concatenate([rng.normal(0, 1, (14, 3)), np.linspace(0, 1, 8)[:, None] * [9, 0, 0],
                        rng.normal(0, 1, (12, 3)) + [9, 0, 0]])  # fmt: skip
    P = np.linalg.norm(X[:, None] - X[None], axis=-1)
    th = float(fx.connecting_threshold(P)) * np.array([0.9, 1.0, 1.2, 1.5, 2.0, 3.0, 6.0])
    got = fx.expression.bridge_parts(P, th)
    want = [_bridge_parts_by_removal(P, e) for e in th]
    np.testing.assert_array_equal(got, want)
    assert max(want) >= 12  # the chain between the blobs is a bridge somewhere


def test_bridge_parts_one_eps_at_a_time_is_one_call_over_all(rng):
    """A sweep cut into one-ε chunks asks about the same JAX array again and again: the
    tree is built once and every ε above the first bridge-free one skipped, with the
    numbers of one call over all ε (and of edge removal)."""
    import fxspace.expression._bridges as B

    X = np.concatenate([rng.normal(0, 1, (14, 3)), np.linspace(0, 1, 8)[:, None] * [9, 0, 0],
                        rng.normal(0, 1, (12, 3)) + [9, 0, 0]])  # fmt: skip
    P = jnp.asarray(np.linalg.norm(X[:, None] - X[None], axis=-1), jnp.float32)
    th = float(fx.connecting_threshold(P)) * np.array([1.0, 1.2, 1.5, 2.0, 3.0, 6.0])
    whole = fx.expression.bridge_parts(np.asarray(P), th)
    one = [int(fx.expression.bridge_parts(P, th[k : k + 1])[0]) for k in range(len(th))]
    np.testing.assert_array_equal(one, whole)
    np.testing.assert_array_equal(whole, [_bridge_parts_by_removal(np.asarray(P), e) for e in th])
    first_free = th[np.flatnonzero(whole == 0)[0]]
    assert B._held(P)[2][0] == first_free  # the bound that skips the larger ε
    Q = jnp.asarray(np.asarray(P) * 2.0)  # another array: its own tree, its own answer
    np.testing.assert_array_equal(fx.expression.bridge_parts(Q, 2.0 * th), whole)


def test_choose_threshold_skips_bridged_eps_fast():
    """The rule on a hand-made sweep: the best r sits on a graph a bridge splits 40/60."""
    z = np.zeros(4)
    sw = fx.expression.SweepResult(
        np.array([1.0, 2.0, 3.0, 4.0]), np.array([np.nan, 0.9999, 0.98, 0.99]),
        np.array([False, True, True, True]), np.array([2, 1, 1, 1]), z, np.zeros((4, 2)),
        100, np.array([0, 40, 1, 0]),
    )  # fmt: skip
    assert fx.choose_threshold(sw, min_bridge_part=None)["threshold"] == 2.0
    best = fx.choose_threshold(sw)
    assert best["threshold"] == 4.0  # ε = 3 has a bridge too, but it cuts off one frame
    assert best["skipped_bridged"] == [{"threshold": 2.0, "score": 0.9999, "bridge_part": 40}]
    assert fx.choose_threshold(sw, min_bridge_part=0.5)["threshold"] == 2.0  # none that big
    no_info = sw._replace(bridge_part=None)  # a result built without it: nothing skipped
    assert fx.choose_threshold(no_info)["threshold"] == 2.0


@pytest.mark.slow
def test_max_r_skips_an_eps_held_together_by_a_bridge():
    """Issue 44: max_r picked the smallest ε (r = 0.9999) on a take whose graph there is
    held together by single edges; its r measured the chain, not the manifold."""
    P = _trajectory()
    sw = fx.threshold_sweep(P, fx.threshold_grid(P, 8))
    plain = fx.choose_threshold(sw, min_bridge_part=None)
    assert plain["index"] == 0 and int(sw.bridge_part[0]) == 120  # half the frames
    best = fx.choose_threshold(sw)
    assert int(sw.bridge_part[best["index"]]) == 0 and best["index"] > 0
    assert [d["bridge_part"] for d in best["skipped_bridged"]] == [
        int(b) for b in np.asarray(sw.bridge_part) if b >= 12
    ]
    assert "held together by a bridge at ε=" in fx.expression.sweep_message(sw)
    only_bridged = sw._replace(**{f: np.asarray(getattr(sw, f))[:2] for f in (
        "thresholds", "scores", "connected", "n_components", "mean_degree", "eigenvalues",
        "bridge_part")})  # fmt: skip
    with pytest.raises(fx.FxspaceError, match=r"held together by one edge \(a bridge\).*"
                                              r"min_bridge_part=None"):
        fx.choose_threshold(only_bridged)
    assert fx.choose_threshold(only_bridged, min_bridge_part=None)["index"] == 0


@pytest.mark.slow
@pytest.mark.data
def test_long_filled_gaps_case_on_a_shared_take(data_dir):
    """The reported case on a cut of a shared capture: 962 frames of the AnimFace jaw take
    with six 40-frame gaps of the whole face, filled with max_gap = 40 (linear chains)."""
    from fxspace.pipelines.threshold_sweep import state_distances

    seq = fx.io.read_markers(data_dir / "face" / "animface_jaw.c3d")
    pos = np.array(seq.positions[:962])
    for a in np.linspace(50, 862, 6).astype(int):
        pos[a : a + 40] = np.nan
    pos = fx.fill_gaps(pos, 40).positions
    P = state_distances(pos, "float64")
    grid = fx.threshold_grid(P, 16)[[0, 1, 5, 10]]
    sw = fx.threshold_sweep(P, grid)
    plain = fx.choose_threshold(sw, min_bridge_part=None)
    assert plain["index"] == 0 and plain["score"] > 0.998  # the smallest ε, r ≈ 1
    assert int(sw.bridge_part[0]) > 0.4 * 962  # a bridge splits the take in two halves
    best = fx.choose_threshold(sw)
    assert best["index"] > 0 and int(sw.bridge_part[best["index"]]) == 0
