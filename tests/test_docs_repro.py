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


def _fake_rows():
    return [
        {"case": "100 frames", "size": 100, "ours": "f", "ours_s": 0.5, "peer": "p",
         "peer_s": 2.0},
        {"case": "200 frames", "size": 200, "ours": "f", "ours_s": 1.0, "peer": "p",
         "peer_s": 3.0, "ratio": 3.0},
    ]  # fmt: skip


def test_benchmark_record_and_page(tmp_path):
    """34.4: a benchmark's record holds its rows, the ratio filled in, and the machine;
    the page draws a labelled figure and shows every number of the record."""
    from fxspace.errors import FxspaceError
    from fxspace.pipelines import write_bench_page
    from fxspace.runs import BENCH_FIELDS, write_bench

    p = write_bench("demo", _fake_rows(), title="Demo", command="python x.py", root=tmp_path)
    rec = json.loads(p.read_text())
    assert p == tmp_path / "bench" / "demo.json"
    assert [tuple(r) for r in rec["rows"]] == [BENCH_FIELDS] * 2
    assert rec["rows"][0]["ratio"] == 4.0 and rec["rows"][1]["ratio"] == 3.0
    assert {"date", "cpu_count", "devices", "versions"} <= set(rec["machine"])
    page = write_bench_page(tmp_path, tmp_path / "site")
    text = page.read_text()
    assert "## Demo" in text and "`python x.py`" in text and rec["machine"]["date"] in text
    assert "**4.00×**" in text and "**3.00×**" in text and "0.5 s" in text
    assert (tmp_path / "site" / "figures" / "demo.png").stat().st_size > 10_000
    with pytest.raises(FxspaceError, match=r"rows\[0\] lacks \['peer_s'\]"):
        write_bench("bad", [{"case": "a", "ours": "f", "ours_s": 1.0, "peer": "p"}],
                    title="t", command="c", root=tmp_path)  # fmt: skip
    with pytest.raises(FxspaceError, match="rows is empty"):
        write_bench("bad", [], title="t", command="c", root=tmp_path)


def test_benchmark_page_in_the_site_equals_its_records():
    """The committed page is what `fxspace docs` renders from the committed records."""
    from fxspace.pipelines._docs import render_bench

    root = Path(__file__).resolve().parents[1] / "docs" / "benchmarks"
    records = [json.loads(p.read_text()) for p in sorted((root / "data").glob("*.json"))]
    assert records, "docs/benchmarks/data holds no benchmark record"
    assert (root / "measured.md").read_text() == render_bench(records)
    for rec in records:
        assert (root / "figures" / f"{rec['name']}.png").is_file()


def test_the_studio_bench_shows_its_command_without_the_copy_path():
    """The measured page shows the command a newcomer runs: ``--json PATH`` (where a copy
    of the rows went) is left out of the recorded command, every other argument kept."""
    import importlib.util

    path = Path(__file__).resolve().parents[1] / "experiments" / "bench_studio.py"
    spec = importlib.util.spec_from_file_location("_bench_studio", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    args = ["--clean", "configs/a.toml", "--json", "/tmp/x.json", "configs/b.toml",
            "--json=/tmp/y.json", "--timeout", "60"]  # fmt: skip
    assert mod._shown(args) == ["--clean", "configs/a.toml", "configs/b.toml", "--timeout", "60"]
    assert mod._shown([]) == []
