"""The planner: a config (a TOML, a run folder or a dict) resolved into validated runs
(`RunSpec`, `resolve_config`), and the checks a plan passes before any run starts (a
finished run of another config, or files fxspace did not write, are never overwritten
without ``force``)."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from types import ModuleType
from typing import Any, NamedTuple

from fxspace.config import (
    ConfigError,
    config_from_dict,
    config_to_dict,
    dumps_toml,
    expand_sweep,
    load_toml,
)
from fxspace.pipelines._registry import available, load_pipeline
from fxspace.runs import MANIFEST, clean_run, read_regular

# the files fxspace writes at the top of every run folder
_RUN_FILES = ("config.toml", "meta.json", "metrics.json", "status.json")


def _resolve_paths(cfg_raw: dict[str, Any], base_dir: Path | None) -> dict[str, Any]:
    """``data.paths`` entries (and ``data.clips``' ``path`` / ``asf``) relative to the
    config file's folder become absolute."""
    data = cfg_raw.get("data")
    if base_dir is None or not isinstance(data, dict):
        return cfg_raw

    def absolute(p: Any) -> Any:
        if not isinstance(p, str) or not p:
            return p
        return str(Path(p).expanduser() if Path(p).expanduser().is_absolute() else base_dir / p)

    if isinstance(data.get("paths"), list):
        data = {**data, "paths": [absolute(p) for p in data["paths"]]}
    if isinstance(data.get("clips"), list):
        data = {**data, "clips": [
            {**c, **{k: absolute(c[k]) for k in ("path", "asf") if k in c}}
            if isinstance(c, dict) else c
            for c in data["clips"]
        ]}  # fmt: skip
    return {**cfg_raw, "data": data}


def _data_files(mod: Any, cfg: Any) -> list[Path]:
    """The data files a run reads (for its content key): the pipeline's ``data_files(cfg)``,
    else the files of every `fxspace.datasets.FaceData` table in the config."""
    fn = getattr(mod, "data_files", None)
    if callable(fn):
        return list(fn(cfg))
    from fxspace.datasets import FaceData, face_data_files

    files: list[Path] = []
    for f in dataclasses.fields(cfg):
        v = getattr(cfg, f.name)
        if isinstance(v, FaceData):
            files += face_data_files(v)
    return files


def _changed_keys(old: str, new: str) -> list[str]:
    a = [ln for ln in old.splitlines() if ln.strip()]
    b = [ln for ln in new.splitlines() if ln.strip()]
    diff = [ln for ln in b if ln not in a] + [ln for ln in a if ln not in b]
    return sorted({ln.split("=")[0].strip() for ln in diff if "=" in ln})


def _check_seed(seed: Any) -> int:
    if isinstance(seed, bool) or not isinstance(seed, int) or not 0 <= seed < 2**32:
        raise ConfigError(f"seed must be an integer in [0, 2**32), got {seed!r}")
    return seed


class RunSpec(NamedTuple):
    """One run a config describes (`resolve_config`): its `pipeline` module, `run_dir`,
    validated `config` (the pipeline's ``Config``), `seed`, `text` (the resolved TOML a run
    folder keeps as ``config.toml``) and the sweep `label` (``""`` for a single run)."""

    pipeline: ModuleType
    run_dir: Path
    config: Any
    seed: int
    text: str
    label: str


def resolve_config(
    config: str | Path | dict[str, Any],
    out: str | Path | None = None,
    *,
    experiment: str | tuple[str, ...] | None = None,
) -> list[RunSpec]:
    """The runs a config describes, each resolved and validated: the one room where a
    TOML becomes runs (`run_config`, `fxspace sweep` and every studio app read it here).

    **Arguments:**

    - `config`: a TOML file, a run folder (its ``config.toml``) or a dict.
    - `out`: the output folder (default: the run folder itself, ``runs/<file stem>`` for a
      file, ``runs/config`` for a dict); a ``[sweep]``'s runs are sub-folders.
    - `experiment`: the experiment(s) the caller can open; another is refused naming both.

    **Returns:** one `RunSpec` per run (all of a ``[sweep]``, in its order); relative
    ``data.paths`` resolve against the config file's folder.

    **Example:**

    ```python
    (spec,) = fx.pipelines.resolve_config("configs/navigation.toml")
    spec.config.hierarchy.c0, spec.seed, spec.run_dir   # (10, 0, PosixPath('runs/navigation'))
    ```
    """
    where, base_dir = "", None
    if isinstance(config, dict):
        raw, default_out = config, Path("runs") / "config"
    elif isinstance(config, str | Path):
        p = Path(config)
        f = p / "config.toml" if p.is_dir() else p
        if not f.is_file():
            raise ConfigError(f"{config}: not a config file nor a run folder with config.toml")
        raw, where, base_dir = load_toml(f), f"{f}: ", f.resolve().parent
        default_out = p if p.is_dir() else Path("runs") / p.stem
    else:
        raise ConfigError(
            f"config must be a TOML path, a run folder or a dict, got {type(config).__name__}"
        )
    if experiment is not None:
        allowed = (experiment,) if isinstance(experiment, str) else tuple(experiment)
        if isinstance(raw, dict) and raw.get("experiment") not in allowed:
            raise ConfigError(
                f"{where}experiment must be {' or '.join(map(repr, allowed))}, "
                f"got {raw.get('experiment')!r}"
            )
    if isinstance(raw, dict) and "search" in raw:
        raise ConfigError(f"{where}a [search] config runs through fxspace sweep CONFIG")
    try:
        plan = _plan(raw, Path(out) if out is not None else default_out, base_dir)
    except ConfigError as e:
        if where and not str(e).startswith(where):
            raise ConfigError(f"{where}{e}") from None
        raise
    return plan


def _plan(raw: dict[str, Any], out: Path, base_dir: Path | None) -> list[RunSpec]:
    """Resolve and validate every run of the config (all of a ``[sweep]``) up front."""
    if not isinstance(raw, dict):
        raise ConfigError(f"a config must be a table (dict), got {type(raw).__name__}")
    if "experiment" not in raw:
        raise ConfigError(f"config has no 'experiment' key; set it to one of {available()}")
    mod = load_pipeline(raw["experiment"])
    plan = []
    for label, cfg_raw in expand_sweep(raw):
        seed = _check_seed(cfg_raw.get("seed", 0))
        cfg_raw = _resolve_paths(cfg_raw, base_dir)
        body = {k: v for k, v in cfg_raw.items() if k not in ("experiment", "seed", "name")}
        where = f" (sweep run {label})" if label else ""
        try:
            cfg = config_from_dict(mod.Config, body)
            cfg.validate()  # the Pipeline protocol: every config check, before any run
        except ConfigError as e:
            raise ConfigError(f"{e}{where}") from None
        resolved = {"experiment": raw["experiment"], "seed": seed, **config_to_dict(cfg)}
        plan.append(
            RunSpec(mod, out / label if label else out, cfg, seed, dumps_toml(resolved), label)
        )
    return plan


def _is_run_folder(d: Path) -> bool:
    return (d / MANIFEST).is_file() or (d / "status.json").is_file()


def _refuse_overwrite(plan: list[tuple], out: Path, force: bool) -> None:
    """A finished run of another config, or files fxspace did not write under the names
    it writes, are never overwritten without ``force``."""
    if force:
        return
    dirs = [p.run_dir for p in plan]
    if dirs != [out] and (out / "metrics.json").is_file() and _is_run_folder(out):
        raise ConfigError(
            f"{out} holds a finished run of another experiment; pass --force to replace "
            "it, or choose another --out"
        )
    for run_dir, text in ((p.run_dir, p.text) for p in plan):
        cfg_p = run_dir / "config.toml"
        if not _is_run_folder(run_dir):
            theirs = [n for n in _RUN_FILES if (run_dir / n).exists()]
            if theirs:
                raise ConfigError(
                    f"{run_dir} holds {', '.join(theirs)} that fxspace did not write; "
                    "choose another --out (or pass --force to overwrite them)"
                )
            continue
        if (run_dir / "metrics.json").is_file() and cfg_p.is_file():
            old = (read_regular(cfg_p) or b"").decode("utf-8", "replace")
            if old != text:
                raise ConfigError(
                    f"{run_dir} holds a finished run of a different config (changed: "
                    f"{', '.join(_changed_keys(old, text)) or 'formatting'}); pass --force "
                    "to overwrite it, or choose another --out"
                )


def _clean_tree(out: Path, plan: list[tuple] = ()) -> None:
    """``--force``: delete the files fxspace wrote in ``out`` (when it is itself an old
    run) and in this config's own run folders, so no old figure or array sits beside
    the new results. Any other run nested under ``out`` is never touched."""
    if not out.is_dir():
        return
    dirs = [out, *(p.run_dir for p in plan)]
    for d in dict.fromkeys(dirs):
        if (d / MANIFEST).is_file():
            clean_run(d)
