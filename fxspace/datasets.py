"""Facial frames for the expression-space experiments: AnimFace capture or the synthetic face.

Shared by the threshold-sweep and navigation pipelines. ``source = "animface"`` reads
the three AnimFace takes from the data root (``FXSPACE_DATA``); ``"files"`` reads the
given marker files; ``"synthetic"`` uses the embedded seeded generator (no data needed).
"""

from __future__ import annotations

import dataclasses
from typing import Literal, NamedTuple

import numpy as np

from fxspace.config import ConfigError
from fxspace.data import data_path
from fxspace.expression._features import clean_frames
from fxspace.io import read_markers, synthetic_face

__all__ = ["FaceData", "FaceFrames", "load_face", "resample_frames", "ANIMFACE_TAKES"]

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
    - `missing`: ``"drop"`` frames with occluded markers (with a warning) or ``"raise"``.
    - `synthetic_frames`, `synthetic_markers`, `synthetic_noise_mm`: generator options.
    """

    source: Literal["animface", "files", "synthetic"] = "animface"
    takes: tuple[str, ...] = ANIMFACE_TAKES
    paths: tuple[str, ...] = ()
    stride: int = 1
    max_frames: int = 0
    target_frames: int = 0
    missing: Literal["drop", "raise"] = "drop"
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
        if self.source == "animface" and not self.takes:
            raise ConfigError("data.takes must name at least one AnimFace file")
        if self.synthetic_frames < 10 or self.synthetic_markers < 4:
            raise ConfigError("data.synthetic_frames must be >= 10 and synthetic_markers >= 4")


class FaceFrames(NamedTuple):
    """Frames of one or more takes, stacked.

    - `positions`: ``(T, M, 3)`` millimetres, no NaN.
    - `take`: ``(T,)`` index into `take_names`; `frame`: ``(T,)`` frame index in its take.
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


def resample_frames(pos: np.ndarray, n: int) -> np.ndarray:
    """Linear interpolation of ``(T, M, 3)`` frames to ``n`` frames over the same time span."""
    T = len(pos)
    src = np.linspace(0.0, T - 1.0, n)
    lo = np.floor(src).astype(int)
    hi = np.minimum(lo + 1, T - 1)
    w = (src - lo)[:, None, None]
    return (1 - w) * pos[lo] + w * pos[hi]


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


def load_face(cfg: FaceData, seed: int = 0) -> FaceFrames:
    """Load, align marker sets (names common to all takes, first take's order), convert to
    millimetres, drop or reject occluded frames, thin/resample, and stack the takes."""
    seqs = _sequences(cfg, seed)
    names = [n for n in seqs[0][1].names if all(n in s.names for _, s, *_ in seqs)]
    if len(names) < 4:
        raise ConfigError(f"the takes share only {len(names)} marker names; need at least 4")
    rate = seqs[0][1].rate
    pos_all, take_all, frame_all, label_all = [], [], [], []
    per_take = []
    for k, (_, seq, lab, _) in enumerate(seqs):
        s = seq.select(names) if tuple(seq.names) != tuple(names) else seq
        s = s.to_units("mm") if s.units in ("mm", "cm", "m") else s
        pos = np.asarray(s.positions, np.float64)
        idx = np.arange(len(pos))
        pos, kept = clean_frames(pos, cfg.missing)
        idx = idx[kept]
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
    return FaceFrames(pos, take, frame, take_names, tuple(names), rate, label, label_names)
