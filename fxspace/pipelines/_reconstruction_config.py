"""The reconstruction experiment's configuration and capture (`fxspace.pipelines.
reconstruction`): the config, the files a run reads, the capture read in millimetres
(its units checked), the neutral frame the head is bound to and the edit's marker."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from fxspace.config import ConfigError
from fxspace.controlpoints import thin_frames
from fxspace.data import data_path
from fxspace.errors import DataNotFoundError

PAPER = {"linear_error": 16.44, "ours_error": 1.82, "ratio": 0.11, "time_s": 18.0,
         "segments": 8, "segment_frames": 43}  # fmt: skip
SYNTHETIC = "synthetic"


@dataclasses.dataclass(frozen=True)
class Config:
    """See ``configs/reconstruction.toml`` for the meaning of every field."""

    file: str = "face/animface_cheeks.c3d"
    start: int = 300
    n_frames: int = 300
    thin: int = 2
    n_vertices: int = 6000
    n_segments: int = 0
    segment_criterion: str = "elbow"
    segment_on: str = "velocity"
    min_length: int = 4
    clusters: tuple[int, ...] = (20, 25, 30)
    gammas: tuple[float, ...] = (0.25, 0.5, 1.0)
    n_init: int = 20
    max_points: int = 1000
    refine_steps: int = 10
    cluster_method: str = "kernel"
    fit_steps: int = 300
    fit_support: int = 3
    fit_smoothness: float = 1e-4
    edit_offset_mm: tuple[float, ...] = (6.0, 8.0, 0.0)
    edit_marker: str = "Mouth_Lend"
    timing_repeats: int = 2
    paper_segment_frames: int = 43
    character: str = "standin"
    character_markers: str = ""
    character_first: str = ""
    character_last: str = ""
    character_vertices: int = 3000
    head: str = "face/ict"
    dense_source: str = "rbf"
    gltf_mesh: str = "CesiumMan"
    gltf_frames: int = 150
    gltf_clusters: int = 25
    x64: bool = True

    def validate(self) -> None:
        """Every config check, naming the key (`fxspace.config.ConfigError`)."""
        for k in ("start", "n_segments", "refine_steps", "fit_steps"):
            if getattr(self, k) < 0:
                raise ConfigError(f"{k} must be >= 0, got {getattr(self, k)}")
        for k in ("n_frames", "thin", "n_vertices", "min_length", "n_init", "max_points",
                  "fit_support", "timing_repeats", "paper_segment_frames", "gltf_frames",
                  "gltf_clusters", "character_vertices"):  # fmt: skip
            if getattr(self, k) < 1:
                raise ConfigError(f"{k} must be >= 1, got {getattr(self, k)}")
        if self.n_frames // self.thin < 3 * max(self.n_segments, 1):
            raise ConfigError(
                f"n_frames/thin = {self.n_frames // self.thin} too short for n_segments="
                f"{self.n_segments}"
            )
        if self.cluster_method not in ("kernel", "hybrid"):
            raise ConfigError(
                f"cluster_method must be 'kernel' (kernel k-means to the end, the paper's) or "
                f"'hybrid' (kernel k-means on a subset, Euclidean steps for the rest), got "
                f"{self.cluster_method!r}"
            )
        if self.segment_criterion not in ("elbow", "bic"):
            raise ConfigError(
                f"segment_criterion must be 'elbow' or 'bic', got {self.segment_criterion!r}"
            )
        if self.dense_source not in ("rbf", "head"):
            raise ConfigError(
                f"dense_source must be 'rbf' (the markers drive a face surface by RBF) or "
                f"'head' (the solved rig's face-area vertices), got {self.dense_source!r}"
            )
        if self.dense_source == "head" and (not self.head or self.file == SYNTHETIC):
            raise ConfigError(
                "dense_source = 'head' needs a rig (head = \"face/ict\") and a named capture "
                '(not file = "synthetic")'
            )
        if self.segment_on not in ("velocity", "position"):
            raise ConfigError(
                f"segment_on must be 'velocity' or 'position', got {self.segment_on!r}"
            )
        if not self.clusters or min(self.clusters) < 1 or not self.gammas or min(self.gammas) <= 0:
            raise ConfigError("clusters must be integers >= 1 and gammas numbers > 0 (non-empty)")
        if len(self.edit_offset_mm) != 3 or not np.all(np.isfinite(self.edit_offset_mm)):
            raise ConfigError(f"edit_offset_mm must be 3 finite numbers, got {self.edit_offset_mm}")
        if self.fit_smoothness < 0 or not np.isfinite(self.fit_smoothness):
            raise ConfigError(f"fit_smoothness must be finite and >= 0, got {self.fit_smoothness}")
        if self.character not in ("", "standin") and not self.character_markers:
            raise ConfigError(
                "character_markers must name a JSON {marker name: vertex index} file when "
                "character is a mesh file"
            )


def _path(name: str) -> Path:
    return data_path(name)


def _head_path(cfg: Config) -> Path:
    """The rig folder ``head``; when it is absent the error says how to run without it."""
    try:
        return data_path(cfg.head)
    except DataNotFoundError as e:
        raise DataNotFoundError(
            f"head: {e}; set head = \"\" in the config to run without the head (no "
            "head.glb, no head metrics), or point head at a rig folder"
        ) from None


def data_files(cfg: Config) -> list[Path]:
    """The files a run reads (for its content key)."""
    files = [] if cfg.file == SYNTHETIC else [_path(cfg.file)]
    if cfg.head and cfg.file != SYNTHETIC and _head_path(cfg).is_dir():
        files += sorted(p for p in _head_path(cfg).iterdir() if p.is_file())
    for f in (cfg.character if cfg.character not in ("", "standin") else "",
              cfg.character_markers, cfg.character_first, cfg.character_last):  # fmt: skip
        if f:
            files.append(_path(f))
    return files


#: the RMS radius of a face's markers about their centroid, in mm, that a capture must
#: have (AnimFace: 66 mm; the synthetic face: 56 mm); outside it the units are wrong
FACE_RADIUS_MM = (20.0, 400.0)


def _read_capture(cfg: Config, seed: int) -> tuple[np.ndarray, tuple[str, ...], float, str]:
    """``(markers (T, M, 3) thinned, names, rate, units)`` of the configured capture, in
    millimetres (every ``*_mm`` metric and the edit's ``edit_offset_mm`` are in mm): a
    capture in other length units is converted (its unit kept as ``file_units``), one
    whose unit is not a length, or whose face is not of a face's size in mm (metre
    values labelled mm), is refused with the fix."""
    from fxspace.io import UNIT_SCALES, read_markers
    from fxspace.synthetic import synthetic_face

    if cfg.file == SYNTHETIC:
        sf = synthetic_face(41, cfg.start + cfg.n_frames, seed=seed, rate=60.0)
        seq = sf.sequence
    else:
        seq = read_markers(_path(cfg.file))
    if seq.units not in UNIT_SCALES:
        raise ConfigError(
            f"file {cfg.file}: its units {seq.units!r} are not a length unit "
            f"{sorted(UNIT_SCALES)}; fix the file's unit label"
        )
    file_units = seq.file_units or seq.units
    seq = seq.to_units("mm") if seq.units != "mm" else seq
    P = np.asarray(seq.positions, dtype=np.float64)
    if cfg.start + cfg.n_frames > P.shape[0]:
        raise ConfigError(
            f"start + n_frames = {cfg.start + cfg.n_frames} exceeds the {P.shape[0]} frames "
            f"of {cfg.file}"
        )
    M = np.asarray(thin_frames(P[cfg.start : cfg.start + cfg.n_frames], cfg.thin))
    if np.isnan(M).any():
        raise ConfigError(
            f"{cfg.file} frames {cfg.start}… have missing markers; pick another start"
        )
    radius = float(np.sqrt(np.mean(np.sum((M[0] - M[0].mean(0)) ** 2, axis=1))))
    lo, hi = FACE_RADIUS_MM
    if not lo <= radius <= hi:
        raise ConfigError(
            f"file {cfg.file}: the face's markers spread {radius:.3g} mm about their centre "
            f"(a face: {lo:g}–{hi:g} mm) with its units read as {file_units!r}: the values "
            "are in another unit than the file says (metres labelled mm?); fix the file's "
            "unit label"
        )
    _edit_marker(cfg, seq.names)  # a misspelt edit_marker stops the run before any stage
    return M, tuple(seq.names), seq.rate / cfg.thin, file_units


def _neutral(cfg: Config, M: np.ndarray) -> np.ndarray:
    """``(M, 3)`` the frame the head is bound to, in mm: the capture's first frame with
    every marker seen (AnimFace: its neutral face at the start), not the first frame of
    the analysed window (``start``), which may hold an expression: bound there, every
    shape's delta is taken from that expression (on the cheeks take from frame 300 the
    solved residual is 0.54 of the rigid-only one, bound at the neutral 0.40)."""
    from fxspace.io import read_markers

    if cfg.file == SYNTHETIC:
        return M[0]
    seq = read_markers(_path(cfg.file))
    seq = seq.to_units("mm") if seq.units != "mm" else seq
    P = np.asarray(seq.positions, np.float64)
    ok = np.flatnonzero(np.all(np.isfinite(P), axis=(1, 2)))
    return P[ok[0]] if len(ok) else M[0]


def _edit_marker(cfg: Config, names) -> int:
    """The index of ``edit_marker`` among the capture's markers (exact, else ignoring
    case; the default ``Mouth_Lend`` is the synthetic face's ``mouth_corner_l``); an
    unknown name is refused, listing the near matches."""
    import difflib

    names = [str(n) for n in names]
    want = cfg.edit_marker
    if cfg.file == SYNTHETIC and want == Config.edit_marker:
        want = "mouth_corner_l"  # the same marker, the synthetic face's name
    if want in names:
        return names.index(want)
    low = [n.lower() for n in names]
    if want.lower() in low:
        return low.index(want.lower())
    near = difflib.get_close_matches(want.lower(), low, n=4, cutoff=0.5)
    near = [names[low.index(n)] for n in near]
    raise ConfigError(
        f"edit_marker {cfg.edit_marker!r} is not a marker of {cfg.file}"
        + (f"; did you mean {near}?" if near else "")
        + f" (its markers: {names[:8]}{' …' if len(names) > 8 else ''})"
    )
