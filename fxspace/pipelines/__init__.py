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


# a thin front: the registry (`_registry`), the planner (`_planner`), the runner
# (`_runner`), the config-file commands (`_commands`), the sweep and the docs pages live in
# their own private modules; every name below is re-exported from them
from fxspace.pipelines._architecture import write_architecture
from fxspace.pipelines._commands import prepare_config, run_config
from fxspace.pipelines._docs import write_bench_page, write_docs
from fxspace.pipelines._planner import _RUN_FILES as _RUN_FILES
from fxspace.pipelines._planner import RunSpec, resolve_config
from fxspace.pipelines._planner import _changed_keys as _changed_keys
from fxspace.pipelines._planner import _check_seed as _check_seed
from fxspace.pipelines._planner import _clean_tree as _clean_tree
from fxspace.pipelines._planner import _data_files as _data_files
from fxspace.pipelines._planner import _is_run_folder as _is_run_folder
from fxspace.pipelines._planner import _plan as _plan
from fxspace.pipelines._planner import _refuse_overwrite as _refuse_overwrite
from fxspace.pipelines._planner import _resolve_paths as _resolve_paths
from fxspace.pipelines._registry import _NAME as _NAME
from fxspace.pipelines._registry import _REGISTERED as _REGISTERED
from fxspace.pipelines._registry import (
    Pipeline,
    PipelineConfig,
    PipelineError,
    available,
    check_pipeline,
    load_pipeline,
    register,
)
from fxspace.pipelines._registry import _takes as _takes
from fxspace.pipelines._runner import _run_locked as _run_locked
from fxspace.pipelines._runner import _run_one as _run_one
from fxspace.pipelines._runner import _what_changed as _what_changed
from fxspace.pipelines._runner import run_dict
from fxspace.pipelines._runner import summary as summary
from fxspace.pipelines._sweep import sweep_config

# the config-level motion session (a TOML and its clips in, poses out): pipelines, not
# motion, since it reads the clips (fxspace.io, a layer above motion)
from fxspace.pipelines.parametric_synthesis import scripted_session, session_parameters

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
    "write_architecture",
    "load_pipeline",
    "available",
    "sweep_config",
]
