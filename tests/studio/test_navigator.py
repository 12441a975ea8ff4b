"""The browser navigator: the controller without a browser, then the real page in headless
Chromium (skipped, with the reason, where viser, playwright or Chromium is absent)."""

import os
import shutil

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import face_like as _face_like

import fxspace as fx
from fxspace.studio._navigator import NavData, NavigatorController

CHROMIUM_ARGS = [
    "--no-sandbox",
    "--disable-gpu",
    "--disable-background-networking",
    "--disable-component-update",
    "--no-first-run",
    "--disable-sync",
]


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
    assert f"Key centres: {a} → {b}" in ctl.status()
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


def _chromium() -> str | None:
    return (
        os.environ.get("FXSPACE_CHROMIUM")
        or shutil.which("chromium")
        or shutil.which("chromium-browser")
    )


@pytest.mark.browser
def test_browser_navigator(data):
    pytest.importorskip("viser", reason="viser not installed (pip install -e '.[viewer]')")
    pw = pytest.importorskip(
        "playwright.sync_api", reason="playwright not installed (pip install -e '.[viewer]')"
    )
    exe = _chromium()
    if exe is None:
        pytest.skip("Chromium not found (apt-get install chromium, or set FXSPACE_CHROMIUM)")
    from fxspace.studio._navigator import serve_navigator

    server, ctl = serve_navigator(data, port=0, environment_map=False, block=False)
    a, b, c = _linked_and_unlinked(data.hierarchy.levels[0])
    try:
        with pw.sync_playwright() as p:
            browser = p.chromium.launch(executable_path=exe, args=CHROMIUM_ARGS)
            try:
                page = browser.new_page()
                page.goto(f"http://127.0.0.1:{server.get_port()}")
                page.get_by_text("Key centres: none").wait_for(timeout=60_000)
                box = page.locator(
                    "xpath=//label[text()='Centre']/ancestor::div"
                    "[contains(@class,'mantine-Flex-root')][1]//input"
                )

                def pick(k):
                    box.fill(str(k))
                    page.get_by_role("button", name="Pick centre").click()

                pick(a)
                page.get_by_text(f"Key centres: {a}", exact=False).wait_for(timeout=20_000)
                pick(b)
                page.get_by_text(f"Key centres: {a} → {b}").wait_for(timeout=20_000)
                pick(c)
                page.get_by_text(f"centres {b} and {c} are not linked", exact=False).wait_for(
                    timeout=20_000
                )
                assert ctl.picks == [a, b]
                page.get_by_role("button", name="Refine").click()
                page.get_by_text("Level 1", exact=True).wait_for(timeout=20_000)
                page.get_by_role("button", name="Play / Pause").click()
                page.get_by_text("Playing", exact=False).wait_for(timeout=20_000)
                assert ctl.level == 1 and ctl.playing
                i0 = ctl.play_index
                page.wait_for_timeout(500)
                assert ctl.play_index != i0
                route_text = page.get_by_text("Route:", exact=False).inner_text()
                assert f"Route: {len(ctl.route.frames)} frames" in route_text
            finally:
                browser.close()
    finally:
        server.stop()
    assert np.all(np.asarray(ctl.route.frames) >= 0)


@pytest.mark.slow
def test_load_nav_data_from_config(tmp_path):
    cfg = tmp_path / "nav.toml"
    cfg.write_text(
        'experiment = "navigation"\nseed = 0\n[data]\nsource = "synthetic"\n'
        "synthetic_frames = 80\n[hierarchy]\nc0 = 8\n"
    )
    from fxspace.studio._navigator import load_nav_data

    d = load_nav_data(cfg)
    assert d.hierarchy.sizes == (8, 16, 32, 64, 80)
    assert d.positions.shape[0] == 80 and len(d.marker_names) == d.positions.shape[1]
    ctl = NavigatorController(d)
    assert ctl.pick(0)
    bad = tmp_path / "other.toml"
    bad.write_text('experiment = "threshold_sweep"\n')
    with pytest.raises(fx.FxspaceError, match="navigation"):
        load_nav_data(bad)
