"""Facial frames for the expression-space experiments: AnimFace capture or the synthetic face.

Shared by the threshold-sweep and navigation pipelines. ``source = "animface"`` reads
the three AnimFace takes from the data root (``FXSPACE_DATA``); ``"files"`` reads the
given marker files; ``"synthetic"`` uses the embedded seeded generator (no data needed).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Literal, NamedTuple

import numpy as np

from fxspace._validate import describe_missing
from fxspace.config import ConfigError
from fxspace.data import data_path
from fxspace.errors import FxspaceError
from fxspace.expression import fill_gaps, missing_report
from fxspace.io import read_markers
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
    - `takes`: AnimFace file names (``source = "animface"``).
    - `paths`: marker files (``source = "files"``): .c3d, .trc, .trc.gz, .npz.
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
    stride: int = 1
    max_frames: int = 0
    target_frames: int = 0
    missing: Literal["fill", "drop", "raise"] = "fill"
    max_gap: int = 10
    synthetic_frames: int = 600
    synthetic_markers: int = 60
    synthetic_noise_mm: float = 0.3

    def validate(self) -> None:
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
        if self.synthetic_frames < 10 or self.synthetic_markers < 4:
            raise ConfigError("data.synthetic_frames must be >= 10 and synthetic_markers >= 4")


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


def _sequences(cfg: FaceData, seed: int) -> list[tuple]:
    if cfg.source == "synthetic":
        syn = synthetic_face(
            n_markers=cfg.synthetic_markers,
            n_frames=cfg.synthetic_frames,
            seed=seed,
            noise_mm=cfg.synthetic_noise_mm,
        )
        mode = np.asarray(syn.mode)
        mode = np.where(mode < 0, len(syn.mode_names), mode)
        return [("synthetic", syn.sequence, mode, (*syn.mode_names, "neutral"))]
    if cfg.source == "animface":
        paths = [data_path("face", t) for t in cfg.takes]
    else:
        paths = list(cfg.paths)
    return [(str(p).rsplit("/", 1)[-1], read_markers(p), None, None) for p in paths]


def _handle_missing(pos: np.ndarray, cfg: FaceData, take: str, names, counts: dict):
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
    if cfg.missing == "fill":
        res = fill_gaps(pos, cfg.max_gap, marker_names=names)
        counts["filled_samples"] += int(res.filled.sum())
        counts["filled_frames"] += int(res.filled.any(axis=1).sum())
        counts["unfilled_gaps"] += [f"{take}: {m} frames {a}-{b}" for m, a, b in res.unfilled]
        pos = res.positions
    kept = np.flatnonzero(np.isfinite(pos).all(axis=(1, 2)))
    counts["dropped_frames"] += len(pos) - len(kept)
    if not len(kept):
        raise FxspaceError(f"{take}: every frame has a missing marker; nothing is left")
    return pos[kept], kept


def load_face(cfg: FaceData, seed: int = 0) -> FaceFrames:
    """Load, align marker sets (names common to all takes, first take's order), convert to
    millimetres, fill/drop/reject occluded markers (``cfg.missing``), thin/resample, and
    stack the takes. ``FaceFrames.frame`` keeps each frame's original number in its take
    and ``FaceFrames.missing`` the counts of filled and dropped frames."""
    seqs = _sequences(cfg, seed)
    names = [n for n in seqs[0][1].names if all(n in s.names for _, s, *_ in seqs)]
    if len(names) < 4:
        raise ConfigError(f"the takes share only {len(names)} marker names; need at least 4")
    rate = seqs[0][1].rate
    pos_all, take_all, frame_all, label_all = [], [], [], []
    per_take = []
    counts = {"filled_samples": 0, "filled_frames": 0, "dropped_frames": 0, "unfilled_gaps": []}
    for k, (take, seq, lab, _) in enumerate(seqs):
        s = seq.select(names) if tuple(seq.names) != tuple(names) else seq
        s = s.to_units("mm") if s.units in ("mm", "cm", "m") else s
        pos = np.asarray(s.positions, np.float64)
        pos, idx = _handle_missing(pos, cfg, take, names, counts)
        lab = (np.full(len(seq.positions), k) if lab is None else np.asarray(lab))[idx]
        per_take.append((pos, idx, lab, k))
    if cfg.target_frames:
        total = sum(len(p) for p, *_ in per_take)
        counts = [max(2, round(cfg.target_frames * len(p) / total)) for p, *_ in per_take]
        counts[-1] += cfg.target_frames - sum(counts)
        new = []
        for (pos, idx, lab, k), c in zip(per_take, counts, strict=True):
            src = np.linspace(0, len(pos) - 1, c)
            near = np.rint(src).astype(int)
            new.append((resample_frames(pos, c), idx[near], lab[near], k))
        per_take = new
    for pos, idx, lab, k in per_take:
        sl = slice(None, None, cfg.stride)
        pos_all.append(pos[sl])
        frame_all.append(idx[sl])
        label_all.append(lab[sl])
        take_all.append(np.full(len(pos[sl]), k))
    pos = np.concatenate(pos_all)
    take = np.concatenate(take_all)
    frame = np.concatenate(frame_all)
    label = np.concatenate(label_all)
    if cfg.max_frames and len(pos) > cfg.max_frames:
        keep = np.unique(np.linspace(0, len(pos) - 1, cfg.max_frames).round().astype(int))
        pos, take, frame, label = pos[keep], take[keep], frame[keep], label[keep]
    take_names = tuple(n for n, *_ in seqs)
    label_names = seqs[0][3] if seqs[0][3] is not None else take_names
    return FaceFrames(pos, take, frame, take_names, tuple(names), rate, label, label_names, counts)
