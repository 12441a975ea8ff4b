"""The site as a reader gets it: built with ``mkdocs build --strict``, opened from disk
(file://) in headless Chromium with the network off; maths rendered (MathML, no raw
``\\(``), every image loaded, the architecture diagram drawn. Slow (a site build)."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
ARGS = ["--no-sandbox", "--disable-gpu", "--disable-background-networking", "--no-first-run"]

PAGES = [
    "index.html",
    "getting-started/index.html",
    "guides/apps/index.html",
    "concepts/architecture/index.html",
    "api/cluster/index.html",
    "reproductions/experiments/index.html",
    *(
        f"reproductions/{k}/index.html"
        for k in ("kim-jung", "hirose-higuchi", "ha-han", "park-kang-kwon")
    ),
    *(
        f"guides/paper-{k}/index.html"
        for k in ("kim-jung", "hirose-higuchi", "ha-han", "park-kang-kwon")
    ),
    "benchmarks/measured/index.html",
]


@pytest.fixture(scope="module")
def site(tmp_path_factory):
    why = "docs extra not installed (pip install -e '.[docs]')"
    pytest.importorskip("mkdocs", reason=why)
    pytest.importorskip("latex2mathml", reason=why)
    out = tmp_path_factory.mktemp("site")
    env = dict(os.environ, NO_MKDOCS_2_WARNING="1", PYTHONPATH=str(ROOT))
    proc = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--quiet", "-d", str(out)],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert proc.returncode == 0, proc.stdout + proc.stderr
    return out


@pytest.fixture(scope="module")
def browser():
    pw = pytest.importorskip(
        "playwright.sync_api", reason="playwright not installed (pip install -e '.[viewer]')"
    )
    exe = (
        os.environ.get("FXSPACE_CHROMIUM")
        or shutil.which("chromium")
        or shutil.which("chromium-browser")
    )
    if exe is None:
        pytest.skip("Chromium not found (apt-get install chromium, or set FXSPACE_CHROMIUM)")
    with pw.sync_playwright() as p:
        b = p.chromium.launch(executable_path=exe, args=ARGS)
        try:
            yield b
        finally:
            b.close()


@pytest.mark.slow
def test_site_offline_maths_images_diagram(site, browser):
    ctx = browser.new_context(offline=True)
    requested = []
    ctx.on("request", lambda r: requested.append(r.url))
    try:
        page = ctx.new_page()
        n_math = n_img = 0
        for rel in PAGES:
            path = site / rel
            assert path.is_file(), f"page not built: {rel}"
            page.goto(path.as_uri(), wait_until="load")
            text = page.inner_text("body")
            assert "\\(" not in text and "\\[" not in text, f"raw TeX on {rel}"
            n_math += page.locator("math").count()
            sizes = page.eval_on_selector_all(
                "img", "els => els.map(e => [e.getAttribute('src'), e.complete, e.naturalWidth])"
            )
            for src, complete, width in sizes:
                assert complete and width > 0, f"image {src} not loaded on {rel}"
            n_img += len(sizes)
            if rel.startswith("concepts/architecture"):
                assert page.locator(".fx-diagram svg rect").count() >= 10
            if rel.startswith("reproductions/") and "experiments" not in rel:
                _numbers_as_generated(page, rel.split("/")[1])
        assert n_math > 0, "no rendered maths found"
        assert n_img >= 3, f"expected the apps' screenshots, found {n_img} images"
        remote = [u for u in requested if u.startswith(("http://", "https://"))]
        assert not remote, f"the site asked the network for {remote[:5]}"
    finally:
        ctx.close()


def _numbers_as_generated(page, key: str) -> None:
    """Each row of a reproduction page's table, as the reader sees it, shows the paper's
    number and ours from the page's snapshot (`tests/test_docs_repro.py` checks the
    snapshot against the runs' ``metrics.json`` where ``runs/`` exists)."""
    import json

    from fxspace.pipelines._docs import PAPERS, fmt

    snap = json.loads((ROOT / "docs" / "reproductions" / "data" / f"{key}.json").read_text())
    rows = page.eval_on_selector_all(
        "table tr", "trs => trs.map(tr => [...tr.cells].map(c => c.innerText.trim()))"
    )
    shown = {r[0]: r[1:3] for r in rows if len(r) >= 3}
    for r in PAPERS[key].rows:
        label = page.evaluate("s => { const d = document.createElement('div'); "
                              "d.innerHTML = s; return d.innerText.trim(); }", r.label)  # fmt: skip
        assert label in shown, f"{key}: row {r.label!r} missing from the rendered page"
        want = [fmt(r.paper), fmt(snap["values"][f"{r.config}:{r.path}"])]
        got = [c.replace("`", "") for c in shown[label]]
        assert got == [w.replace("`", "") for w in want], f"{key}: {r.label}: {got} != {want}"
