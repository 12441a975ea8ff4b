"""`fxspace report`: the swept keys and only the metrics that differ, with units; one
figure per differing metric (words and units on the axes, integer ticks on integer keys,
a "best" star only where the metric has a direction); every column kept in runs.csv."""

import csv
import dataclasses
import io
import types
import zipfile
from pathlib import Path

import numpy as np
import pytest

import fxspace.plot
from fxspace import report as runs
from fxspace.cli import main
from fxspace.pipelines import _REGISTERED, register, sweep_config
from fxspace.plot import plot_report_metric
from fxspace.report import describe

ROOT = Path(__file__).resolve().parents[2]


@dataclasses.dataclass(frozen=True)
class _Cfg:
    n: int = 2
    k: float = 1.0

    def validate(self):
        pass


def _toy_run(cfg, run_dir, seed):
    return {
        "fit_error_mm": (cfg.n - 3) ** 2 * cfg.k + 0.5,  # lower is better, mm
        "r": 1.0 / cfg.n,  # higher is better
        "spread_deg": 10.0 * cfg.n + cfg.k,  # differs, no direction
        "rate_hz": 60.0,  # constant
        "label": "toy",  # constant text
        "choice": {"index": cfg.n, "solve_s": 0.01 * cfg.n},  # an index and a timing
    }


@pytest.fixture
def toy():
    mod = types.ModuleType("report_toy")
    mod.Config, mod.STAGES, mod.run = _Cfg, (), _toy_run
    register(mod, "report_toy")
    yield "report_toy"
    _REGISTERED.pop("report_toy", None)


@pytest.fixture
def sweep(tmp_path, toy):
    """A sweep of 2 swept keys: n (integer, 3 values) × k (float, 2 values)."""
    p = tmp_path / "s.toml"
    p.write_text(f'experiment = "{toy}"\n[sweep]\nn = [2, 3, 5]\nk = [1.0, 2.5]\n')
    sweep_config(p, tmp_path / "o", engine="serial")
    return tmp_path / "o"


@pytest.fixture
def drawn(monkeypatch):
    """The figures the report draws, with the arguments it drew them from."""
    got = []

    def spy(*a, **kw):
        fig = plot_report_metric(*a, **kw)
        got.append((kw, fig))
        return fig

    # plot_report_figure draws it (fxspace.plot._report: where it looks the name up)
    monkeypatch.setattr(fxspace.plot._report, "plot_report_metric", spy)
    return got


def _header_and_rows(printed: str, n: int = 6) -> tuple[str, list[str]]:
    lines = printed.splitlines()
    rule = next(i for i, ln in enumerate(lines) if set(ln.replace(" ", "")) == {"-"})
    return "\n".join(lines[:rule]), lines[rule + 1 : rule + 1 + n]


def test_table_shows_swept_keys_then_only_differing_metrics_with_units(sweep, drawn, capsys):
    rows, folder = runs.write_report(sweep)
    printed = capsys.readouterr().out
    head, body = _header_and_rows(printed)
    # the line of the names' last parts (without the direction arrows)
    cols = [c for c in head.splitlines()[-2].split() if c not in ("↑", "↓")]
    # swept keys first, then the differing metrics (direction arrows), then the wall time
    assert cols[:2] == ["k", "n"]
    for m in ("fit_error_mm", "spread_deg"):
        assert m in cols
    assert "r" in cols and "↑" in head and "↓" in head
    for const in ("rate_hz", "label", "index", "solve_s", "wall_time_s"):
        assert const not in head
    units = head.splitlines()[-1]
    assert "[mm]" in units and "[°]" in units and "[s]" in units
    assert len(body) == 6 and all(ln.split()[1] in ("2", "3", "5") for ln in body)
    # the constants in one line, with their units; the timings and indices named
    assert "same in all 6 runs: rate_hz = 60 Hz; label = toy" in printed
    assert "choice.index" in printed and "choice.solve_s" in printed
    # best starred in the table only for the directed metrics: fit_error_mm at n = 3
    err_col = cols.index("fit_error_mm")
    starred = [ln.split()[err_col] for ln in body if ln.split()[err_col].endswith("*")]
    assert len(starred) == 2 and all(float(c[:-1]) == 0.5 for c in starred)
    # every column, nothing lost, in runs.csv and runs.md
    with open(folder / "runs.csv") as f:
        table = list(csv.DictReader(f))
    assert len(table) == 6 and {"rate_hz", "label", "choice.index", "choice.solve_s",
                                "compile_s", "status"} <= set(table[0])  # fmt: skip
    assert "rate_hz" in (folder / "runs.md").read_text().splitlines()[0]
    assert len(rows) == 6


def test_one_figure_per_differing_metric_with_words_units_and_integer_ticks(sweep, drawn):
    _, folder = runs.write_report(sweep)
    pngs = sorted(p.name for p in folder.glob("*.png"))
    differing = ["fit_error_mm", "r", "spread_deg"]
    assert len(pngs) == len(differing) == len(drawn)
    assert pngs == [f"{m}_vs_n_by_k.png" for m in differing]
    for kw, fig in drawn:
        ax = fig.axes[0]
        assert ax.get_xlabel() == "n"  # the integer key with the most values on x
        ticks = ax.get_xticks()
        assert list(ticks) == [2, 3, 5] and [t.get_text() for t in ax.get_xticklabels()] == [
            "2", "3", "5"]  # fmt: skip
        assert ax.get_legend().get_title().get_text() == "k"
        stars = [ln for ln in ax.get_lines() if ln.get_marker() == "*"]
        if kw["title"] == "spread_deg":  # no direction: no best marker at all
            assert ax.get_ylabel() == "spread [°]" and not stars
            assert not any("best" in t.get_text() for t in ax.get_legend().get_texts())
        elif kw["title"] == "fit_error_mm":
            assert ax.get_ylabel() == "fit error [mm]" and kw["better"] == "lower"
            (star,) = stars
            assert list(star.get_xdata()) == [3.0, 3.0]  # the tie: both n = 3 runs
        else:
            assert kw["title"] == "r" and kw["better"] == "higher" and len(stars) == 1
            assert ax.get_ylabel() == "Pearson r"


def test_report_all_prints_every_column_and_cli_counts_figures(sweep, capsys):
    assert main(["report", str(sweep), "--all"]) == 0
    out = capsys.readouterr().out
    head, _ = _header_and_rows(out)
    for col in ("rate_hz", "label", "index", "solve_s", "compile_s", "status"):
        assert col in head
    assert "same in all" not in out
    assert "3 figures in" in out and "runs.csv" in out


def test_failed_runs_keep_their_row_and_error(tmp_path, toy, capsys):
    p = tmp_path / "s.toml"
    p.write_text(f'experiment = "{toy}"\n[sweep]\nn = [2, 3]\nk = [1.0, 2.0]\n')
    sweep_config(p, tmp_path / "o", engine="serial")
    bad = next((tmp_path / "o").glob("*n=3*"))
    (bad / "metrics.json").write_text("{torn")
    rows, folder = runs.write_report(tmp_path / "o")
    out = capsys.readouterr()
    assert "status" in out.out and "corrupt: " in out.out and "metrics.json" in out.err
    assert len(list(folder.glob("*.png"))) == 3  # the complete runs still differ


def test_describe_units_words_and_direction():
    assert describe("gap_ms") == ("gap", "ms", None)
    assert describe("rate_hz").unit == "Hz" and describe("angle_deg").unit == "°"
    assert describe("wall_s").unit == "s" and describe("head.rmse_mm").better == "lower"
    assert describe("graph.num_thresholds").words == "number of thresholds (graph)"
    assert describe("mean_degree").unit is None  # unknown: no unit is made up
    ts = describe("choices.elbow.threshold", "threshold_sweep")
    assert ts == ("ε chosen by elbow", "mm", None)
    assert describe("choices.elbow.score", "threshold_sweep").better == "higher"


def test_plot_report_metric_refuses_a_best_without_direction():
    with pytest.raises(ValueError, match="better='higher' or 'lower'"):
        plot_report_metric([1, 2], [0.1, 0.2], x_label="n", y_label="y", best=0)
    fig = plot_report_metric(["a", "b", "c"], [1, 3, 2], x_label="mode", y_label="count")
    ax = fig.axes[0]
    assert [t.get_text() for t in ax.get_xticklabels()] == ["a", "b", "c"]
    assert all(float(t).is_integer() for t in ax.get_yticks())


def test_torn_setup_cache_is_rebuilt_with_a_message(tmp_path, monkeypatch, capsys):
    """A torn ``cache/*_setup.npz`` (BadZipFile) is not raised into the studio: the set-up
    is rebuilt, with a message naming the file."""
    from fxspace.pipelines import parametric_synthesis as ps

    (tmp_path / "cache").mkdir()
    (tmp_path / "config.toml").write_text('experiment = "parametric_synthesis"\n')
    (tmp_path / "cache" / "KEY").write_text("k\n")
    np.savez(tmp_path / "whole.npz", a=np.zeros(1000))
    torn = (tmp_path / "whole.npz").read_bytes()[:-60]  # the zip directory cut off
    (tmp_path / "cache" / "walk_setup.npz").write_bytes(torn)
    with pytest.raises(zipfile.BadZipFile):  # what the studio hit before
        zipfile.ZipFile(io.BytesIO(torn))
    monkeypatch.setattr(ps, "run_key", lambda *a, **k: "k")
    monkeypatch.setattr(ps, "_data_files", lambda *a, **k: [])
    assert ps._stored_setup(tmp_path, "walk", None) is None
    out = capsys.readouterr().out
    assert "walk_setup.npz is damaged (BadZipFile); rebuilding the walk set-up" in out


@pytest.mark.slow
def test_report_of_the_example_sweep(tmp_path, capsys):
    """The shipped example (threshold sweep, 2 swept keys): 9 differing metrics, 9 figures."""
    text = (ROOT / "configs" / "sweep_example.toml").read_text()
    cfg = tmp_path / "s.toml"
    cfg.write_text(text.replace("max_frames = 120", "max_frames = 40"))
    sweep_config(cfg, tmp_path / "o", engine="serial")
    capsys.readouterr()
    rows, folder = runs.write_report(tmp_path / "o")
    printed = capsys.readouterr().out
    head, body = _header_and_rows(printed, 4)
    assert head.splitlines()[-2].split()[:2] == ["dim", "num_thresholds"]
    assert "[mm]" in head and "timings" not in head and "same in all 4 runs" in printed
    assert [ln.split()[:2] for ln in body] == [["2", "3"], ["2", "5"], ["3", "3"], ["3", "5"]]
    assert 1 <= len(list(folder.glob("*.png"))) <= 12


def test_runs_that_vary_every_key_at_once_get_one_panel_per_key(tmp_path, toy, monkeypatch):
    """Search trials (no combination of the other keys repeated): small multiples."""
    from fxspace.pipelines import run_dict

    got = []

    def spy(*a, **kw):
        fig = fxspace.plot.plot_report_grid(*a, **kw)  # the real one (the front's)
        got.append((kw, fig))
        return fig

    monkeypatch.setattr(fxspace.plot._report, "plot_report_grid", spy)
    for i, (n, k) in enumerate([(2, 1.0), (3, 3.5), (5, 2.0), (4, 1.5)]):
        run_dict({"experiment": toy, "n": n, "k": k}, tmp_path / "o" / f"trial_{i}")
    _, folder = runs.write_report(tmp_path / "o")
    pngs = sorted(p.name for p in folder.glob("*.png"))
    assert pngs == [f"{m}_vs_k_n.png" for m in ("fit_error_mm", "r", "spread_deg")]
    assert len(got) == 3
    for kw, fig in got:
        k_ax, n_ax = [ax for ax in fig.axes if ax.get_visible()]
        assert k_ax.get_xlabel() == "k" and n_ax.get_xlabel() == "n"
        assert [t.get_text() for t in n_ax.get_xticklabels()] == ["2", "3", "4", "5"]
        stars = [ln for ln in n_ax.get_lines() if ln.get_marker() == "*"]
        assert bool(stars) == (kw["title"] != "spread_deg")
