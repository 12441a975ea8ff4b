"""``fxspace docs``: the reproduction pages, generated from the shipped configs' runs.

Each paper's page (``docs/reproductions/<paper>.md``) sets the paper's published numbers
beside fxspace's, read from the ``metrics.json`` of the shipped configs' run folders
(``runs/<config stem>``; ``--run`` runs the missing ones first, finished stages reused),
with the figures those runs drew. What each page shows is written down here (`PAPERS`:
rows, figures, what differs in the data), never typed into the page: the page is
`render`\\ ed from a snapshot of the numbers it uses (``docs/reproductions/data/<paper>.json``,
written beside it), and a test renders every page again from its snapshot and compares.

Every file ``fxspace docs`` writes is its own: listed in the output folder's manifest
(`fxspace.runs.record`), or recognisably generated (a page carrying the generated-page
line, a snapshot or benchmark record of fxspace's shape); any other file in the way (a
user's ``kim-jung.md``) is refused before anything is written, unless ``--force``. A
``--runs`` folder that does not exist is refused, and a paper none of whose runs exists
keeps its page (never replaced by a "Not run yet" page without ``--force``). A figure
that is a symbolic link, or not a regular file, is skipped with a message; a copied
figure keeps its file's permissions (a 0600 figure is never made world-readable). A
benchmark record whose ``name`` is not a plain file name is refused.
"""

from __future__ import annotations

import json
import math
import os
import stat
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from fxspace.errors import CorruptFileError, FxspaceError
from fxspace.pipelines._citations import CITATIONS
from fxspace.runs import (
    BENCH_FIELDS,
    active_run,
    bench_name_ok,
    check_writable,
    read_json,
    read_regular,
    write_bytes_atomic,
    write_text_atomic,
)

__all__ = [
    "PAPERS", "Paper", "Row", "snapshot", "render", "write_docs", "fmt",
    "render_bench", "write_bench_page", "read_bench_record", "GENERATED",
]  # fmt: skip


@dataclass(frozen=True)
class Row:
    """One line of a paper's table: ``label``, the paper's number (``None``: the paper
    gives none), where ours is (``config``, a dotted ``path`` into its metrics; ``mean``
    reduces a list) and a ``note`` (what differs)."""

    label: str
    paper: float | str | None
    config: str
    path: str
    note: str = ""
    mean: bool = False


@dataclass(frozen=True)
class Paper:
    title: str
    source: str
    configs: tuple[str, ...]
    rows: tuple[Row, ...]
    figures: tuple[tuple[str, str, str], ...]  # (config, file in its run folder, caption)
    differs: str
    intro: str = ""
    extra: tuple[str, ...] = field(default=())


_FIG3_ROWS = (  # Ha & Han Fig. 3 read off the joints (metric suffix, label, note)
    ("unaligned", "clocks apart (a)", "a 60-s scripted session, each body half on its own "
     "clock; the paper shows it (Fig. 3a) and prints no number"),
    ("aligned_as_printed", "aligned, eqs. 2–3 as printed (b)", "max_clock_rate = inf, α = ½"),
    ("aligned", "aligned, eqs. 2–3 bounded (default)", "each clock at most its set's "
     "fastest example at that phase"),
    ("examples", "the captured takes", "the same measure on every take of the set-up"),
)  # fmt: skip
_FIG5_ROWS = (  # Ha & Han §3.2, Fig. 5: re-placement against stale samples
    ("upper samples' error, stale (not re-placed)", "stale_sample_error_mean_m",
     "mean distance to exactly re-sampled parameters after a lower-body change; the "
     "paper shows Fig. 5 (\"approximated without large error\") and prints no number"),
    ("upper samples' error, re-placed (Horn rotation from k samples)",
     "replacement_error_mean_m", "lower is better: re-placement should cut the stale error"),
    ("hand target error over stale samples", "upper_target_error_stale_mean_m",
     "k-NN blend aimed at a reachable hand target, then measured"),
    ("hand target error over re-placed samples", "upper_target_error_replaced_mean_m", ""),
)  # fmt: skip

PAPERS: dict[str, Paper] = {
    "kim-jung": Paper(
        title="Kim & Jung: the expression space and its navigation",
        source="../shared/papers/000_5ac3516e1e4af788.txt",
        configs=("navigation",),
        intro="AnimFace's 2 400 frames × 41 markers, the state the whole marker-distance "
        "matrix (mm), ε chosen by the paper's rule (the highest Pearson r over a sweep).",
        rows=(
            Row(
                "ε chosen (mm)",
                230.0,
                "navigation",
                "threshold",
                "the paper's capture has 100 markers, ours 41: only the order compares",
            ),
            Row("Pearson r at ε", 0.9647, "navigation", "r"),
            Row(
                "levels of the hierarchy",
                "9 (≈10 · 2⁸ ≥ 2 400)",
                "navigation",
                "num_levels",
                "the paper prints no count: ≈10 centres at the first level, the count "
                "doubled at every level, all ≈2 400 frames at the last (§4.1, §5)",
            ),
            Row(
                "ρ scale chosen by the link-radius experiment (× centre spacing)",
                None,
                "navigation",
                "rho_experiment.chosen_scale",
                "the paper finds ρ by experiment and gives no value; ours: the largest "
                "scale that keeps the levels up to 320 centres connected by the rule alone",
            ),
            Row(
                "links added outside the paper's rule (bridges)",
                0,
                "navigation",
                "links_bridged",
                "the rule alone by default (hierarchy.bridges = false); the paper adds none",
            ),
            Row(
                "pieces the links leave the finest level in",
                None,
                "navigation",
                "link_pieces_finest",
                "centres closer than ρ to another can only link to that one; the paper "
                "shows links only at its ~10-centre level",
            ),
            Row(
                "route: consecutive frames are neighbours in the frame graph",
                None,
                "navigation",
                "path_is_graph_walk",
                "the paper joins the animator's key frames along the links between "
                "neighbouring centres (§4.2) and says nothing of the frames between them",
            ),
        ),
        figures=(
            ("navigation", "r_vs_threshold.png", "Pearson r against ε (the sweep)"),
            ("navigation", "levels_grid.png", "the levels of the hierarchy and the route"),
            (
                "navigation",
                "link_radius.png",
                "links and coverage against ρ: the experiment that chooses ρ",
            ),
        ),
        differs="AnimFace (41 markers, one performer) stands in for the paper's 100-marker "
        "capture; the state distance and the ε rule are the paper's.",
    ),
    "hirose-higuchi": Paper(
        title="Hirose & Higuchi: control points of a dense face",
        source="../shared/papers/004_96e90575cb94c762.txt",
        configs=("reconstruction",),
        intro="AnimFace cheeks, frames 300–599 thinned to 150 as in the paper; the dense "
        "face is the markers' RBF surface (≈ 6 000 vertices, as the paper's 6 331) and, "
        "beside it, the solved ICT head's 9 409 face vertices.",
        rows=(
            Row(
                "frames of the compared segment",
                43,
                "reconstruction",
                "paper_segment.n_frames",
                "ours: the fused-lasso segment closest to 43 frames",
            ),
            Row(
                "linear interpolation, eq. (1)",
                16.44,
                "reconstruction",
                "paper_segment.linear_error",
                "eq. (1) sums squared mm over vertices and "
                "frames: the magnitudes depend on the surface, the ratio compares",
            ),
            Row("control points, eq. (1)", 1.82, "reconstruction", "paper_segment.ours_error"),
            Row(
                "ratio ours / linear (that segment)",
                0.111,
                "reconstruction",
                "error_ratio_paper_segment",
            ),
            Row(
                "ratio, whole scene (RBF surface)", None, "reconstruction", "error_ratio_scene_rbf"
            ),
            Row(
                "ratio, whole scene (ICT head vertices)",
                None,
                "reconstruction",
                "error_ratio_scene_head",
            ),
            Row(
                "segments",
                8,
                "reconstruction",
                "n_segments_chosen",
                "ours chosen from the data (elbow of the fused-lasso path)",
            ),
            Row(
                "whole-scene pipeline time (s)",
                18.0,
                "reconstruction",
                "scene_pipeline_time_s",
                "the paper's machine is not ours",
            ),
            Row("head marker residual, solved (mm)", None, "reconstruction", "head.residual_mean"),
            Row(
                "head marker residual, rigid only (mm)",
                None,
                "reconstruction",
                "head.residual_rigid_only_mean",
            ),
        ),
        figures=(
            ("reconstruction", "reconstruction.png", "original, linear and ours"),
            ("reconstruction", "segmentation.png", "the fused-lasso segmentation"),
            ("reconstruction", "scene_errors.png", "eq. (1) per segment"),
        ),
        differs="The paper's face is 6 331 vertices from a dense capture; ours is driven by "
        "41 markers (RBF) or solved from them (the ICT head), so its motion between the "
        "markers is smoother than a dense capture's.",
    ),
    "ha-han": Paper(
        title="Ha & Han: decoupled parametric motion",
        source="../shared/papers/002_fec3f42589414a0d.txt",
        configs=("parametric_synthesis",),
        intro="The three set-ups of Table 1 on Bandai Namco and CMU clips.",
        rows=tuple(
            r
            for s in ("mood_walk", "block_walk", "block_kick")
            for r in (
                Row(
                    f"{s}: upper / lower examples (Table 1)",
                    {"mood_walk": "2 / 10", "block_walk": "12 / 12", "block_kick": "12 / 11"}[s],
                    "parametric_synthesis",
                    f"{s}.table1.ours_upper_lower",
                    "the CMU takes hold 7 clean right kicks" if s == "block_kick" else "",
                ),
                *(
                    Row(
                        f"{s}: Fig. 3, arm swing / stride cycle length, {lab}",
                        None,
                        "parametric_synthesis",
                        f"{s}.fig3_cycle_ratio_{k}",
                        note,
                    )
                    for k, lab, note in _FIG3_ROWS
                    if s != "block_kick"
                ),
                *(
                    Row(
                        f"{s}: Fig. 3, arm-swing phase drift against the strides "
                        f"(cycles/min), {lab}",
                        None,
                        "parametric_synthesis",
                        f"{s}.fig3_phase_drift_{k}",
                        note,
                    )
                    for k, lab, note in _FIG3_ROWS
                    if s != "block_kick"
                ),
                *(
                    Row(
                        f"{s}: §3.2 (Fig. 5), {lab} (m)",
                        None,
                        "parametric_synthesis",
                        f"{s}.{path}",
                        note,
                    )
                    for lab, path, note in _FIG5_ROWS
                    if s != "mood_walk"
                ),
                Row(f"{s}: synthesis step (ms)", None, "parametric_synthesis", f"{s}.step_ms"),
            )
        ),
        figures=(
            (
                "parametric_synthesis",
                "mood_walk_fig3.png",
                "Fig. 3 read off the joints, mood walk: the arm swing's phase at each stride "
                "over a 60-s session, clocks apart (a) and aligned (b)",
            ),
            (
                "parametric_synthesis",
                "block_walk_fig3.png",
                "Fig. 3 read off the joints, block walk",
            ),
            (
                "parametric_synthesis",
                "block_walk_replacement.png",
                "§3.2 (Fig. 5), block walk: upper samples stale, re-placed and re-sampled",
            ),
        ),
        differs="Bandai Namco's and CMU's clips stand in for the paper's captures; the "
        "paper's Table 1 counts are matched where the clips allow.",
    ),
    "park-kang-kwon": Paper(
        title="Park, Kang & Kwon: mesh IK with the factored gradient",
        source="../shared/papers/003_8b82dd8ad91a5214.txt",
        configs=("mesh_ik",),
        intro="The shipped skinned glTF models, markers on visible triangles.",
        rows=(
            Row(
                "naive / factored, per solved frame (BFGS on eq. 9 vs eq. 13, CesiumMan, cold)",
                3.14,
                "mesh_ik",
                "paper_comparison.ratio_per_solved_frame_cold",
                "as the paper: every frame solved from rest, time per frame; the paper's "
                "human model is not shipped, CesiumMan stands in",
            ),
            Row(
                "naive / factored, per gradient evaluation (mean over the five models)",
                None,
                "mesh_ik",
                "models.per evaluation",
                "not the paper's measure: one gradient call in a jitted loop, models "
                "including a synthetic 48-joint chain (see the benchmark page)",
                mean=True,
            ),
        ),
        figures=(
            ("mesh_ik", "models_speedup.png", "Fig. 9: speed-up per model"),
            ("mesh_ik", "models_time_vs_markers.png", "Fig. 10: time per frame vs markers"),
        ),
        differs="The paper's human models are not shipped; the glTF samples (CesiumMan, Fox, "
        "RiggedSimple…) stand in, with fewer joints.",
    ),
}


def fmt(v: Any) -> str:
    """A number as the pages print it (4 significant digits; booleans as yes/no)."""
    if v is None:
        return "—"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if not math.isfinite(v):
            return str(v)
        return f"{v:.4g}"
    if isinstance(v, list | tuple):
        return " / ".join(fmt(x) for x in v)
    return str(v)


def _get(metrics: dict, path: str) -> Any:
    node: Any = metrics
    for p in path.split("."):
        if not isinstance(node, dict) or p not in node:
            return None
        node = node[p]
    return node


GENERATED = "<!-- generated by `fxspace docs`: do not edit -->"


def _metrics(runs: Path, config: str) -> dict | None:
    """``runs/CONFIG/metrics.json`` (None when absent); a damaged one is a
    `CorruptFileError` naming it and the fix."""
    p = runs / config / "metrics.json"
    try:
        return read_json(p)
    except CorruptFileError as e:
        raise CorruptFileError(
            f"{e}; rerun it: fxspace run configs/{config}.toml --out {runs / config} --force"
        ) from None


def _figure_ok(p: Path) -> bool:
    """A run's figure may be copied into the docs: a regular file, not a link."""
    try:
        return stat.S_ISREG(os.lstat(p).st_mode)
    except OSError:
        return False


def snapshot(paper: Paper, runs: Path) -> dict:
    """The numbers ``paper``'s page uses, read from the run folders under ``runs``
    (its figures: the regular files among them; a symbolic link is never shown)."""
    runs = Path(runs)
    out: dict = {"values": {}, "runs": {}}
    metrics = {c: _metrics(runs, c) for c in {*paper.configs, *(r.config for r in paper.rows)}}
    for c in paper.configs:
        out["runs"][c] = metrics[c] is not None
    for r in paper.rows:
        m = metrics[r.config]
        v = _get(m, r.path) if m is not None else None
        if r.mean and isinstance(v, list) and v:
            v = float(sum(v) / len(v))
        out["values"][f"{r.config}:{r.path}"] = v
    out["figures"] = [f for c, f, _ in paper.figures if _figure_ok(runs / c / f)]
    return out


def render(key: str, snap: dict) -> str:
    """The page of paper ``key`` from its snapshot (pure: same snapshot, same text)."""
    paper = PAPERS[key]
    lines = [f"# {paper.title}", "", GENERATED, ""]
    if paper.intro:
        lines += [paper.intro, ""]
    if key in CITATIONS:  # authors, title, venue and year as the paper's header prints them
        lines += [f"**Citation:** {CITATIONS[key]}", ""]
    lines += [
        f"Paper: `{paper.source}`. Configs: "
        + ", ".join(f"`configs/{c}.toml`" for c in paper.configs) + ". Regenerate: "
        "`fxspace docs --run` (runs what is missing, then writes this page).", "",
        "| | paper | fxspace | note |", "| --- | --- | --- | --- |",
    ]  # fmt: skip
    for r in paper.rows:
        v = snap["values"].get(f"{r.config}:{r.path}")
        lines.append(f"| {r.label} | {fmt(r.paper)} | {fmt(v)} | {r.note} |")
    missing = [c for c, ok in snap["runs"].items() if not ok]
    if missing:
        todo = ", ".join(f"`fxspace run configs/{c}.toml`" for c in missing)
        lines += ["", f"Not run yet: {todo} (then `fxspace docs`)."]
    lines += ["", "## What differs", "", paper.differs, ""]
    shown = [(c, f, cap) for c, f, cap in paper.figures if f in snap["figures"]]
    if shown:
        lines += ["## Figures", ""]
        for c, f, cap in shown:
            lines += [f"![{cap}](figures/{key}/{f})", "", f"*{cap}* (`runs/{c}/{f}`)", ""]
    return "\n".join(lines).rstrip() + "\n"


def _generated_page(p: Path) -> bool:
    try:
        return GENERATED in (read_regular(p) or b"").decode("utf-8", "replace")
    except (OSError, FxspaceError):
        return False


def _recognise_docs(out: Path):
    """fxspace's own reproduction files from before the folder had a manifest: pages
    carrying the generated-page line, snapshots of the snapshot's shape, and the figures
    of a generated page."""

    def recognise(p: Path) -> bool:
        try:
            parts = Path(os.path.abspath(p)).relative_to(Path(os.path.abspath(out))).parts
        except ValueError:
            return False
        if len(parts) == 1 and p.suffix == ".md":
            return _generated_page(p)
        if len(parts) == 2 and parts[0] == "data" and p.suffix == ".json":
            try:
                snap = read_json(p)
            except (OSError, FxspaceError):
                return False
            return isinstance(snap, dict) and set(snap) == {"values", "runs", "figures"}
        if len(parts) == 3 and parts[0] == "figures":
            return _generated_page(out / f"{parts[1]}.md")
        return False

    return recognise


def _copy_figure(src: Path, dst: Path) -> None:
    """Copy a run's figure (a regular file) keeping its permissions: a figure readable
    only by its owner stays so in the docs."""
    data = read_regular(src)
    mask = os.umask(0o022)
    os.umask(mask)
    mode = stat.S_IMODE(os.stat(src).st_mode) & 0o666 & ~mask
    write_bytes_atomic(dst, data or b"", mode=mode)  # the mode set before it appears


def write_docs(runs: str | Path = "runs", out: str | Path = "docs/reproductions",
               run: bool = False, configs_dir: str | Path = "configs",
               force: bool = False) -> list[Path]:  # fmt: skip
    """Write every paper's page, its snapshot and its figures under ``out`` from the run
    folders under ``runs`` (``run``: run the shipped configs that are missing first).

    A ``runs`` folder that does not exist is refused (nothing is written); a paper none of
    whose configs has run keeps the page it has (said, not replaced by "Not run yet")
    unless ``force``. A file in ``out`` that ``fxspace docs`` did not write is refused
    before anything is written (`fxspace.runs.OverwriteRefusedError`) unless ``force``.
    Returns the pages written."""
    runs, out = Path(runs), Path(out)
    if run:
        from fxspace.pipelines import run_config

        for c in sorted({c for p in PAPERS.values() for c in p.configs}):
            if not (runs / c / "metrics.json").is_file():
                run_config(Path(configs_dir) / f"{c}.toml", runs / c)
    if not runs.is_dir():
        raise FxspaceError(
            f"--runs {runs} is not a folder, so no run could be read; nothing was written "
            "(the pages are kept): pass --runs the folder holding the configs' run folders, "
            "or fxspace docs --run to run them first"
        )
    plan = []
    for key, paper in PAPERS.items():
        snap = snapshot(paper, runs)
        page = out / f"{key}.md"
        if not any(snap["runs"].values()) and os.path.lexists(page) and not force:
            print(f"fxspace docs: kept {page}: no finished run of "
                  f"{', '.join(paper.configs)} under {runs} (run it, or pass --force to "
                  "write a 'Not run yet' page)")  # fmt: skip
            continue
        for c, f, _ in paper.figures:
            src = runs / c / f
            if f not in snap["figures"] and os.path.lexists(src):
                print(f"fxspace docs: skipped {src}: not a regular file (a symbolic link?); "
                      "only a figure the run wrote itself is copied")  # fmt: skip
        plan.append((key, snap, page))
    recognise = _recognise_docs(out)
    targets = [t for key, snap, page in plan
               for t in (page, out / "data" / f"{key}.json",
                         *(out / "figures" / key / f for f in snap["figures"]))]  # fmt: skip
    check_writable(out, targets, force=force, recognise=recognise)
    written = []
    with active_run(out, force=force, recognise=recognise):
        for key, snap, page in plan:
            paper = PAPERS[key]
            write_text_atomic(out / "data" / f"{key}.json",
                              json.dumps(snap, indent=1, sort_keys=True))  # fmt: skip
            for c, f, _ in paper.figures:
                if f in snap["figures"]:
                    _copy_figure(runs / c / f, out / "figures" / key / f)
            write_text_atomic(page, render(key, snap))
            written.append(page)
    return written


def _bench_figure(rec: dict[str, Any], path: Path) -> None:
    """Time of ours and of each peer (log scale) against size — or per case when the rows
    have no sizes — and the ratio peer / ours per case, labelled."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from fxspace.runs import save_figure_atomic

    rows = rec["rows"]
    sized = len({r["size"] for r in rows if r["size"] is not None}) >= 2
    fig, (ax, bx) = plt.subplots(1, 2, figsize=(11, 3.8))
    pairs = list(dict.fromkeys((r["ours"], r["peer"]) for r in rows))
    if sized:
        for ours, peer in pairs:
            rr = sorted((r for r in rows if (r["ours"], r["peer"]) == (ours, peer)
                         and r["size"] is not None), key=lambda r: r["size"])  # fmt: skip
            x = [r["size"] for r in rr]
            ax.plot(x, [r["ours_s"] for r in rr], "o-", label=f"ours: {ours}")
            ax.plot(x, [r["peer_s"] for r in rr], "s--", label=f"{peer}")
        ax.set_xlabel("size")
    else:
        x = range(len(rows))
        ax.bar([i - 0.2 for i in x], [r["ours_s"] for r in rows], 0.4, label="ours")
        ax.bar([i + 0.2 for i in x], [r["peer_s"] for r in rows], 0.4, label="peer")
        ax.set_xticks(list(x), [r["case"] for r in rows], rotation=20, ha="right", fontsize=7)
    ax.set_yscale("log")
    ax.set_ylabel("median time (s)")
    ax.set_title("time: ours and the peers")
    ax.legend(fontsize=7)
    labels = [r["case"] for r in rows]
    ratios = [r["ratio"] or 0.0 for r in rows]
    bx.barh(range(len(rows)), ratios, color=["tab:green" if v >= 1 else "tab:red" for v in ratios])
    bx.axvline(1.0, color="k", lw=0.8)
    bx.set_yticks(range(len(rows)), labels, fontsize=7)
    bx.set_xlabel("peer time / our time (> 1: ours faster)")
    bx.set_title("speed-up")
    fig.suptitle(rec["title"], fontsize=10)
    fig.tight_layout()
    save_figure_atomic(fig, path)
    plt.close(fig)


def render_bench(records: list[dict[str, Any]]) -> str:
    """The benchmark page (Markdown) from the benchmarks' records (`fxspace.runs.write_bench`):
    per benchmark its command, machine and date, its figure and its table."""
    lines = [
        "# Measured benchmarks",
        "",
        "Generated by `fxspace docs` from the records the benchmarks write "
        "(`runs/bench/NAME.json`); rerun the command beside a benchmark, then `fxspace docs`, "
        "to redraw it on your machine. Times are medians of several runs measured in the "
        "same process as the peer's.",
        "",
    ]
    for rec in records:
        m = rec["machine"]
        lines += [
            f"## {rec['title']}",
            "",
            f"`{rec['command']}` — {m['date']}, {m['processor']}, {m['cpu_count']} cores, "
            f"{m['devices']}, jax {m['versions'].get('jax', '?')}.",
            "",
            f"![{rec['title']}](figures/{rec['name']}.png)",
            "",
            "| case | ours | time | peer | time | peer / ours |",
            "| --- | --- | --- | --- | --- | --- |",
        ]
        for r in rec["rows"]:
            ratio = "—" if r["ratio"] is None else f"**{r['ratio']:.2f}×**"
            lines.append(
                f"| {r['case']} | {r['ours']} | {fmt(r['ours_s'])} s | {r['peer']} | "
                f"{fmt(r['peer_s'])} s | {ratio} |"
            )
        lines.append("")
    if not records:
        lines += ["No benchmark records yet: run `fxspace bench NAME`, then `fxspace docs`.", ""]
    return "\n".join(lines).rstrip() + "\n"


def read_bench_record(p: Path) -> dict[str, Any]:
    """A benchmark record (`fxspace.runs.write_bench`) read and checked: a
    `CorruptFileError` naming the file, what is wrong and the fix for anything else (a
    ``name`` that is not the file's own plain name, a missing field, a row without its
    times)."""
    rec = read_json(p)

    def bad(what: str) -> CorruptFileError:
        return CorruptFileError(
            f"{p} is not a benchmark record ({what}); rerun fxspace bench {p.stem}, or move "
            "the file out of the bench folder"
        )

    if rec is None:
        raise bad("it vanished")
    name = rec.get("name")
    if not bench_name_ok(name) or name != p.stem:
        raise bad(f"its name {name!r} is not its file's plain name {p.stem!r}")
    for k, kind in (("title", str), ("command", str), ("machine", dict), ("rows", list)):
        if not isinstance(rec.get(k), kind):
            raise bad(f"{k!r} is missing or not a {kind.__name__}")
    m = rec["machine"]
    for k in ("date", "processor", "cpu_count", "devices"):
        if k not in m:
            raise bad(f"machine lacks {k!r}")
    if not isinstance(m.get("versions", {}), dict):
        raise bad("machine.versions is not an object")
    for i, r in enumerate(rec["rows"]):
        if not isinstance(r, dict) or any(k not in r for k in BENCH_FIELDS):
            raise bad(f"rows[{i}] lacks one of {', '.join(BENCH_FIELDS)}")
        for k in ("ours_s", "peer_s"):
            if isinstance(r[k], bool) or not isinstance(r[k], int | float):
                raise bad(f"rows[{i}].{k} is not a number")
        if r["ratio"] is not None and (
            isinstance(r["ratio"], bool) or not isinstance(r["ratio"], int | float)
        ):
            raise bad(f"rows[{i}].ratio is not a number")
    return rec


def _recognise_bench(out: Path):
    def recognise(p: Path) -> bool:
        try:
            parts = Path(os.path.abspath(p)).relative_to(Path(os.path.abspath(out))).parts
        except ValueError:
            return False
        if parts == ("measured.md",):
            try:
                text = (read_regular(p) or b"").decode("utf-8", "replace")
            except (OSError, FxspaceError):
                return False
            return text.startswith("# Measured benchmarks\n") and "`fxspace docs`" in text
        if len(parts) == 2 and parts[0] in ("data", "figures"):
            try:
                read_bench_record(out / "data" / f"{p.stem}.json")
            except (OSError, FxspaceError):
                return False
            return True
        return False

    return recognise


def write_bench_page(
    runs: str | Path = "runs", out: str | Path = "docs/benchmarks", force: bool = False
) -> Path:
    """Write ``out/measured.md``, its figures and a copy of every record it shows
    (``out/data/NAME.json``, so a test renders the page again) from ``runs/bench/*.json``.

    Every record is checked first (`read_bench_record`: a record whose ``name`` is a path,
    absolute or holds ``..`` is refused, never used to name a file); a file in ``out``
    that fxspace did not write is refused unless ``force``."""
    runs, out = Path(runs), Path(out)
    records = [read_bench_record(p) for p in sorted((runs / "bench").glob("*.json"))]
    recognise = _recognise_bench(out)
    page = out / "measured.md"
    targets = [page, *(out / d / f"{r['name']}.{x}" for r in records
                       for d, x in (("figures", "png"), ("data", "json")))]  # fmt: skip
    check_writable(out, targets, force=force, recognise=recognise)
    with active_run(out, force=force, recognise=recognise):
        for rec in records:
            _bench_figure(rec, out / "figures" / f"{rec['name']}.png")
            data = out / "data" / f"{rec['name']}.json"
            write_text_atomic(data, json.dumps(rec, indent=2) + "\n")
        write_text_atomic(page, render_bench(records))
    return page
