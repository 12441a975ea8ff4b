"""Experiment pipelines, each driven by one config file.

A config's ``experiment = "NAME"`` selects the pipeline ``NAME``: a module
``fxspace.pipelines.NAME`` (or one added with `register`) that satisfies the `Pipeline`
protocol — a frozen dataclass ``Config`` with ``validate(self) -> None``, a module-level
``STAGES`` (its costly cached stages, in order), ``run(cfg, run_dir, seed) -> dict`` (the
metrics) and optionally ``data_files(cfg)``. A module is checked against the protocol when
it is loaded or registered (`check_pipeline`), so a malformed one fails with an error
naming what it lacks, before anything runs.

`run_config` resolves the config, expands a ``[sweep]`` table, validates every run
(``cfg.validate()``), writes ``config.toml`` and ``meta.json`` first and ``metrics.json``
last (atomically), and skips runs whose ``metrics.json`` already exists for the same
content key (resolved config + data digests + code digest), so an interrupted sweep
resumes; ``status.json`` marks a run ``running``, ``complete``, ``failed`` or
``interrupted``. Every file a run writes is listed in the run folder's manifest
(`fxspace.runs.record`): a rerun of another config deletes only those files, never a
user's, and never anything behind a symbolic link. A finished run is kept across
versions: rerunning it after fxspace's code or the data changed is refused, naming the
fix (``--force`` replaces it, another ``--out`` runs beside it), never silently redone.
"""

from __future__ import annotations

import dataclasses
import importlib
import inspect
import os
import re
import time
from pathlib import Path
from types import ModuleType
from typing import Any, NamedTuple, Protocol, runtime_checkable

from fxspace import runs as _runs
from fxspace._compile_cache import compile_timer
from fxspace.config import (
    ConfigError,
    config_from_dict,
    config_to_dict,
    dumps_toml,
    expand_sweep,
    load_toml,
)

# the config-level motion session (a TOML and its clips in, poses out): pipelines, not
# motion, since it reads the clips (fxspace.io, a layer above motion)
from fxspace.pipelines.parametric_synthesis import scripted_session as scripted_session  # noqa: E402
from fxspace.pipelines.parametric_synthesis import session_parameters as session_parameters  # noqa: E402,E501
from fxspace.runs import (
    MANIFEST,
    UnsafePathError,
    active_run,
    clean_run,
    read_json,
    read_regular,
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

__all__ = [
    "scripted_session",
    "session_parameters",
    "Pipeline",
    "PipelineConfig",
    "PipelineError",
    "check_pipeline",
    "register",
    "run_config",
    "run_dict",
    "prepare_config",
    "resolve_config",
    "RunSpec",
    "write_docs",
    "write_bench_page",
    "load_pipeline",
    "available",
    "sweep_config",
]

_NAME = re.compile(r"^[a-z_][a-z0-9_]*$")
_REGISTERED: dict[str, ModuleType] = {}
# the files fxspace writes at the top of every run folder
_RUN_FILES = ("config.toml", "meta.json", "metrics.json", "status.json")


class PipelineError(ConfigError):
    """A pipeline module does not satisfy the `Pipeline` protocol (names what it lacks)."""


@runtime_checkable
class PipelineConfig(Protocol):
    """A pipeline's ``Config``: a frozen dataclass whose ``validate`` raises
    `fxspace.config.ConfigError` naming the key for every config check."""

    def validate(self) -> None: ...


class Pipeline(Protocol):
    """What ``experiment = "NAME"`` runs: a module with these attributes.

    - ``Config``: a frozen dataclass (tables of the config file) with ``validate()``.
    - ``STAGES``: ``tuple[str, ...]``, its costly stages in order, each cached with
      `fxspace.runs.cached_arrays` (or `fxspace.runs.cached`) so an interrupted run resumes.
    - ``run(cfg, run_dir, seed) -> dict``: the run body, returning the metrics.
    - ``data_files(cfg)`` (optional): the files the run reads (part of its content key).
    - ``prepare_app(cfg, run_dir, seed) -> None`` (optional): only what the experiment's
      app shows, from the run's own cached stages (`prepare_config`: ``fxspace studio
      CONFIG`` opens the app without running the whole experiment; ``fxspace run``
      completes the run later, reusing those stages).
    - ``APP`` (optional): ``"module:function"`` of its browser app (``fxspace studio``
      reads it here: the one registry of experiments); ``APP_OPENS_CONFIG = True`` when
      the app builds what it shows from the config itself, with no run first.
    """

    Config: type[PipelineConfig]
    STAGES: tuple[str, ...]

    def run(self, cfg: Any, run_dir: Path, seed: int) -> dict[str, Any]: ...


def check_pipeline(mod: Any, name: str | None = None) -> Any:
    """``mod`` if it satisfies the `Pipeline` protocol, else a `PipelineError` naming
    every missing or malformed part (``Config``, ``Config.validate``, ``STAGES``, ``run``,
    ``data_files``)."""
    label = name or getattr(mod, "__name__", repr(mod))
    problems = []
    cfg = getattr(mod, "Config", None)
    if not (isinstance(cfg, type) and dataclasses.is_dataclass(cfg)):
        problems.append("a dataclass `Config`")
    else:
        if not cfg.__dataclass_params__.frozen:  # type: ignore[attr-defined]
            problems.append("`Config` frozen (@dataclasses.dataclass(frozen=True))")
        if not callable(getattr(cfg, "validate", None)):
            problems.append("a method `Config.validate(self) -> None`")
    stages = getattr(mod, "STAGES", None)
    if not (
        isinstance(stages, tuple)
        and all(isinstance(s, str) and _NAME.match(s) for s in stages)
        and len(set(stages)) == len(stages)
    ):
        problems.append("`STAGES`, a tuple of distinct stage names (e.g. ('geodesics',))")
    run = getattr(mod, "run", None)
    if not callable(run) or not _takes(run, 3):
        problems.append("a function `run(cfg, run_dir, seed) -> dict`")
    data_files = getattr(mod, "data_files", None)
    if data_files is not None and (not callable(data_files) or not _takes(data_files, 1)):
        problems.append("`data_files(cfg)` callable with the config (or no `data_files`)")
    if problems:
        raise PipelineError(
            f"pipeline {label} does not satisfy the Pipeline protocol: it needs "
            + "; ".join(problems)
        )
    return mod


def _takes(fn: Any, n: int) -> bool:
    try:
        inspect.signature(fn).bind(*range(n))
    except TypeError:
        return False
    except ValueError:  # no signature (a builtin): accept
        return True
    return True


def register(mod: Any, name: str | None = None) -> str:
    """Add a pipeline module (checked against the `Pipeline` protocol) under ``name``
    (default: the module's last dotted name); configs then select it with
    ``experiment = "name"``. Returns the name."""
    name = name or getattr(mod, "__name__", "").rpartition(".")[2]
    if not isinstance(name, str) or not _NAME.match(name):
        raise PipelineError(f"pipeline name must be a lower-case identifier, got {name!r}")
    _REGISTERED[name] = check_pipeline(mod, name)
    return name


def available() -> list[str]:
    """The pipeline names: the modules of ``fxspace.pipelines`` and registered ones."""
    here = Path(__file__).parent
    builtin = {p.stem for p in here.glob("*.py") if not p.stem.startswith("_")}
    return sorted(builtin | set(_REGISTERED))


def load_pipeline(name: str) -> Any:
    """The pipeline module ``name``, checked against the `Pipeline` protocol."""
    if not isinstance(name, str) or not _NAME.match(name) or name not in available():
        raise ConfigError(f"experiment = {name!r} is not known; choose one of {available()}")
    if name in _REGISTERED:
        return _REGISTERED[name]
    return check_pipeline(importlib.import_module(f"{__name__}.{name}"), name)


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


def run_config(path: str | Path, out: str | Path | None = None, force: bool = False) -> list[Path]:
    """Run the experiment described by the TOML file at ``path``.

    The default output folder is ``runs/<config file stem>``; relative ``data.paths``
    resolve against the config file's folder (absolute paths are kept).
    """
    raw = load_toml(path)
    if out is None:
        out = Path("runs") / Path(path).stem
    if "search" in raw:  # an Optuna search, here one trial after another
        from fxspace.pipelines._sweep import sweep_config

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


def summary(run_dir: str | Path) -> dict[str, Any]:
    """The run's ``metrics.json`` (a `CorruptFileError` naming it when damaged)."""
    p = Path(run_dir) / "metrics.json"
    m = read_json(p)
    if m is None:
        raise FileNotFoundError(f"{p} does not exist: the run has not finished (fxspace run)")
    return m


from fxspace.pipelines._docs import write_bench_page, write_docs  # noqa: E402
from fxspace.pipelines._sweep import sweep_config  # noqa: E402  (uses the names above)
