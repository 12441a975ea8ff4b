"""The README's and the apps guide's screenshots, taken from the real apps in headless
Chromium (playwright): ``docs/images/navigator.png`` and ``docs/images/editor.png``.

- navigator: a navigation run folder (``--nav runs/navigation``) or, by default, the
  expression space of 600 AnimFace frames built here (the data root's
  ``face/animface_cheeks.c3d``), two key centres picked, the head of the selected frame;
- editor: a reconstruction run folder (``--editor runs/reconstruction``: run
  ``fxspace run configs/reconstruction.toml`` first), at a frame inside its edit;
- walker: the live controller of ``configs/mood_walk.toml`` (``--walker CONFIG``)
  wearing CesiumMan (the data root's ``mesh/CesiumMan.glb``), mid-stride:
  ``docs/images/walker.png``.

Both show the ICT head when it is under the data root. Usage:
``python experiments/screenshots.py [--nav RUN_DIR] [--editor RUN_DIR] [--walker CONFIG]
[--out docs/images] [--only navigator|editor|walker]``.
"""

from __future__ import annotations

import argparse
import os
import shutil
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
ARGS = ["--no-sandbox", "--disable-gpu", "--no-first-run", "--disable-sync"]


def _shoot(server, path: Path, wait_text: str, size=(1280, 800), prepare=None) -> None:
    from playwright.sync_api import sync_playwright

    exe = os.environ.get("FXSPACE_CHROMIUM") or shutil.which("chromium") or "/usr/bin/chromium"
    try:
        with sync_playwright() as p:
            b = p.chromium.launch(executable_path=exe, args=ARGS)
            pg = b.new_page(viewport={"width": size[0], "height": size[1]})
            pg.goto(f"http://127.0.0.1:{server.get_port()}")
            pg.get_by_text(wait_text, exact=False).first.wait_for(timeout=120_000)
            if prepare is not None:  # once the page is connected: e.g. the camera
                pg.wait_for_timeout(2000)
                prepare()
            pg.wait_for_timeout(8000)  # software WebGL: let the meshes arrive and render
            # viser's notice about software rendering is not part of the app
            for btn in pg.locator(".mantine-Notification-closeButton").all():
                btn.click()
            pg.wait_for_timeout(500)
            pg.screenshot(path=str(path))
            b.close()
    finally:
        server.stop()
    print(f"wrote {path}")


def navigator(run: str | None, out: Path) -> None:
    import jax

    from fxspace.studio import NavData, load_nav_data, serve_navigator

    if run:
        data = load_nav_data(run)
    else:
        from fxspace.datasets import FaceData, load_face
        from fxspace.navigation import navigation_space

        face = load_face(FaceData(source="animface", max_frames=600), 0)
        ns = navigation_space(face.positions, None, key=jax.random.PRNGKey(0),
                              hierarchy={"restarts": 0})  # fmt: skip
        data = NavData(ns.hierarchy, ns.space.geodesics, np.asarray(face.positions),
                       tuple(face.marker_names), face.rate)  # fmt: skip
    server, ctl = serve_navigator(data, port=0, block=False)
    lv = data.hierarchy.levels[0]
    ctl.pick(0)
    ctl.pick(int(lv.neighbours(0)[0]))
    server.fxspace_view.refresh(full=True)
    _shoot(server, out / "navigator.png", "Face:")


def editor(run: str, out: Path) -> None:
    from fxspace.studio._editor import serve

    server, ctl = serve(run, port=0, block=False)
    ctl.set_frame(ctl.keys[0].frame if ctl.keys else ctl.n_frames // 2)
    server.fxspace_view.refresh()
    _shoot(server, out / "editor.png", "Face:", size=(1280, 900))


def walker(config: str, out: Path) -> None:
    import time

    from fxspace.studio._motion import serve

    server, ctl = serve(config, port=0, block=False, export_path=out / "_unused.bvh")
    body = server.fxspace_view.body
    if body.skin is None:
        server.stop()
        raise SystemExit("walker: no character (CesiumMan under the data root?) — not shot")
    def closer() -> None:  # a few seconds of walking, then paused mid-stride, framed
        time.sleep(6.0)
        server.fxspace_view.play.value = False
        time.sleep(0.5)
        at = np.asarray(body.center)
        for client in server.get_clients().values():
            with client.atomic():
                # viser moves look_at with position: position first, then look_at
                client.camera.position = tuple(at + np.asarray([1.7, 0.35, 1.7]))
                client.camera.look_at = tuple(at)

    t0 = time.monotonic()
    _shoot(server, out / "walker.png", "mood_walk", size=(1280, 800), prepare=closer)
    print(f"walker: {ctl.frame} frames played in {time.monotonic() - t0:.0f} s")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--nav", default=None, help="navigation run folder (default: built here)")
    ap.add_argument("--editor", default="runs/reconstruction", help="reconstruction run folder")
    ap.add_argument("--walker", default=str(ROOT / "configs" / "mood_walk.toml"),
                    help="parametric_synthesis config or run folder")  # fmt: skip
    ap.add_argument("--out", default=str(ROOT / "docs" / "images"))
    ap.add_argument("--only", choices=("navigator", "editor", "walker"), default=None)
    a = ap.parse_args()
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    if a.only in (None, "navigator"):
        navigator(a.nav, out)
    if a.only in (None, "editor"):
        editor(a.editor, out)
    if a.only in (None, "walker"):
        walker(a.walker, out)


if __name__ == "__main__":
    main()
