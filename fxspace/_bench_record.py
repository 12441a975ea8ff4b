"""Benchmark records: one benchmark's comparisons and the machine they ran on.

`write_bench` writes ``runs/bench/NAME.json`` (the rows of `BENCH_FIELDS` and
`machine`), which the docs' benchmark page reads (`fxspace docs`).

The public front is `fxspace.runs`, which re-exports every name here.
"""

from __future__ import annotations

import datetime as _dt
import os
import platform
import re
from pathlib import Path
from typing import Any

from fxspace._atomic import (
    OverwriteRefusedError,
    active_run,
    read_json,
    to_jsonable,
    write_json_atomic,
)
from fxspace._run_folder import versions
from fxspace.errors import FxspaceError

__all__ = ["machine", "BENCH_FIELDS", "write_bench", "bench_name_ok", "is_bench_record"]


#: The fields of one benchmark comparison (a row of `write_bench`).
BENCH_FIELDS = ("case", "size", "ours", "ours_s", "peer", "peer_s", "ratio")


def machine() -> dict[str, Any]:
    """The machine a measurement ran on: host OS, CPU, core count, JAX devices, versions
    and the date (UTC), for benchmark records."""
    import jax

    devs = jax.devices()
    return {
        "platform": platform.platform(),
        "processor": platform.processor() or platform.machine(),
        "cpu_count": os.cpu_count(),
        "devices": f"{len(devs)} x {devs[0].platform} ({devs[0].device_kind})",
        "python": platform.python_version(),
        "versions": versions(),
        "date": _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%d %H:%M UTC"),
    }


def write_bench(
    name: str,
    rows: list[dict[str, Any]],
    *,
    title: str,
    command: str,
    root: str | Path | None = None,
    force: bool = False,
) -> Path:
    """Write a benchmark's comparisons to ``root/bench/NAME.json`` (``root``: ``$FXSPACE_RUNS``
    or ``runs``) with the machine it ran on, for the docs' benchmark page (`fxspace docs`).

    Each row is one comparison, `BENCH_FIELDS`: ``case`` (a label), ``size`` (a number to
    plot against, or ``None``), ``ours`` / ``peer`` (what was timed), ``ours_s`` /
    ``peer_s`` (median seconds) and ``ratio`` (``peer_s / ours_s``, filled in when left out).

    ``name`` must be a plain file name (`bench_name_ok`). An existing ``NAME.json`` that
    fxspace did not write (not in ``bench/``'s manifest, not a benchmark record of that
    name) is refused (`OverwriteRefusedError`) unless ``force``.
    """
    if not bench_name_ok(name):
        raise FxspaceError(
            f"write_bench: name must be a plain file name (letters, digits, _ . -, no "
            f"folder, no '..'), got {name!r}"
        )
    if not rows:
        raise FxspaceError(f"write_bench({name!r}): rows is empty; pass one dict per comparison")
    out = []
    for i, r in enumerate(rows):
        missing = [k for k in ("case", "ours", "ours_s", "peer", "peer_s") if k not in r]
        if missing:
            raise FxspaceError(
                f"write_bench({name!r}): rows[{i}] lacks {missing}; each row needs "
                f"{', '.join(BENCH_FIELDS)} (size and ratio may be left out)"
            )
        r = {k: r.get(k) for k in BENCH_FIELDS}
        r["ours_s"], r["peer_s"] = float(r["ours_s"]), float(r["peer_s"])
        if r["ratio"] is None:
            r["ratio"] = r["peer_s"] / r["ours_s"] if r["ours_s"] > 0 else None
        out.append(r)
    root = Path(root if root is not None else os.environ.get("FXSPACE_RUNS", "runs"))
    rec = {"name": name, "title": title, "command": command.strip(), "machine": machine(),
           "rows": out}  # fmt: skip
    folder = root / "bench"
    with active_run(folder, force=force, recognise=is_bench_record):
        try:
            return write_json_atomic(folder / f"{name}.json", to_jsonable(rec))
        except OverwriteRefusedError:
            raise OverwriteRefusedError(
                f"{folder / (name + '.json')} exists and is not a benchmark record fxspace "
                "wrote; nothing was written: move that file away, or set FXSPACE_RUNS to "
                "another folder (write_bench(..., force=True) replaces it)"
            ) from None


def bench_name_ok(name: Any) -> bool:
    """Whether ``name`` may name a benchmark record (``runs/bench/NAME.json``) and its
    figure: a plain file name, never a path, an absolute name or ``..``."""
    return (
        isinstance(name, str)
        and re.fullmatch(r"[A-Za-z0-9][A-Za-z0-9_.-]{0,99}", name) is not None
        and ".." not in name
    )


def is_bench_record(p: Path) -> bool:
    """A benchmark record fxspace wrote before records were listed in a manifest: a JSON
    object with the record's keys whose ``name`` is the file's stem."""
    try:
        rec = read_json(p)
    except (OSError, FxspaceError):
        return False
    return (
        isinstance(rec, dict)
        and {"name", "title", "command", "machine", "rows"} <= set(rec)
        and rec.get("name") == p.stem
    )


_is_bench_record = is_bench_record  # the earlier private name
