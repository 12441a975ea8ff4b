"""Issue 34.3: the reproduction pages are generated (`fxspace docs`), not typed: each
page is rendered again from the snapshot of numbers written beside it and compared, its
figures are there, and where the shipped configs' run folders exist (``runs/``) the
snapshot's numbers are theirs."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from fxspace.pipelines._docs import PAPERS, fmt, render, snapshot

ROOT = Path(__file__).resolve().parents[1]
REPRO = ROOT / "docs" / "reproductions"


@pytest.mark.parametrize("key", sorted(PAPERS))
def test_page_is_rendered_from_its_snapshot(key):
    page = REPRO / f"{key}.md"
    snap = json.loads((REPRO / "data" / f"{key}.json").read_text())
    assert page.read_text() == render(key, snap), f"regenerate {page}: fxspace docs"
    text = page.read_text()
    for r in PAPERS[key].rows:  # every number of the table is the snapshot's
        v = snap["values"][f"{r.config}:{r.path}"]
        assert f"| {r.label} | {fmt(r.paper)} | {fmt(v)} |" in text
    for f in snap["figures"]:
        assert (REPRO / "figures" / key / f).is_file()
    nav = (ROOT / "mkdocs.yml").read_text()
    assert f"reproductions/{key}.md" in nav


@pytest.mark.parametrize("key", sorted(PAPERS))
def test_snapshot_equals_the_runs_metrics(key):
    runs = ROOT / "runs"
    paper = PAPERS[key]
    if not all((runs / c / "metrics.json").is_file() for c in paper.configs):
        pytest.skip(f"no finished runs of {paper.configs} under runs/ (fxspace docs --run)")
    snap = json.loads((REPRO / "data" / f"{key}.json").read_text())
    assert snapshot(paper, runs)["values"] == snap["values"]


def test_render_is_pure_and_shows_missing_runs():
    snap = {"values": {}, "runs": {"navigation": False}, "figures": []}
    a = render("kim-jung", snap)
    assert a == render("kim-jung", snap) and "Not run yet" in a and "| — |" in a
    assert fmt(0.123456) == "0.1235" and fmt(True) == "yes" and fmt([2, 10]) == "2 / 10"
