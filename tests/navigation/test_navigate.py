"""Navigation: key-frame routes, refinement, playback, figures and the animation."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import face_like as _face_like
from matplotlib.figure import Figure

import fxspace as fx
from fxspace.plot import (
    face_wireframe,
    plot_level,
    plot_levels_grid,
    write_navigation_animation,
)


@pytest.fixture(scope="module")
def nav():
    xy, pos = _face_like()
    P = fx.pairwise_distances(jnp.asarray(xy))
    W = fx.epsilon_graph(P, float(fx.connecting_threshold(P)) * 1.3)
    geo = fx.geodesic_distances(W)
    h = fx.build_hierarchy(xy, geo, c0=8, key=jax.random.PRNGKey(1), restarts=0)
    return xy, pos, np.asarray(W), geo, h


def _linked_walk(lv, n):
    seq = [0]
    while len(seq) < n:
        nb = [int(k) for k in lv.neighbours(seq[-1]) if int(k) not in seq]
        if not nb:
            break
        seq.append(nb[0])
    return seq


def test_route_follows_geodesic_paths(nav):
    _, _, W, geo, h = nav
    lv = h.levels[0]
    keys = _linked_walk(lv, 3)
    r = fx.make_route(h, geo, 0, keys)
    assert r.centres == tuple(keys)
    np.testing.assert_array_equal(r.key_frames, lv.center_frames[keys])
    assert r.frames[0] == r.key_frames[0] and r.frames[-1] == r.key_frames[-1]
    assert set(r.key_frames.tolist()) <= set(r.frames.tolist())
    assert fx.is_graph_walk(r.frames, W)
    # the path length equals the sum of geodesic distances between key frames
    D = np.asarray(geo.distances)
    length = sum(W[a, b] for a, b in zip(r.frames[:-1], r.frames[1:], strict=True))
    expect = sum(D[a, b] for a, b in zip(r.key_frames[:-1], r.key_frames[1:], strict=True))
    assert length == pytest.approx(expect, rel=1e-9)


def test_unlinked_key_frames_rejected(nav):
    _, _, _, geo, h = nav
    lv = h.levels[0]
    a = 0
    unlinked = [k for k in range(1, lv.n_clusters) if not lv.links[a, k]]
    assert unlinked, "fixture should have an unlinked pair"
    with pytest.raises(
        fx.NavigationError,
        match=rf"centres {a} and {unlinked[0]} are not "
        r"linked at level 0.*linked to 0: \[",
    ):
        fx.make_route(h, geo, 0, [a, unlinked[0]])
    with pytest.raises(fx.NavigationError, match="does not exist"):
        fx.make_route(h, geo, 0, [0, 99])
    with pytest.raises(fx.NavigationError, match="level must be"):
        fx.make_route(h, geo, 7, [0])


def test_candidates_lie_near_path_in_order(nav):
    xy, _, _, geo, h = nav
    r = fx.make_route(h, geo, 0, _linked_walk(h.levels[0], 3))
    cands = fx.path_candidates(h, 1, r.frames)
    lv = h.levels[1]
    p = xy[r.frames]
    for k in cands:
        d = np.min(np.linalg.norm(p - xy[lv.center_frames[k]], axis=1))
        assert d <= lv.radius + 1e-12
    pos_along = [np.argmin(np.linalg.norm(p - xy[lv.center_frames[k]], axis=1)) for k in cands]
    assert pos_along == sorted(pos_along)


def test_manual_repick_and_automatic_refinement_to_finest(nav):
    _, _, W, geo, h = nav
    keys = _linked_walk(h.levels[0], 4)
    routes = fx.navigate(h, geo, keys)
    assert [r.level for r in routes] == list(range(len(h.levels)))
    for r in routes:
        lv = h.levels[r.level]
        assert all(lv.links[a, b] for a, b in zip(r.centres[:-1], r.centres[1:], strict=True))
        assert fx.is_graph_walk(r.frames, W)
    final = routes[-1].frames
    assert fx.is_graph_walk(final, W)
    # the user's first and last key frames survive to the finest level
    assert final[0] == routes[0].key_frames[0] and final[-1] == routes[0].key_frames[-1]
    # re-picking by hand: the automatic picks are valid manual picks too
    r1 = fx.refine_route(h, geo, routes[0], picks=routes[1].centres)
    assert r1.centres == routes[1].centres and r1.anchors == routes[1].anchors
    np.testing.assert_array_equal(r1.frames, routes[1].frames)
    with pytest.raises(fx.NavigationError, match="finest"):
        fx.refine_route(h, geo, routes[-1])


def test_is_graph_walk_detects_jumps(nav):
    _, _, W, _, _ = nav
    far = np.unravel_index(np.argmax(np.where(np.isfinite(W), -1, 1)), W.shape)
    assert not fx.is_graph_walk([far[0], far[1]], W)
    assert not fx.is_graph_walk([3, 3], W)


def test_playback_resamples_to_fps(nav):
    xy, pos, _, geo, h = nav
    r = fx.navigate(h, geo, _linked_walk(h.levels[0], 3))[-1]
    pb = fx.playback(r.frames, xy, pos, fps=24, duration=2.0, align=False)
    assert len(pb.times) == 49 and pb.positions.shape == (49, pos.shape[1], 3)
    assert np.all(np.diff(pb.times) > 0)
    np.testing.assert_allclose(pb.xy[0], xy[r.frames[0]])
    np.testing.assert_allclose(pb.xy[-1], xy[r.frames[-1]])
    np.testing.assert_allclose(pb.positions[-1], pos[r.frames[-1]])
    assert set(pb.frame.tolist()) <= set(r.frames.tolist())
    # constant speed along the 2-D path
    step = np.linalg.norm(np.diff(pb.xy, axis=0), axis=1)
    total = np.sum(np.linalg.norm(np.diff(xy[r.frames], axis=0), axis=1))
    assert step.max() <= total / 48 * (1 + 1e-9)
    with pytest.raises(fx.FxspaceError, match="fps"):
        fx.playback(r.frames, xy, pos, fps=0)


def test_rigid_align_recovers_pose(rng):
    ref = rng.normal(size=(15, 3))
    th = 0.7
    R = np.array([[np.cos(th), -np.sin(th), 0], [np.sin(th), np.cos(th), 0], [0, 0, 1]])
    moved = ref @ R.T + np.array([1.0, -2.0, 3.0])
    out = fx.rigid_align(moved[None], ref)
    np.testing.assert_allclose(out[0], ref, atol=1e-10)


def test_figures(nav):
    _, _, _, geo, h = nav
    routes = fx.navigate(h, geo, _linked_walk(h.levels[0], 3))
    assert isinstance(plot_level(h, 0, routes[0]), Figure)
    assert isinstance(plot_levels_grid(h, routes), Figure)
    import matplotlib.pyplot as plt

    plt.close("all")


def test_wireframe_edges(nav):
    _, pos, _, _, _ = nav
    e = face_wireframe(pos[0])
    assert e.ndim == 2 and e.shape[1] == 2 and len(e) >= pos.shape[1] - 1
    assert e.min() >= 0 and e.max() < pos.shape[1]


def test_animation_written(nav, tmp_path):
    xy, pos, _, geo, h = nav
    routes = fx.navigate(h, geo, _linked_walk(h.levels[0], 3))
    pb = fx.playback(routes[-1].frames, xy, pos, fps=10, duration=0.6)
    out = write_navigation_animation(
        tmp_path / "nav.gif", pb, xy, route=routes[0], max_frames=4, dpi=40
    )
    assert out.exists() and out.stat().st_size > 1000
    with open(out, "rb") as f:
        assert f.read(6) in (b"GIF89a", b"GIF87a")
    assert not list(tmp_path.glob(".*tmp*"))  # atomic: no temporary left behind


def test_real_animface_subsample(data_dir):
    from fxspace.datasets import FaceData, load_face

    face = load_face(FaceData(source="animface", max_frames=150), 0)
    P = fx.pairwise_distances(fx.distance_features(jnp.asarray(face.positions)))
    W = fx.epsilon_graph(P, float(fx.connecting_threshold(P)) * 1.25)
    geo = fx.geodesic_distances(W)
    Y = fx.classical_mds(geo.distances, 2).embedding
    h = fx.build_hierarchy(Y, geo, c0=10, key=jax.random.PRNGKey(0), restarts=0)
    assert h.sizes == (10, 20, 40, 80, 150)
    # the paper's rule alone: a level is in one piece exactly where the experiment says
    sw = h.link_sweep
    k = list(sw.scales).index(fx.navigation.choose_link_scale(sw))
    for a, li in enumerate(sw.levels):
        assert fx.link_graph_connected(h.levels[li]) == (sw.coverage[a, k] == 1.0)
    assert not any(lv.n_bridges for lv in h.levels)
    lv = h.levels[0]
    keys = _linked_walk(lv, 4)
    routes = fx.navigate(h, geo, keys)
    assert fx.is_graph_walk(routes[-1].frames, np.asarray(W))
    pb = fx.playback(routes[-1].frames, np.asarray(Y), face.positions, fps=30, rate=face.rate)
    assert np.all(np.isfinite(pb.positions))


@pytest.mark.slow
def test_pipeline_on_synthetic_face(tmp_path, capsys, monkeypatch):
    import json

    from fxspace.pipelines import run_dict

    raw = {
        "experiment": "navigation",
        "seed": 0,
        "data": {"source": "synthetic", "synthetic_frames": 80},
        "hierarchy": {"c0": 8, "restarts": 0},
        "navigation": {"animation_frames": 4, "level_figures": False},
    }
    monkeypatch.delenv("FXSPACE_QUIET", raising=False)
    (d,) = run_dict(raw, tmp_path / "run", force=True)
    m = json.loads((d / "metrics.json").read_text())
    assert m["centres_per_level"] == [8, 16, 32, 64, 80]
    # the missing-data counts (none in the synthetic face) and a line per stage
    assert m["missing"]["policy"] == "fill" and m["missing"]["max_gap"] == 10
    err = capsys.readouterr().err
    assert err.count("[fxspace] ") >= 5
    for line in ("loading frames", "geodesics and 2-D embedding", "fuzzy c-means levels",
                 "route through key centres", "figures"):  # fmt: skip
        assert line in err
    assert m["path_is_graph_walk"] is True
    assert (d / "navigation.gif").stat().st_size > 0
    assert (d / "levels_grid.png").stat().st_size > 0


def test_refinement_stays_in_one_piece_of_the_links(nav):
    """The paper's rule can leave a fine level in pieces (no bridges): automatic
    refinement keeps the route in the piece that holds the key frames' centres, every
    step along a link, and still ends in a walk of the frame graph; a hand-picked key
    in another piece is refused with the reason and the fix."""
    _, _, W, geo, h = nav
    rule = fx.navigation.relink(h, geo, 0.5)  # levels 3 and 4 fall apart at this ρ
    pieces = [len(np.unique(fx.navigation.link_components(lv))) for lv in rule.levels]
    assert pieces[0] == 1 and max(pieces) > 1
    assert not any(lv.n_bridges for lv in rule.levels)
    routes = fx.navigate(rule, geo, _linked_walk(rule.levels[0], 4))
    assert [r.level for r in routes] == list(range(len(rule.levels)))
    for r in routes:
        lv = rule.levels[r.level]
        lab = fx.navigation.link_components(lv)
        assert len(set(lab[list(r.centres)].tolist())) == 1
        assert all(lv.links[a, b] for a, b in zip(r.centres[:-1], r.centres[1:], strict=True))
    assert fx.is_graph_walk(routes[-1].frames, W)
    last = len(rule.levels) - 1
    lab = fx.navigation.link_components(rule.levels[last])
    a = routes[-1].centres[0]
    b = int(np.flatnonzero(lab != lab[a])[0])
    with pytest.raises(fx.navigation.NavigationError, match="different pieces.*bridges=True"):
        fx.navigation.bridge_keys(rule, geo, last, [a, b])
