"""``fxspace report DIR``: compare the runs under a folder.

`collect` reads one row per run (swept keys, scalar metrics, timing, status); `write_report`
writes every column to ``runs.csv`` / ``runs.md``, prints a short table (the swept keys,
then only the metrics that differ between the runs, each headed with its unit; the
constant ones in one line) and draws one figure per differing metric against the swept
key(s) (`fxspace.plot.plot_report_metric`).

What the report knows of a metric — its words, its unit and which way is better — is in
one place, `KNOWN` (an experiment's own entries first, then everyone's); a unit is else
read from the name's suffix (`SUFFIX_UNITS`: ``_mm``, ``_s``, ``_hz``, ...). A metric
with no known direction gets no "best" mark. That vocabulary lives in
``fxspace._report_known`` (re-exported here); the figures are drawn by
`fxspace.plot.plot_report_figure` and saved here.

This module is the report's one home (it draws with ``fxspace.plot``, a layer above
``fxspace.runs``, so it sits beside the command line, not in ``fxspace.runs``).
"""

from __future__ import annotations

import json
import os
import shutil
import sys
import textwrap
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from fxspace._report_known import KNOWN as KNOWN
from fxspace._report_known import SUFFIX_UNITS as SUFFIX_UNITS
from fxspace._report_known import Known as Known
from fxspace._report_known import _lookup as _lookup
from fxspace._report_known import describe as describe
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
    """One figure per differing numeric metric, against the swept key(s), drawn by
    `fxspace.plot.plot_report_figure` (lines per combination of the other keys, or one
    panel per key for a search) and saved as ``out/NAME.png``, NAME the figure's label."""
    from fxspace.plot import plot_report_figure

    ok = [r for r in rows if r["status"] == "complete"]
    if not plan.swept or not ok:
        return []
    exp, files = plan.experiment, []
    for m in plan.differ:
        vals = [r for r in ok if _num(r[m]) is not None and np.isfinite(r[m])]
        if len({r[m] for r in vals}) < 2:
            continue  # a text metric, or one value among the complete runs
        best = _best_index(vals, m, describe(m, exp).better)
        fig = plot_report_figure(vals, m, plan.swept, x=_x_key(vals, plan.swept),
                                 describe=lambda k: describe(k, exp), best=best)  # fmt: skip
        name = fig.get_label()
        files.append(save_figure_atomic(fig, out / f"{name.replace('/', '-')[:120]}.png"))
    return files
