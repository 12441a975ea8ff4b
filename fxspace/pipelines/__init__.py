"""Experiment pipelines, each driven by one config file.

A config's ``experiment = "NAME"`` selects the module ``fxspace.pipelines.NAME``,
which defines a frozen dataclass ``Config`` and ``run(cfg, run_dir, seed) -> dict``
(the metrics). :func:`run_config` resolves the config, expands a ``[sweep]`` table,
writes ``config.toml`` and ``meta.json`` first and ``metrics.json`` last (atomically),
and skips runs whose ``metrics.json`` already exists for the same resolved config
(so an interrupted sweep resumes).
"""

from __future__ import annotations

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
from fxspace.runs import write_json_atomic, write_meta, write_text_atomic

__all__ = ["run_config", "run_dict", "load_pipeline", "available"]

_NAME = re.compile(r"^[a-z_][a-z0-9_]*$")


def available() -> list[str]:
    here = Path(__file__).parent
    return sorted(p.stem for p in here.glob("*.py") if not p.stem.startswith("_"))


def load_pipeline(name: str) -> Any:
    if not isinstance(name, str) or not _NAME.match(name) or name not in available():
        raise ConfigError(f"experiment = {name!r} is not known; choose one of {available()}")
    return importlib.import_module(f"{__name__}.{name}")


def run_dict(raw: dict[str, Any], out: str | Path, force: bool = False) -> list[Path]:
    """Run the experiment(s) described by the config dict ``raw`` under ``out``."""
    if "experiment" not in raw:
        raise ConfigError(f"config has no 'experiment' key; set it to one of {available()}")
    mod = load_pipeline(raw["experiment"])
    runs = expand_sweep(raw)
    out = Path(out)
    done = []
    for label, cfg_raw in runs:
        seed = cfg_raw.get("seed", 0)
        if isinstance(seed, bool) or not isinstance(seed, int):
            raise ConfigError(f"seed must be an integer, got {seed!r}")
        body = {k: v for k, v in cfg_raw.items() if k not in ("experiment", "seed", "name")}
        cfg = config_from_dict(mod.Config, body)
        resolved = {"experiment": raw["experiment"], "seed": seed, **config_to_dict(cfg)}
        text = dumps_toml(resolved)
        run_dir = out / label if label else out
        metrics_p = run_dir / "metrics.json"
        cfg_p = run_dir / "config.toml"
        if not force and metrics_p.is_file() and cfg_p.is_file() and cfg_p.read_text() == text:
            print(f"[fxspace] {run_dir}: already complete (metrics.json present); --force reruns")
            done.append(run_dir)
            continue
        run_dir.mkdir(parents=True, exist_ok=True)
        if metrics_p.exists():
            metrics_p.unlink()
        write_text_atomic(cfg_p, text)
        write_meta(run_dir, seed, {"experiment": raw["experiment"]})
        t0 = time.perf_counter()
        metrics = mod.run(cfg, run_dir, seed)
        metrics = dict(metrics)
        metrics.setdefault("wall_time_s", time.perf_counter() - t0)
        write_json_atomic(metrics_p, metrics)
        print(f"[fxspace] wrote {run_dir}")
        done.append(run_dir)
    return done


def run_config(path: str | Path, out: str | Path | None = None, force: bool = False) -> list[Path]:
    """Run the experiment described by the TOML file at ``path``.

    The default output folder is ``runs/<config file stem>``.
    """
    raw = load_toml(path)
    if out is None:
        out = Path("runs") / Path(path).stem
    return run_dict(raw, out, force=force)


def summary(run_dir: str | Path) -> dict[str, Any]:
    return json.loads((Path(run_dir) / "metrics.json").read_text())
