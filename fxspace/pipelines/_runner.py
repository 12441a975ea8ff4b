"""The runner: one run in its folder, under its lock (`run_dict`): the content key, the
status, ``config.toml`` / ``meta.json`` first and ``metrics.json`` last, a finished run of
other code or data kept (never silently redone)."""

from __future__ import annotations

import os
import time
from pathlib import Path
from typing import Any

from fxspace import runs as _runs
from fxspace._compile_cache import compile_timer
from fxspace.config import ConfigError
from fxspace.pipelines._planner import (
    RunSpec,
    _clean_tree,
    _data_files,
    _plan,
    _refuse_overwrite,
)
from fxspace.runs import (
    UnsafePathError,
    active_run,
    clean_run,
    read_json,
    read_status,
    reset_cache,
    run_key,
    run_lock,
    update_meta,
    write_json_atomic,
    write_meta,
    write_status,
    write_text_atomic,
)


def _run_one(
    mod: Any,
    run_dir: Path,
    cfg: Any,
    seed: int,
    text: str,
    experiment: str,
    force: bool,
    wait: float | None = 0.0,
) -> Path:
    """One run, holding its folder's lock (`fxspace.runs.run_lock`) throughout; the
    overwrite checks are repeated under the lock (another process may have finished a
    run of another config there meanwhile)."""
    with run_lock(run_dir, wait=wait):
        if not force:
            _refuse_overwrite([RunSpec(mod, run_dir, cfg, seed, text, "")], run_dir, False)
        return _run_locked(mod, run_dir, cfg, seed, text, experiment, force)


def _what_changed(run_dir: Path, st: dict[str, Any]) -> str:
    """What differs from the finished run in ``run_dir``: fxspace's code (with the
    versions, where ``meta.json`` says) or the data."""
    if not st:
        return "a key fxspace cannot read (status.json is missing or damaged)"
    old_code = st.get("code")
    if not isinstance(old_code, str):
        return "other code or data (a run from before fxspace recorded which)"
    if old_code == _runs.code_digest()[:16]:
        return "other data (a data file's content changed)"
    try:
        meta = read_json(run_dir / "meta.json") or {}
    except (OSError, ValueError):
        meta = {}
    old_v = meta.get("versions", {}).get("fxspace") if isinstance(meta, dict) else None
    new_v = _runs.versions().get("fxspace")
    sha = meta.get("git_sha") if isinstance(meta, dict) else None
    tail = f", fxspace {old_v} → {new_v}" if old_v and old_v != new_v else ""
    tail += f", git {str(sha)[:12]}" if sha else ""
    return f"other fxspace code (its source changed since{tail})"


def _run_locked(
    mod: Any, run_dir: Path, cfg: Any, seed: int, text: str, experiment: str, force: bool
) -> Path:
    metrics_p = run_dir / "metrics.json"
    key = run_key(text, _data_files(mod, cfg))
    st = read_status(run_dir)
    if not force and os.path.lexists(metrics_p):
        same = st.get("key") == key
        if same and st.get("status") == "complete" and (run_dir / "config.toml").is_file():
            print(f"[fxspace] {run_dir}: already complete (metrics.json present); --force reruns")
            return run_dir
        if not same:
            # results are kept across versions: never silently replaced
            raise ConfigError(
                f"{run_dir} holds a finished run made with {_what_changed(run_dir, st)}; its "
                "results are kept: pass --force to replace them, or choose another --out to "
                "run beside them"
            )
        print(f"[fxspace] {run_dir}: the finished run's folder is incomplete; rerunning")
    kp = run_dir / "cache" / "KEY"
    old_key = st.get("key") or _runs._read_key(kp)
    if old_key is not None and old_key != key:
        clean_run(run_dir)  # another config's (or code's) files: stale beside the new ones
    run_dir.mkdir(parents=True, exist_ok=True)
    if os.path.lexists(metrics_p):
        if os.path.isdir(metrics_p) and not os.path.islink(metrics_p):
            raise UnsafePathError(
                f"{metrics_p} is a folder; fxspace writes its metrics there: move it away, "
                "or choose another --out"
            )
        metrics_p.unlink()  # marked unfinished first: a stop part-way is never "complete"
    code = _runs.code_digest()[:16]
    with active_run(run_dir, force=force):
        reset_cache(run_dir, key, force=force)
        write_status(run_dir, "running", key=key, code=code)
        write_text_atomic(run_dir / "config.toml", text)
        write_meta(run_dir, seed, {"experiment": experiment, "run_key": key})
        t0 = time.perf_counter()
        timer = compile_timer()  # meta.json "timing": compile vs compute, even if it fails
        try:
            with timer:
                metrics = dict(mod.run(cfg, run_dir, seed))
        except KeyboardInterrupt:
            write_status(run_dir, "interrupted", key=key, code=code,
                         note="rerun the same command to resume")  # fmt: skip
            raise
        except BaseException as e:
            write_status(run_dir, "failed", key=key, code=code, error=f"{type(e).__name__}: {e}")
            raise
        finally:
            update_meta(run_dir, {"timing": timer.summary()})
        metrics.setdefault("wall_time_s", time.perf_counter() - t0)
        write_json_atomic(metrics_p, metrics)
        write_status(run_dir, "complete", key=key, code=code)
    print(f"[fxspace] wrote {run_dir}")
    return run_dir


def run_dict(
    raw: dict[str, Any], out: str | Path, force: bool = False, base_dir: str | Path | None = None
) -> list[Path]:
    """Run the experiment(s) described by the config dict ``raw`` under ``out``.

    Every run of a ``[sweep]`` is resolved and validated (``cfg.validate()``) before the
    first starts. A run whose ``metrics.json`` exists for the same config, data and code
    (its content key) is skipped; a folder holding a finished run of a *different* config
    is an error unless ``force``. ``force`` reruns everything and first deletes the files
    fxspace wrote in ``out`` (its manifest: an old experiment's figures, arrays, cache);
    files fxspace did not write are never deleted. ``base_dir`` is the folder relative
    ``data.paths`` resolve against (the config file's folder for `run_config`).
    """
    out = Path(out)
    if isinstance(raw, dict) and "search" in raw:
        raise ConfigError(
            "a config with [search] runs through its file: fxspace sweep CONFIG (or "
            "fxspace run CONFIG for one trial after another)"
        )
    plan = _plan(raw, out, None if base_dir is None else Path(base_dir))
    _refuse_overwrite(plan, out, force)
    if force:
        _clean_tree(out, plan)
    return [
        _run_one(r.pipeline, r.run_dir, r.config, r.seed, r.text, raw["experiment"], force)
        for r in plan
    ]


def summary(run_dir: str | Path) -> dict[str, Any]:
    """The run's ``metrics.json`` (a `CorruptFileError` naming it when damaged)."""
    p = Path(run_dir) / "metrics.json"
    m = read_json(p)
    if m is None:
        raise FileNotFoundError(f"{p} does not exist: the run has not finished (fxspace run)")
    return m

