"""The navigation experiment's ε (`fxspace.pipelines.navigation`), resolved once, here in
the pipeline layer, from the ``[graph]`` table: a number is taken as it is; ``"from:RUN_DIR"``
is read from that finished threshold-sweep run (`threshold_from_run`, the one place a run
folder's ε is read); a criterion or 0 goes to the library's own rule
(`fxspace.navigation.resolve_threshold`) over these frames, its sweep a cached stage."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from fxspace._progress import stage
from fxspace._validate import checked
from fxspace.config import ConfigError
from fxspace.errors import FxspaceError
from fxspace.expression import SweepResult, choose_threshold
from fxspace.navigation import resolve_threshold
from fxspace.pipelines._navigation_config import GraphConfig
from fxspace.pipelines.threshold_sweep import sweep_stage
from fxspace.runs import sweep_threshold


@checked
def threshold_from_run(run_dir: str | Path) -> tuple[float, str]:
    """``(ε, criterion)`` chosen by a finished threshold-sweep run (its ``metrics.json``:
    ``best_threshold`` and ``criterion``); pass the ε to `fxspace.navigation.navigation_space`
    or `fxspace.navigation.resolve_threshold` as a number.

    **Arguments:**

    - `run_dir`: the threshold-sweep run's folder (``fxspace run
      configs/threshold_sweep.toml``).

    **Returns:** ``(ε, criterion)``. Raises ``FxspaceError`` naming what is missing."""
    return sweep_threshold(run_dir)


def _threshold(cfg: GraphConfig, P: Callable, run_dir: Path | None):
    """``(ε, source, sweep, choice)`` as the config says (the sweep: a cached stage). A
    number is used as it is, without the distances (a finished run reopens in seconds)."""
    t = cfg.threshold
    if isinstance(t, str) and t.startswith("from:"):
        try:
            eps, crit = threshold_from_run(t.removeprefix("from:"))
        except FxspaceError as e:
            raise ConfigError(f"graph.threshold: {e}") from e
        return eps, f"{t} ({crit})", None, None
    if t and not isinstance(t, str):
        return float(t), "value", None, None
    if isinstance(t, str):
        stage(f"threshold sweep over these frames ({cfg.num_thresholds} ε, criterion {t})")
    swept: list[SweepResult] = []

    def sweep(pairwise, grid) -> SweepResult:
        swept.append(sweep_stage(run_dir, pairwise, grid))
        return swept[-1]

    try:
        eps, _, source = resolve_threshold(
            P(), t or None, cfg.threshold_factor, with_source=True,
            num_thresholds=cfg.num_thresholds, sweep=sweep,
        )  # fmt: skip
    except FxspaceError as e:
        raise ConfigError(f"graph.threshold: {e}") from e
    sw = swept[-1] if swept else None
    return eps, source, sw, (choose_threshold(sw, t) if sw is not None else None)
