"""The navigator on a k-NN run (issues 24, 45: navigation at scale): opened through the
pipeline object like any navigation run, the controller makes, bridges, refines and
plays routes on the frames' neighbourhood graph down to the level where every frame is a
centre, with no dense geodesics; the page opens from ``fxspace studio`` on a
``navigation_scale`` run and draws the links."""

import json

import numpy as np
import pytest

import fxspace as fx
from fxspace.studio import NavigatorController, load_nav_data

SMALL = {
    "experiment": "navigation_scale",
    "seed": 0,
    "data": {"source": "synthetic", "synthetic_frames": 1500, "synthetic_markers": 24},
    "graph": {"k": 8, "landmarks": 64},
    "hierarchy": {"c0": 6, "levels": 3},
    "navigation": {"figure": False},
}


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    from fxspace.pipelines import run_dict

    (d,) = run_dict(SMALL, tmp_path_factory.mktemp("scale") / "run")
    return d


@pytest.fixture(scope="module")
def data(run_dir):
    return load_nav_data(run_dir)


def _walk(data, frames) -> bool:
    W = fx.expression.to_scipy(data.paths)
    f = np.asarray(frames)
    return bool(np.all(f[1:] != f[:-1]) and np.all(np.asarray(W[f[:-1], f[1:]]).ravel() > 0))


def test_run_folder_opens_sparse(data, run_dir):
    assert data.sparse and isinstance(data.paths, fx.expression.NeighbourGraph)
    assert [lv.n_clusters for lv in data.hierarchy.levels] == [6, 12, 24, 1500]
    assert all(hasattr(lv.links, "tocoo") for lv in data.hierarchy.levels)  # csr, not dense
    assert data.positions.shape == (1500, 24, 3)
    assert "k-NN graph, k = 8" in data.threshold_source


def test_pick_bridge_refine_to_frames_play_and_export(data, tmp_path):
    ctl = NavigatorController(data, restrict=False)
    lv = data.hierarchy.levels[0]
    a = 0
    b = int(lv.neighbours(a)[0])
    c = next(k for k in range(lv.n_clusters) if k not in (a, b) and not lv.links[b, k])
    assert ctl.status()["fcm"] == ""  # every level at its fixed point: nothing to say
    assert ctl.pick(a) and ctl.pick(b)
    assert not ctl.pick(c) and "not linked" in ctl.message
    ctl.preview_centre(c)
    assert ctl.commit() and "bridged via" in ctl.message  # joined along links
    keys = list(ctl.picks)
    assert keys[0] == a and keys[-1] == c
    assert all(lv.links[p, q] for p, q in zip(keys[:-1], keys[1:], strict=True))
    while ctl.level + 1 < ctl.n_levels:
        ctl.refine()
    assert ctl.level == 3 and ctl.route.level == 3  # every frame a centre
    fr = np.asarray(ctl.route.frames)
    assert _walk(data, fr)
    assert "already at the finest level" not in ctl.message
    ctl.refine()
    assert "already at the finest level" in ctl.message
    # candidates near the level-2 route, and the status names them without a dense matrix
    from fxspace.studio._navigator import status_text

    assert len(ctl.candidates()) > 0 and "Candidates here" in status_text(ctl.status())
    shown = {ctl.step() for _ in range(30)}
    assert shown <= set(fr.tolist())
    out = ctl.export(tmp_path / "exp", animation="none")
    assert {p.name for p in out} == {"route.trc", "route.json"}
    assert json.loads((tmp_path / "exp" / "route.json").read_text())["frames"] == fr.tolist()
    ctl.undo()
    assert ctl.level == 2


def test_held_to_candidates_at_a_finer_level(data):
    ctl = NavigatorController(data)  # restrict: finer picks held to the candidates
    lv0 = data.hierarchy.levels[0]
    assert ctl.pick(0) and ctl.pick(int(lv0.neighbours(0)[0]))
    ctl.set_level(1)
    cand = ctl.candidates()
    assert len(cand) > 0
    outside = next(k for k in range(data.hierarchy.levels[1].n_clusters) if k not in cand)
    assert not ctl.pick(outside) and "not near the route" in ctl.message
    xy = data.hierarchy.embedding[data.hierarchy.levels[1].center_frames[cand[0]]]
    assert ctl.nearest_centre(xy) == int(cand[0])


@pytest.mark.slow
@pytest.mark.browser
def test_browser_studio_scale_run(run_dir, chromium):
    """``fxspace studio RUN`` on a navigation_scale run: picks through the page's controls,
    refines to every frame (the levels' sparse links drawn on the way), plays."""
    from fxspace.studio import serve

    server, ctl = serve(run_dir, port=0, block=False, environment_map=False)
    lv = ctl.data.hierarchy.levels[0]
    a, b = 0, int(lv.neighbours(0)[0])
    with chromium.page(server) as page:
        page.get_by_text("Key centres: none").wait_for(timeout=60_000)
        box = chromium.field(page, "Centre")
        for k in (a, b):
            box.fill(str(k))
            page.get_by_role("button", name="Pick centre").click()
        page.get_by_text(f"Key centres: {a} → {b}").wait_for(timeout=60_000)
        for lvl in (1, 2, 3):
            page.get_by_role("button", name="Refine").click()
            page.get_by_text(f"Level {lvl}", exact=True).wait_for(timeout=60_000)
        assert ctl.level == 3 and _walk(ctl.data, ctl.route.frames)
        page.get_by_role("button", name="Play / Pause").click()
        page.get_by_text("Playing", exact=False).wait_for(timeout=60_000)
        i0 = ctl.play_index
        page.wait_for_timeout(500)
        assert ctl.play_index != i0
