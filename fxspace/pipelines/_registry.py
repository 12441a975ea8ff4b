"""The pipelines' registry: the `Pipeline` protocol, `check_pipeline`, `register`,
`available` and `load_pipeline` (``experiment = "NAME"`` selects the module here)."""

from __future__ import annotations

import dataclasses
import importlib
import inspect
import re
from pathlib import Path
from types import ModuleType
from typing import Any, Protocol, runtime_checkable

from fxspace.config import ConfigError

_NAME = re.compile(r"^[a-z_][a-z0-9_]*$")
_REGISTERED: dict[str, ModuleType] = {}


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
    - ``REPRODUCTION`` (optional): the key of the reproduction page it feeds (``fxspace docs``
      reads it here, `experiments_of`).
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


def experiments_of(paper: str) -> tuple[str, ...]:
    """The experiments whose pipeline module declares ``REPRODUCTION = paper``: the configs a
    reproduction page reads (``fxspace docs``), from the one registry."""
    return tuple(n for n in available() if getattr(load_pipeline(n), "REPRODUCTION", None) == paper)


def load_pipeline(name: str) -> Any:
    """The pipeline module ``name``, checked against the `Pipeline` protocol."""
    if not isinstance(name, str) or not _NAME.match(name) or name not in available():
        raise ConfigError(f"experiment = {name!r} is not known; choose one of {available()}")
    if name in _REGISTERED:
        return _REGISTERED[name]
    return check_pipeline(importlib.import_module(f"{__package__}.{name}"), name)
