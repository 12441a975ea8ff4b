"""Facial frames for the expression-space experiments: AnimFace capture or the synthetic face.

Shared by the threshold-sweep and navigation pipelines. ``source = "animface"`` reads
the three AnimFace takes from the data root (``FXSPACE_DATA``); ``"files"`` reads the
given marker files (C3D, TRC, NPZ, CSV/TSV tables); ``"synthetic"`` uses the embedded
seeded generator (no data needed).

Nothing is dropped, converted or resampled without a word: `load_face` says on the
console (``fxspace._progress.note``) every marker cut to the shared set, unit converted,
take resampled (only when ``resample_hz`` asks: mixed rates are refused otherwise),
frame filled or dropped for missing markers and frame thinned, and keeps the same in
``FaceFrames.reading`` for the run's metrics.
"""

from __future__ import annotations

import dataclasses
import math
import threading
from pathlib import Path
from typing import Literal, NamedTuple

import numpy as np

from fxspace._progress import note
from fxspace._validate import describe_missing
from fxspace.config import ConfigError
from fxspace.data import data_path
from fxspace.errors import FxspaceError
from fxspace.expression import fill_gaps, missing_report
from fxspace.io import UNIT_SCALES, MarkerSequence, read_markers
from fxspace.synthetic import synthetic_face

__all__ = [
    "FaceData",
    "FaceFrames",
    "load_face",
    "face_data_files",
    "resample_frames",
    "ANIMFACE_TAKES",
]

ANIMFACE_TAKES = ("animface_cheeks.c3d", "animface_jaw.c3d", "animface_eyebrows.trc.gz")


@dataclasses.dataclass(frozen=True)
class FaceData:
    """Where the frames come from and how they are thinned.

    - `source`: ``"animface"`` (real capture under ``$FXSPACE_DATA/face``), ``"files"``
      (``paths``) or ``"synthetic"`` (embedded generator).
    - `takes`: AnimFace file names (``source = "animface"`` only; empty otherwise, so a
      resolved config lists only what was read).
    - `paths`: marker files (``source = "files"`` only): .c3d, .trc, .trc.gz, .npz, or
      tables .csv/.tsv/.txt (``.gz`` too); relative to the config file's folder.
    - `units`: the files' length unit (``"mm"``, ``"cm"``, ``"m"``, ``"in"``, ``"ft"``):
      declares it for tables, overrides a file's own label; ``""`` = as each file says
      (tables: inferred from the extent, said).
    - `rate`: Hz for tables without a time column; ``0`` = from each file.
    - `resample_hz`: ``0`` (default) refuses takes of different rates; ``> 0`` resamples
      every take whose rate differs to this rate (linear in time), said on the console.
    - `stride`: keep every ``stride``-th frame of each take.
    - `max_frames`: if > 0, thin evenly to at most this many frames in all.
    - `target_frames`: if > 0, resample every take in time (linear interpolation) so the
      total is exactly this many frames — used by benchmarks to scale realistic data.
    - `missing`: what to do with occluded (NaN) markers: ``"fill"`` interpolates each
      marker's gaps of at most `max_gap` frames (`fxspace.fill_gaps`) and drops the
      frames still incomplete; ``"drop"`` drops every frame with a missing marker;
      ``"raise"`` stops with an error naming the missing markers and frames.
    - `max_gap`: the longest gap (frames) ``"fill"`` interpolates.
    - `synthetic_frames`, `synthetic_markers`, `synthetic_noise_mm`: generator options.
    """

    source: Literal["animface", "files", "synthetic"] = "animface"
    takes: tuple[str, ...] = ANIMFACE_TAKES
    paths: tuple[str, ...] = ()
    units: str = ""
    rate: float = 0.0
    resample_hz: float = 0.0
    stride: int = 1
    max_frames: int = 0
    target_frames: int = 0
    missing: Literal["fill", "drop", "raise"] = "fill"
    max_gap: int = 10
    synthetic_frames: int = 600
    synthetic_markers: int = 60
    synthetic_noise_mm: float = 0.3

    def __post_init__(self) -> None:
        # the AnimFace takes belong to source = "animface" only: elsewhere the default list
        # is cleared, so the resolved config.toml records only the files read
        if self.source != "animface" and tuple(self.takes) == ANIMFACE_TAKES:
            object.__setattr__(self, "takes", ())

    def validate(self) -> None:
        if self.source != "animface" and self.takes:
            raise ConfigError(
                f"data.takes names AnimFace files, read only with source = 'animface' (here "
                f"{self.source!r}); list your own files in data.paths with source = 'files'"
            )
        if self.source != "files" and self.paths:
            raise ConfigError(
                f"data.paths is read only with source = 'files' (here {self.source!r}); set "
                "data.source = 'files' or remove data.paths"
            )
        if self.units and self.units not in UNIT_SCALES:
            raise ConfigError(
                f"data.units must be one of {sorted(UNIT_SCALES)} or '' (as the files say), "
                f"got {self.units!r}"
            )
        for key in ("rate", "resample_hz"):
            v = getattr(self, key)
            if not (math.isfinite(v) and v >= 0):
                raise ConfigError(f"data.{key} must be a number of Hz >= 0 (0: off), got {v}")
        if self.stride < 1:
            raise ConfigError(f"data.stride must be >= 1, got {self.stride}")
        if self.max_frames < 0 or self.target_frames < 0:
            raise ConfigError("data.max_frames and data.target_frames must be >= 0")
        if self.source == "files" and not self.paths:
            raise ConfigError("data.source = 'files' needs data.paths = ['a.c3d', ...]")
        if self.source == "files":
            for p in self.paths:
                if not Path(p).is_file():
                    what = "is a directory, not a file" if Path(p).is_dir() else "does not exist"
                    raise ConfigError(
                        f"data.paths: {p} {what} (relative paths resolve against the config "
                        "file's folder)"
                    )
        if self.source == "animface" and not self.takes:
            raise ConfigError("data.takes must name at least one AnimFace file")
        if self.max_gap < 0:
            raise ConfigError(f"data.max_gap must be >= 0 frames, got {self.max_gap}")
        if self.synthetic_frames < 10:
            raise ConfigError(f"data.synthetic_frames must be >= 10, got {self.synthetic_frames}")
        if not 12 <= self.synthetic_markers <= 200:  # the synthetic face's layout (face_layout)
            raise ConfigError(
                f"data.synthetic_markers must lie in [12, 200] (the synthetic face's layout), "
                f"got {self.synthetic_markers}"
            )


class FaceFrames(NamedTuple):
    """Frames of one or more takes, stacked.

    - `positions`: ``(T, M, 3)`` millimetres, no NaN.
    - `take`: ``(T,)`` index into `take_names`; `frame`: ``(T,)`` frame index in its take
      (the original frame number: dropped frames leave gaps in it).
    - `label`: ``(T,)`` a known class per frame, indexing `label_names`: the expression
      mode for the synthetic face (last name = neutral), else the take index.
    """

    positions: np.ndarray
    take: np.ndarray
    frame: np.ndarray
    take_names: tuple[str, ...]
    marker_names: tuple[str, ...]
    rate: float
    label: np.ndarray
    label_names: tuple[str, ...]
    missing: dict | None = None  # counts: filled samples/frames, dropped frames, gaps left
    reading: dict | None = None  # what was read and every drop / resample / conversion said


def resample_frames(pos: np.ndarray, n: int) -> np.ndarray:
    """Linear interpolation of ``(T, M, 3)`` frames to ``n`` frames over the same time span."""
    T = len(pos)
    src = np.linspace(0.0, T - 1.0, n)
    lo = np.floor(src).astype(int)
    hi = np.minimum(lo + 1, T - 1)
    w = (src - lo)[:, None, None]
    return (1 - w) * pos[lo] + w * pos[hi]


def face_data_files(cfg: FaceData) -> list[Path]:
    """The files ``cfg`` reads (empty for the synthetic face); missing ones raise."""
    if cfg.source == "synthetic":
        return []
    if cfg.source == "animface":
        return [data_path("face", t) for t in cfg.takes]
    return [Path(p) for p in cfg.paths]


_SYNTHETIC: dict = {}  # the last synthetic take made in this process: key -> sequences
_SYNTHETIC_LOCK = threading.Lock()
_SYNTHETIC_KEEP = 2e7  # kept only up to this many marker positions (10⁵ frames × 60: 6e6)


def _synthetic(cfg: FaceData, seed: int) -> list[tuple]:
    """The synthetic take of ``cfg``, made once per process for takes of up to
    `_SYNTHETIC_KEEP` positions: `fxspace studio` reads it three times (its stages, the
    app's warm-up thread and the app), 0.9 s each at 10⁵ frames. `load_face` copies the
    positions it works on, so the kept take is never written."""
    key = (cfg.synthetic_markers, cfg.synthetic_frames, int(seed), cfg.synthetic_noise_mm)
    with _SYNTHETIC_LOCK:  # a second reader waits for the first's take
        if key in _SYNTHETIC:
            return _SYNTHETIC[key]
        syn = synthetic_face(
            n_markers=cfg.synthetic_markers,
            n_frames=cfg.synthetic_frames,
            seed=seed,
            noise_mm=cfg.synthetic_noise_mm,
        )
        mode = np.asarray(syn.mode)
        mode = np.where(mode < 0, len(syn.mode_names), mode)
        out = [("synthetic", syn.sequence, mode, (*syn.mode_names, "neutral"))]
        _SYNTHETIC.clear()
        if cfg.synthetic_markers * cfg.synthetic_frames <= _SYNTHETIC_KEEP:
            _SYNTHETIC[key] = out
        return out


def _sequences(cfg: FaceData, seed: int) -> list[tuple]:
    if cfg.source == "synthetic":
        return list(_synthetic(cfg, seed))
    if cfg.source == "animface":
        paths = [data_path("face", t) for t in cfg.takes]
    else:
        paths = [Path(p) for p in cfg.paths]
    kw = {"units": cfg.units or None, "rate": cfg.rate or None}
    return [(p.name, read_markers(p, **kw), None, None) for p in paths]


def _resample_seq(seq: MarkerSequence, hz: float) -> MarkerSequence:
    """``seq`` at ``hz`` over the same time span: linear in time, NaN where a neighbour is."""
    T = seq.n_frames
    n = max(2, int(math.floor((T - 1) * hz / seq.rate + 1e-9)) + 1)
    src = np.arange(n) * (seq.rate / hz)
    lo = np.minimum(np.floor(src).astype(int), T - 1)
    hi = np.minimum(lo + 1, T - 1)
    w = (src - lo)[:, None, None]
    p = np.asarray(seq.positions, np.float64)
    out = (1 - w) * p[lo] + w * p[hi]
    exact = w[:, 0, 0] == 0
    out[exact] = p[lo[exact]]  # a sample on a source frame is that frame, NaN or not
    return dataclasses.replace(seq, positions=out, rate=float(hz))


def _align_rates(seqs: list[tuple], cfg: FaceData, reading: dict) -> list[tuple]:
    """One rate for every take: mixed rates refused unless ``resample_hz`` asks (said)."""
    rates = {take: float(s.rate) for take, s, *_ in seqs}
    reading["rates_hz"] = rates
    target = cfg.resample_hz
    if not target:
        if len({round(r, 6) for r in rates.values()}) > 1:
            listed = ", ".join(f"{t} {r:g} Hz" for t, r in rates.items())
            raise ConfigError(
                f"the takes have different frame rates ({listed}); set [data] resample_hz "
                f"to one rate (e.g. {min(rates.values()):g}) to resample them to it"
            )
        return seqs
    out = []
    for take, s, lab, ln in seqs:
        if abs(s.rate - target) > 1e-9 * target:
            if lab is not None:
                src = np.rint(np.arange(_resample_seq(s, target).n_frames) * s.rate / target)
                lab = np.asarray(lab)[np.minimum(src.astype(int), len(lab) - 1)]
            r = _resample_seq(s, target)
            msg = (f"{take}: resampled {s.rate:g} → {target:g} Hz ({s.n_frames} → "
                   f"{r.n_frames} frames, linear in time; [data] resample_hz)")  # fmt: skip
            _say(reading, msg)
            reading.setdefault("resampled", {})[take] = {
                "from_hz": float(s.rate), "to_hz": float(target),
                "from_frames": s.n_frames, "to_frames": r.n_frames,
            }  # fmt: skip
            s = r
        out.append((take, s, lab, ln))
    return out


def _shared_markers(seqs: list[tuple], reading: dict) -> list[str]:
    """The marker names every take has (the first take's order); any cut is said."""
    first = seqs[0][1].names
    names = [n for n in first if all(n in s.names for _, s, *_ in seqs)]
    if len(names) < 4:
        raise ConfigError(
            f"the takes share only {len(names)} marker names ({names}); need at least 4 — "
            "check that every take uses the same marker names"
        )
    dropped: dict[str, list[str]] = {}
    lacking: dict[str, list[str]] = {}
    for take, s, *_ in seqs:
        unused = [n for n in s.names if n not in names]
        lacks = [n for n in first if n not in s.names]
        if not unused and not lacks:
            continue
        if unused:
            dropped[take] = unused
        if lacks:
            lacking[take] = lacks
        parts = []
        if lacks:
            parts.append(f"lacks {len(lacks)} of {seqs[0][0]}'s markers ({', '.join(lacks)})")
        if unused:
            parts.append(f"{len(unused)} of its markers are not in every take, dropped "
                         f"({', '.join(unused)})")  # fmt: skip
        _say(reading, f"{take}: " + "; ".join(parts))
    if dropped:
        _say(reading, f"markers: using the {len(names)} shared by every take")
    reading["markers_used"] = list(names)
    reading["markers_dropped"] = dropped  # per take: its markers left out
    reading["markers_lacking"] = lacking  # per take: the first take's markers it lacks
    return names


def _say(reading: dict, msg: str) -> None:
    note(msg)
    reading.setdefault("notes", []).append(msg)


def _handle_missing(pos: np.ndarray, cfg: FaceData, take: str, names, counts: dict,
                    reading: dict):  # fmt: skip
    """Apply ``cfg.missing`` to one take: returns ``(positions, kept frame indices)``."""
    bad = ~np.isfinite(pos).all(axis=2)
    if not bad.any():
        return pos, np.arange(len(pos))
    if cfg.missing == "raise":
        runs = missing_report(pos, names)
        raise FxspaceError(
            f"{take}: {int(bad.any(axis=1).sum())} of {len(pos)} frames have missing markers "
            f"({describe_missing(runs)}); set [data] missing = 'fill' (gaps up to max_gap "
            "frames) or 'drop'"
        )
    said = []
    unfilled: list = []
    if cfg.missing == "fill":
        res = fill_gaps(pos, cfg.max_gap, marker_names=names)
        counts["filled_samples"] += int(res.filled.sum())
        counts["filled_frames"] += int(res.filled.any(axis=1).sum())
        counts["unfilled_gaps"] += [f"{take}: {m} frames {a}-{b}" for m, a, b in res.unfilled]
        unfilled = res.unfilled
        pos = res.positions
        if res.filled.any():
            said.append(f"gaps of at most max_gap = {cfg.max_gap} frames filled in "
                        f"{int(res.filled.any(axis=1).sum())} frames")  # fmt: skip
    kept = np.flatnonzero(np.isfinite(pos).all(axis=(1, 2)))
    n_drop = len(pos) - len(kept)
    counts["dropped_frames"] += n_drop
    per = counts.setdefault("dropped_frames_per_take", {})
    per[take] = n_drop
    if n_drop:
        why = ("markers missing (missing = 'drop')" if cfg.missing == "drop" else
               f"gaps longer than max_gap = {cfg.max_gap} frames or at a take's end: "
               f"{describe_missing(unfilled)}")  # fmt: skip
        said.append(f"{n_drop} of {len(pos)} frames dropped ({why})")
    if said:
        _say(reading, f"{take}: " + "; ".join(said))
    if not len(kept):
        raise FxspaceError(
            f"{take}: every frame has a missing marker; nothing is left (raise [data] "
            "max_gap, or remove the markers that are never seen)"
        )
    return pos[kept], kept


def load_face(cfg: FaceData, seed: int = 0) -> FaceFrames:
    """Load, align marker sets (names common to all takes, first take's order), convert to
    millimetres, fill/drop/reject occluded markers (``cfg.missing``), thin/resample, and
    stack the takes. ``FaceFrames.frame`` keeps each frame's original number in its take
    and ``FaceFrames.missing`` the counts of filled and dropped frames.

    Every marker cut, rate resample (mixed rates are refused unless ``resample_hz`` is
    set), unit conversion, frame fill, drop and thinning is said on the console as it
    happens and recorded in ``FaceFrames.reading`` (``notes``, ``files``,
    ``markers_used``, ``markers_dropped`` (a take's markers left out),
    ``markers_lacking`` (the first take's markers a take lacks), ``rates_hz``,
    ``resampled``, ``converted``)."""
    reading: dict = {"notes": []}
    seqs = _sequences(cfg, seed)
    if cfg.source != "synthetic":
        reading["files"] = [
            {"take": t, "path": str(p), "frames": s.n_frames, "markers": s.n_markers,
             "rate_hz": float(s.rate), "units": s.units, "file_units": s.file_units}
            for (t, s, *_), p in zip(seqs, face_data_files(cfg), strict=True)
        ]  # fmt: skip
    seqs = _align_rates(seqs, cfg, reading)
    names = _shared_markers(seqs, reading)
    rate = seqs[0][1].rate
    pos_all, take_all, frame_all, label_all = [], [], [], []
    per_take = []
    counts = {"filled_samples": 0, "filled_frames": 0, "dropped_frames": 0, "unfilled_gaps": []}
    for k, (take, seq, lab, _) in enumerate(seqs):
        s = seq.select(names) if tuple(seq.names) != tuple(names) else seq
        if s.units in ("cm", "m"):
            _say(reading, f"{take}: converted from {s.units} to mm")
            reading.setdefault("converted", {})[take] = f"{s.units} -> mm"
            s = s.to_units("mm")
        elif s.units != "mm":
            raise ConfigError(
                f"{take}: units {s.units!r} are not a length unit fxspace knows; set "
                f"[data] units to one of {sorted(UNIT_SCALES)}"
            )
        pos = np.array(s.positions, np.float64)  # a copy: the take may be kept (`_synthetic`)
        pos, idx = _handle_missing(pos, cfg, take, names, counts, reading)
        lab = (np.full(len(seq.positions), k) if lab is None else np.asarray(lab))[idx]
        per_take.append((pos, idx, lab, k))
    if cfg.target_frames:
        total = sum(len(p) for p, *_ in per_take)
        sizes = [max(2, round(cfg.target_frames * len(p) / total)) for p, *_ in per_take]
        sizes[-1] += cfg.target_frames - sum(sizes)
        new = []
        for (pos, idx, lab, k), c in zip(per_take, sizes, strict=True):
            src = np.linspace(0, len(pos) - 1, c)
            near = np.rint(src).astype(int)
            new.append((resample_frames(pos, c), idx[near], lab[near], k))
        _say(reading, f"resampled to target_frames = {cfg.target_frames} frames in all "
                      f"({total} before; linear interpolation in time)")  # fmt: skip
        per_take = new
    before = sum(len(p) for p, *_ in per_take)
    for pos, idx, lab, k in per_take:
        sl = slice(None, None, cfg.stride)
        pos_all.append(pos[sl])
        frame_all.append(idx[sl])
        label_all.append(lab[sl])
        take_all.append(np.full(len(pos[sl]), k))
    pos = np.concatenate(pos_all)
    if cfg.stride > 1:
        _say(reading, f"stride = {cfg.stride}: every {cfg.stride}th frame kept "
                      f"({before} → {len(pos)} frames)")  # fmt: skip
    take = np.concatenate(take_all)
    frame = np.concatenate(frame_all)
    label = np.concatenate(label_all)
    if cfg.max_frames and len(pos) > cfg.max_frames:
        keep = np.unique(np.linspace(0, len(pos) - 1, cfg.max_frames).round().astype(int))
        _say(reading, f"max_frames = {cfg.max_frames}: thinned evenly from {len(pos)} to "
                      f"{len(keep)} frames")  # fmt: skip
        pos, take, frame, label = pos[keep], take[keep], frame[keep], label[keep]
    take_names = tuple(n for n, *_ in seqs)
    label_names = seqs[0][3] if seqs[0][3] is not None else take_names
    return FaceFrames(pos, take, frame, take_names, tuple(names), rate, label, label_names,
                      counts, reading)  # fmt: skip
