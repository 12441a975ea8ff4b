"""Scale benchmark (issue 14): the expression space past one dense matrix.

``python experiments/bench_scale.py --frames N`` runs the whole chain at N frames (the
synthetic face by default; ``--source animface`` resamples the real AnimFace capture to N
frames) and prints one table, per stage: wall time and peak resident memory (sampled
every 20 ms while the stage runs; the process baseline is printed apart).

ours:   features → sparse neighbourhood graph → max-min landmarks + landmark geodesics →
        landmark MDS → landmark score, then the navigation at scale: FCM levels
        (10, 20, 40, … centres), links on the sparse graph and a route between centres;
        then the finest level (every frame a centre, links on the graph's edges; skip
        with ``--no-finest``) and a route query: 4 key centres of the coarsest level
        refined level by level down to frames (`fxspace.navigation.navigate` on the k-NN graph).
peers:  the route a user would otherwise take in the same run — scipy Dijkstra from the
        same landmarks on the same graph, scikit-learn's k-NN graph, and scikit-learn
        ``Isomap`` end to end (its own landmark-free graph) where it fits in memory.
quality (where the exact method fits, ``--exact-max``): exact all-pairs geodesics on the
        same graph (scipy Dijkstra), the exact classical MDS, and Pearson r of each
        embedding against the exact geodesics, plus r between the landmark and the exact
        embeddings' distances.

Exits non-zero if any stage fails. Usage:
``python experiments/bench_scale.py --frames 2400 [--source animface] [--landmarks 256]
[--k 10] [--levels 4] [--exact-max 5000] [--isomap-max 10000] [--no-finest]
[--scheduler local|tcp://HOST:PORT] [--workers 2] [--json out.json]``.
``--scheduler local`` runs the per-block stages (features, neighbour search, landmark
rounds, FCM sums) on a local Dask cluster of ``--workers`` processes, as the navigation
pipeline's ``[graph] scheduler``; the memory figures then include the workers.
"""

from __future__ import annotations

import argparse
import os
import resource
import sys
import tempfile
import threading
import time
import traceback

import numpy as np


def _rss_mb() -> float:
    """Resident memory of this process and its children (a local Dask cluster's workers)."""
    try:
        import psutil

        me = psutil.Process()
        procs = [me, *me.children(recursive=True)]
    except ImportError:  # no psutil (it comes with Dask): this process alone
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20
    total = 0
    for p in procs:
        try:
            total += p.memory_info().rss
        except psutil.Error:  # a worker that just exited
            pass
    return total / 2**20


class _Skipped(Exception):
    pass


class Stage:
    """Time a stage and sample the peak RSS while it runs."""

    rows: list[dict] = []
    failed: list[str] = []

    def __init__(self, name: str, group: str = "ours"):
        self.name, self.group = name, group

    def __enter__(self):
        if Stage.failed:  # caught by _run: nothing after a failed stage runs
            raise _Skipped(self.name)
        self.peak = _rss_mb()
        self._stop = threading.Event()

        def sample():
            while not self._stop.wait(0.02):
                self.peak = max(self.peak, _rss_mb())

        self._t = threading.Thread(target=sample, daemon=True)
        self._t.start()
        self.t0 = time.perf_counter()
        return self

    def __exit__(self, exc_type, exc, tb):
        dt = time.perf_counter() - self.t0
        self._stop.set()
        self._t.join()
        self.peak = max(self.peak, _rss_mb())
        ok = exc_type is None
        row = {"stage": self.name, "group": self.group, "s": dt, "peak_mb": self.peak, "ok": ok}
        print(f"  [{self.name}: {dt:.1f} s, peak {self.peak:.0f} MB]", file=sys.stderr, flush=True)
        Stage.rows.append(row)
        if not ok:
            Stage.failed.append(self.name)
            row["error"] = "".join(traceback.format_exception_only(exc_type, exc)).strip()
            print(f"  stage {self.name} FAILED: {row['error']}", file=sys.stderr, flush=True)
        return True  # the next stage is skipped; the exit code reports the failure


def _frames(T: int, source: str, seed: int = 0) -> tuple[np.ndarray, str]:
    from fxspace.datasets import FaceData, load_face

    # float32, as the navigation pipeline's default graph.dtype (the features on disk:
    # 7 GB at 10⁶ frames of 60 markers, not 14)
    if source == "animface":
        face = load_face(FaceData(source="animface", target_frames=T), seed)
        return np.asarray(face.positions, np.float32), "AnimFace (resampled)"
    from fxspace.synthetic import synthetic_face

    X = synthetic_face(n_frames=T, seed=seed).sequence.positions
    return np.asarray(X, np.float32), "synthetic face"


def _landmark_medians(g, L: int, csr, lm: np.ndarray, repeats: int, out: dict) -> None:
    """Ours (max-min landmarks + their rows) against scipy's Dijkstra from the same
    landmarks, alternated ``repeats`` times (the first pair is the stages above); medians.
    Also scipy's best call: the symmetric matrix with ``directed=True`` (half the work)."""
    from scipy.sparse.csgraph import dijkstra

    import fxspace as fx
    from fxspace.pipelines.navigation import GraphConfig

    ours = [r["s"] for r in Stage.rows if r["stage"] == "landmark geodesics" and r["ok"]]
    peer = [r["s"] for r in Stage.rows if r["stage"] == "scipy Dijkstra, same landmarks"]
    best = []
    sym = csr.astype(np.float64)
    sym.sort_indices()
    for _ in range(max(repeats - 1, 0)):
        t = time.perf_counter()
        fx.farthest_point_landmarks(g, L, batch=GraphConfig().landmark_batch or None)
        ours.append(time.perf_counter() - t)
        t = time.perf_counter()
        dijkstra(csr, directed=False, indices=lm)
        peer.append(time.perf_counter() - t)
    for _ in range(max(repeats, 1)):
        t = time.perf_counter()
        dijkstra(sym, directed=True, indices=lm)
        best.append(time.perf_counter() - t)
    mo, mp, mb = (float(np.median(v)) for v in (ours, peer, best))
    out.update(
        landmark_s_ours=ours,
        landmark_s_scipy=peer,
        landmark_s_scipy_directed=best,
        ratio_landmark_geodesics_median=mp / mo,
        ratio_landmark_vs_scipy_directed=mb / mo,
    )
    print(
        f"\nlandmark geodesics, {len(lm)} landmarks, median of {len(ours)} runs (machine "
        f"shared: noisy): ours {mo:.2f} s (max-min choice included), scipy Dijkstra "
        f"(directed=False, all at once) {mp:.2f} s, ratio {mp / mo:.2f}x; scipy directed "
        f"on the symmetric matrix {mb:.2f} s, ratio {mb / mo:.2f}x",
        flush=True,
    )


def _navigation(a, g, mds, out: dict, client=None) -> None:
    """The navigation pipeline's hierarchy on the graph (`fxspace.pipelines.navigation.
    build_levels` of its ``[hierarchy]`` defaults: truncated FCM levels in blocks, links
    by the paper's rule with ρ by its experiment, no bridges; the finest level where every
    frame is a centre) and a route of 4 key centres of the coarsest level refined level
    by level."""
    from fxspace.expression import to_scipy
    from fxspace.navigation import bridge_keys, navigate
    from fxspace.pipelines.navigation import Config, GraphConfig, HierarchyConfig, build_levels

    Y = np.asarray(mds.embedding, np.float64)
    cfg = Config(graph=GraphConfig(kind="knn", k=a.k, landmarks=a.landmarks),
                 hierarchy=HierarchyConfig(levels=a.levels, finest=not a.no_finest))  # fmt: skip
    name = "hierarchy: FCM levels + links" + ("" if a.no_finest else " + finest level")
    with Stage(name):
        h = build_levels(cfg, Y, g, a.seed, kind="knn", client=client)
    lvs = h.levels
    out["levels"] = [int(lv.n_clusters) for lv in lvs]
    out["links"] = [int(lv.n_links) for lv in lvs]
    out["links_bridged"] = int(sum(lv.n_bridges for lv in lvs))
    out["levels_converged"] = f"{sum(bool(lv.converged) for lv in lvs)}/{len(lvs)}"
    out["level_steps"] = [int(lv.stats.get("total_steps", -1)) for lv in lvs]
    with Stage("route: 4 keys, coarsest → " + ("centres" if a.no_finest else "frames")):
        picks = np.linspace(0, lvs[0].n_clusters - 1, 4).astype(int).tolist()
        keys, _ = bridge_keys(h, g, 0, picks)
        routes = navigate(h, g, keys)
        fr = np.asarray(routes[-1].frames)
        csr = to_scipy(g)
        out["route_levels_centres"] = [len(r.centres) for r in routes]
        out["route_finest_frames"] = int(len(fr))
        out["route_is_graph_walk"] = bool(
            np.all(fr[1:] != fr[:-1]) and np.all(csr[fr[:-1], fr[1:]] > 0)
        )

def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--frames", type=int, default=2400)
    ap.add_argument("--source", choices=["synthetic", "animface"], default="synthetic")
    ap.add_argument("--landmarks", type=int, default=256)
    ap.add_argument("--k", type=int, default=10, help="neighbours chosen by each frame")
    ap.add_argument("--levels", type=int, default=4, help="FCM levels: 10, 20, 40, …")
    ap.add_argument("--exact-max", type=int, default=5000)
    ap.add_argument("--isomap-max", type=int, default=10000)
    ap.add_argument("--no-navigation", action="store_true")
    ap.add_argument(
        "--no-finest",
        action="store_true",
        help="skip the finest level (T centres) and the route refined down to it",
    )
    ap.add_argument("--no-peers", action="store_true")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--json", default=None)
    ap.add_argument(
        "--repeats", type=int, default=3, help="runs of ours vs scipy on the same landmarks"
    )
    ap.add_argument("--scheduler", default="", help="'' here (default), 'local' (a local "
                    "Dask cluster of --workers processes) or tcp://HOST:PORT (--tmp must "
                    "then be a folder every worker reaches)")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--tmp", default=None, help="folder for the streamed features (default: the "
                    "system's temporary folder; 7 GB at 10⁶ frames of 60 markers)")
    a = ap.parse_args(argv)
    from fxspace.pipelines._dask import check_stage_scheduler, dask_client

    check_stage_scheduler(a.scheduler, a.workers, "--scheduler")
    with tempfile.TemporaryDirectory(dir=a.tmp) as tmp, dask_client(a.scheduler,
                                                                     a.workers) as client:
        return _run(a, tmp, client)


def _run(a, tmp: str, client=None) -> int:
    import jax
    import jax.numpy as jnp

    import fxspace as fx
    from fxspace.expression import to_scipy
    from fxspace.pipelines.navigation import GraphConfig

    T, L = a.frames, min(a.landmarks, a.frames)
    X, source = _frames(T, a.source, a.seed)
    base = _rss_mb()
    print(
        f"T = {T} frames of {source} ({X.shape[1]} markers), k = {a.k}, L = {L} landmarks, "
        f"{jax.device_count()} × {jax.devices()[0].platform}, float32, "
        f"{'here' if client is None else f'Dask {a.scheduler} ({a.workers} workers)'}; "
        f"baseline RSS {base:.0f} MB (other agents may share the CPU: times are noisy)",
        flush=True,
    )
    out: dict = {"T": T, "source": source, "k": a.k, "L": L}
    F = g = geo = mds = None
    store = os.path.join(tmp, "features.npy")

    try:  # a failed stage ends the chain: the stages after it have nothing to work on
        with Stage("features + k-NN graph (streamed)"):
            # the (T, P) features live in a memory-mapped .npy, never whole in RAM
            g = fx.expression.neighbourhood_graph_blocks(X, k=a.k, store=store, client=client)
        with Stage("join the graph's pieces (takes)"):
            # several takes make a graph in pieces: joined at their closest frames, as the
            # navigation pipeline's [graph] join = "closest" does
            g, joins = fx.expression.join_components(g, X)
            out["components_joined"] = len(joins.sizes) if len(joins.lengths) else 0
            out["max_degree"] = int(g.indices.shape[1])
        F = np.load(store, mmap_mode="r")
        with Stage("k-NN recall (1000 frames, exact)", "check"):
            q = fx.expression.knn_quality(F, g, k=a.k, sample=1000, seed=a.seed)
            out["knn_recall"], out["knn_distance_ratio"] = q.recall, round(q.distance_ratio, 4)
            out["mean_degree"] = float(np.mean(g.degree))
        with Stage("landmark geodesics"):
            # the navigation pipeline's landmarks: max-min in rounds of [graph] landmark_batch
            batch = GraphConfig().landmark_batch or None
            geo = fx.farthest_point_landmarks(g, L, batch=batch, client=client if batch else None)
        with Stage("landmark MDS"):
            mds = fx.landmark_mds(geo, dim=2)
            jax.block_until_ready(mds.embedding)
        with Stage("score"):
            out["r_landmark_pairs"] = float(fx.landmark_score(geo, mds.embedding))
        chain = [
            r
            for r in Stage.rows
            if r["stage"]
            in ("features + k-NN graph (streamed)", "join the graph's pieces (takes)",
                "landmark geodesics", "landmark MDS", "score")
        ]
        out["chain_s"] = sum(r["s"] for r in chain)
        out["chain_peak_mb"] = max(r["peak_mb"] for r in chain)

        if not a.no_navigation and mds is not None:
            _navigation(a, g, mds, out, client)

        if not a.no_peers and g is not None and geo is not None:
            from scipy.sparse.csgraph import dijkstra

            csr = to_scipy(g)
            lm = np.asarray(geo.landmarks)
            with Stage("scipy Dijkstra, same landmarks", "peer"):
                Dp = dijkstra(csr, directed=False, indices=lm)
            out["max_rel_diff_vs_scipy"] = float(
                np.max(np.abs(np.asarray(geo.distances, np.float64) - Dp) / np.maximum(Dp, 1e-9))
            )
            out["identical_to_scipy"] = bool(
                np.array_equal(np.asarray(geo.distances),
                               Dp.astype(np.asarray(geo.distances).dtype))  # fmt: skip
            )
            _landmark_medians(g, L, csr, lm, a.repeats, out)
            if T <= 50000:
                from sklearn.neighbors import kneighbors_graph

                with Stage("sklearn k-NN graph", "peer"):
                    kneighbors_graph(np.asarray(F), a.k, mode="distance", n_jobs=-1)
            if T <= a.isomap_max:
                from sklearn.manifold import Isomap

                with Stage("sklearn Isomap (dense)", "peer"):
                    iso = Isomap(n_neighbors=a.k, n_components=2, path_method="D", n_jobs=-1)
                    Yiso = iso.fit_transform(np.asarray(F, np.float64))

        if T <= a.exact_max and g is not None and mds is not None:
            from scipy.sparse.csgraph import dijkstra

            with Stage("exact geodesics (quality)", "exact"):
                Dex = dijkstra(to_scipy(g), directed=False).astype(np.float32)
            with Stage("exact classical MDS (quality)", "exact"):
                cm = fx.classical_mds(jnp.asarray(Dex), dim=2)
                jax.block_until_ready(cm.embedding)
            Dj = jnp.asarray(Dex)
            out["r_exact_embedding"] = float(fx.pearson_score(Dj, cm.embedding))
            out["r_landmark_embedding"] = float(fx.pearson_score(Dj, mds.embedding))
            E = fx.pairwise_distances(cm.embedding)
            out["r_landmark_vs_exact_embedding"] = float(fx.pearson_score(E, mds.embedding))
            if "Yiso" in locals():
                out["r_isomap_embedding"] = float(fx.pearson_score(Dj, jnp.asarray(Yiso, Dj.dtype)))

    except _Skipped as e:
        print(f"  stage {e} and the rest skipped after {Stage.failed}", file=sys.stderr)

    print(f"\n{'stage':<34} {'group':<6} {'time s':>8} {'peak MB':>9}")
    for r in Stage.rows:
        flag = "" if r["ok"] else "  FAILED"
        print(f"{r['stage']:<34} {r['group']:<6} {r['s']:>8.2f} {r['peak_mb']:>9.0f}{flag}")
    if "chain_s" in out:
        print(
            f"{'chain: graph → landmarks → MDS → r':<34} {'ours':<6} {out['chain_s']:>8.2f} "
            f"{out['chain_peak_mb']:>9.0f}"
        )
    peer = {r["stage"]: r["s"] for r in Stage.rows if r["ok"]}
    if "scipy Dijkstra, same landmarks" in peer and "landmark geodesics" in peer:
        out["ratio_landmark_geodesics"] = (
            peer["scipy Dijkstra, same landmarks"] / peer["landmark geodesics"]
        )
    if "sklearn Isomap (dense)" in peer and "chain_s" in out:
        out["ratio_isomap_vs_chain"] = peer["sklearn Isomap (dense)"] / out["chain_s"]
    for key in sorted(out):
        if key.startswith(("r_", "ratio_", "max_", "mean_", "levels", "links", "route", "ident")):
            v = out[key]
            print(f"{key}: {v:.4f}" if isinstance(v, float) else f"{key}: {v}")
    ours = [r for r in Stage.rows if r["group"] == "ours"]
    out["frames"] = T
    out["seconds"] = round(sum(r["s"] for r in ours), 1)
    # the process's own peak (ru_maxrss: every stage and the frames' making included), or
    # the sampled peak of it and its workers together where that is higher
    own = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**10
    out["peak_rss_gb"] = round(max([own] + [r["peak_mb"] for r in Stage.rows]) / 2**10, 2)
    print("\nsummary (ours, features to the route down to frames):")
    for key in ("frames", "seconds", "peak_rss_gb", "links_bridged", "levels_converged",
                "knn_recall", "knn_distance_ratio", "components_joined"):  # fmt: skip
        if key in out:
            print(f"{key}: {out[key]}")
    out["stages"] = Stage.rows
    record = []
    if "ratio_landmark_geodesics" in out:
        record.append({"case": f"{T} frames: landmark geodesics", "size": T,
                       "ours": "landmark geodesics", "ours_s": peer["landmark geodesics"],
                       "peer": "scipy Dijkstra, same landmarks",
                       "peer_s": peer["scipy Dijkstra, same landmarks"]})  # fmt: skip
    if "ratio_isomap_vs_chain" in out:
        record.append({"case": f"{T} frames: whole chain", "size": T,
                       "ours": "graph → landmarks → MDS → r", "ours_s": out["chain_s"],
                       "peer": "sklearn Isomap (dense)",
                       "peer_s": peer["sklearn Isomap (dense)"]})  # fmt: skip
    if record:
        from fxspace.runs import write_bench

        write_bench(
            f"scale_{T}",
            record,
            title=f"Past the dense range: {T} frames",
            command="python experiments/bench_scale.py " + " ".join(sys.argv[1:]),
        )
    if a.json:
        from fxspace.runs import write_json_atomic

        write_json_atomic(a.json, out)
    if Stage.failed:
        print(f"FAILED stages: {Stage.failed}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
