"""What ``fxspace report`` knows of a key or metric: its words, unit and better direction.

`KNOWN` holds them (an experiment's own entries first, then everyone's); a unit is else
read from the name's suffix (`SUFFIX_UNITS`: ``_mm``, ``_s``, ``_hz``, ...). A metric
with no known direction gets no "best" mark.

The public front is `fxspace.report`, which re-exports every name here.
"""

from __future__ import annotations

from fnmatch import fnmatchcase
from typing import NamedTuple

__all__ = ["KNOWN", "SUFFIX_UNITS", "Known", "describe"]


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
