"""The commands that take a config file: `run_config` (``fxspace run CONFIG``: its runs,
or a ``[search]``'s trials one after another) and `prepare_config` (``fxspace studio
CONFIG``: only the stages the experiment's app shows)."""

from __future__ import annotations

import os
from pathlib import Path

from fxspace import runs as _runs
from fxspace.config import load_toml
from fxspace.pipelines._planner import _data_files, _plan, _refuse_overwrite
from fxspace.pipelines._runner import _what_changed, run_dict
from fxspace.pipelines._sweep import sweep_config
from fxspace.runs import (
    active_run,
    clean_run,
    read_status,
    reset_cache,
    run_key,
    run_lock,
    write_meta,
    write_status,
    write_text_atomic,
)


def run_config(path: str | Path, out: str | Path | None = None, force: bool = False) -> list[Path]:
    """Run the experiment described by the TOML file at ``path``.

    The default output folder is ``runs/<config file stem>``; relative ``data.paths``
    resolve against the config file's folder (absolute paths are kept).
    """
    raw = load_toml(path)
    if out is None:
        out = Path("runs") / Path(path).stem
    if "search" in raw:  # an Optuna search, here one trial after another
        res = sweep_config(path, out, workers=1, force=force, engine="serial")
        return [Path(r["run_dir"]) for r in res if r.get("status") == "complete"]
    return run_dict(raw, out, force=force, base_dir=Path(path).resolve().parent)


def prepare_config(path: str | Path, out: str | Path | None = None) -> Path:
    """The run folder an app opens for the config at ``path`` (its first run, for a
    ``[sweep]``): a finished run of the same config, data and code as it is; else, when
    the experiment has ``prepare_app``, only the stages its app shows, computed (or read)
    in the run's own folder under its content key, the run left ``partial`` (``fxspace
    run`` completes it, reusing them); else the whole run (`run_config`)."""
    raw = load_toml(path)
    out = Path("runs") / Path(path).stem if out is None else Path(out)
    plan = _plan(raw, out, Path(path).resolve().parent)
    mod, run_dir, cfg, seed, text, _ = plan[0]
    prep = getattr(mod, "prepare_app", None)
    if prep is None:
        return run_config(path, out)[0]
    with run_lock(run_dir, wait=0.0):
        _refuse_overwrite([plan[0]], run_dir, False)
        key = run_key(text, _data_files(mod, cfg))
        st = read_status(run_dir)
        if (run_dir / "metrics.json").is_file() and st.get("key") == key:
            return run_dir  # a finished run: the app reads it
        if os.path.lexists(run_dir / "metrics.json"):
            # kept across versions: shown as it is, never cleared for the app's stages
            print(f"[fxspace] {run_dir} holds a finished run made with "
                  f"{_what_changed(run_dir, st)}; the app shows it as it is (fxspace run "
                  f"{path} --force redoes it, or pass another --out)")  # fmt: skip
            return run_dir
        kp = run_dir / "cache" / "KEY"
        old_key = st.get("key") or _runs._read_key(kp)
        if old_key is not None and old_key != key:
            clean_run(run_dir)
        run_dir.mkdir(parents=True, exist_ok=True)
        with active_run(run_dir):
            reset_cache(run_dir, key)
            write_text_atomic(run_dir / "config.toml", text)
            write_meta(run_dir, seed, {"experiment": raw["experiment"], "run_key": key})
            write_status(run_dir, "partial", key=key,
                         note="the app's stages only; fxspace run completes the run")  # fmt: skip
            prep(cfg, run_dir, seed)
    print(f"[fxspace] {run_dir}: the app's stages are ready (fxspace run {path} completes it)")
    return run_dir

