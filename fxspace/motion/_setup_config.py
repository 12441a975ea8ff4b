"""What a set-up of Ha & Han's Table 1 reads (`fxspace.motion.prepare_setup`): its name
(`SETUPS`), its clips (`SetupData`: the default Bandai Namco / CMU takes, or one's own
files as `SetupClip` entries) with their labels (`setup_takes`, `setup_labels`), and how
its spaces are sampled (`SetupSpace`).
"""

from __future__ import annotations

import dataclasses
from typing import Literal

import numpy as np

from fxspace.config import ConfigError
from fxspace.errors import FxspaceError

__all__ = [
    "SetupName",
    "SETUPS",
    "SetupClip",
    "SetupData",
    "SetupSpace",
    "setup_takes",
    "setup_labels",
]

SetupName = Literal["mood_walk", "block_walk", "block_kick"]
SETUPS: tuple[str, ...] = ("mood_walk", "block_walk", "block_kick")

_B = "dataset-2_walk"
_WALKS = tuple(
    [f"{_B}_normal_00{i}" for i in (1, 2, 3, 4)]
    + [f"{_B}-turn-left_normal_00{i}" for i in (1, 2, 3, 4)]
    + [f"{_B}-turn-right_normal_00{i}" for i in (1, 2, 3, 4)]
)
DEFAULTS: dict[str, tuple[tuple[str, ...], tuple[str, ...]]] = {
    "mood_walk": (_WALKS[:2] + _WALKS[4:], ("dataset-1_walk_happy_001", "dataset-1_walk_sad_001")),
    "block_walk": (_WALKS, tuple(f"dataset-2_raise-up-left-hand_normal_{i:03d}"
                                 for i in range(1, 13))),
    "block_kick": (("135_04", "135_07", "135_11"), ("135_05", "135_10", "135_09")),
}  # fmt: skip

# labels of the default clips where the take name does not say it (Ha & Han's mood walk)
DEFAULT_LABELS: dict[str, tuple[tuple[str, ...], tuple[str, ...]]] = {
    "mood_walk": ((), ("joy", "sad")),
}
_CLIP_SUFFIXES = (".bvh", ".bvh.gz", ".amc", ".amc.gz")


@dataclasses.dataclass(frozen=True)
class SetupClip:
    """One of one's own clips (``[[data.clips]]`` of a config; ``SetupData.source =
    "files"``).

    - ``path``: a BVH (``.bvh``, ``.bvh.gz``) or an AMC (``.amc``, ``.amc.gz``) file.
    - ``part``: ``"lower"`` (the lower-body examples: walks, kicks) or ``"upper"`` (the
      upper body: moods, hand raises, blocks).
    - ``label``: what the clip is (``"proud"``); default the file name. The mood walk's
      two upper labels name its weight axis (``"proud weight (tired = 1 − proud)"``).
    - ``asf``: an AMC's skeleton (default ``<subject>.asf`` beside it, CMU-style).
    - ``units``: a BVH's length unit (`fxspace.motion.LENGTH_UNITS` name, or metres per
      file unit); ``""``: the data table's ``units``.
    - ``stride``: keep every ``stride``-th frame (0: the config's ``stride`` for AMC, 1 for
      BVH); ``rate``: an AMC's frame rate (0: CMU's 120 Hz).
    """

    path: str
    part: Literal["lower", "upper"] = "lower"
    label: str = ""
    asf: str = ""
    units: str | float = ""
    stride: int = 0
    rate: float = 0.0

    def validate(self) -> None:
        if not isinstance(self.path, str) or not self.path.lower().endswith(_CLIP_SUFFIXES):
            raise ConfigError(
                f"data.clips: path {self.path!r} must be a BVH (.bvh, .bvh.gz) or an AMC "
                "(.amc, .amc.gz) file"
            )
        if self.part not in ("lower", "upper"):
            raise ConfigError(
                f"data.clips: {self.path}: part must be 'lower' or 'upper', got {self.part!r}"
            )
        _check_units(self.units, f"data.clips: {self.path}: units", allow_empty=True)
        if self.stride < 0 or not self.rate >= 0:
            raise ConfigError(f"data.clips: {self.path}: stride and rate must be >= 0")

    @property
    def name(self) -> str:
        """The label, else the file name without its extension."""
        if self.label:
            return self.label
        base = self.path.replace("\\", "/").rsplit("/", 1)[-1]
        for suf in sorted(_CLIP_SUFFIXES, key=len, reverse=True):
            if base.lower().endswith(suf):
                return base[: -len(suf)]
        return base


def _check_units(units, where: str, allow_empty: bool = False) -> None:
    from fxspace.joints import LENGTH_UNITS

    if isinstance(units, str):
        if units in LENGTH_UNITS or units == "auto" or (allow_empty and units == ""):
            return
    elif isinstance(units, int | float) and not isinstance(units, bool) and units > 0:
        if np.isfinite(units):
            return
    raise ConfigError(
        f"{where} must be 'auto' (inferred from the skeleton's size), one of "
        f"{list(LENGTH_UNITS)} or metres per file unit (a positive number), got {units!r}"
    )


@dataclasses.dataclass(frozen=True)
class SetupData:
    """Clips of a set-up and how they are cut.

    - ``source``: ``"default"`` (the set-up's Bandai Namco / CMU takes under the data root,
      or those named by ``lower`` / ``upper``) or ``"files"`` (``clips``, one's own).
    - ``lower`` / ``upper``: take names (``source = "default"``; empty: the defaults).
    - ``clips``: `SetupClip` entries (``source = "files"``).
    - ``units``: the BVH files' length unit: ``"auto"`` (inferred by `fxspace.io.read_bvh`
      from the skeleton's size, said on the console, checked against an adult's leg), a
      `fxspace.motion.LENGTH_UNITS` name (``"cm"`` for Bandai Namco, ``"cmu"`` for the CMU
      BVH conversion) or metres per file unit.
    """

    lower: tuple[str, ...] = ()
    upper: tuple[str, ...] = ()
    cycles: int = 2  # gait cycles per walk clip
    max_reps: int = 4  # repetitions taken per karate take
    half_window_s: float = 1.0  # karate hand window around its key time
    source: Literal["default", "files"] = "default"
    clips: tuple[SetupClip, ...] = ()
    units: str | float = "auto"

    def validate(self) -> None:
        if self.source not in ("default", "files"):
            raise ConfigError(f"data.source must be 'default' or 'files', got {self.source!r}")
        _check_units(self.units, "data.units")
        if self.source == "files":
            if self.lower or self.upper:
                raise ConfigError(
                    "data.lower / data.upper name default takes; with data.source = 'files' "
                    "list the clips as data.clips = [{path = ..., part = 'lower'}, ...]"
                )
            parts = {c.part for c in self.clips}
            if parts != {"lower", "upper"}:
                raise ConfigError(
                    "data.source = 'files' needs data.clips with part = 'lower' and part = "
                    f"'upper' clips, e.g. [[data.clips]] path = 'walk_01.bvh', part = 'lower'; "
                    f"got parts {sorted(parts)}"
                )
            for c in self.clips:
                c.validate()
            paths = [c.path for c in self.clips]
            dup = sorted({p for p in paths if paths.count(p) > 1})
            if dup:
                raise ConfigError(f"data.clips lists {dup} more than once")
        elif self.clips:
            raise ConfigError("data.clips are read with data.source = 'files'; set it")


@dataclasses.dataclass(frozen=True)
class SetupSpace:
    """Sampling of both spaces (Kovar & Gleicher) and §3.2's re-placement ``k``."""

    n_samples: int = 1000
    knn_k: int = 6
    k_replace: int = 10
    concentration: float = 0.5
    max_active: int = 3
    posture_transfer: float = 1.0
    splice: str = "heck"  # "heck": spatial alignment + posture transfer; "heading"
    replace: str = "rotation"  # §3.2: "rotation" about the root (as printed) or "rigid"
    min_slope: float = 0.05
    max_clock_rate: float = 1.0  # eqs. 2–3 never rush a clock past this × its own rate


def setup_takes(name: str, data: SetupData = SetupData()) -> tuple[tuple[str, ...], ...]:
    """``(lower takes, upper takes)`` the set-up ``name`` reads: the clip paths of
    ``data.clips`` (``source = "files"``), ``data``'s take names, else its defaults
    (Bandai ``dataset-…`` or CMU ``SSS_TT`` names)."""
    if not isinstance(name, str) or name not in SETUPS:
        raise FxspaceError(f"unknown set-up {name!r}; choose one of {list(SETUPS)}")
    if not isinstance(data, SetupData):
        raise FxspaceError(f"data must be a SetupData, got {type(data).__name__}")
    if data.source == "files":
        return tuple(
            tuple(c.path for c in data.clips if c.part == part) for part in ("lower", "upper")
        )
    return tuple(data.lower or DEFAULTS[name][0]), tuple(data.upper or DEFAULTS[name][1])


def setup_labels(name: str, data: SetupData = SetupData()) -> tuple[tuple[str, ...], ...]:
    """``(lower labels, upper labels)``, one per take of `setup_takes`: the clips'
    ``label`` (else their file names) for ``source = "files"``; the mood walk's default
    upper clips are ``("joy", "sad")``; other takes are labelled by their names."""
    lower, upper = setup_takes(name, data)
    if data.source == "files":
        return tuple(
            tuple(c.name for c in data.clips if c.part == part) for part in ("lower", "upper")
        )
    out = []
    for takes, default, labels in zip(
        (lower, upper), DEFAULTS[name], DEFAULT_LABELS.get(name, ((), ())), strict=True
    ):
        out.append(tuple(labels) if labels and takes == default else tuple(takes))
    return out[0], out[1]
