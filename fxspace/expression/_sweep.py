"""Threshold sweep and threshold choice (Kim & Jung, §3.3).

For each ε the chain graph → geodesic → MDS → Pearson r runs as one branch-free kernel,
``jax.lax.map``-ped (vmapped in batches) over the thresholds. A threshold that leaves the
graph disconnected gets ``r = nan`` and ``connected = False`` with its component count —
never ``inf`` distances fed to the embedding.

**Bridged graphs.** Just above the connecting threshold the ε-graph is held together by
*bridges*: single edges whose removal splits the frames in two (the bottleneck edge of the
minimum spanning tree is one by construction). Every geodesic between the two parts runs
through that edge, so the geodesic matrix is dominated by a few long chains — close to a
1-D (tree) metric that a 2-D MDS reproduces almost exactly: r → 1 for a graph that is a
poor manifold model. On a real take (962 frames of AnimFace cheeks) the connecting ε holds
47 bridges, the largest splitting 417 frames from 545, and its r beats every denser graph
when long filled gaps stretch the take into chains. `threshold_sweep` therefore reports,
per ε, the size of the smaller part the graph's largest bridge cuts off
(``bridge_part``), and `choose_threshold` skips ε whose graph a bridge splits with at
least ``min_bridge_part`` of the frames on each side (default 5 %), naming them. Kim &
Jung (§2.2) sweep ε "between the smallest and the largest distance" and keep the highest
r; they do not discuss this degenerate end of the range.
"""

from __future__ import annotations

from functools import partial
from typing import Literal, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int

from fxspace._validate import (
    as_float_array,
    check_choice,
    check_distance_matrix,
    check_int,
    check_scalar,
    checked,
)
from fxspace.errors import FxspaceError
from fxspace.expression._bridges import bridge_parts
from fxspace.expression._geodesic import (
    _BLOCKED_FROM,
    _equals_transpose,
    connected_components,
    connecting_threshold,
    epsilon_graph,
)
from fxspace.expression._space import _remember, embed_graph

__all__ = [
    "CRITERIA",
    "SweepResult",
    "threshold_sweep",
    "threshold_grid",
    "choose_threshold",
    "sweep_message",
    "bridge_parts",
]

CRITERIA = ("max_r", "bounded_degree", "elbow")
"""The threshold criteria of `choose_threshold`; ``"max_r"`` is the paper's (the default)."""


class SweepResult(NamedTuple):
    """Per-threshold results of `threshold_sweep`.

    - `thresholds`: ``(S,)`` the ε values.
    - `scores`: ``(S,)`` Pearson r of geodesic vs embedded distances; NaN where disconnected.
    - `connected`: ``(S,)`` bool.
    - `n_components`: ``(S,)`` connected components of each ε-graph.
    - `mean_degree`: ``(S,)`` mean number of neighbours per frame.
    - `eigenvalues`: ``(S, dim)`` top MDS eigenvalues (NaN where disconnected).
    - `num_frames`: number of frames ``n``.
    - `bridge_part`: ``(S,)`` frames in the smaller part cut off by the graph's largest
      bridge (an edge whose removal disconnects it): 0 when no edge is a bridge or the
      graph is disconnected, -1 when not computed (a traced sweep); ``None`` for a
      result built without it.
    """

    thresholds: Float[Array, " S"]
    scores: Float[Array, " S"]
    connected: Bool[Array, " S"]
    n_components: Int[Array, " S"]
    mean_degree: Float[Array, " S"]
    eigenvalues: Float[Array, "S dim"]
    num_frames: int
    bridge_part: Int[Array, " S"] | None = None


def _one(P: Array, eps: Array, dim: int, method: str, mds_method: str, symmetric: bool):
    W = epsilon_graph(P, eps)
    emb = embed_graph(W, dim, method=method, mds_method=mds_method, symmetric=symmetric)
    # undirected: the geodesics say it (a component's first frame reaches none before it)
    n_comp = _components(emb.distances) if symmetric else connected_components(W)[0]
    nan = jnp.asarray(jnp.nan, P.dtype)
    return (
        emb.score,
        emb.connected,
        n_comp.astype(jnp.int32),
        _mean_degree(W),
        jnp.where(emb.connected, emb.mds.eigenvalues, nan),
    )


@partial(
    jax.jit,
    static_argnames=("dim", "batch_size", "method", "mds_method", "shard", "symmetric"),
)
def _sweep(P, thresholds, dim, batch_size, method, mds_method, shard, symmetric=False):
    if method == "auto" and P.shape[0] >= _BLOCKED_FROM:
        method = "blocked"  # one Floyd per threshold; devices share the thresholds instead
    f = partial(_one, P, dim=dim, method=method, mds_method=mds_method, symmetric=symmetric)
    nd = jax.local_device_count()
    if not shard or nd == 1 or thresholds.shape[0] == 1:
        return jax.lax.map(f, thresholds, batch_size=batch_size)
    from jax.sharding import Mesh
    from jax.sharding import PartitionSpec as Ps

    S = thresholds.shape[0]
    pad = (-S) % nd
    th = jnp.concatenate([thresholds, jnp.repeat(thresholds[-1:], pad)])
    mesh = Mesh(np.array(jax.local_devices()), ("eps",))
    bs = None if batch_size is None else max(1, batch_size // nd)
    # no collective inside and none after: the padded, sharded outputs are returned as
    # they are and gathered on the host (XLA:CPU aborts a collective whose participants
    # arrive far apart, so downstream ops must not be partitioned)
    return jax.shard_map(
        lambda t: jax.lax.map(f, t, batch_size=bs),
        mesh=mesh,
        in_specs=Ps("eps"),
        out_specs=Ps("eps"),
        check_vma=False,
    )(th)


def threshold_sweep(
    pairwise: Float[Array, "n n"],
    thresholds: Float[Array, " S"],
    dim: int = 2,
    batch_size: int | None = None,
    method: Literal["auto", "scan", "blocked", "sharded"] = "auto",
    mds_method: Literal["auto", "eigh", "lobpcg"] = "auto",
    shard: bool | None = None,
) -> SweepResult:
    """Score every threshold: ε-graph → geodesics → classical MDS → Pearson r.

    **Arguments:**
    - `pairwise`: ``(n, n)`` state distances (`pairwise_distances`).
    - `thresholds`: ``(S,)`` ε values.
    - `dim`: embedding dimension.
    - `batch_size`: thresholds evaluated together (vmapped); ``None`` = one at a time
      (lowest memory, O(n²) each); ``S`` = a single ``vmap``.
    - `method`, `mds_method`: Floyd and eigensolver variants.

    - `shard`: split the thresholds across all local devices with ``shard_map`` (GPUs,
      or CPU cores exposed as devices with ``--xla_force_host_platform_device_count``);
      ``None`` (default) shards whenever there is more than one local device. It is safe
      by construction: no collective runs inside the sweep, and the sharded outputs are
      gathered on the host before anything else uses them.

    Under ``jax.distributed`` (several processes, e.g. one per GPU node) the thresholds
    are first split over the processes, each sweeps its share on its local devices, and
    the results are gathered, so every process returns the same `SweepResult`,
    identical to a one-process run.

    **Returns:** `SweepResult`. Cost O(S·n³); the dense Floyd costs the same at every
    ε, while Dijkstra slows down as the graph densifies.
    """
    P = as_float_array(pairwise, "pairwise", ndim=2, finite="allow")
    if P.ndim != 2 or P.shape[0] != P.shape[1]:
        raise FxspaceError(f"pairwise must be a square (n, n) matrix, got shape {P.shape}")
    check_distance_matrix(P, "pairwise", allow_inf=True)
    th = _as_thresholds(thresholds, P.dtype)
    dim = check_int(dim, "dim", low=1)
    if batch_size is not None:
        batch_size = check_int(batch_size, "batch_size", low=1)
    check_choice(method, "method", ("auto", "scan", "blocked", "sharded"))
    check_choice(mds_method, "mds_method", ("auto", "eigh", "lobpcg"))
    traced = isinstance(P, jax.core.Tracer) or isinstance(th, jax.core.Tracer)
    shard = (jax.local_device_count() > 1 and not traced) if shard is None else bool(shard)
    # an undirected graph (P equal to its transpose, checked once here) runs the folded
    # Floyd, half the work; a traced P counts as directed, as in floyd_warshall
    sym = not traced and bool(_equals_transpose(P))
    if not traced and not shard and batch_size is None and jax.process_count() == 1:
        out = _sweep_eager(pairwise, P, th, dim, method, mds_method, sym)
    elif jax.process_count() > 1 and not traced:
        out = _across_processes(P, np.asarray(th), dim, batch_size, method, mds_method, shard,
                                sym)  # fmt: skip
    else:
        out = _sweep(P, th, dim, batch_size, method, mds_method, shard, sym)
        S = th.shape[0]  # gathered on the host unless traced
        out = tuple(a[:S] if traced else np.asarray(a)[:S] for a in out)
    r, conn, ncomp, deg, eig = (jnp.asarray(a) for a in out)
    if traced:
        bridge = jnp.full(th.shape, -1, jnp.int32)
    else:
        bridge = jnp.asarray(bridge_parts(P, np.asarray(th), np.asarray(conn)))
    return SweepResult(th, r, conn, ncomp, deg, eig, int(P.shape[0]), bridge)


def _sweep_eager(pairwise, P, th, dim, method, mds_method, sym):
    """`_sweep` one ε at a time from the host (concrete, unbatched, one device): the same
    chain through `embed_graph`'s compiled kernels, which `expression_space` at the chosen
    ε then reuses (no second compile), and the best-scoring embedding kept for it."""
    rows = []
    for eps in th:
        W = epsilon_graph(P, eps)
        emb = embed_graph(W, dim, method=method, mds_method=mds_method, symmetric=sym)
        ncomp = _components(emb.distances) if sym else connected_components(W)[0]
        rows.append((emb.score, emb.connected, ncomp, _mean_degree(W), emb.mds.eigenvalues))
        if bool(emb.connected):
            _remember(pairwise, (float(eps), dim, method, mds_method), emb)
    r, conn, ncomp, deg, eig = (np.stack([np.asarray(x[i]) for x in rows]) for i in range(5))
    eig = np.where(conn[:, None], eig, np.asarray(np.nan, eig.dtype))
    return r, conn, ncomp.astype(np.int32), deg.astype(r.dtype), eig


@jax.jit
def _components(D: Array) -> Array:
    """Components of an undirected graph from its geodesics: the frames that reach no
    frame before them (each component's first)."""
    n = D.shape[0]
    before = jnp.arange(n)[None, :] < jnp.arange(n)[:, None]
    return jnp.sum(~jnp.any(jnp.isfinite(D) & before, axis=1)).astype(jnp.int32)


@jax.jit
def _mean_degree(W: Array) -> Array:
    n = W.shape[0]
    return ((jnp.sum(jnp.isfinite(W)) - n) / n).astype(W.dtype)


def _as_thresholds(thresholds, dtype) -> Array:
    """``thresholds`` as a non-empty 1-D array of finite ε > 0 (a string or a NaN refused)."""
    if isinstance(thresholds, jax.core.Tracer):
        return jnp.atleast_1d(thresholds.astype(dtype))
    th = as_float_array(jnp.atleast_1d(_numeric(thresholds)), "thresholds", finite="raise")
    if th.ndim != 1:
        raise FxspaceError(f"thresholds must be a 1-D array of ε values, got shape {th.shape}")
    if not bool(jnp.all(th > 0)):
        raise FxspaceError("thresholds must all be > 0 (ε is a distance)")
    return th.astype(dtype)


def _numeric(x):
    if isinstance(x, str | bytes) or (
        isinstance(x, list | tuple) and any(isinstance(v, str | bytes) for v in x)
    ):
        raise FxspaceError(f"thresholds must be numbers (ε in the features' units), got {x!r}")
    try:
        return jnp.asarray(x)
    except (TypeError, ValueError) as e:
        raise FxspaceError(f"thresholds must be a numeric array ({e})") from None


def _across_processes(P, th, dim, batch_size, method, mds_method, shard, sym=False):
    """Thresholds split round-robin over the ``jax.distributed`` processes, then gathered."""
    from jax.experimental import multihost_utils

    nproc, me = jax.process_count(), jax.process_index()
    S = th.shape[0]
    per = -(-S // nproc)
    padded = np.concatenate([th, np.repeat(th[-1:], per * nproc - S)])
    mine = _sweep(P, jnp.asarray(padded[me::nproc]), dim, batch_size, method, mds_method, shard,
                  sym)  # fmt: skip
    mine = tuple(np.asarray(a)[:per] for a in mine)
    every = [np.asarray(multihost_utils.process_allgather(a)) for a in mine]  # (nproc, per…)
    out = []
    for a in every:
        full = np.empty((per * nproc, *a.shape[2:]), a.dtype)
        for q in range(nproc):
            full[q::nproc] = a[q]
        out.append(full[:S])
    return tuple(out)


def threshold_grid(
    pairwise: Float[Array, "n n"],
    num: int = 16,
    upper_quantile: float = 1.0,
    lower_factor: float = 1.0,
) -> np.ndarray:
    """``num`` geometrically spaced ε over the whole meaningful range (Kim & Jung §2.2:
    thresholds "between the smallest and the largest distance"): from the connecting
    threshold (× ``lower_factor``; below it the graph falls apart) up to the
    ``upper_quantile`` of the off-diagonal distances — by default the largest pairwise
    distance, where the ε-graph is complete and geodesics are straight lines. The last
    grid point is exactly that distance.

    **Arguments:** `pairwise` ``(n, n)`` state distances; `num` ≥ 2 (an integer);
    `upper_quantile` in (0, 1]; `lower_factor` > 0.

    **Returns:** ``(num,)`` ascending float64 thresholds.
    """
    num = check_int(num, "num", low=2)
    upper_quantile = check_scalar(
        upper_quantile, "upper_quantile", low=0.0, high=1.0, low_open=True
    )
    lower_factor = check_scalar(lower_factor, "lower_factor", low=0.0, low_open=True)
    P = np.asarray(as_float_array(pairwise, "pairwise", ndim=2, xp="numpy"), np.float64)
    if P.shape[0] != P.shape[1] or P.shape[0] < 2:
        raise FxspaceError(f"pairwise must be a square (n, n) matrix, n ≥ 2; got {P.shape}")
    lo = float(connecting_threshold(jnp.asarray(P))) * lower_factor
    off = P[~np.eye(len(P), dtype=bool)]
    hi = float(off.max()) if upper_quantile == 1.0 else float(np.quantile(off, upper_quantile))
    if not lo > 0:
        lo = float(off[off > 0].min()) if (off > 0).any() else 1.0
    if hi <= lo:
        hi = lo * 4
    grid = np.geomspace(lo, hi, num)
    grid[0], grid[-1] = lo, hi
    return grid


def choose_threshold(
    sweep: SweepResult,
    criterion: Literal["max_r", "bounded_degree", "elbow"] = "max_r",
    max_mean_degree: float | None = None,
    *,
    min_bridge_part: float | None = 0.05,
) -> dict:
    """Pick a threshold from a sweep.

    Only connected ε are candidates, and (with ``min_bridge_part``, default 0.05) not
    those whose graph a single edge — a bridge — splits into two parts each holding at
    least that fraction of the frames (at least 2): their geodesics are chains through
    that edge and their r measures the chain, not the manifold (module docstring). The
    skipped ε are listed in the result's ``skipped_bridged``; ``None`` keeps them (the
    paper's plain rule). A sweep without ``bridge_part`` skips nothing.

    **Criteria:**
    - ``"max_r"`` (default): the paper's — the threshold whose 2-D embedding best keeps
      the geodesic distances (highest Pearson r; Kim & Jung §2.2 choose 230 mm at
      r = 0.9647). Over the whole range (`threshold_grid`) r rises from the connecting
      threshold, peaks, and falls toward the complete graph; on AnimFace it peaks near
      220 mm.
    - ``"bounded_degree"``: the highest r among graphs whose mean degree is at most
      ``max_mean_degree`` (default: a quarter of the frames) — for when the peak lies at
      a nearly complete graph, whose geodesics are straight lines (no manifold left).
    - ``"elbow"``: the knee of the r-vs-log ε curve (largest height above the chord
      between the first and last connected thresholds; Kneedle) — the smallest ε past
      which extra neighbours buy little correlation (sparser graph, cheaper geodesics).

    **Returns:** dict with ``threshold``, ``score``, ``index``, ``criterion``,
    ``mean_degree``.
    """
    check_choice(criterion, "criterion", CRITERIA)
    if max_mean_degree is not None:
        max_mean_degree = check_scalar(max_mean_degree, "max_mean_degree", low=0.0)
    if not isinstance(sweep, SweepResult):
        raise FxspaceError(f"sweep must be a SweepResult (threshold_sweep), got {type(sweep)}")
    th = np.asarray(sweep.thresholds, float)
    r = np.asarray(sweep.scores, float)
    conn = np.asarray(sweep.connected, bool) & np.isfinite(r)
    if not conn.any():
        raise FxspaceError(
            "no threshold in the sweep gives a connected graph: " + sweep_message(sweep)
        )
    skipped: list[dict] = []
    bp = sweep.bridge_part
    if min_bridge_part is not None and bp is not None:
        min_bridge_part = check_scalar(min_bridge_part, "min_bridge_part", low=0.0, high=0.5)
        bp = np.asarray(bp).reshape(-1)
        k_min = max(2, int(np.ceil(min_bridge_part * sweep.num_frames)))
        held = conn & (bp >= k_min)
        skipped = [{"threshold": float(th[k]), "score": float(r[k]), "bridge_part": int(bp[k])}
                   for k in np.flatnonzero(held)]  # fmt: skip
        if held.any() and not (conn & ~held).any():
            listed = ", ".join(f"ε={d['threshold']:.4g} (r={d['score']:.4f}, splits off "
                               f"{d['bridge_part']} frames)" for d in skipped)  # fmt: skip
            raise FxspaceError(
                f"every connected threshold of the sweep leaves a graph held together by one "
                f"edge (a bridge): {listed}; their r measures that chain, not the manifold. "
                "Extend the grid toward the largest distance, or pass min_bridge_part=None "
                "to accept them"
            )
        conn = conn & ~held
    idx = np.flatnonzero(conn)
    if criterion == "max_r":
        k = idx[np.argmax(r[idx])]
    elif criterion == "bounded_degree":
        deg = np.asarray(sweep.mean_degree, float)
        limit = max_mean_degree if max_mean_degree is not None else 0.25 * sweep.num_frames
        ok = idx[deg[idx] <= limit]
        if not ok.size:
            ok = idx[:1]
        k = ok[np.argmax(r[ok])]
    elif criterion == "elbow":
        if idx.size < 3:
            k = idx[np.argmax(r[idx])]
        else:
            x = np.log(th[idx])
            y = r[idx]
            xn = (x - x[0]) / max(x[-1] - x[0], 1e-12)
            yr = y.max() - y.min()
            yn = (y - y.min()) / (yr if yr > 0 else 1.0)
            chord = yn[0] + (yn[-1] - yn[0]) * xn
            k = idx[np.argmax(yn - chord)]
    else:
        raise FxspaceError(
            f"criterion must be 'max_r', 'bounded_degree' or 'elbow', got {criterion!r}"
        )
    return {
        "criterion": criterion,
        "index": int(k),
        "threshold": float(th[k]),
        "score": float(r[k]),
        "mean_degree": float(np.asarray(sweep.mean_degree)[k]),
        "skipped_bridged": skipped,
    }


@checked
def sweep_message(sweep: SweepResult, pairwise: Array | None = None) -> str:
    """Human-readable note on the disconnected thresholds of a sweep."""
    conn = np.asarray(sweep.connected)
    th = np.asarray(sweep.thresholds)
    nc = np.asarray(sweep.n_components)
    parts = [f"ε={t:.4g}: {c} components" for t, c, ok in zip(th, nc, conn, strict=True) if not ok]
    bp = None if sweep.bridge_part is None else np.asarray(sweep.bridge_part)
    held = (
        []
        if bp is None
        else [f"ε={t:.4g} (a bridge splits off {b} frames)"
              for t, b, ok in zip(th, bp, conn, strict=True) if ok and b > 0]
    )  # fmt: skip
    tail = ("; held together by a bridge at " + "; ".join(held)) if held else ""
    if not parts:
        return "all thresholds give a connected graph" + tail
    msg = "disconnected at " + "; ".join(parts) + tail
    if pairwise is not None:
        msg += (
            f". The smallest threshold that connects the graph is "
            f"{float(connecting_threshold(jnp.asarray(pairwise))):.6g}"
        )
    return msg
