"""FCM hierarchy and links between centres."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import fxspace as fx
from fxspace.navigation._level import _components


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


@pytest.fixture(scope="module", params=["epsilon", "knn"])
def both(request, space):
    """The same frames as the dense Geodesics (an ε-graph) and as a NeighbourGraph with
    the default FCM of each kind: the full one and the truncated one."""
    X, W, geo, h = space
    if request.param == "epsilon":
        return X, geo, h
    g = fx.expression.graph_from_dense(W)
    hs = fx.build_hierarchy(X, g, c0=8, key=jax.random.PRNGKey(0),
                            fcm=fx.navigation.TruncatedFuzzyCMeans(nearest=4))  # fmt: skip
    return X, g, hs


def test_level_sizes():
    assert fx.level_sizes(2400, 10) == (10, 20, 40, 80, 160, 320, 640, 1280, 2400)
    assert fx.level_sizes(120, 8) == (8, 16, 32, 64, 120)
    assert fx.level_sizes(5, 10) == (5,)
    with pytest.raises(fx.FxspaceError, match="c0"):
        fx.level_sizes(10, 0)


def test_levels_shapes_and_memberships(space):
    X, _, _, h = space
    assert h.sizes == (8, 16, 32, 64, 120)
    for lv in h.levels[:-1]:
        assert lv.centers.shape == (lv.n_clusters, 2)
        assert lv.memberships.shape == (len(X), lv.n_clusters)
        np.testing.assert_allclose(lv.memberships.sum(1), 1.0, rtol=1e-9)
        assert lv.labels.shape == (len(X),)
        # each centre is shown as its nearest frame
        d = np.linalg.norm(X[None] - lv.centers[:, None], axis=-1)
        np.testing.assert_array_equal(lv.center_frames, np.argmin(d, axis=1))
    # the finest level shows every frame: the FCM's fixed point with every frame a centre
    fin = h.levels[-1]
    assert sorted(fin.center_frames.tolist()) == list(range(len(X)))
    assert fin.objective < 1e-12 and fin.converged and fin.init == "frames"
    np.testing.assert_array_equal(fin.labels, np.arange(len(X)))


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


def test_links_are_one_sparse_form_and_every_level_converged(both):
    """One `Level` type at every size: links, bridges and lengths as symmetric CSR
    arrays, the FCM record as `.fit` with `.result` and `.stats`, every level at its
    fixed point; the links' lengths are the geodesic lengths of the pairs."""
    X, paths, h = both
    assert h.converged
    for lv in h.levels:
        assert isinstance(lv, fx.navigation.Level) and lv.converged
        assert lv.fit.result == fx.RESULTS.successful and "max_steps" in lv.fit.stats
        L = lv.links
        assert L.format == "csr" and L.shape == (lv.n_clusters, lv.n_clusters)
        assert (L != L.T).nnz == 0 and not L.diagonal().any()
        assert lv.n_bridges == 0 and lv.bridges.shape == L.shape
        i, j = fx.navigation.link_pairs(L)
        got = np.asarray(lv.lengths[i, j]).reshape(-1)
        want = paths.lengths(lv.center_frames[i], lv.center_frames[j])
        np.testing.assert_allclose(got, want, rtol=1e-5)


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
        np.testing.assert_array_equal(links.toarray(), ref)


def test_bridges_connect_a_disconnected_link_graph(space):
    X, _, geo, h = space
    lv = h.levels[1]
    huge = 100.0 * lv.radius  # every path is blocked → only bridges remain
    links, bridges = fx.center_links(X, geo, lv.center_frames, huge, bridge=True)
    assert (links != bridges).nnz == 0
    assert len(np.unique(_components(links))) == 1
    assert bridges.nnz // 2 == lv.n_clusters - 1  # a spanning tree


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
    assert fx.navigation.link_radius_sweep(h, geo, scales).levels.tolist() == [0, 1, 2, 3]
    for a, li in enumerate(sw.levels):
        cf = h.levels[li].center_frames
        for b, sc in enumerate(scales):
            rho = fx.default_link_radius(X[cf], sc)
            assert sw.radii[a, b] == pytest.approx(rho)
            L, B = fx.center_links(X, geo, cf, rho, bridge=False)
            L = L.toarray()
            assert not B.nnz and sw.links[a, b] == L.sum() // 2
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


def _rule_links_reference(X, paths, cf, rho):
    """The paper's rule, pair by pair with numpy: i—j unless the polyline of the shortest
    path between their frames (the paths' own walk) passes within rho of a centre other
    than the two."""
    c, pos = len(cf), X[cf]
    out = np.zeros((c, c), bool)
    for i in range(c):
        for j in range(i + 1, c):
            if cf[i] == cf[j]:
                continue
            path = paths.path(int(cf[i]), int(cf[j]))
            keep = (np.arange(c) != i) & (np.arange(c) != j) & (cf != cf[i]) & (cf != cf[j])
            q = pos[keep]
            a, b = X[path[:-1]], X[path[1:]]
            ab = b - a
            L2 = np.maximum(np.sum(ab * ab, axis=1), 1e-300)
            t = np.clip(np.einsum("skd,sd->sk", q[None] - a[:, None], ab) / L2[:, None], 0, 1)
            d = np.linalg.norm(q[None] - (a[:, None] + t[..., None] * ab[:, None]), axis=-1)
            out[i, j] = out[j, i] = not np.any(d < rho)
    return out


def test_default_links_are_the_rule_exactly(both):
    """Kim & Jung §4.2 by default, in both graph kinds: no bridges, ρ by the experiment,
    and every link (and no other pair) passes the ρ rule, checked pair by pair against a
    direct numpy walk of the shortest paths — on every level, the one where every frame
    is a centre included (the k-d tree test of its steps); the conservative near test
    (levels above EXACT_CENTRES) keeps only pairs that pass."""
    X, paths, h = both
    sw = h.link_sweep
    scale = fx.navigation.choose_link_scale(sw)
    assert sw.levels.tolist() == [0, 1, 2, 3]  # every FCM level (the finest has no choice)
    for lv in h.levels:
        assert lv.n_bridges == 0
        assert lv.radius == pytest.approx(fx.default_link_radius(X[lv.center_frames], scale))
        ref = _rule_links_reference(X, paths, lv.center_frames, lv.radius)
        np.testing.assert_array_equal(lv.links.toarray(), ref)
    lv = h.levels[3]
    near, _ = fx.center_links(X, paths, lv.center_frames, lv.radius, exact=False)
    assert (near.toarray() <= lv.links.toarray()).all()  # a subset of the rule's links


def test_options_are_solver_objects_and_old_keywords_map_onto_them(space):
    """Options sit on `FuzzyCMeans` / `TruncatedFuzzyCMeans` / `LinkRule`; the old
    keywords map onto them for either graph kind (none refused by branch)."""
    X, W, geo, _ = space
    g = fx.expression.graph_from_dense(W)
    nav = fx.navigation
    new = fx.build_hierarchy(X, g, c0=8, levels=2, finest=False,
                             fcm=nav.TruncatedFuzzyCMeans(nearest=4, max_steps=500),
                             links=nav.LinkRule(rho=0.5))  # fmt: skip
    old = fx.build_hierarchy(X, g, c0=8, levels=2, finest=False, nearest=4, max_steps=500,
                             rho_scale=0.5)  # fmt: skip
    dense_kw = fx.build_hierarchy(X, geo, c0=8, levels=2, finest=False, nearest=4,
                                  max_steps=500, rho_scale=0.5)  # fmt: skip
    assert new.sizes == old.sizes == dense_kw.sizes == (8, 16)
    for a, b, c in zip(new.levels, old.levels, dense_kw.levels, strict=True):
        np.testing.assert_array_equal(a.centers, b.centers)
        assert (a.links != b.links).nnz == 0 and (a.links != c.links).nnz == 0
    assert new.link_sweep is None and nav.is_sparse(new) and not nav.is_sparse(space[3])
    with pytest.raises(fx.FxspaceError, match="unknown option"):
        fx.build_hierarchy(X, g, c0=8, levels=1, rho=0.5)


def test_hierarchy_rho_by_experiment_and_bridges_option(space):
    """The default: ρ from the experiment on every level (the sweep kept), links by the
    rule; ``bridges=True`` joins the pieces a level is left in, with links outside it."""
    X, _, geo, h = space
    sw = h.link_sweep
    assert sw is not None and sw.levels.tolist() == [0, 1, 2, 3]
    chosen = fx.navigation.choose_link_scale(sw)
    assert np.all(sw.coverage[:, list(sw.scales).index(chosen)] == 1.0)
    for lv in h.levels:
        rho = fx.default_link_radius(X[lv.center_frames], chosen)
        assert lv.radius == pytest.approx(rho)
        L, B = fx.center_links(X, geo, lv.center_frames, rho)
        assert (lv.links != L).nnz == 0 and not lv.bridges.nnz and not B.nnz
    # relink: the same centres, links at another ρ; bridges join what falls apart
    wide = fx.navigation.relink(h, geo, 3.0, bridges=True)
    for a, b in zip(h.levels, wide.levels, strict=True):
        np.testing.assert_array_equal(a.center_frames, b.center_frames)
        assert b.radius == pytest.approx(fx.default_link_radius(X[b.center_frames], 3.0))
        L, _ = fx.center_links(X, geo, b.center_frames, b.radius, bridge=False)
        np.testing.assert_array_equal(b.links.toarray() & ~b.bridges.toarray(), L.toarray())
        assert fx.link_graph_connected(b)
    assert sum(lv.n_bridges for lv in wide.levels) > 0
    rule = fx.navigation.relink(h, geo, 3.0)
    assert not any(lv.n_bridges for lv in rule.levels)
    assert not all(fx.link_graph_connected(lv) for lv in rule.levels)
    # the sweep travels with the stored hierarchy
    back = fx.navigation.hierarchy_from_arrays(fx.navigation.hierarchy_to_arrays(h))
    for f in sw._fields:
        np.testing.assert_array_equal(getattr(back.link_sweep, f), getattr(sw, f))
    for a, b in zip(h.levels, back.levels, strict=True):
        assert (a.links != b.links).nnz == 0 and b.result == a.result
        np.testing.assert_allclose(b.lengths.toarray(), a.lengths.toarray())
    with pytest.raises(fx.FxspaceError, match="rho_scale"):
        fx.build_hierarchy(X, geo, c0=8, rho_scale="paper")


@pytest.mark.parametrize("rho", ["experiment", 0.5])
def test_links_made_beside_the_fcm_are_those_made_after_it(both, rho):
    """`build_hierarchy` makes each level's links in a thread while the next level's FCM
    runs: the same hierarchy (every array) as the levels first and their links after,
    one after another (`relink`'s path), for ρ by the experiment and a fixed ρ."""
    from fxspace.navigation import LinkRule, hierarchy_to_arrays
    from fxspace.navigation._rho import _link_all

    X, paths, h = both
    fcm = h.levels[1].fit  # the kind of FCM of this graph kind
    solver = (fx.navigation.TruncatedFuzzyCMeans(nearest=4) if hasattr(fcm, "indices")
              else fx.navigation.FuzzyCMeans())  # fmt: skip
    kw = dict(c0=8, key=jax.random.PRNGKey(0), fcm=solver)
    rule = LinkRule(rho=rho)
    beside = fx.build_hierarchy(X, paths, links=rule, **kw)
    after = _link_all(fx.build_hierarchy(X, paths, links=False, **kw), paths, rule)
    a, b = hierarchy_to_arrays(beside), hierarchy_to_arrays(after)
    assert sorted(a) == sorted(b)
    for k in a:
        np.testing.assert_array_equal(np.asarray(a[k]), np.asarray(b[k]), err_msg=k)
    assert (beside.link_sweep is None) == (rho != "experiment")


@pytest.mark.parametrize("factor", [1.0, 1.5, 4.0])
def test_finest_links_from_blocks_at_a_smaller_rho_are_the_direct_ones(both, factor):
    """The finest level's steps are tested at the experiment's smallest ρ₀ beside the FCM
    levels (`step_blocks`); its links at ρ ≥ ρ₀ then test only the steps left clear: the
    same links as testing every step at ρ, and the blocks at ρ₀ equal the direct test."""
    from fxspace.navigation._links import _step_links, step_blocks
    from fxspace.navigation._segments import segments_near_points

    X, paths, _ = both
    xy = np.asarray(X, np.float64)
    rho0 = fx.navigation.default_link_radius(xy, 0.05)
    pre = step_blocks(xy, paths, rho0)
    i, j, w, blocked, r0 = pre
    np.testing.assert_array_equal(blocked, segments_near_points(xy, i, j, rho0))
    rho = factor * r0
    got = _step_links(xy, paths, rho, pre)
    want = _step_links(xy, paths, rho)
    for a, b in zip(got, want, strict=True):
        np.testing.assert_array_equal(a, b)
    assert 0 < len(got[0]) < len(i)  # some steps are links, some are blocked
    if factor == 4.0:  # steps clear at ρ₀ that ρ blocks: the rest was tested again
        assert len(got[0]) < int((~blocked).sum())
    # a ρ below ρ₀ cannot use the blocks: every step is tested at it
    low = _step_links(xy, paths, 0.5 * r0, pre)
    for a, b in zip(low, _step_links(xy, paths, 0.5 * r0), strict=True):
        np.testing.assert_array_equal(a, b)
