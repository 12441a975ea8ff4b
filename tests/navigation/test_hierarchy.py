"""FCM hierarchy and links between centres."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import fxspace as fx
from fxspace.navigation._links import _components


def _curve(n=120, seed=0):
    """A noisy 2-D 'Y' (three arms from a neutral centre), like the expression space."""
    rng = np.random.default_rng(seed)
    arm = rng.integers(0, 3, n)
    t = rng.uniform(0, 1, n)
    ang = np.array([0.3, 2.4, 4.4])[arm]
    pts = np.stack([t * 10 * np.cos(ang), t * 10 * np.sin(ang)], 1)
    return pts + rng.normal(scale=0.15, size=(n, 2))


@pytest.fixture(scope="module")
def space():
    X = _curve()
    P = fx.pairwise_distances(jnp.asarray(X))
    eps = float(fx.connecting_threshold(P)) * 1.3
    W = fx.epsilon_graph(P, eps)
    geo = fx.geodesic_distances(W)
    h = fx.build_hierarchy(X, geo, c0=8, key=jax.random.PRNGKey(0))
    return X, W, geo, h


def test_level_sizes():
    assert fx.level_sizes(2400, 10) == (10, 20, 40, 80, 160, 320, 640, 1280, 2400)
    assert fx.level_sizes(120, 8) == (8, 16, 32, 64, 120)
    assert fx.level_sizes(5, 10) == (5,)
    with pytest.raises(fx.FxspaceError, match="c0"):
        fx.level_sizes(10, 0)


def test_levels_shapes_and_memberships(space):
    X, _, _, h = space
    assert h.sizes == (8, 16, 32, 64, 120)
    for lv in h.levels:
        assert lv.centers.shape == (lv.n_clusters, 2)
        assert lv.memberships.shape == (len(X), lv.n_clusters)
        np.testing.assert_allclose(lv.memberships.sum(1), 1.0, rtol=1e-9)
        assert lv.labels.shape == (len(X),)
        # each centre is shown as its nearest frame
        d = np.linalg.norm(X[None] - lv.centers[:, None], axis=-1)
        np.testing.assert_array_equal(lv.center_frames, np.argmin(d, axis=1))
    # the finest level shows every frame
    assert sorted(h.levels[-1].center_frames.tolist()) == list(range(len(X)))
    assert h.levels[-1].objective < 1e-12


def test_finer_level_never_worse_in_objective(space):
    _, _, _, h = space
    objs = [lv.objective for lv in h.levels]
    assert all(b <= a for a, b in zip(objs[:-1], objs[1:], strict=True)), objs
    for lv in h.levels[1:-1]:
        assert lv.init in ("split", "kmeans++-extend") and lv.init == lv.stats["init"]
        assert lv.total_steps >= lv.num_steps > 0 and lv.converged


def test_warm_start_never_worse_than_its_split_start(space):
    X, _, _, h = space
    lv0, lv1 = h.levels[0], h.levels[1]
    init = fx.split_centers(X, lv0.centers, lv0.memberships, lv1.n_clusters)
    u0 = fx.fcm_memberships(X, init)
    start = float(fx.fcm_objective(X, init, u0))
    res = fx.fuzzy_cmeans(X, lv1.n_clusters, init_centers=init)
    assert float(res.objective) <= start + 1e-9
    assert lv1.objective <= float(res.objective) + 1e-9  # the best start is kept


def test_split_centers_shape_and_error(space):
    X, _, _, h = space
    lv = h.levels[0]
    v = np.asarray(fx.split_centers(X, lv.centers, lv.memberships, 12))
    assert v.shape == (12, 2) and np.all(np.isfinite(v))
    with pytest.raises(fx.FxspaceError, match="n_clusters must lie"):
        fx.split_centers(X, lv.centers, lv.memberships, 17)


def test_links_symmetric_and_connected(space):
    _, W, _, h = space
    n_comp, _ = fx.connected_components(W)
    assert int(n_comp) == 1
    for lv in h.levels:
        L = lv.links
        assert L.dtype == bool and L.shape == (lv.n_clusters, lv.n_clusters)
        np.testing.assert_array_equal(L, L.T)
        assert not L.diagonal().any()
        assert fx.link_graph_connected(lv)
        assert np.all(L[lv.bridges])  # bridges are links


def _seg_dist(p, a, b):
    ab = b - a
    L2 = ab @ ab
    t = 0.0 if L2 == 0 else np.clip((p - a) @ ab / L2, 0, 1)
    return np.linalg.norm(p - (a + t * ab))


def _reference_links(xy, geo, frames, rho):
    c = len(frames)
    pos = xy[frames]
    L = np.zeros((c, c), bool)
    for i in range(c):
        for j in range(i + 1, c):
            if frames[i] == frames[j]:
                continue
            path = fx.shortest_path(geo, frames[i], frames[j])
            ok = True
            for a, b in zip(path[:-1], path[1:], strict=True):
                for k in range(c):
                    if k in (i, j) or frames[k] in (frames[i], frames[j]):
                        continue
                    if _seg_dist(pos[k], xy[a], xy[b]) < rho:
                        ok = False
            L[i, j] = L[j, i] = ok
    return L


def test_links_match_bruteforce_reference(space):
    X, _, geo, h = space
    for lv in h.levels[:2]:  # ≤ 16 centres: the kernel's near list covers every centre
        links, bridges = fx.center_links(X, geo, lv.center_frames, lv.radius, bridge=False)
        ref = _reference_links(X, geo, lv.center_frames, lv.radius)
        np.testing.assert_array_equal(links, ref)


def test_bridges_connect_a_disconnected_link_graph(space):
    X, _, geo, h = space
    lv = h.levels[1]
    huge = 100.0 * lv.radius  # every path is blocked → only bridges remain
    links, bridges = fx.center_links(X, geo, lv.center_frames, huge, bridge=True)
    np.testing.assert_array_equal(links, bridges)
    assert len(np.unique(_components(links))) == 1
    assert bridges.sum() // 2 == lv.n_clusters - 1  # a spanning tree


def test_default_link_radius():
    pts = np.array([[0.0, 0.0], [1.0, 0.0], [3.0, 0.0]])
    assert fx.default_link_radius(pts, 0.5) == pytest.approx(0.5 * 1.0)


def test_embedding_with_nan_rejected():
    X = np.zeros((10, 2))
    X[3, 0] = np.nan
    with pytest.raises(fx.FxspaceError, match="NaN"):
        fx.build_hierarchy(X)


def test_cold_levels_are_the_cold_runs_apart_from_the_hierarchy(space):
    """Issue 31.9 / 29.3: the warm start's benchmark runs apart from the hierarchy (the
    app builds none of it; `Level` carries no benchmark fields): every warm-started level
    gets fuzzy c-means from one k-means++ seed of the hierarchy's own key sequence."""
    from fxspace.navigation import cold_levels

    X, _, _, h = space
    assert not {"num_steps_cold", "objective_cold", "time_s"} & set(h.levels[0]._fields)
    cold = cold_levels(X, c0=8, key=jax.random.PRNGKey(0))
    assert [c["n_clusters"] for c in cold] == list(h.sizes)
    key = jax.random.PRNGKey(0)
    for c, lv in zip(cold, h.levels, strict=True):
        key, k_cold, _ = jax.random.split(key, 3)
        if c is cold[0] or c is cold[-1]:
            assert c["num_steps_cold"] == -1 and np.isnan(c["objective_cold"])
            continue
        ref = fx.fuzzy_cmeans(jnp.asarray(X), lv.n_clusters, key=k_cold)
        assert c["num_steps_cold"] == int(ref.num_steps) > 0
        assert c["objective_cold"] == pytest.approx(float(ref.objective), rel=1e-9)


def _reach_coverage(links: np.ndarray) -> float:
    """Fraction of ordered centre pairs joined through links: boolean transitive closure
    by repeated squaring (independent of the scipy components the library uses)."""
    c = len(links)
    R = np.asarray(links, bool) | np.eye(c, dtype=bool)
    for _ in range(int(np.ceil(np.log2(max(c, 2)))) + 1):
        R = (R.astype(np.int64) @ R.astype(np.int64)) > 0
    return float((R.sum() - c) / (c * (c - 1)))


def test_link_radius_sweep_against_its_definition(space):
    """Kim & Jung §4.2's experiment: at each ρ, the paper's links (no bridges), their
    count and the centre pairs they join, recomputed from `center_links` directly."""
    X, _, geo, h = space
    scales = (0.05, 0.3, 1.0, 3.0)
    sw = fx.navigation.link_radius_sweep(h, geo, scales, max_centres=64)
    assert sw.levels.tolist() == [0, 1, 2, 3] and sw.centres.tolist() == [8, 16, 32, 64]
    for a, li in enumerate(sw.levels):
        cf = h.levels[li].center_frames
        for b, sc in enumerate(scales):
            rho = fx.default_link_radius(X[cf], sc)
            assert sw.radii[a, b] == pytest.approx(rho)
            L, B = fx.center_links(X, geo, cf, rho, bridge=False)
            assert not B.any() and sw.links[a, b] == L.sum() // 2
            assert sw.coverage[a, b] == pytest.approx(_reach_coverage(L))
            assert sw.components[a, b] == len(np.unique(_components(L)))
    # wider circles block more paths: fewer links
    assert np.all(np.diff(sw.links, axis=1) <= 0)
    with pytest.raises(fx.FxspaceError, match="scales"):
        fx.navigation.link_radius_sweep(h, geo, (0.1, -1.0))
    with pytest.raises(fx.FxspaceError, match="max_centres"):
        fx.navigation.link_radius_sweep(h, geo, max_centres=4)


def test_choose_link_scale_known_answers():
    def sweep(cov):
        cov = np.asarray(cov, float)
        z = np.zeros_like(cov)
        return fx.navigation.LinkRadiusSweep(
            np.array([0.1, 0.2, 0.4]), np.arange(len(cov)), np.arange(len(cov)) + 8,
            z, z.astype(int), z.astype(int), cov,
        )  # fmt: skip

    # the largest scale joining every level
    assert fx.navigation.choose_link_scale(sweep([[1, 1, 0.5], [1, 1, 1]])) == 0.2
    assert fx.navigation.choose_link_scale(sweep([[1, 1, 1], [1, 1, 1]])) == 0.4
    # none joins every level: the largest with the best worst-level coverage
    assert fx.navigation.choose_link_scale(sweep([[0.9, 0.9, 0.5], [1, 1, 1]])) == 0.2


def _rule_links_reference(X, geo, cf, rho):
    """The paper's rule, pair by pair with numpy: i—j unless the polyline of the geodesic
    path between their frames passes within rho of a centre other than the two."""
    c, pos = len(cf), X[cf]
    nh = np.asarray(geo.next_hop)
    out = np.zeros((c, c), bool)
    for i in range(c):
        for j in range(i + 1, c):
            path = [int(cf[i])]
            while path[-1] != cf[j] and nh[path[-1], cf[j]] >= 0:
                path.append(int(nh[path[-1], cf[j]]))
            if path[-1] != cf[j] or cf[i] == cf[j]:
                continue
            keep = (np.arange(c) != i) & (np.arange(c) != j) & (cf != cf[i]) & (cf != cf[j])
            q = pos[keep]
            a, b = X[path[:-1]], X[path[1:]]
            if len(a) == 0:
                continue
            ab = b - a
            L2 = np.maximum(np.sum(ab * ab, axis=1), 1e-300)
            t = np.clip(np.einsum("skd,sd->sk", q[None] - a[:, None], ab) / L2[:, None], 0, 1)
            d = np.linalg.norm(q[None] - (a[:, None] + t[..., None] * ab[:, None]), axis=-1)
            out[i, j] = out[j, i] = not np.any(d < rho)
    return out


def test_default_links_are_the_rule_exactly(space):
    """Kim & Jung §4.2 by default: no bridges, every link (and no other pair) passes the
    ρ rule, checked pair by pair against a direct numpy walk of the geodesic paths; the
    conservative near-list test (levels above EXACT_CENTRES) keeps only pairs that pass."""
    X, _, geo, h = space
    for lv in h.levels:
        assert not lv.bridges.any()
        if lv.n_clusters <= 64:
            ref = _rule_links_reference(X, geo, lv.center_frames, lv.radius)
            np.testing.assert_array_equal(lv.links, ref)
    lv = h.levels[3]
    near, _ = fx.center_links(X, geo, lv.center_frames, lv.radius, exact=False)
    assert not (near & ~lv.links).any()  # a subset of the rule's links


def test_hierarchy_rho_by_experiment_and_bridges_option(space):
    """The default: ρ from the experiment on every level (the sweep kept), links by the
    rule; ``bridges=True`` joins the pieces a level is left in, with links outside it."""
    X, _, geo, h = space
    sw = h.link_sweep
    assert sw is not None and sw.levels.tolist() == [0, 1, 2, 3, 4]
    chosen = fx.navigation.choose_link_scale(sw)
    assert np.all(sw.coverage[:, list(sw.scales).index(chosen)] == 1.0)
    for lv in h.levels:
        rho = fx.default_link_radius(X[lv.center_frames], chosen)
        assert lv.radius == pytest.approx(rho)
        L, B = fx.center_links(X, geo, lv.center_frames, rho)
        np.testing.assert_array_equal(lv.links, L)
        assert not lv.bridges.any() and not B.any()
    # relink: the same centres, links at another ρ; bridges join what falls apart
    wide = fx.navigation.relink(h, geo, 3.0, bridges=True)
    for a, b in zip(h.levels, wide.levels, strict=True):
        np.testing.assert_array_equal(a.center_frames, b.center_frames)
        assert b.radius == pytest.approx(fx.default_link_radius(X[b.center_frames], 3.0))
        L, _ = fx.center_links(X, geo, b.center_frames, b.radius, bridge=False)
        np.testing.assert_array_equal(b.links & ~b.bridges, L)
        assert fx.link_graph_connected(b)
    assert sum(int(lv.bridges.sum()) for lv in wide.levels) > 0
    rule = fx.navigation.relink(h, geo, 3.0)
    assert not any(lv.bridges.any() for lv in rule.levels)
    assert not all(fx.link_graph_connected(lv) for lv in rule.levels)
    # the sweep travels with the stored hierarchy
    back = fx.navigation.hierarchy_from_arrays(fx.navigation.hierarchy_to_arrays(h))
    for f in sw._fields:
        np.testing.assert_array_equal(getattr(back.link_sweep, f), getattr(sw, f))
    with pytest.raises(fx.FxspaceError, match="rho_scale"):
        fx.build_hierarchy(X, geo, c0=8, rho_scale="paper")
