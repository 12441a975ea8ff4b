"""``fxspace report DIR``: compare the runs under a folder.

`collect` reads one row per run (swept keys, scalar metrics, timing, status); `write_report`
writes every column to ``runs.csv`` / ``runs.md``, prints a short table (the swept keys,
then only the metrics that differ between the runs, each headed with its unit; the
constant ones in one line) and draws one figure per differing metric against the swept
key(s) (`fxspace.plot.plot_report_metric`).

What the report knows of a metric — its words, its unit and which way is better — is in
one place, `KNOWN` (an experiment's own entries first, then everyone's); a unit is else
read from the name's suffix (`SUFFIX_UNITS`: ``_mm``, ``_s``, ``_hz``, ...). A metric
with no known direction gets no "best" mark.

This module is the report's one home (it draws with ``fxspace.plot``, a layer above
``fxspace.runs``, so it sits beside the command line, not in ``fxspace.runs``).
"""

from __future__ import annotations

import json
import os
import shutil
import sys
import textwrap
from fnmatch import fnmatchcase
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from fxspace.errors import CorruptFileError
from fxspace.runs import (
    UnsafePathError,
    active_run,
    check_writable,
    clean_run,
    read_json,
    read_regular,
    save_figure_atomic,
    write_text_atomic,
)

__all__ = ["collect", "write_report", "KNOWN", "SUFFIX_UNITS", "Known", "describe"]


class Known(NamedTuple):
    """What the report says of a key or metric: its words (``{1}`` is the name's second
    dotted part, ...), its unit ("" for a pure number, None when unknown) and which way
    is better (``"higher"``, ``"lower"``, or None: no direction, no "best" mark)."""

    words: str | None = None
    unit: str | None = None
    better: str | None = None


#: Known keys and metrics: ``{experiment or "*": {name pattern: Known}}``. A pattern
#: (`fnmatch`) is tried against the full dotted name, then its last part; an
#: experiment's own entries before everyone's (``"*"``). Add a metric's unit and
#: direction here.
KNOWN: dict[str, dict[str, Known]] = {
    "threshold_sweep": {
        "dim": Known("embedding dimension", ""),
        "graph.num_thresholds": Known("number of thresholds swept", ""),
        "best_threshold": Known("chosen threshold ε", "mm"),
        "r_at_best": Known("r at the chosen ε", "", "higher"),
        "choices.*.threshold": Known("ε chosen by {1}", "mm"),
        "choices.*.score": Known("r at the {1} choice", "", "higher"),
        "choices.*.mean_degree": Known("mean degree at the {1} choice", "neighbours"),
        "connecting_threshold": Known("smallest connecting ε", "mm"),
        "largest_distance": Known("largest pairwise distance", "mm"),
        "paper.threshold_mm": Known("paper's ε", "mm"),
        "paper.r": Known("paper's r", ""),
        "seed_paper_r": Known("paper's r", ""),
    },
    "*": {
        "seed": Known("random seed", ""),
        "wall_s": Known("wall time", "s"),
        "compile_s": Known("compile time", "s"),
        "frames": Known("frames", "frames"),
        "n_frames": Known("frames", "frames"),
        "markers": Known("markers", "markers"),
        "missing.max_gap": Known("longest gap filled", "frames"),
        "missing.filled_frames": Known("frames with a filled gap", "frames"),
        "missing.dropped_frames": Known("frames dropped", "frames"),
        "missing.filled_samples": Known("samples filled", "samples"),
        "r": Known("Pearson r", "", "higher"),
        "*rmse*": Known(None, None, "lower"),
        "*error*": Known(None, None, "lower"),
        "*accuracy*": Known(None, None, "higher"),
    },
}

#: Units read from a name's last suffix when `KNOWN` gives none (longest first).
SUFFIX_UNITS: tuple[tuple[str, str], ...] = (
    ("_percent", "%"), ("_frames", "frames"), ("_deg", "°"), ("_rad", "rad"),
    ("_pct", "%"), ("_mm", "mm"), ("_cm", "cm"), ("_ms", "ms"), ("_us", "µs"),
    ("_hz", "Hz"), ("_px", "px"), ("_mb", "MB"), ("_gb", "GB"), ("_s", "s"), ("_m", "m"),
)  # fmt: skip


def _lookup(name: str, experiment: str | None) -> Known:
    """The first entry of `KNOWN` whose pattern matches (the experiment's, then "*")."""
    last = name.rsplit(".", 1)[-1]
    for table in (KNOWN.get(experiment or "", {}), KNOWN["*"]):
        for pat, k in table.items():
            if fnmatchcase(name, pat) or ("." not in pat and fnmatchcase(last, pat)):
                words = k.words.format(*name.split("."), *[""] * 4) if k.words else None
                return Known(words, k.unit, k.better)
    return Known()


def describe(name: str, experiment: str | None = None) -> Known:
    """The words, unit and direction of a config key or metric (`KNOWN`, else the name:
    ``missing.max_gap_mm`` → "max gap (missing)", ``mm``, no direction)."""
    k = _lookup(name, experiment)
    last = name.rsplit(".", 1)[-1]
    unit, stem = k.unit, last
    for part in reversed(name.split(".")):  # ``rates_hz.synthetic``: the parent's unit
        suf, u = next(((s, u) for s, u in SUFFIX_UNITS
                       if part.lower().endswith(s) and len(part) > len(s)), ("", None))  # fmt: skip
        if u is not None:
            unit = u if unit is None else unit
            stem = last[: -len(suf)] if part == last else stem
            break
    words = k.words
    if words is None:
        w = stem.replace("_", " ")
        w = "number of " + w[4:] if w.startswith("num ") else w
        parents = name.split(".")[:-1]
        words = w + (f" ({' '.join(parents)})" if parents else "")
    return Known(words, unit, k.better)


def _axis_label(name: str, experiment: str | None) -> str:
    k = describe(name, experiment)
    return f"{k.words} [{k.unit}]" if k.unit else k.words


# ------------------------------------------------------------------ reading the runs


def _flatten(d: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k, v in d.items():
        if isinstance(v, dict):
            out.update(_flatten(v, f"{prefix}{k}."))
        else:
            out[f"{prefix}{k}"] = v
    return out


def _scalar(v: Any) -> bool:
    return isinstance(v, int | float | str) and not isinstance(v, bool) or isinstance(v, bool)


def _run_folders(root: Path) -> list[Path]:
    found = []
    for dirpath, dirnames, filenames in os.walk(root):
        d = Path(dirpath)
        dirnames[:] = sorted(n for n in dirnames if n != "report" and not n.startswith("."))
        if "status.json" in filenames or "metrics.json" in filenames:
            found.append(d)
    return sorted(found)


def collect(run_dir: str | Path, as_frame: bool = False) -> Any:
    """One row per run under ``run_dir`` (every folder holding ``status.json`` or
    ``metrics.json``): ``run`` (its path relative to ``run_dir``), the swept keys (the
    config keys whose values differ between the runs, dotted), the scalar metrics,
    ``wall_s`` / ``compile_s`` (``meta.json`` timing), ``status`` and ``error``.

    Returns a list of dicts, or a pandas DataFrame with ``as_frame=True`` (needs pandas).
    A missing value is ``None`` (NaN in the frame), never 0.
    """
    rows = _collect(run_dir)[0]
    if as_frame:
        try:
            import pandas as pd
        except ImportError:
            raise ImportError("collect(as_frame=True) needs pandas: pip install pandas") from None
        return pd.DataFrame(rows, columns=list(rows[0]) if rows else None)
    return rows


def _collect(
    run_dir: str | Path,
) -> tuple[list[dict[str, Any]], list[str], list[str], str | None]:
    """The rows of `collect`, the swept keys, the numeric metric columns and the
    experiment (None when the runs name none or several)."""
    import tomllib

    root = Path(run_dir)
    if not root.is_dir():
        raise FileNotFoundError(f"run_dir {root} is not a folder; pass a sweep's --out folder")
    runs = []
    for d in _run_folders(root):
        problems: list[str] = []

        def load(name: str, d: Path = d, problems: list[str] = problems) -> dict[str, Any]:
            try:
                v = read_json(d / name)
            except (CorruptFileError, UnsafePathError) as e:
                problems.append(str(e))
                return {}
            except OSError as e:
                problems.append(f"{d / name}: {e.strerror or e}")
                return {}
            return v or {}

        try:
            cfg_text = (read_regular(d / "config.toml") or b"").decode("utf-8")
            cfg = _flatten(tomllib.loads(cfg_text))
        except (OSError, UnsafePathError, UnicodeDecodeError, tomllib.TOMLDecodeError) as e:
            problems.append(f"{d / 'config.toml'} is unreadable ({e})")
            cfg = {}
        metrics = load("metrics.json")
        timing = load("meta.json").get("timing")
        if not isinstance(timing, dict):
            timing = {}
        st = load("status.json")
        if problems:
            st = {"status": "corrupt", "error": "; ".join(problems)
                  + " (rerun that run with --force, or move the file away)"}  # fmt: skip
        runs.append((d, cfg, metrics, timing, st))
    keys = sorted({k for _, c, *_ in runs for k in c})
    swept = [
        k for k in keys
        if len({json.dumps(c.get(k), sort_keys=True) for _, c, *_ in runs}) > 1
    ]  # fmt: skip
    exps = {c.get("experiment") for _, c, *_ in runs if c}
    experiment = next(iter(exps)) if len(exps) == 1 and isinstance(next(iter(exps)), str) else None
    rows = []
    for d, cfg, metrics, timing, st in runs:
        row: dict[str, Any] = {"run": d.relative_to(root).as_posix() or "."}
        for k in swept:
            v = cfg.get(k)
            row[k] = v if _scalar(v) or v is None else json.dumps(v)
        for k, v in _flatten(metrics).items():
            if _scalar(v) and k not in row:
                row[k] = v
        row["wall_s"] = _num(timing.get("wall_s", metrics.get("wall_time_s")))
        row["compile_s"] = _num(timing.get("compile_s"))
        status = st.get("status") or ("complete" if metrics else "unknown")
        row["status"] = status if isinstance(status, str) else json.dumps(status)
        err = st.get("error")
        row["error"] = err if err is None or isinstance(err, str) else json.dumps(err)
        rows.append(row)
    cols: list[str] = []
    for r in rows:
        cols += [k for k in r if k not in cols]
    rows = [{k: r.get(k) for k in cols} for r in rows]
    fixed = {"run", "wall_s", "compile_s", "status", "error", *swept}
    metric_cols = [
        k for k in cols if k not in fixed and any(r[k] is not None for r in rows) and all(
            r[k] is None or (isinstance(r[k], int | float) and not isinstance(r[k], bool))
            for r in rows
        )
    ]  # fmt: skip
    return rows, swept, metric_cols, experiment


def _num(v: Any) -> float | int | None:
    return v if isinstance(v, int | float) and not isinstance(v, bool) else None


def _is_bookkeeping(metric: str) -> bool:
    """Timings, indices and seeds: they differ between runs but compare nothing."""
    last = metric.rsplit(".", 1)[-1]
    return metric.startswith("timings.") or last.endswith("_s") or last in ("index", "seed")


def _better(metric: str, experiment: str | None) -> str | None:
    """``"higher"`` / ``"lower"`` where `KNOWN` gives the metric a direction, else None."""
    return describe(metric, experiment).better


# ------------------------------------------------------------------ the report


class _Plan(NamedTuple):
    """Which columns the report shows, and how."""

    swept: list[str]
    differ: list[str]  # metrics that differ between runs (table + a figure each)
    constant: list[str]  # one value in every run that has one (one summary line)
    hidden: list[str]  # timings / indices that differ (in runs.csv; --all shows them)
    experiment: str | None


def _plan(rows: list[dict[str, Any]], swept: list[str], experiment: str | None) -> _Plan:
    fixed = {"run", "status", "error", "wall_s", *swept}
    differ, constant, hidden = [], [], []
    for k in rows[0]:
        if k in fixed:
            continue
        vals = {json.dumps(r[k], sort_keys=True) for r in rows if r[k] is not None}
        if not vals:
            continue
        if len(vals) == 1:
            constant.append(k)
        elif _is_bookkeeping(k) or k == "wall_time_s":
            hidden.append(k)
        else:
            differ.append(k)
    return _Plan(swept, differ, constant, hidden, experiment)


def _short(v: Any, n: int = 40) -> str:
    s = str(v).replace("\n", " ")
    return s if len(s) <= n else s[: n - 1] + "…"


def _col_format(vals: list[Any]) -> dict[Any, str]:
    """Cell text for each value of one column: floats with one number of decimals, the
    fewest (4 to 8 significant digits of the largest) that keep distinct values distinct."""
    floats = sorted({v for v in vals if isinstance(v, float) and np.isfinite(v)})
    top = max((abs(v) for v in floats), default=0.0)
    mag = int(np.floor(np.log10(top))) if top > 0 else 0

    def text(v: float, digits: int) -> str:
        if not np.isfinite(v) or not -4 <= mag <= 6:
            return f"{v:.{digits}g}"
        return f"{v:.{max(0, digits - 1 - mag)}f}"

    digits = 4
    while digits < 8 and len({text(v, digits) for v in floats}) < len(floats):
        digits += 1
    out: dict[Any, str] = {}
    for v in vals:
        if v is None:
            out[v] = "-"
        elif isinstance(v, float):
            out[v] = text(v, digits)
        else:
            out[json.dumps(v)] = _short(v, 24)
    return out


def _cell(fmt: dict[Any, str], v: Any) -> str:
    return fmt[v] if v is None or isinstance(v, float) else fmt[json.dumps(v)]


def _best_index(rows: list[dict[str, Any]], k: str, better: str | None) -> list[int]:
    """The best complete runs of a directed metric (ties: all of them); none without a
    direction or when every complete run has the same value."""
    if better is None:
        return []
    cand = [(r[k], i) for i, r in enumerate(rows) if r["status"] == "complete"
            and _num(r[k]) is not None and np.isfinite(r[k])]  # fmt: skip
    if len({v for v, _ in cand}) < 2:
        return []
    top = (max if better == "higher" else min)(v for v, _ in cand)
    return [i for v, i in cand if v == top]


def _table(rows: list[dict[str, Any]], plan: _Plan, show_all: bool) -> str:
    """The terminal table: the swept keys first, then the differing metrics (all columns
    with ``show_all``), each headed by its name split at the dots and its unit."""
    exp = plan.experiment
    if show_all:
        cols = plan.swept + [k for k in rows[0] if k not in plan.swept and k != "error"]
    else:
        ids = [tuple(json.dumps(r[k]) for k in plan.swept) for r in rows]
        need_run = not plan.swept or len(set(ids)) < len(ids)
        cols = (["run"] if need_run else []) + plan.swept + plan.differ
        if any(r["wall_s"] is not None for r in rows):
            cols.append("wall_s")
        if any(r["status"] != "complete" for r in rows):
            cols.append("status")
    heads, cells, right = [], [], []
    for k in cols:
        d = describe(k, exp) if k not in ("run", "status") else Known(None, "")
        parts = [p + "." for p in k.split(".")[:-1]] + [k.split(".")[-1]]
        if d.better:
            parts[-1] += " ↑" if d.better == "higher" else " ↓"
        parts.append(f"[{d.unit}]" if d.unit else "")
        vals = [r[k] for r in rows]
        fmt = _col_format(vals)
        best = _best_index(rows, k, d.better) if k in plan.differ else []
        col = [_cell(fmt, v) + ("*" if i in best else " " if best else "")
               for i, v in enumerate(vals)]  # fmt: skip
        heads.append(parts)
        cells.append(col)
        right.append(all(v is None or _num(v) is not None for v in vals))
    depth = max(len(h) for h in heads)
    heads = [[""] * (depth - len(h)) + h[:-1] + [h[-1]] for h in heads]
    widths = [max(len(s) for s in h + c) for h, c in zip(heads, cells, strict=True)]

    def line(items: list[str]) -> str:
        return "  ".join(
            s.rjust(w) if r else s.ljust(w)
            for s, w, r in zip(items, widths, right, strict=True)
        ).rstrip()  # fmt: skip

    out = [line([h[i] for h in heads]) for i in range(depth)]
    out.append("  ".join("-" * w for w in widths))
    out += [line([c[i] for c in cells]) for i in range(len(rows))]
    return "\n".join(out) + "\n"


def _notes(rows: list[dict[str, Any]], plan: _Plan, show_all: bool, width: int) -> str:
    exp, lines = plan.experiment, []
    if any(describe(k, exp).better for k in plan.differ):
        lines.append("↑ higher is better, ↓ lower is better; * the best complete run")
    for r in rows:
        if r["error"]:
            who = ", ".join(f"{k}={r[k]}" for k in plan.swept) or r["run"]
            lines.append(f"{r['status']}: {who} ({r['run']}): {r['error']}")
    wrap = textwrap.TextWrapper(width=max(width, 60), subsequent_indent="    ")
    if plan.constant and not show_all:
        vals = []
        for k in plan.constant:
            v = next(r[k] for r in rows if r[k] is not None)
            unit = describe(k, exp).unit
            text = f"{v:.6g}" if isinstance(v, float) else _short(v, 24)
            vals.append(f"{k} = {text}" + (f" {unit}" if unit else ""))
        text, budget = f"same in all {len(rows)} runs: ", 2 * max(width, 60) - 40
        for i, v in enumerate(vals):
            if len(text) + len(v) > budget:
                text += f"; and {len(vals) - i} more (runs.csv, or --all)"
                break
            text += ("; " if i else "") + v
        lines += wrap.wrap(text)
    if plan.hidden and not show_all:
        lines += wrap.wrap("timings and indices not shown (see runs.csv, or --all): "
                           + ", ".join(plan.hidden))  # fmt: skip
    return "".join(s + "\n" for s in lines)


def _fmt_cell(v: Any) -> str:
    if v is None:
        return ""
    if isinstance(v, float):
        return f"{v:.6g}"
    return str(v).replace("|", "\\|").replace("\n", " ")


def write_report(
    run_dir: str | Path,
    out: str | Path | None = None,
    force: bool = False,
    *,
    show_all: bool = False,
) -> tuple[list[dict[str, Any]], Path]:
    """``fxspace report DIR``: `collect` the runs under ``run_dir``, write every column
    to ``DIR/report/runs.csv`` and ``runs.md``, and print a short table: the swept keys,
    then only the metrics that differ between the runs, each headed with its unit (and
    ↑ / ↓ where a higher / lower value is better, the best run starred), the metrics
    that are the same in every run in one line, the timings and indices named in
    another (``show_all`` prints every column). One figure per differing metric against
    the swept key(s) — one line per combination of the other swept keys, axes in words
    with units, the best run starred only where the metric has a direction (`KNOWN`).
    Returns (rows, report folder).

    ``out``: the report folder (default ``DIR/report``). The report folder is the
    report's own: its files are listed in its manifest and replaced (an older report's
    figures removed) on the next report; a file there that fxspace did not write (the
    user's own ``runs.md``) is refused (`OverwriteRefusedError`) unless ``force``. A run
    whose ``metrics.json`` / ``status.json`` / ``meta.json`` is damaged is a row with
    status ``corrupt`` and the reason, said on stderr too."""
    rows, swept, _, experiment = _collect(run_dir)
    out = Path(run_dir) / "report" if out is None else Path(out)
    if not rows:
        raise FileNotFoundError(
            f"no runs under {run_dir} (no folder holds status.json or metrics.json); "
            "pass the --out folder of a run or sweep"
        )
    for r in rows:
        if r["status"] == "corrupt":
            print(f"fxspace report: {r['run']}: {r['error']}", file=sys.stderr)
    check_writable(out, [out / "runs.csv", out / "runs.md"], force=force)
    if not any(os.path.lexists(out / n) for n in ("status.json", "metrics.json", "config.toml")):
        # the previous report's files (only those fxspace wrote, only a report's names),
        # never in a folder that holds a run (``--out`` pointed at one)
        clean_run(out, keep=lambda rel: not _report_file(rel))
    plan = _plan(rows, swept, experiment)
    with active_run(out, force=force):
        _write_tables(rows, out)
        width = shutil.get_terminal_size((100, 24)).columns
        print(_table(rows, plan, show_all) + _notes(rows, plan, show_all, width), end="")
        _report_figures(rows, plan, out)
    return rows, out


def _report_file(rel: str) -> bool:
    return rel in ("runs.csv", "runs.md") or ("/" not in rel and "_vs_" in rel
                                               and rel.endswith(".png"))  # fmt: skip


def _write_tables(rows: list[dict[str, Any]], out: Path) -> None:
    """``runs.csv`` and ``runs.md``: every column, nothing left out."""
    import csv
    import io

    cols = list(rows[0])
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=cols, lineterminator="\n")
    w.writeheader()
    for r in rows:
        w.writerow({k: "" if v is None else v for k, v in r.items()})
    write_text_atomic(out / "runs.csv", buf.getvalue())
    md = "| " + " | ".join(cols) + " |\n|" + "---|" * len(cols) + "\n"
    md += "".join("| " + " | ".join(_fmt_cell(r[k]) for k in cols) + " |\n" for r in rows)
    write_text_atomic(out / "runs.md", md)


def _x_key(rows: list[dict[str, Any]], swept: list[str]) -> str:
    """The swept key on the x axis: a numeric one with the most values (ties: the first)."""

    def rank(k: str) -> tuple[bool, int]:
        vals = [r[k] for r in rows]
        numeric = all(_num(v) is not None for v in vals)
        return numeric, len({json.dumps(v) for v in vals})

    return max(swept, key=lambda k: (*rank(k), -swept.index(k)))


def _report_figures(rows: list[dict[str, Any]], plan: _Plan, out: Path) -> list[Path]:
    """One figure per differing numeric metric, against the swept key(s): lines per
    combination of the other keys, or one panel per key when the runs vary several keys
    at once (more than 6 combinations, or none repeated: a search)."""
    from fxspace.plot import plot_report_grid, plot_report_metric

    ok = [r for r in rows if r["status"] == "complete"]
    if not plan.swept or not ok:
        return []
    exp, files = plan.experiment, []
    for m in plan.differ:
        vals = [r for r in ok if _num(r[m]) is not None and np.isfinite(r[m])]
        if len({r[m] for r in vals}) < 2:
            continue  # a text metric, or one value among the complete runs
        x = _x_key(vals, plan.swept)
        others = [k for k in plan.swept if k != x]
        d = describe(m, exp)
        best = _best_index(vals, m, d.better)
        kw = dict(y_label=_axis_label(m, exp), title=m, best=best or None,
                  better=d.better if best else None)  # fmt: skip
        combos = [tuple(json.dumps(r[k]) for k in others) for r in vals]
        sizes = [combos.count(c) for c in set(combos)]
        if others and (len(sizes) > 6 or max(sizes) < 2):
            # several keys vary at once (a search, a large grid): one panel per key
            xs = {_axis_label(k, exp): [r[k] for r in vals] for k in plan.swept}
            fig = plot_report_grid(xs, [r[m] for r in vals], **kw)
            name = f"{m}_vs_{'_'.join(plan.swept)}"
        else:
            if len(others) == 1:
                u = describe(others[0], exp).unit
                group = [f"{r[others[0]]}" + (f" {u}" if u else "") for r in vals]
                glabel = describe(others[0], exp).words
            else:
                group = [", ".join(f"{k} = {r[k]}" for k in others) for r in vals]
                glabel = ""
            fig = plot_report_metric(
                [r[x] for r in vals], [r[m] for r in vals], x_label=_axis_label(x, exp),
                group=group if others else None, group_label=glabel, **kw,
            )  # fmt: skip
            name = f"{m}_vs_{x}" + (f"_by_{'_'.join(others)}" if others else "")
        files.append(save_figure_atomic(fig, out / f"{name.replace('/', '-')[:120]}.png"))
    return files
