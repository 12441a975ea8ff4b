"""`fuzzy_cmeans`: full memberships or, with ``nearest``, truncated ones — one name.

The full-membership FCM (`._fcm`) and the truncated one (`._fcm_sparse`, each point's
``nearest`` centres) are two implementations of one routine; this front runs the one
the call asks for and refuses an option of the other, naming it.
"""

from __future__ import annotations

from typing import Literal

from jaxtyping import Array, Float

from fxspace.cluster import _fcm, _fcm_blocks, _fcm_sparse
from fxspace.errors import FxspaceError

__all__ = ["fuzzy_cmeans"]


def fuzzy_cmeans(
    x: Float[Array, "n d"],
    n_clusters: int,
    m: float = 2.0,
    *,
    key: Array | None = None,
    tol: float = 1e-4,
    max_steps: int = 300,
    n_init: int = 1,
    init_centers: Float[Array, "c d"] | None = None,
    init_memberships: Float[Array, "n c"] | None = None,
    criterion: Literal["max", "fro"] = "max",
    check_every: int = 4,
    throw: bool = False,
    nearest: int | None = None,
    chunk: int | None = None,
    rows_per_task: int | None = None,
    client=None,
    accelerate: bool | None = None,
):
    """Fuzzy c-means clustering (Bezdek's alternating updates) as one jitted while-loop.

    **Arguments:**

    - `x`: data, (n_samples, n_features) — not transposed as in scikit-fuzzy.
    - `n_clusters`: number of centres c (1 ≤ c ≤ n_samples).
    - `m`: fuzzifier, m > 1 (2 is the usual choice and has a fast path).
    - `key`: PRNG key for k-means++ seeding (required unless an initial state is given).
    - `tol`: stop when max_ik |u_ik^(t) − u_ik^(t−1)| < tol (per entry, so it means the
      same in float32 at any n and c).
    - `max_steps`: iteration cap.
    - `n_init`: restarts from independent k-means++ seeds, run together under `vmap`;
      the lowest objective wins.
    - `init_centers`: warm start from these (c, d) centres (e.g. a coarser level's centres
      split in two); `key`/`n_init` are then unused.
    - `init_memberships`: start from these (n, c) memberships (rows are normalised), e.g.
      to reproduce scikit-fuzzy's ``init=`` runs.
    - `criterion`: ``"max"`` (per-entry change, the default) or ``"fro"`` (Frobenius norm of
      the change, scikit-fuzzy's and fuzzy-c-means' rule, for like-for-like comparisons).
    - `check_every`: measure the change every this many steps (the steps in between update
      the centres only, which is cheaper); `num_steps` is then a multiple of it (or
      `max_steps`). 1 checks every step.
    - `nearest`: keep only each point's ``nearest`` centres in its memberships (truncated
      FCM: memory O(n·p) instead of O(n·c), for 10⁵ points and hundreds of centres); the
      result is then a [`SparseFCMResult`][fxspace.cluster.SparseFCMResult] (memberships
      ``(n, p)`` with their ``indices``). ``n_init``, ``init_memberships``, ``criterion``
      and ``check_every`` belong to the full memberships; ``chunk`` (points per block of
      the distance pass) to the truncated ones.
    - `rows_per_task`, `client` (with `nearest`): run the steps a block of
      ``rows_per_task`` points at a time (default 65 536 when a client is given), in this
      process or as Dask tasks on a ``dask.distributed.Client`` (each block sent to a
      worker once and kept there; per step the centres go out and each block's partial
      sums ``c × (1 + d)`` come back, added here in block order). The result is the same
      bit for bit with and without the client for the same ``rows_per_task``; it differs
      from the one-loop default (neither given) only in the last bits of the sums
      (`fxspace.cluster._fcm_blocks`). Driven from Python: not under `jit`/`vmap`.
    - `accelerate` (with `rows_per_task`/`client`; default on): SQUAREM cycles
      (Varadhan & Roland 2008, with a monotone safeguard on the objective) instead of
      plain steps — the same kind of fixed point (the stop is still one plain step
      moving no centre more than ``tol`` × the data's spread) in fewer block passes;
      `num_steps` counts the passes. ``False``: Bezdek's plain steps.
    - `throw`: raise [`FxspaceError`][fxspace.FxspaceError] when the result is not
      `RESULTS.successful` (NaN/inf in `x` is named by position before any work; under
      `jit` the check runs through `equinox.error_if`). With `False` (the default) the
      outcome is reported in `.result`, so a `vmap`ped sweep keeps going.

    **Returns:** an [`FCMResult`][fxspace.FCMResult] (with `nearest`: a `SparseFCMResult`)
    with `.result`, `.num_steps` and `.stats`. Cost O(n c d) per step, O(n c) memory (with
    `nearest`: O(n p)). Empty clusters keep their previous centre; coincident centres
    stay finite. NaN/inf input gives `result == RESULTS.nonfinite_input` (and NaN
    centres), never `successful`.

    **Example:**

    ```python
    import jax
    import numpy as np
    import fxspace as fx

    X = np.random.default_rng(0).normal(size=(200, 2))
    res = fx.fuzzy_cmeans(X, 3, key=jax.random.key(0))
    assert res.result == fx.RESULTS.successful
    ```
    """
    if nearest is None:
        for name, val in (("chunk", chunk), ("rows_per_task", rows_per_task),
                          ("client", client), ("accelerate", accelerate)):  # fmt: skip
            if val is not None:
                raise FxspaceError(f"{name} applies to truncated memberships: pass nearest=p too")
        return _fcm.fuzzy_cmeans(
            x, n_clusters, m, key=key, tol=tol, max_steps=max_steps, n_init=n_init,
            init_centers=init_centers, init_memberships=init_memberships,
            criterion=criterion, check_every=check_every, throw=throw,
        )  # fmt: skip
    full = {"n_init": n_init != 1, "init_memberships": init_memberships is not None,
            "criterion": criterion != "max", "check_every": check_every != 4}  # fmt: skip
    return _truncated(x, n_clusters, m, nearest, key, init_centers, tol, max_steps, chunk,
                      rows_per_task, client, accelerate, throw, full)  # fmt: skip


def _truncated(x, n_clusters, m, nearest, key, init_centers, tol, max_steps, chunk,
               rows_per_task, client, accelerate, throw, full: dict):  # fmt: skip
    """`fuzzy_cmeans` with ``nearest``: the one-loop solver, or the block solver with
    ``rows_per_task``/``client``; ``full`` names the full-membership options given."""
    given = sorted(k for k, v in full.items() if v)
    if given:
        raise FxspaceError(
            f"{', '.join(given)}: options of full memberships; with nearest = {nearest!r} "
            "the options are key or init_centers, tol, max_steps, chunk, rows_per_task, "
            "client, accelerate, throw"
        )
    if rows_per_task is not None or client is not None:
        return _fcm_blocks.blocked_fuzzy_cmeans(
            x, n_clusters, m, nearest=nearest, key=key, init_centers=init_centers, tol=tol,
            max_steps=max_steps, chunk=8192 if chunk is None else chunk,
            rows_per_task=rows_per_task, client=client, throw=throw,
            accelerate=True if accelerate is None else accelerate,
        )  # fmt: skip
    if accelerate is not None:
        raise FxspaceError("accelerate applies to the block solver: pass rows_per_task or "
                           "client too (the one-loop solver has plain steps only)")  # fmt: skip
    return _fcm_sparse.sparse_fuzzy_cmeans(
        x, n_clusters, m, nearest=nearest, key=key, init_centers=init_centers, tol=tol,
        max_steps=max_steps, chunk=8192 if chunk is None else chunk, throw=throw,
    )  # fmt: skip
