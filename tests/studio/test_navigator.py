"""The browser navigator: the controller without a browser, then the real page in headless
Chromium (skipped, with the reason, where viser, playwright or Chromium is absent)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import face_like as _face_like

import fxspace as fx
from fxspace.studio import NavData, NavigatorController
from fxspace.studio._navigator import status_text


@pytest.fixture(scope="module")
def data():
    xy, pos = _face_like()
    P = fx.pairwise_distances(jnp.asarray(xy))
    W = fx.epsilon_graph(P, float(fx.connecting_threshold(P)) * 1.3)
    geo = fx.geodesic_distances(W)
    h = fx.build_hierarchy(xy, geo, c0=8, key=jax.random.PRNGKey(1), restarts=0)
    return NavData(h, geo, pos)


def _linked_and_unlinked(lv):
    a = 0
    b = int(lv.neighbours(a)[0])
    c = next(k for k in range(lv.n_clusters) if k not in (a, b) and not lv.links[b, k])
    return a, b, c


def test_controller_pick_refine_play(data):
    ctl = NavigatorController(data)
    a, b, c = _linked_and_unlinked(data.hierarchy.levels[0])
    assert ctl.pick(a) and ctl.pick(b)
    assert ctl.route is not None and ctl.route.centres == (a, b)
    assert not ctl.pick(c) and "not linked" in ctl.message
    st = ctl.status()
    assert st["keys"] == [a, b] and f"Key centres: {a} → {b}" in status_text(st)
    assert st["bridges"] == data.hierarchy.levels[0].n_bridges == 0
    ctl.refine()
    assert ctl.level == 1 and ctl.route.level == 1
    f0 = ctl.selected_frame
    frames = {ctl.step() for _ in range(20)}
    assert frames <= set(ctl.route.frames.tolist()) and (len(frames) > 1 or f0 in frames)
    ctl.undo()
    ctl.clear()
    assert ctl.route is None
    ctl.set_level(0)
    with pytest.raises(fx.FxspaceError):
        ctl.set_level(99)


def _all_linked(lv, keys):
    return all(bool(lv.links[a, b]) for a, b in zip(keys[:-1], keys[1:], strict=False))


def test_preview_does_not_commit_and_edits_keep_the_route_valid(data):
    """Look, then choose: a preview shows a centre's face without touching the keys;
    insert / replace / delete edit in place, at any level; unlinked neighbours are
    bridged along links with a note; undo restores the keys."""
    ctl = NavigatorController(data, restrict=False)
    h = data.hierarchy
    lv = h.levels[0]
    a, b, c = _linked_and_unlinked(lv)
    ctl.preview_at(h.embedding[lv.center_frames[c]] + 1e-9)
    assert ctl.preview == c and ctl.picks == [] and ctl.route is None
    assert ctl.selected_frame == lv.center_frames[c] and ctl.status()["preview"] == c
    assert f"Preview: centre {c}" in status_text(ctl.status())
    assert ctl.commit(a) and ctl.commit(b) and ctl.picks == [a, b]
    assert ctl.commit(c)  # not linked to b: bridged
    assert _all_linked(lv, ctl.picks) and ctl.picks[-1] == c and ctl.picks[:2] == [a, b]
    assert "bridged" in ctl.message and len(ctl.picks) > 3  # c is not linked to b
    keys = list(ctl.picks)
    ctl.preview_centre(c)
    assert ctl.insert_key(1) and ctl.picks[0] == a and c in ctl.picks[1:]
    assert _all_linked(lv, ctl.picks)
    assert ctl.replace_key(0, centre=b) and ctl.picks[0] == b and _all_linked(lv, ctl.picks)
    n = len(ctl.picks)
    assert ctl.delete_key(0) and _all_linked(lv, ctl.picks) and ctl.picks[0] != b
    assert ctl.route.centres == tuple(ctl.picks) and len(ctl.picks) >= n - 1
    for _ in range(3):
        ctl.undo()
    assert ctl.picks == keys
    assert not ctl.delete_key(99) and "does not exist" in ctl.message
    assert not ctl.insert_key(99) and "cannot insert" in ctl.message
    # at a finer level too
    ctl.level_down()
    assert ctl.level == 1
    lv1 = h.levels[1]
    ctl.preview_centre(0)
    assert ctl.commit() and ctl.commit(int(lv1.neighbours(0)[0]))
    far = int(np.argmax(data.geodesics.distances[lv1.center_frames[0], lv1.center_frames]))
    assert ctl.insert_key(1, centre=far) and _all_linked(lv1, ctl.picks)
    ctl.level_up()
    assert ctl.level == 0
    with pytest.raises(fx.FxspaceError):
        ctl.preview_centre(10_000)


def test_toggle_play_and_hotkeys(data):
    from fxspace.studio._navigator import HOTKEYS

    ctl = NavigatorController(data)
    assert not ctl.toggle_play() and "pick key centres" in ctl.message
    assert ctl.commit(0) and ctl.toggle_play() and not ctl.toggle_play()
    for _label, method in HOTKEYS.values():
        assert callable(getattr(ctl, method))
    assert {"space", "U", "arrowup", "arrowdown"} <= set(HOTKEYS)


def test_click_picks_the_nearest_centre_at_every_level(data, rng):
    ctl = NavigatorController(data, restrict=False)
    h = data.hierarchy
    for li, lv in enumerate(h.levels):
        ctl.set_level(li)
        for q in rng.normal(size=(5, 2)) * 6:
            ctl.clear()
            k, ok = ctl.pick_at(q)
            pos = h.embedding[lv.center_frames]
            d = np.linalg.norm(pos - q, axis=1)
            assert d[k] == pytest.approx(d.min(), abs=1e-12)
            assert ok and ctl.picks == [k] and ctl.route.level == li


def test_level_change_keeps_the_route_and_holds_picks_to_candidates(data):
    ctl = NavigatorController(data)
    a, b, _ = _linked_and_unlinked(data.hierarchy.levels[0])
    assert ctl.pick(a) and ctl.pick(b)
    r0 = ctl.route
    ctl.set_level(2)
    assert ctl.route is r0 and ctl.guide is r0  # kept, shown, and guiding
    cand = ctl.candidates()
    assert len(cand) > 0
    np.testing.assert_array_equal(cand, fx.path_candidates(data.hierarchy, 2, r0.frames))
    st = ctl.status()
    assert st["guide_level"] == 0 and st["candidates"] == cand.tolist()
    assert "Candidates here (near the level-0 route)" in status_text(st)
    other = next(k for k in range(data.hierarchy.levels[2].n_clusters) if k not in cand)
    assert not ctl.pick(other) and "not near the route" in ctl.message
    # a click far from the route snaps to the nearest candidate while restricted
    far = data.hierarchy.embedding[data.hierarchy.levels[2].center_frames[other]]
    k, ok = ctl.pick_at(far)
    assert ok and k in cand and ctl.route.level == 2 and ctl.route.centres == (k,)
    # undo across levels: the pick, then the level change
    ctl.undo()
    assert ctl.level == 2 and ctl.picks == [] and ctl.route is r0
    ctl.undo()
    assert ctl.level == 0 and ctl.picks == [a, b] and ctl.route is r0 and ctl.guide is None
    # the toggle frees the picks
    ctl.set_restrict(False)
    ctl.set_level(2)
    assert ctl.pick(other)


def test_refine_across_three_levels_and_back(data):
    ctl = NavigatorController(data)
    a, b, _ = _linked_and_unlinked(data.hierarchy.levels[0])
    ctl.pick(a)
    ctl.pick(b)
    r0 = ctl.route
    routes = [r0]
    for lvl in (1, 2, 3):
        ctl.refine()
        assert ctl.level == lvl and ctl.route.level == lvl and ctl.guide is routes[-1]
        assert ctl.route.anchors == r0.anchors  # the animator's key frames are kept
        assert fx.is_graph_walk(ctl.route.frames, data.geodesics.distances)
        routes.append(ctl.route)
    for lvl in (2, 1, 0):
        ctl.undo()
        assert ctl.level == lvl and ctl.route is routes[lvl]
    ctl.undo()
    ctl.undo()
    assert ctl.route is None and "nothing to undo" not in ctl.message
    ctl.undo()
    assert ctl.message == "nothing to undo"


def test_play_once_and_export(data, tmp_path):
    ctl = NavigatorController(data, loop=False)
    a, b, _ = _linked_and_unlinked(data.hierarchy.levels[0])
    ctl.pick(a)
    ctl.pick(b)
    ctl.playing = True
    n = len(ctl.playback().times)
    for _ in range(n + 2):
        ctl.step()
    assert not ctl.playing and ctl.play_index == n - 1
    paths = ctl.export(tmp_path, "gif")
    names = {p.name for p in paths}
    assert {"route.trc", "route.json", "route.gif"} <= names
    seq = fx.io.read_markers(tmp_path / "route.trc")
    assert seq.positions.shape == (len(ctl.route.frames), data.positions.shape[1], 3)
    # rigidly aligned copies of the route's frames: the shape (pairwise distances) is kept
    F = np.asarray(fx.distance_features(jnp.asarray(seq.positions)))
    F0 = np.asarray(fx.distance_features(jnp.asarray(data.positions[ctl.route.frames])))
    np.testing.assert_allclose(F, F0, atol=1e-6)


def _many_frames(T=30_000, c=8, seed=0):
    """A large 2-D embedding (a dense blob plus a uniform spread) with a tiny hierarchy
    built directly: a level of ``c`` centres on a ring of links and a finest level of
    every frame (no memberships, no links), no geodesics."""
    from scipy.sparse import csr_array

    from fxspace.cluster import FCMResult
    from fxspace.navigation import Hierarchy, Level

    rng = np.random.default_rng(seed)
    xy = np.concatenate([rng.uniform(-10, 10, (T // 2, 2)), rng.normal(4, 0.3, (T // 2, 2))])
    cf = rng.choice(T, c, replace=False)
    links = np.zeros((c, c), bool)
    links[np.arange(c), (np.arange(c) + 1) % c] = True
    links |= links.T
    fit = FCMResult(xy[cf], np.full((T, c), 1.0 / c), 0.0, 0, fx.RESULTS.successful, {})
    lv = Level(c, xy[cf], cf, fit, csr_array(links), csr_array((c, c), dtype=bool),
               csr_array(links.astype(float)), 1.0, {"init": "kmeans++"})  # fmt: skip
    fine = lv._replace(n_clusters=T, centers=xy, center_frames=np.arange(T), links=None,
                       bridges=None, lengths=None)  # fmt: skip
    return NavData(Hierarchy((lv, fine), xy), None, np.zeros((T, 3, 3)))


def test_many_frames_are_drawn_by_density():
    from fxspace.studio import DENSITY_ABOVE

    d = _many_frames()
    xy = d.hierarchy.embedding
    assert len(xy) > DENSITY_ABOVE
    ctl = NavigatorController(d, density_bins=64)
    assert ctl.pad_mode == "density" and ctl.status()["density"]
    assert "shown by density  " in status_text(ctl.status())
    assert not ctl.centres_by_density
    g = ctl.frame_density()
    assert g.counts.shape == (64, 64) and g.counts.sum() == len(xy)
    # reference: numpy's histogram over the same box; rows are y, columns x
    ref, _, _ = np.histogram2d(
        xy[:, 0], xy[:, 1], bins=64, range=[[g.lo[0], g.hi[0]], [g.lo[1], g.hi[1]]]
    )
    np.testing.assert_array_equal(g.counts, ref.T.astype(int))
    # the densest cell holds the blob at (4, 4)
    i, j = np.unravel_index(np.argmax(g.counts), g.counts.shape)
    cell = (g.hi - g.lo) / 64
    centre = g.lo + (np.array([j, i]) + 0.5) * cell
    np.testing.assert_allclose(centre, [4.0, 4.0], atol=2 * cell.max())
    assert ctl.frame_density() is g  # computed once
    # picking still works on the pad: the nearest centre of the level
    q = np.array([-9.0, 9.0])
    k, ok = ctl.pick_at(q)
    pos = xy[d.hierarchy.levels[0].center_frames]
    assert ok and k == int(np.argmin(np.linalg.norm(pos - q, axis=1)))
    # at the finest level (every frame a centre) the centres are shown by density too
    ctl.set_level(1)
    assert ctl.centres_by_density and ctl.status()["centres_by_density"]
    assert "(centres too)" in status_text(ctl.status())
    assert ctl.nearest_centre(q) == int(np.argmin(np.linalg.norm(xy - q, axis=1)))
    # below the threshold (or with a higher one) the frames are points
    assert NavigatorController(d, density_above=len(xy)).pad_mode == "points"


def test_density_image_rows_and_opacity():
    from fxspace.studio import density_rgba, frame_density

    g = frame_density(np.array([[0.0, 0.0], [1.0, 1.0], [1.0, 1.0]]), bins=2)
    np.testing.assert_array_equal(g.counts, [[1, 0], [0, 2]])  # row 0: low y
    img = density_rgba(g.counts)
    assert img.shape == (2, 2, 4) and img.dtype == np.uint8
    assert img[0, 1, 3] == img[1, 0, 3] == 0 and img[1, 1, 3] == 255
    assert 0 < img[0, 0, 3] < 255
    with pytest.raises(fx.FxspaceError, match="xy"):
        frame_density(np.zeros((0, 2)))


def test_server_draws_density_not_points(data):
    pytest.importorskip("viser", reason="viser not installed (pip install -e '.[viewer]')")
    from fxspace.studio import serve_navigator

    server, ctl = serve_navigator(
        data, port=0, environment_map=False, block=False, density_above=10
    )
    try:
        assert ctl.pad_mode == "density"
        nodes = server.scene._handle_from_node_name
        assert "/pad/density" in nodes and "/pad/frames" not in nodes
        assert "/pad/centres" in nodes
        # the image covers the frames' box on the pad (whose longer side is 2), below z = 0
        img = nodes["/pad/density"]
        assert max(img.render_width, img.render_height) == pytest.approx(2.0)
        assert img.position[2] < 0
    finally:
        server.stop()


@pytest.mark.browser
def test_browser_navigator(data, chromium):
    from fxspace.studio import serve_navigator

    server, ctl = serve_navigator(data, port=0, environment_map=False, block=False)
    a, b, c = _linked_and_unlinked(data.hierarchy.levels[0])
    with chromium.page(server) as page:
        page.get_by_text("Key centres: none").wait_for(timeout=60_000)
        box = chromium.field(page, "Centre")

        def pick(k):
            box.fill(str(k))
            page.get_by_role("button", name="Pick centre").click()

        pick(a)
        page.get_by_text(f"Key centres: {a}", exact=False).wait_for(timeout=60_000)
        pick(b)
        page.get_by_text(f"Key centres: {a} → {b}").wait_for(timeout=60_000)
        pick(c)
        page.get_by_text(f"centres {b} and {c} are not linked", exact=False).wait_for(
            timeout=20_000
        )
        assert ctl.picks == [a, b]
        page.get_by_role("button", name="Refine").click()
        page.get_by_text("Level 1", exact=True).wait_for(timeout=60_000)
        page.get_by_role("button", name="Play / Pause").click()
        page.get_by_text("Playing", exact=False).wait_for(timeout=60_000)
        assert ctl.level == 1 and ctl.playing
        i0 = ctl.play_index
        page.wait_for_timeout(500)
        assert ctl.play_index != i0
        route_text = page.get_by_text("Route:", exact=False).inner_text()
        assert f"Route: {len(ctl.route.frames)} frames" in route_text
    assert np.all(np.asarray(ctl.route.frames) >= 0)


@pytest.mark.slow
def test_load_nav_data_from_config(tmp_path):
    cfg = tmp_path / "nav.toml"
    cfg.write_text(
        'experiment = "navigation"\nseed = 0\n[data]\nsource = "synthetic"\n'
        "synthetic_frames = 80\n[hierarchy]\nc0 = 8\n"
    )
    from fxspace.studio import load_nav_data

    d = load_nav_data(cfg)
    assert d.hierarchy.sizes == (8, 16, 32, 64, 80)
    assert d.positions.shape[0] == 80 and len(d.marker_names) == d.positions.shape[1]
    ctl = NavigatorController(d)
    assert ctl.pick(0)
    bad = tmp_path / "other.toml"
    bad.write_text('experiment = "threshold_sweep"\n')
    with pytest.raises(fx.FxspaceError, match="navigation"):
        load_nav_data(bad)


@pytest.mark.browser
def test_browser_click_on_the_pad_previews_the_nearest_centre(data, chromium):
    from fxspace.studio import serve_navigator

    server, ctl = serve_navigator(data, port=0, environment_map=False, block=False)
    last = len(data.hierarchy.levels) - 1
    ctl.set_level(last)  # the finest level: every frame is a centre
    with chromium.page(server, viewport={"width": 1200, "height": 700}) as page:
        page.get_by_text("Key centres: none").wait_for(timeout=60_000)
        canvas = page.locator("canvas").first
        canvas.wait_for(timeout=30_000)
        box = canvas.bounding_box()
        for _ in range(40):  # the scene accepts clicks once the camera is set
            page.mouse.click(box["x"] + 0.3 * box["width"], box["y"] + 0.5 * box["height"])
            page.wait_for_timeout(250)
            if ctl.preview is not None:
                break
        assert ctl.preview is not None, ctl.message
        k = ctl.preview
        assert k == ctl.index(last).nearest(ctl.last_click)
        page.get_by_text(f"Preview: centre {k}", exact=False).wait_for(timeout=60_000)
        assert ctl.picks == [] and ctl.route is None  # a click looks, it does not commit
        page.get_by_role("button", name="Commit").click()
        page.get_by_text(f"Key centres: {k}", exact=False).wait_for(timeout=60_000)
        assert ctl.picks == [k] and ctl.route is not None and ctl.route.level == last


@pytest.mark.slow
def test_animface_2400_click_finest_and_refine_across_three_levels(data_dir):
    """The seed paper's scale: 2400 AnimFace frames. A click at the finest level picks the
    nearest of its 2400 centres; a route picked at level 0 is refined across three levels,
    kept through level changes, and a finer-level pick is held to its candidates."""
    from fxspace.datasets import FaceData, load_face
    from fxspace.navigation import navigation_space

    face = load_face(FaceData(source="animface", max_frames=2400), 0)
    ns = navigation_space(face.positions, None, key=jax.random.PRNGKey(0),
                          hierarchy={"restarts": 0})  # fmt: skip
    d = NavData(ns.hierarchy, ns.space.geodesics, np.asarray(face.positions),
                tuple(face.marker_names), face.rate)  # fmt: skip
    h = d.hierarchy
    finest = len(h.levels) - 1
    assert h.levels[finest].n_clusters == len(face.positions) >= 2400
    ctl = NavigatorController(d, restrict=False)
    ctl.set_level(finest)
    target = h.embedding[h.levels[finest].center_frames[1234]] + 1e-6
    k, ok = ctl.pick_at(target)
    assert ok and k == 1234 and ctl.route.level == finest
    ctl.clear()
    ctl.set_level(0)
    ctl.set_restrict(True)
    lv0 = h.levels[0]
    a = 0
    b = int(lv0.neighbours(a)[0])
    assert ctl.pick(a) and ctl.pick(b)
    r0 = ctl.route
    for lvl in (1, 2, 3):
        ctl.refine()
        assert ctl.route is not None and ctl.route.level == lvl
        assert ctl.route.anchors == r0.anchors
    r3 = ctl.route
    ctl.set_level(finest)  # jump: the route is kept and guides the picks
    assert ctl.route is r3 and len(ctl.candidates()) > 0
    k, ok = ctl.pick_at(h.embedding[r3.frames[len(r3.frames) // 2]])
    assert ok and k in set(ctl.candidates().tolist())
    for _ in range(2):
        ctl.undo()
    assert ctl.level == 3 and ctl.route is r3


def _studio_scenario(page, ctl, chromium, lvl0) -> None:
    """Preview a centre without committing it, build a route of four keys, insert one,
    replace one, delete one, undo — through the page's controls only."""

    def until(cond, what):
        for _ in range(600):
            if cond():
                return
            page.wait_for_timeout(100)
        raise AssertionError(f"timed out waiting for {what}: {ctl.message}")

    def press(name):
        page.get_by_role("button", name=name).click()

    def preview(k):
        chromium.field(page, "Centre").fill(str(k))
        press("Preview centre")
        until(lambda: ctl.preview == k, f"preview of {k}")

    def key_no(i):
        chromium.field(page, "Key #").fill(str(i))
        chromium.field(page, "Key #").press("Enter")
        page.wait_for_timeout(300)

    from fxspace.pipelines.navigation import auto_key_centres

    page.get_by_text("Key centres: none").wait_for(timeout=120_000)
    route4 = auto_key_centres(ctl.data.hierarchy, ctl.data.geodesics, 4)
    assert len(route4) == 4
    other = next(k for k in range(lvl0.n_clusters) if k not in route4)
    preview(other)  # look first: nothing is committed
    page.get_by_text(f"Preview: centre {other}", exact=False).wait_for(timeout=30_000)
    assert ctl.picks == [] and ctl.route is None
    assert ctl.selected_frame == int(lvl0.center_frames[other])
    for n, k in enumerate(route4, 1):  # a route of four keys
        preview(k)
        press("Commit")
        until(lambda n=n: len(ctl.picks) == n, f"key {n}")
    assert ctl.picks == route4
    page.get_by_text("Key centres: " + " → ".join(map(str, route4))).wait_for(timeout=30_000)
    key_no(2)  # insert before key #2
    preview(other)
    press("Insert before key")
    until(lambda: other in ctl.picks, "insert")
    replacement = next(k for k in range(lvl0.n_clusters) if k not in ctl.picks)
    key_no(0)  # replace key #0
    preview(replacement)
    press("Replace key")
    until(lambda: ctl.picks[0] == replacement, "replace")
    after_replace = list(ctl.picks)
    # delete a key whose neighbours are linked (else it would be bridged straight back)
    i = next(
        (
            j
            for j in range(1, len(after_replace) - 1)
            if lvl0.links[after_replace[j - 1], after_replace[j + 1]]
        ),
        len(after_replace) - 1,
    )
    key_no(i)
    press("Delete key")
    until(lambda: "deleted key" in ctl.message, "delete")
    assert len(ctl.picks) == len(after_replace) - 1
    press("Undo")
    until(lambda: ctl.picks == after_replace, "undo")
    final = ctl.route
    assert final is not None and list(final.centres) == after_replace
    for a, b in zip(final.centres[:-1], final.centres[1:], strict=True):
        assert lvl0.links[a, b], (a, b)


@pytest.mark.browser
def test_browser_studio_from_a_config_preview_and_edit(tmp_path, chromium, monkeypatch):
    """The done-when scenario on a small synthetic config, through the same path as
    ``fxspace studio CONFIG``: `fxspace.cli.studio_target` runs the config (sweep, space,
    hierarchy cached), the studio's serve opens the run on a free port."""
    from fxspace.cli import studio_target
    from fxspace.studio import serve

    cfg = tmp_path / "nav.toml"
    cfg.write_text(
        'experiment = "navigation"\nseed = 0\n[data]\nsource = "synthetic"\n'
        'synthetic_frames = 120\nsynthetic_markers = 24\n[graph]\nthreshold = "max_r"\n'
        "num_thresholds = 4\n[hierarchy]\nc0 = 8\nrestarts = 0\ncompare_cold = false\n"
        '[navigation]\nanimation = "none"\nlevel_figures = false\n'
    )
    run_dir = studio_target(cfg, tmp_path / "run")
    assert (run_dir / "cache" / "hierarchy.npz").is_file()
    server, ctl = serve(run_dir, port=0, block=False, environment_map=False)
    with chromium.page(server) as page:
        _studio_scenario(page, ctl, chromium, ctl.data.hierarchy.levels[0])


@pytest.mark.slow
@pytest.mark.browser
@pytest.mark.timeout(3600)  # the first launch builds the sweep, space and hierarchy
def test_browser_studio_navigation_toml_from_a_clean_checkout(
    tmp_path, chromium, data_dir, monkeypatch
):
    """Done when (issue 20): `fxspace studio configs/navigation.toml` alone — the sweep,
    space and hierarchy built (cached), the page opened — previews a centre without
    committing it, builds a route of four keys, inserts, replaces, deletes, undoes, and
    every consecutive pair of the final route is linked. A second launch reads the
    cached stages."""
    import time
    from pathlib import Path

    from fxspace.cli import studio_target
    from fxspace.studio import serve

    root = Path(__file__).resolve().parents[2]
    run_dir = studio_target(root / "configs" / "navigation.toml", tmp_path / "run")
    server, ctl = serve(run_dir, port=0, block=False, environment_map=False)
    with chromium.page(server) as page:
        _studio_scenario(page, ctl, chromium, ctl.data.hierarchy.levels[0])
    t0 = time.perf_counter()
    again = studio_target(root / "configs" / "navigation.toml", tmp_path / "run")
    server, ctl2 = serve(again, port=0, block=False, environment_map=False)
    server.stop()
    assert time.perf_counter() - t0 < 120 and ctl2.data.hierarchy.sizes == ctl.data.hierarchy.sizes


def test_bridges_drawn_apart_from_links():
    """The pad colours a bridge (not a link by the paper's ρ rule) orange, a link blue;
    the status counts the level's bridges."""
    from fxspace.studio._navigator import BRIDGE_RGB, LINK_RGB, _link_colours

    links = np.zeros((4, 4), bool)
    links[0, 1] = links[1, 2] = links[2, 3] = True
    links |= links.T
    bridges = np.zeros_like(links)
    bridges[1, 2] = bridges[2, 1] = True

    class Lv:
        pass

    from scipy.sparse import csr_array

    lv = Lv()
    lv.links, lv.bridges = csr_array(links), csr_array(bridges)
    i, j = fx.navigation.link_pairs(lv.links)
    cols = _link_colours(lv, i, j)
    assert [tuple(c[0]) for c in cols] == [LINK_RGB, BRIDGE_RGB, LINK_RGB]
    st = {"level": 0, "n_levels": 2, "n_clusters": 4, "bridges": 1, "keys": [],
          "preview": None, "selected_key": None, "route_frames": 0, "route_level": None,
          "density": False, "n_frames": 9, "centres_by_density": False, "guide_level": None,
          "candidates": [], "restricted": False, "next_candidates": [], "frame": 0,
          "playing": False, "message": ""}  # fmt: skip
    assert "Bridges: 1 (orange" in status_text(st)
    assert "Bridges" not in status_text({**st, "bridges": 0})
    assert "FCM" not in status_text({**st, "fcm": ""})


def test_status_line_says_when_a_level_is_not_at_its_fixed_point(data):
    """Issue 45: a level whose FCM stopped at its cap says so, with the reason, on the
    status line; a level at its fixed point says nothing."""
    from fxspace.studio._nav_controller import fcm_status

    xy = data.hierarchy.embedding
    capped = fx.build_hierarchy(xy, c0=8, levels=2, finest=False, max_steps=2).levels[1]
    assert not capped.converged
    note = fcm_status(capped)
    assert "max_steps_reached after 2 iterations" in note and "raise max_steps" in note
    assert fcm_status(data.hierarchy.levels[0]) == ""
    st = NavigatorController(data).status()
    assert st["fcm"] == "" and "FCM:" in status_text({**st, "fcm": note})


def test_status_line_says_when_the_graphs_pieces_were_joined(data):
    """A k-NN run whose takes were joined at their closest frames says so on the status
    line (the pieces counted); a run in one piece says nothing."""
    import dataclasses

    st = NavigatorController(data).status()
    assert st["pieces"] == 0 and "Takes:" not in status_text(st)
    joins = {"pieces": [400, 300, 100], "frames": [[1, 500], [20, 750]], "lengths": [3.0, 4.0]}
    st = NavigatorController(dataclasses.replace(data, joins=joins)).status()
    assert st["pieces"] == 3
    assert "Takes: the graph's 3 pieces joined at their closest frames" in status_text(st)
