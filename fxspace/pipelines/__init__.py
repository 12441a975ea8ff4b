"""Experiment pipelines, each driven by one config file.

A config's ``experiment = "NAME"`` selects the module ``fxspace.pipelines.NAME``,
which defines a frozen dataclass ``Config`` and ``run(cfg, run_dir, seed) -> dict``
(the metrics). :func:`run_config` resolves the config, expands a ``[sweep]`` table,
writes ``config.toml`` and ``meta.json`` first and ``metrics.json`` last (atomically),
and skips runs whose ``metrics.json`` already exists for the same content key (resolved
config + data digests + code digest), so an interrupted sweep resumes; ``status.json``
marks a run ``running``, ``complete``, ``failed`` or ``interrupted``.
"""

from __future__ import annotations

import dataclasses
import importlib
import json
import re
import time
from pathlib import Path
from typing import Any

from fxspace.config import (
    ConfigError,
    config_from_dict,
    config_to_dict,
    dumps_toml,
    expand_sweep,
    load_toml,
)
from fxspace.runs import (
    read_status,
    reset_cache,
    run_key,
    write_json_atomic,
    write_meta,
    write_status,
    write_text_atomic,
)

__all__ = ["run_config", "run_dict", "load_pipeline", "available"]

_NAME = re.compile(r"^[a-z_][a-z0-9_]*$")


def available() -> list[str]:
    here = Path(__file__).parent
    return sorted(p.stem for p in here.glob("*.py") if not p.stem.startswith("_"))


def load_pipeline(name: str) -> Any:
    if not isinstance(name, str) or not _NAME.match(name) or name not in available():
        raise ConfigError(f"experiment = {name!r} is not known; choose one of {available()}")
    return importlib.import_module(f"{__name__}.{name}")


def _resolve_paths(cfg_raw: dict[str, Any], base_dir: Path | None) -> dict[str, Any]:
    """``data.paths`` entries relative to the config file's folder become absolute."""
    data = cfg_raw.get("data")
    if base_dir is None or not isinstance(data, dict) or not isinstance(data.get("paths"), list):
        return cfg_raw
    paths = [
        str(Path(p).expanduser() if Path(p).expanduser().is_absolute() else base_dir / p)
        if isinstance(p, str)
        else p
        for p in data["paths"]
    ]
    return {**cfg_raw, "data": {**data, "paths": paths}}


def _data_files(mod: Any, cfg: Any) -> list[Path]:
    """The data files a run reads (for its content key): the pipeline's ``data_files(cfg)``,
    else the files of every :class:`~fxspace.datasets.FaceData` table in the config."""
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


def _plan(raw: dict[str, Any], out: Path, base_dir: Path | None) -> list[tuple]:
    """Resolve and validate every run of the config (all of a ``[sweep]``) up front."""
    if "experiment" not in raw:
        raise ConfigError(f"config has no 'experiment' key; set it to one of {available()}")
    mod = load_pipeline(raw["experiment"])
    plan = []
    for label, cfg_raw in expand_sweep(raw):
        seed = cfg_raw.get("seed", 0)
        if isinstance(seed, bool) or not isinstance(seed, int) or not 0 <= seed < 2**32:
            raise ConfigError(f"seed must be an integer in [0, 2**32), got {seed!r}")
        cfg_raw = _resolve_paths(cfg_raw, base_dir)
        body = {k: v for k, v in cfg_raw.items() if k not in ("experiment", "seed", "name")}
        where = f" (sweep run {label})" if label else ""
        try:
            cfg = config_from_dict(mod.Config, body)
        except ConfigError as e:
            raise ConfigError(f"{e}{where}") from None
        resolved = {"experiment": raw["experiment"], "seed": seed, **config_to_dict(cfg)}
        plan.append((out / label if label else out, cfg, seed, dumps_toml(resolved)))
    return [(mod, *p) for p in plan]


def run_dict(
    raw: dict[str, Any], out: str | Path, force: bool = False, base_dir: str | Path | None = None
) -> list[Path]:
    """Run the experiment(s) described by the config dict ``raw`` under ``out``.

    Every run of a ``[sweep]`` is resolved and validated before the first starts. A run
    whose ``metrics.json`` exists for the same config, data and code (its content key) is
    skipped; a folder holding a finished run of a *different* config is an error unless
    ``force``; ``force`` also clears the run's cache. ``base_dir`` is the folder relative
    ``data.paths`` resolve against (the config file's folder for :func:`run_config`).
    """
    out = Path(out)
    plan = _plan(raw, out, None if base_dir is None else Path(base_dir))
    for _, run_dir, _, _, text in plan:
        cfg_p = run_dir / "config.toml"
        if not force and (run_dir / "metrics.json").is_file() and cfg_p.is_file():
            old = cfg_p.read_text()
            if old != text:
                raise ConfigError(
                    f"{run_dir} holds a finished run of a different config (changed: "
                    f"{', '.join(_changed_keys(old, text)) or 'formatting'}); pass --force "
                    "to overwrite it, or choose another --out"
                )
    done = []
    for mod, run_dir, cfg, seed, text in plan:
        metrics_p = run_dir / "metrics.json"
        key = run_key(text, _data_files(mod, cfg))
        st = read_status(run_dir)
        if not force and metrics_p.is_file() and st.get("status") == "complete":
            if st.get("key") == key:
                print(
                    f"[fxspace] {run_dir}: already complete (metrics.json present); --force reruns"
                )
                done.append(run_dir)
                continue
            print(f"[fxspace] {run_dir}: data or code changed since the finished run; rerunning")
        run_dir.mkdir(parents=True, exist_ok=True)
        if metrics_p.exists():
            metrics_p.unlink()
        reset_cache(run_dir, key, force=force)
        write_status(run_dir, "running", key=key)
        write_text_atomic(run_dir / "config.toml", text)
        write_meta(run_dir, seed, {"experiment": raw["experiment"], "run_key": key})
        t0 = time.perf_counter()
        try:
            metrics = dict(mod.run(cfg, run_dir, seed))
        except KeyboardInterrupt:
            write_status(run_dir, "interrupted", key=key, note="rerun the same command to resume")
            raise
        except BaseException as e:
            write_status(run_dir, "failed", key=key, error=f"{type(e).__name__}: {e}")
            raise
        metrics.setdefault("wall_time_s", time.perf_counter() - t0)
        write_json_atomic(metrics_p, metrics)
        write_status(run_dir, "complete", key=key)
        print(f"[fxspace] wrote {run_dir}")
        done.append(run_dir)
    return done


def run_config(path: str | Path, out: str | Path | None = None, force: bool = False) -> list[Path]:
    """Run the experiment described by the TOML file at ``path``.

    The default output folder is ``runs/<config file stem>``; relative ``data.paths``
    resolve against the config file's folder (absolute paths are kept).
    """
    raw = load_toml(path)
    if out is None:
        out = Path("runs") / Path(path).stem
    return run_dict(raw, out, force=force, base_dir=Path(path).resolve().parent)


def summary(run_dir: str | Path) -> dict[str, Any]:
    return json.loads((Path(run_dir) / "metrics.json").read_text())
