"""The clips of a ``parametric_synthesis`` run: the shipped takes by name (`take_files`,
`load_take`), one's own files (`read_clip`: units declared or inferred, checked against an
adult's leg), the files a run reads (`data_files`) and a set-up built from them."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from fxspace import motion as M
from fxspace._progress import note
from fxspace.config import ConfigError
from fxspace.data import data_path
from fxspace.errors import CorruptFileError, FxspaceError
from fxspace.io import Motion, read_amc, read_bvh
from fxspace.pipelines._synthesis_config import Config


def take_files(take: str) -> list[Path]:
    """The data files of a clip: Bandai Namco ``dataset-…`` (one BVH) or CMU ``SSS_TT``
    (the subject's ASF and the take's AMC)."""
    if take.startswith("dataset-"):
        return [data_path("body", "bandai", f"{take}.bvh.gz")]
    subj = take.split("_")[0]
    return [data_path("body", "cmu", subj, f"{subj}.asf"),
            data_path("body", "cmu", subj, f"{take}.amc.gz")]  # fmt: skip


def _clip_asf(clip: M.SetupClip) -> Path:
    """An AMC clip's skeleton: its ``asf``, else ``<subject>.asf`` beside it (CMU-style
    ``SSS_TT.amc``), else the only ``.asf`` there."""
    if clip.asf:
        return Path(clip.asf)
    p = Path(clip.path)
    cand = p.parent / f"{p.name.split('_')[0].split('.')[0]}.asf"
    if cand.is_file():
        return cand
    asfs = sorted(p.parent.glob("*.asf"))
    if len(asfs) == 1:
        return asfs[0]
    raise ConfigError(
        f"data.clips: {clip.path}: an AMC needs its skeleton; set asf = \"…/subject.asf\" "
        f"({'none' if not asfs else len(asfs)} .asf beside it)"
    )


def _is_amc(path: str) -> bool:
    return path.lower().endswith((".amc", ".amc.gz"))


def data_files(cfg: Config) -> list[Path]:
    """The files a run reads (for its content key): every clip of every set-up, so a run
    (and its stored set-up) is never served after a clip changed on disk."""
    files: list[Path] = []
    if cfg.data.source == "files":
        for c in cfg.data.clips:
            for f in ([_clip_asf(c)] if _is_amc(c.path) else []) + [Path(c.path)]:
                files += [f] if f not in files else []
        return files
    for name in cfg.setups:
        for takes in M.setup_takes(name, cfg.data):
            for t in takes:
                files += [f for f in take_files(t) if f not in files]
    return files


def load_take(take: str, stride: int = 4) -> Motion:
    """A clip by take name: Bandai Namco ``dataset-…`` (BVH, cm, static root dropped) or CMU
    ``SSS_TT`` (ASF/AMC, every ``stride``-th frame)."""
    files = take_files(take)
    if take.startswith("dataset-"):
        return M.drop_root(read_bvh(files[0], scale=0.01))
    return read_amc(*files).frames(slice(None, None, stride))


def read_clip(
    clip: M.SetupClip,
    data: M.SetupData | None = None,
    stride: int = 4,
    skeleton: M.SkeletonSpec | None = None,
) -> tuple[Motion, dict]:
    """One's own clip (``[[data.clips]]``) in metres, and a record of what was read.

    A BVH's lengths are converted by its ``units`` (the clip's, else ``data.units``):
    declared (`fxspace.motion.LENGTH_UNITS` or metres per unit) or ``"auto"``, inferred by
    `fxspace.io.read_bvh` from the rest skeleton's size and checked against an adult's leg
    (a leg outside 0.59–1.15 m is refused, asking for the unit); a static root above the
    hips (Bandai Namco's ``joint_Root``) is dropped; every ``stride``-th frame is kept
    (the clip's ``stride``, else 1). An AMC is read with its ASF (`read_amc`, metres),
    every ``stride``-th frame (the clip's, else the config's). Says on the console what
    was read: file, label, frames, rate, units and how they were found, joint names.

    **Returns:** ``(motion, record)``: record keys ``path``, ``part``, ``label``, ``units``,
    ``units_from`` (``declared`` / ``inferred …``), ``metres_per_unit``, ``frames``,
    ``rate_hz``, ``stride``, ``joint_convention`` (and ``asf`` for an AMC).
    """
    data = M.SetupData() if data is None else data
    skeleton = M.SkeletonSpec() if skeleton is None else skeleton
    p = Path(clip.path)
    rec: dict = {"path": str(p), "part": clip.part, "label": clip.name}
    if _is_amc(clip.path):
        asf = _clip_asf(clip)
        k = clip.stride or stride
        m = read_amc(asf, p, rate=clip.rate or 120.0).frames(slice(None, None, k))
        jm = skeleton.joint_map(m.names, required=(), what=str(p))
        rec |= {"asf": str(asf), "units": "m", "units_from": "ASF (converted by read_amc)",
                "metres_per_unit": M.LENGTH_UNITS["cmu"], "stride": k}  # fmt: skip
    else:
        units = clip.units or data.units
        if isinstance(units, str) and units in _READ_BVH_UNITS:  # read_bvh converts, says so
            try:
                m = read_bvh(p, units=units)
            except FxspaceError as e:
                if isinstance(e, CorruptFileError) or units != "auto":
                    raise
                raise ConfigError(f"data.clips: {e}; {_DECLARE}") from None
            scale = None if units == "auto" else M.LENGTH_UNITS[units]
        else:  # the CMU unit, or metres per file unit
            scale = M.LENGTH_UNITS[units] if isinstance(units, str) else float(units)
            m = read_bvh(p, scale=scale)
        jm = skeleton.joint_map(m.names, required=(), what=str(p))
        if units == "auto":
            _check_leg(_leg_m(m, jm), p)
        if "hips" in jm and jm.index("hips") == 1 and m.parents.count(0) == 1:
            m = M.drop_root(m)  # a static root above the hips (Bandai Namco's joint_Root)
            jm = skeleton.joint_map(m.names, required=(), what=str(p))
        k = clip.stride or 1
        m = m.frames(slice(None, None, k))
        rec |= {"units": units, "metres_per_unit": scale, "stride": k,
                "units_from": "inferred by fxspace.io.read_bvh from the rest skeleton's size"
                if units == "auto" else "declared"}  # fmt: skip
    rec |= {"frames": m.num_frames, "rate_hz": float(m.rate), "joint_convention": jm.convention,
            "leg_m": _leg_m(m, jm)}  # fmt: skip
    note(
        f"{p.name}: {clip.part} clip {rec['label']!r}, {m.num_frames} frames at "
        f"{m.rate:.4g} Hz, units {rec['units']} ({rec['units_from']}), leg "
        f"{rec['leg_m']:.3g} m, joints: {jm.describe()}"
    )
    return m, rec


# the units fxspace.io.read_bvh converts itself (and says so on the console)
_READ_BVH_UNITS = ("auto", "m", "cm", "mm", "in", "ft")


def _leg_m(m: Motion, jm) -> float:
    """The left hip-to-ankle length (m) by role; NaN where the roles are missing."""
    off = np.asarray(m.offsets)
    roles = ("left_lower_leg", "left_foot")
    if not all(r in jm for r in roles):
        return float("nan")
    return float(sum(np.linalg.norm(off[jm.index(r)]) for r in roles))


def _check_leg(leg: float, path: Path) -> None:
    """A clip whose units were inferred must have an adult's leg once in metres."""
    if np.isfinite(leg) and not 0.82 / 1.4 <= leg <= 0.82 * 1.4:
        raise ConfigError(
            f"data.clips: {path}: with its units inferred (fxspace.io.read_bvh) its leg is "
            f"{leg:.3g} m, not an adult's (~0.8 m); {_DECLARE}"
        )


_DECLARE = (
    f"declare the file's unit on the clip or in [data]: units = one of {list(M.LENGTH_UNITS)} "
    "('cmu' for the CMU BVH conversion) or metres per file unit"
)


def _setup_loader(cfg: Config):
    """``(load(take) -> Motion, records)``: the config's clips by take name (defaults) or
    path (``source = "files"``); ``records`` fills with what was read."""
    records: dict = {}
    if cfg.data.source != "files":

        def load(take: str) -> Motion:
            records.setdefault(take, {"take": take, "files": [str(f) for f in take_files(take)]})
            return load_take(take, cfg.stride)

        return load, records
    clips = {c.path: c for c in cfg.data.clips}

    def load_file(path: str) -> Motion:
        m, rec = read_clip(clips[path], cfg.data, cfg.stride, cfg.skeleton)
        records.setdefault(path, rec)
        return m

    return load_file, records


def _build_setup(name: str, cfg: Config, key) -> M.Setup:
    """`fxspace.motion.prepare_setup` on the config's clips, with the config's joint map;
    the clips read (and, for one's own files, the units they are written back in) go to
    the set-up's ``info``."""
    load, records = _setup_loader(cfg)
    st = M.prepare_setup(name, load, cfg.data, cfg.space, key, joints=cfg.skeleton)
    info = {**st.info, "clips": list(records.values()), "data_source": cfg.data.source}
    if cfg.data.source == "files":
        lower = M.setup_takes(name, cfg.data)[0]
        # written back in the first lower clip's unit (metres where read_bvh inferred it)
        scale = records[lower[0]]["metres_per_unit"] or 1.0
        return st._replace(scale=float(scale), info=info)
    return st._replace(info=info)
