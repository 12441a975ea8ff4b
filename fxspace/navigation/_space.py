"""The navigable space in one call: expression space at a threshold + its FCM hierarchy.

Shared by the navigation pipeline and the browser navigator (one home for the wiring of
the library's chain into a hierarchy). ε is a number or the library's own rule over the
frames (a factor of the connecting ε, or a criterion's sweep); the library reads no run
folder: a finished threshold-sweep run's ε is read in the pipeline layer
(`fxspace.pipelines.navigation.threshold_from_run`) and passed here as a number.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any, Literal, NamedTuple

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from fxspace._validate import check_choice, check_int, check_scalar, checked
from fxspace.errors import FxspaceError
from fxspace.expression import (
    CRITERIA,
    ExpressionSpace,
    SweepResult,
    choose_threshold,
    connecting_threshold,
    distance_features,
    expression_space,
    pairwise_distances,
    threshold_grid,
    threshold_sweep,
)
from fxspace.navigation._hierarchy import Hierarchy, build_hierarchy
from fxspace.runs import sweep_threshold

__all__ = [
    "NavigationSpace",
    "navigation_space",
    "resolve_threshold",
    "threshold_from_run",
    "THRESHOLD_CRITERIA",
]

THRESHOLD_CRITERIA = CRITERIA
SWEEP_THRESHOLDS = 16
"""Thresholds of the sweep a criterion runs (connecting ε to the largest distance)."""


class NavigationSpace(NamedTuple):
    """An expression space, its hierarchy, the connecting ε, the ε used and where it came
    from (``threshold_source``: ``"value"``, ``"factor 1.25 × connecting"`` or
    ``"criterion max_r (sweep of 16 …)"``)."""

    space: ExpressionSpace
    hierarchy: Hierarchy | None
    connecting_threshold: float
    threshold: float
    threshold_source: str = "value"


@checked
def threshold_from_run(run_dir: str | Path) -> tuple[float, str]:
    """Deprecated: use `fxspace.pipelines.navigation.threshold_from_run` (reading a run
    folder is the pipeline layer's job; nothing in the library calls this, and it goes in
    a later release).

    ``(ε, criterion)`` chosen by a finished threshold-sweep run (its ``metrics.json``:
    ``best_threshold`` and ``criterion``). Raises ``FxspaceError`` naming what is missing."""
    warnings.warn(
        "fxspace.navigation.threshold_from_run is deprecated: use "
        "fxspace.pipelines.navigation.threshold_from_run (a run folder is read in the "
        "pipeline layer) and pass the number as the threshold",
        DeprecationWarning,
        stacklevel=2,
    )
    return sweep_threshold(run_dir)


def _threshold_value(
    pairwise, threshold: float | str | None, threshold_factor: float, t_conn: float,
    num_thresholds: int = SWEEP_THRESHOLDS,
    sweep: Callable[..., SweepResult] = threshold_sweep,
) -> tuple[float, str]:  # fmt: skip
    if isinstance(threshold, str):
        if threshold.startswith("from:"):
            raise FxspaceError(
                f"threshold = {threshold!r}: the library reads no run folder; read that "
                "run's ε with fxspace.pipelines.navigation.threshold_from_run("
                f"{threshold.removeprefix('from:')!r}) and pass the number (a navigation "
                "config's graph.threshold = 'from:RUN_DIR' does this)"
            )
        if threshold in THRESHOLD_CRITERIA:
            grid = threshold_grid(pairwise, num_thresholds)
            ch = choose_threshold(sweep(pairwise, grid), threshold)
            return ch["threshold"], (
                f"criterion {threshold} (sweep of {len(grid)} from the connecting ε to the "
                f"largest distance; r = {ch['score']:.4f})"
            )
        raise FxspaceError(
            f"threshold must be a number or a criterion {THRESHOLD_CRITERIA}; got {threshold!r}"
        )
    if threshold:
        return check_scalar(threshold, "threshold", low=0.0, low_open=True), "value"
    return threshold_factor * t_conn, f"factor {threshold_factor:g} × connecting"


def resolve_threshold(
    pairwise: Float[Array, "n n"],
    threshold: float | str | None,
    threshold_factor: float = 1.25,
    *,
    with_source: bool = False,
    num_thresholds: int = SWEEP_THRESHOLDS,
    sweep: Callable[..., SweepResult] | None = None,
) -> tuple[float, float] | tuple[float, float, str]:
    """``(ε, connecting ε)`` (and the source with ``with_source``): ``threshold`` when a
    number; a criterion name (``"max_r"`` — the paper's, ``"bounded_degree"``,
    ``"elbow"``) → a sweep of `num_thresholds` thresholds from the connecting ε to the
    largest distance (`fxspace.threshold_grid`) here and `fxspace.choose_threshold`;
    ``None``/0 → ``threshold_factor`` × the smallest threshold that connects the graph.
    A finished threshold-sweep run's ε (``"from:RUN_DIR"``) is not read here: read it with
    `fxspace.pipelines.navigation.threshold_from_run` and pass the number. `sweep`: how a
    criterion's sweep runs, ``sweep(pairwise, thresholds) -> SweepResult`` (default
    `fxspace.threshold_sweep`; the navigation pipeline passes its cached stage). Raises
    ``FxspaceError`` when ε leaves the graph disconnected."""
    if not isinstance(threshold, str) and threshold is not None:
        threshold = check_scalar(threshold, "threshold", low=0.0)
    threshold_factor = check_scalar(threshold_factor, "threshold_factor", low=1.0)
    num_thresholds = check_int(num_thresholds, "num_thresholds", low=2)
    t_conn = float(connecting_threshold(pairwise))
    eps, source = _threshold_value(pairwise, threshold, threshold_factor, t_conn, num_thresholds,
                                   threshold_sweep if sweep is None else sweep)  # fmt: skip
    if eps < t_conn:
        raise FxspaceError(
            f"threshold = {eps:.4g} leaves the graph disconnected; the smallest connecting "
            f"threshold is {t_conn:.4g}: raise it"
        )
    return (eps, t_conn, source) if with_source else (eps, t_conn)


@checked
def navigation_space(
    positions: Float[Array, "n markers 3"],
    threshold: float | str | None = None,
    *,
    threshold_factor: float = 1.25,
    dtype: Literal["float32", "float64"] = "float32",
    key: Array | None = None,
    hierarchy: dict[str, Any] | None = None,
) -> NavigationSpace:
    """Expression space (with next hops, for paths) and, unless ``hierarchy is False``-y
    (``{}`` builds the defaults; ``None`` skips it), the FCM hierarchy over its 2-D embedding.

    **Arguments:**

    - `positions`: ``(n, M, 3)`` marker frames without NaN.
    - `threshold`: ε; ``None`` or 0 → `threshold_factor` × the connecting threshold;
      ``"max_r"``, ``"bounded_degree"`` or ``"elbow"`` → a sweep here, chosen by that
      criterion (see `resolve_threshold`). A finished sweep run's ε: read it with
      `fxspace.pipelines.navigation.threshold_from_run` and pass the number. The
      result's ``threshold_source`` records which.
    - `dtype`: ``"float32"`` or ``"float64"`` for the chain.
    - `key`: PRNG key of the FCM seeding.
    - `hierarchy`: keyword arguments of `fxspace.build_hierarchy`.
    """
    check_choice(dtype, "dtype", ("float32", "float64"))
    X = jnp.asarray(positions, jnp.float32 if dtype == "float32" else jnp.float64)
    P = pairwise_distances(distance_features(X))
    eps, t_conn, source = resolve_threshold(P, threshold, threshold_factor, with_source=True)
    es = expression_space(None, eps, 2, pairwise=P)
    es = jax.block_until_ready(es)
    h = None
    if hierarchy is not None:
        h = build_hierarchy(
            es.embedding,
            es.geodesics,
            key=jax.random.PRNGKey(0) if key is None else key,
            **hierarchy,
        )
    return NavigationSpace(es, h, t_conn, eps, source)
