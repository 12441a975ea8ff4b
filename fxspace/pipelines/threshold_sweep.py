"""Threshold sweep of the expression space (issue 2, Kim & Jung §3.3).

Loads facial frames (AnimFace takes or the synthetic face), builds the pairwise-distance
state, sweeps ε through graph → geodesic → MDS → Pearson r, picks ε by the configured
criterion (reporting all criteria), and writes the 2-D expression space and figures.
"""

from __future__ import annotations

import dataclasses
import math
import time
from pathlib import Path
from typing import Literal

import jax
import jax.numpy as jnp
import numpy as np

from fxspace._progress import progress, stage
from fxspace.config import ConfigError
from fxspace.datasets import FaceData, load_face
from fxspace.expression import connecting_threshold, expression_space
from fxspace.expression._features import distance_features, pairwise_distances
from fxspace.expression._sweep import (
    SweepResult,
    choose_threshold,
    sweep_message,
    threshold_grid,
    threshold_sweep,
)
from fxspace.runs import cached, save_figure_atomic, save_npz_atomic

__all__ = ["Config", "GraphConfig", "SelectConfig", "run", "SEED_PAPER_R"]

SEED_PAPER_R = 0.9647  # Kim & Jung: r at their chosen threshold (230 mm, ~2400 frames, 100 markers)


@dataclasses.dataclass(frozen=True)
class GraphConfig:
    """The ε grid: explicit ``thresholds`` or ``num_thresholds`` geometric steps from
    ``lower_factor`` × the connecting threshold to the ``upper_quantile`` of all distances."""

    thresholds: tuple[float, ...] = ()
    num_thresholds: int = 24
    upper_quantile: float = 0.6
    lower_factor: float = 0.9
    batch_size: int = 1
    dtype: Literal["float32", "float64"] = "float32"

    def validate(self) -> None:
        if not self.thresholds and self.num_thresholds < 2:
            raise ConfigError("graph.num_thresholds must be >= 2")
        if any(t <= 0 for t in self.thresholds):
            raise ConfigError("graph.thresholds must all be > 0")
        if self.batch_size < 1:
            raise ConfigError("graph.batch_size must be >= 1")
        if not 0.0 < self.upper_quantile <= 1.0:
            raise ConfigError(f"graph.upper_quantile must be in (0, 1], got {self.upper_quantile}")
        if not (math.isfinite(self.lower_factor) and self.lower_factor > 0):
            raise ConfigError(f"graph.lower_factor must be > 0, got {self.lower_factor}")
        if any(not math.isfinite(t) for t in self.thresholds):
            raise ConfigError("graph.thresholds must all be finite")


@dataclasses.dataclass(frozen=True)
class SelectConfig:
    """How ε is chosen: ``max_r`` (the seed paper's), ``bounded_degree`` (highest r with mean
    degree ≤ ``max_mean_degree``, default a quarter of the frames) or ``elbow`` (knee of r vs ε)."""

    criterion: Literal["max_r", "bounded_degree", "elbow"] = "bounded_degree"
    max_mean_degree: float | None = None

    def validate(self) -> None:
        m = self.max_mean_degree
        if m is not None and not (math.isfinite(m) and m > 0):
            raise ConfigError(f"select.max_mean_degree must be a number > 0, got {m}")


@dataclasses.dataclass(frozen=True)
class Config:
    data: FaceData = FaceData()
    graph: GraphConfig = GraphConfig()
    select: SelectConfig = SelectConfig()
    dim: int = 2

    def validate(self) -> None:
        if self.dim < 1:
            raise ConfigError("dim must be >= 1")


def _sweep_chunks(
    P, thresholds, cfg: GraphConfig, run_dir: Path, dim: int = 2
) -> tuple[SweepResult, float]:
    """Sweep in chunks; each finished chunk is cached in the run folder (resume)."""
    bs = cfg.batch_size
    chunks = [thresholds[i : i + bs] for i in range(0, len(thresholds), bs)]
    parts = []
    t_compute = 0.0
    for k, th in enumerate(progress(chunks, desc="threshold sweep")):
        key = f"sweep_{k:03d}_" + "_".join(f"{t:.6g}" for t in th)

        def compute(th=th):
            nonlocal t_compute
            t0 = time.perf_counter()
            sw = threshold_sweep(P, np.asarray(th), dim=dim, batch_size=None if bs == 1 else bs)
            jax.block_until_ready(sw.scores)
            t_compute += time.perf_counter() - t0
            return {f: np.asarray(v) for f, v in sw._asdict().items() if f != "num_frames"}

        parts.append(cached(run_dir, key, compute))
    fields = {
        f: np.concatenate([np.asarray(p[f]) for p in parts])
        for f in SweepResult._fields
        if f != "num_frames"
    }
    fields["scores"] = fields["scores"].astype(float)
    return SweepResult(**fields, num_frames=int(P.shape[0])), t_compute


def run(cfg: Config, run_dir: Path, seed: int) -> dict:
    """Run the sweep in ``graph.dtype`` (float64 turns on ``jax_enable_x64`` for the run)."""
    with jax.enable_x64(cfg.graph.dtype == "float64"):
        return _run(cfg, run_dir, seed)


def _run(cfg: Config, run_dir: Path, seed: int) -> dict:
    from fxspace.plot import plot_embedding_panels, plot_sweep

    timings = {}
    t0 = time.perf_counter()
    stage(f"loading frames ({cfg.data.source})")
    face = load_face(cfg.data, seed)
    timings["load_s"] = time.perf_counter() - t0
    dtype = jnp.float32 if cfg.graph.dtype == "float32" else jnp.float64
    X = jnp.asarray(face.positions, dtype)

    t0 = time.perf_counter()
    stage(f"{len(X)} frames × {X.shape[1]} markers: distance features and pairwise distances")
    F = distance_features(X)
    P = jax.block_until_ready(pairwise_distances(F))
    timings["features_pairwise_s"] = time.perf_counter() - t0
    t_conn = float(connecting_threshold(P))
    if cfg.graph.thresholds:
        th = np.asarray(sorted(cfg.graph.thresholds), float)
    else:
        th = threshold_grid(
            P, cfg.graph.num_thresholds, cfg.graph.upper_quantile, cfg.graph.lower_factor
        )

    t0 = time.perf_counter()
    sw, t_compute = _sweep_chunks(P, th, cfg.graph, run_dir, cfg.dim)
    timings["sweep_s"] = time.perf_counter() - t0
    timings["sweep_compute_s"] = t_compute

    choices = {}
    for crit in ("max_r", "bounded_degree", "elbow"):
        try:
            choices[crit] = choose_threshold(sw, crit, cfg.select.max_mean_degree)
        except ValueError as e:
            choices[crit] = {"error": str(e)}
    chosen = choices[cfg.select.criterion]
    if "error" in chosen:
        raise ConfigError(chosen["error"] + f" ({sweep_message(sw, P)})")

    t0 = time.perf_counter()
    stage(f"ε = {chosen['threshold']:.4g} ({cfg.select.criterion}): final space and figures")
    es = expression_space(None, chosen["threshold"], cfg.dim, pairwise=P, paths=False)
    D, mds, r = es.geodesics.distances, es.mds, float(es.score)
    timings["final_space_s"] = time.perf_counter() - t0

    Y = np.asarray(mds.embedding)
    save_npz_atomic(
        run_dir / "expression_space.npz",
        embedding=Y,
        geodesic=np.asarray(D, np.float32),
        take=face.take,
        frame=face.frame,
        label=face.label,
        threshold=chosen["threshold"],
        positions=face.positions.astype(np.float32),
        marker_names=np.asarray(face.marker_names),
        take_names=np.asarray(face.take_names),
        label_names=np.asarray(face.label_names),
    )
    marks = {k: v["threshold"] for k, v in choices.items() if "threshold" in v}
    save_figure_atomic(
        plot_sweep(
            sw.thresholds, sw.scores, sw.connected, marks, t_conn, mean_degree=sw.mean_degree
        ),
        run_dir / "r_vs_threshold.png",
    )
    save_figure_atomic(
        plot_embedding_panels(
            Y,
            face.label,
            face.frame,
            face.label_names,
            f"expression space, ε = {chosen['threshold']:.4g} "
            f"({cfg.select.criterion}), r = {r:.4f}",
        ),
        run_dir / "expression_space.png",
    )
    for crit, ch in choices.items():
        if crit == cfg.select.criterion or "threshold" not in ch:
            continue
        es_c = expression_space(None, ch["threshold"], cfg.dim, pairwise=P, paths=False)
        Yc = np.asarray(es_c.embedding)
        save_figure_atomic(
            plot_embedding_panels(
                Yc,
                face.label,
                face.frame,
                face.label_names,
                f"ε = {ch['threshold']:.4g} ({crit}), r = {ch['score']:.4f}",
            ),
            run_dir / f"expression_space_{crit}.png",
        )

    per = [
        {
            "threshold": float(t),
            "r": (float(s) if np.isfinite(s) else None),
            "connected": bool(c),
            "n_components": int(n),
            "mean_degree": float(d),
        }
        for t, s, c, n, d in zip(
            sw.thresholds, sw.scores, sw.connected, sw.n_components, sw.mean_degree, strict=True
        )
    ]
    return {
        "frames": int(len(Y)),
        "dtype": str(P.dtype),
        "dim": int(Y.shape[1]),
        "missing": {"policy": cfg.data.missing, "max_gap": cfg.data.max_gap, **face.missing},
        "markers": int(face.positions.shape[1]),
        "takes": list(face.take_names),
        "connecting_threshold": t_conn,
        "sweep": per,
        "disconnected_note": sweep_message(sw, P),
        "criterion": cfg.select.criterion,
        "best_threshold": chosen["threshold"],
        "r_at_best": r,
        "choices": choices,
        "seed_paper_r": SEED_PAPER_R,
        "eigenvalues": np.asarray(mds.eigenvalues).tolist(),
        "timings": timings,
    }
