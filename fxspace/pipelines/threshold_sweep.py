"""Threshold sweep of the expression space (Kim & Jung §2.2).

Loads facial frames (AnimFace takes or the synthetic face), builds the paper's state
distances (the Frobenius distance between the frames' marker-distance matrices, mm),
sweeps ε over the whole meaningful range — from the connecting threshold to the largest
pairwise distance — through graph → geodesic → MDS → Pearson r, picks ε by the configured
criterion (default ``max_r``, the paper's: the highest r; the other criteria are reported
beside it), and writes the 2-D expression space and figures.

Stages (`STAGES`, cached in ``run_dir/cache`` so an interrupted run resumes): ``sweep``
(one cached chunk per ``graph.batch_size`` thresholds, then the whole table) and
``space`` (the expression space at the chosen ε).
"""

from __future__ import annotations

import dataclasses
import math
import time
import zlib
from collections.abc import Callable
from pathlib import Path
from typing import Any, Literal

import jax
import jax.numpy as jnp
import numpy as np

from fxspace._progress import note, progress, stage
from fxspace.config import ConfigError
from fxspace.datasets import FaceData, load_face
from fxspace.expression import (
    CRITERIA,
    SweepResult,
    choose_threshold,
    connecting_threshold,
    distance_features,
    expression_space,
    pairwise_distances,
    sweep_message,
    threshold_grid,
    threshold_sweep,
)
from fxspace.runs import cached_arrays, save_figure_atomic, save_npz_atomic

__all__ = [
    "Config",
    "GraphConfig",
    "SelectConfig",
    "STAGES",
    "run",
    "sweep_stage",
    "all_choices",
    "PAPER_THRESHOLD_MM",
    "SEED_PAPER_R",
]

STAGES = ("sweep", "space")
SEED_PAPER_R = 0.9647  # Kim & Jung: r at their chosen threshold (230 mm, ~2400 frames, 100 markers)
PAPER_THRESHOLD_MM = 230.0


@dataclasses.dataclass(frozen=True)
class GraphConfig:
    """The ε grid: explicit ``thresholds`` or ``num_thresholds`` geometric steps from
    ``lower_factor`` × the connecting threshold to the ``upper_quantile`` of all distances
    (default 1.0: the largest pairwise distance, the complete graph)."""

    thresholds: tuple[float, ...] = ()
    num_thresholds: int = 16
    upper_quantile: float = 1.0
    lower_factor: float = 1.0
    batch_size: int = 1
    dtype: Literal["float32", "float64"] = "float32"

    def validate(self) -> None:
        if not self.thresholds and self.num_thresholds < 2:
            raise ConfigError("graph.num_thresholds must be >= 2")
        if any(not math.isfinite(t) for t in self.thresholds):
            raise ConfigError("graph.thresholds must all be finite")
        if any(t <= 0 for t in self.thresholds):
            raise ConfigError("graph.thresholds must all be > 0")
        if self.batch_size < 1:
            raise ConfigError("graph.batch_size must be >= 1")
        if not 0.0 < self.upper_quantile <= 1.0:
            raise ConfigError(f"graph.upper_quantile must be in (0, 1], got {self.upper_quantile}")
        if not (math.isfinite(self.lower_factor) and self.lower_factor > 0):
            raise ConfigError(f"graph.lower_factor must be > 0, got {self.lower_factor}")


@dataclasses.dataclass(frozen=True)
class SelectConfig:
    """How ε is chosen: ``max_r`` (default, the paper's: highest Pearson r over the
    sweep), ``bounded_degree`` (highest r with mean degree ≤ ``max_mean_degree``, default
    a quarter of the frames: keeps the graph sparse when r peaks near the complete graph)
    or ``elbow`` (knee of r vs ε: the sparsest graph past which r gains little)."""

    criterion: Literal["max_r", "bounded_degree", "elbow"] = "max_r"
    max_mean_degree: float | None = None

    def validate(self) -> None:
        m = self.max_mean_degree
        if m is not None and not (math.isfinite(m) and m > 0):
            raise ConfigError(f"select.max_mean_degree must be a number > 0, got {m}")
        if self.criterion not in CRITERIA:
            raise ConfigError(f"select.criterion must be one of {CRITERIA}")


@dataclasses.dataclass(frozen=True)
class Config:
    data: FaceData = FaceData(max_frames=2400)
    graph: GraphConfig = GraphConfig()
    select: SelectConfig = SelectConfig()
    dim: int = 2

    def validate(self) -> None:
        if self.dim < 1:
            raise ConfigError("dim must be >= 1")


def _stage(run_dir: Path | None, name: str, compute: Callable[[], dict]) -> dict:
    """`cached_arrays` in a run folder; computed directly without one."""
    if run_dir is None:
        return {k: np.asarray(v) for k, v in compute().items()}
    return cached_arrays(run_dir, name, compute)


def state_distances(positions: np.ndarray, dtype: str = "float32") -> jax.Array:
    """The paper's state distances of marker frames: ``‖D_s − D_t‖_F`` (mm)."""
    X = jnp.asarray(positions, jnp.float32 if dtype == "float32" else jnp.float64)
    return jax.block_until_ready(pairwise_distances(distance_features(X)))


def sweep_stage(
    run_dir: Path | None, P, thresholds, batch_size: int = 1, dim: int = 2
) -> SweepResult:
    """The stage ``sweep``: `threshold_sweep` of ``P`` over ``thresholds`` in chunks of
    ``batch_size``, each chunk cached (``sweep_KKK_CRC``) so an interrupted sweep resumes
    at the chunk it stopped in, then the whole table cached as ``sweep``."""
    th_all = np.asarray(thresholds, np.float64)
    bs = int(batch_size)

    def chunk(k: int, th: np.ndarray) -> dict:
        name = f"sweep_{k:03d}_{zlib.crc32(th.tobytes()):08x}"

        def one() -> dict:
            sw = threshold_sweep(P, th, dim=dim, batch_size=None if bs == 1 else bs)
            return {f: v for f, v in sw._asdict().items() if f != "num_frames"}

        # a worker thread does not inherit the caller's jax.enable_x64 context
        with jax.enable_x64(bool(P.dtype == np.float64)):
            return _stage(run_dir, name, one)

    def compute() -> dict:
        from concurrent.futures import ThreadPoolExecutor

        chunks = [th_all[i : i + bs] for i in range(0, len(th_all), bs)]

        def all_chunks():
            yield chunk(0, chunks[0])  # alone: it compiles what the others reuse
            # then two at a time: one ε's Floyd + MDS leaves a CPU core idle part of the
            # time (1.2x on 2 cores, same numbers); each is cached as it finishes. (The
            # first two at once, sharing the compiles, hung a slow test: both threads
            # waiting on their results, the CPU idle.) Several local devices: one chunk
            # at a time (each already runs on every device)
            workers = 2 if jax.local_device_count() == 1 else 1
            ex = ThreadPoolExecutor(max_workers=workers, thread_name_prefix="fxspace-sweep")
            try:
                yield from ex.map(chunk, range(1, len(chunks)), chunks[1:])
            finally:  # on Ctrl-C: the chunks not started are dropped, the finished kept
                ex.shutdown(wait=True, cancel_futures=True)

        parts = list(progress(all_chunks(), desc="threshold sweep", total=len(chunks)))
        return {f: np.concatenate([p[f] for p in parts]) for f in parts[0]}

    a = _stage(run_dir, "sweep", compute)
    fields = {f: a[f] for f in SweepResult._fields if f != "num_frames"}
    fields["scores"] = fields["scores"].astype(float)
    return SweepResult(**fields, num_frames=int(P.shape[0]))


def all_choices(sw: SweepResult, max_mean_degree: float | None = None) -> dict[str, dict]:
    """Every criterion's choice (or its error) — the chosen one and the others beside it."""
    choices: dict[str, dict] = {}
    for crit in CRITERIA:
        try:
            choices[crit] = choose_threshold(sw, crit, max_mean_degree)
        except ValueError as e:
            choices[crit] = {"error": str(e)}
    return choices


def grid_for(cfg: GraphConfig, P) -> np.ndarray:
    if cfg.thresholds:
        return np.asarray(sorted(cfg.thresholds), float)
    return threshold_grid(P, cfg.num_thresholds, cfg.upper_quantile, cfg.lower_factor)


def run(cfg: Config, run_dir: Path, seed: int) -> dict:
    """Run the sweep in ``graph.dtype`` (float64 turns on ``jax_enable_x64`` for the run)."""
    with jax.enable_x64(cfg.graph.dtype == "float64"):
        return _run(cfg, Path(run_dir), seed)


def _run(cfg: Config, run_dir: Path, seed: int) -> dict:
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    stage(f"loading frames ({cfg.data.source})")
    face = load_face(cfg.data, seed)
    timings["load_s"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    n, m = face.positions.shape[:2]
    stage(f"{n} frames × {m} markers: marker-distance matrices and their distances")
    P = state_distances(face.positions, cfg.graph.dtype)
    timings["features_pairwise_s"] = time.perf_counter() - t0
    th = grid_for(cfg.graph, P)

    t0 = time.perf_counter()
    sw = sweep_stage(run_dir, P, th, cfg.graph.batch_size, cfg.dim)
    timings["sweep_s"] = time.perf_counter() - t0
    choices = all_choices(sw, cfg.select.max_mean_degree)
    chosen = choices[cfg.select.criterion]
    if "error" in chosen:
        raise ConfigError(chosen["error"] + f" ({sweep_message(sw, P)})")

    t0 = time.perf_counter()
    eps = chosen["threshold"]
    for sk in chosen.get("skipped_bridged", []):  # issue 44: said, not silently passed over
        note(f"ε = {sk['threshold']:.4g} (r = {sk['score']:.4f}) skipped: its graph is held "
             f"together by one edge that splits off {sk['bridge_part']} frames, so its r "
             "measures that chain (fxspace.choose_threshold, min_bridge_part)")  # fmt: skip
    stage(f"ε = {eps:.4g} ({cfg.select.criterion}, r = {chosen['score']:.4f}): final space")
    sp = _stage(run_dir, "space", lambda: _space_arrays(P, eps, cfg.dim))
    timings["final_space_s"] = time.perf_counter() - t0
    _write_outputs(cfg, run_dir, face, P, sw, choices, sp)
    return _metrics(cfg, face, P, sw, choices, sp, timings)


def _space_arrays(P, eps: float, dim: int) -> dict[str, Any]:
    es = expression_space(None, eps, dim, pairwise=P, paths=False)
    return {
        "embedding": es.embedding,
        "geodesic": np.asarray(es.geodesics.distances, np.float32),
        "eigenvalues": es.mds.eigenvalues,
        "score": es.score,
    }


def _write_outputs(cfg: Config, run_dir: Path, face, P, sw, choices, sp) -> None:
    from fxspace.plot import plot_embedding_panels, plot_sweep

    crit = cfg.select.criterion
    chosen = choices[crit]
    Y = np.asarray(sp["embedding"])
    save_npz_atomic(
        run_dir / "expression_space.npz",
        embedding=Y,
        geodesic=sp["geodesic"],
        take=face.take,
        frame=face.frame,
        label=face.label,
        threshold=chosen["threshold"],
        criterion=crit,
        positions=face.positions.astype(np.float32),
        marker_names=np.asarray(face.marker_names),
        take_names=np.asarray(face.take_names),
        label_names=np.asarray(face.label_names),
    )
    marks = {k: v["threshold"] for k, v in choices.items() if "threshold" in v}
    fig = plot_sweep(
        sw.thresholds, sw.scores, sw.connected, marks, float(connecting_threshold(P)),
        mean_degree=sw.mean_degree, chosen=crit, largest=float(np.max(np.asarray(P))),
        paper_point=(PAPER_THRESHOLD_MM, SEED_PAPER_R),
    )  # fmt: skip
    save_figure_atomic(fig, run_dir / "r_vs_threshold.png")
    r = float(sp["score"])
    title = f"expression space, ε = {chosen['threshold']:.4g} chosen by {crit}, r = {r:.4f}"
    panels = plot_embedding_panels(Y, face.label, face.frame, face.label_names, title)
    save_figure_atomic(panels, run_dir / "expression_space.png")
    for other, ch in choices.items():
        if other == crit or "threshold" not in ch:
            continue
        Yc = np.asarray(expression_space(None, ch["threshold"], cfg.dim, pairwise=P,
                                         paths=False).embedding)  # fmt: skip
        t = f"ε = {ch['threshold']:.4g} ({other}, not chosen), r = {ch['score']:.4f}"
        fig = plot_embedding_panels(Yc, face.label, face.frame, face.label_names, t)
        save_figure_atomic(fig, run_dir / f"expression_space_{other}.png")


def _metrics(cfg: Config, face, P, sw, choices, sp, timings) -> dict:
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
    largest = float(np.max(np.asarray(P)))
    chosen = choices[cfg.select.criterion]
    return {
        "frames": int(len(sp["embedding"])),
        "dtype": str(P.dtype),
        "dim": int(sp["embedding"].shape[1]),
        "missing": {"policy": cfg.data.missing, "max_gap": cfg.data.max_gap, **face.missing},
        "reading": face.reading,  # what was read; every drop/resample/conversion said
        "markers": int(face.positions.shape[1]),
        "takes": list(face.take_names),
        "state_distance": "Frobenius distance between marker-distance matrices (mm)",
        "connecting_threshold": float(connecting_threshold(P)),
        "largest_distance": largest,
        "thresholds_reach_largest_distance": bool(
            np.isclose(float(np.max(sw.thresholds)), largest, rtol=1e-6)
        ),
        "sweep": per,
        "disconnected_note": sweep_message(sw, P),
        "criterion": cfg.select.criterion,
        "best_threshold": chosen["threshold"],
        "r_at_best": float(sp["score"]),
        "choices": choices,
        "paper": {"threshold_mm": PAPER_THRESHOLD_MM, "r": SEED_PAPER_R},
        "seed_paper_r": SEED_PAPER_R,
        "eigenvalues": np.asarray(sp["eigenvalues"]).tolist(),
        "timings": timings,
    }
