"""Geodesic benchmark (issues 2, 31): fxspace vs scipy (Dijkstra, FW) and scikit-learn Isomap.

For T frames of realistic data (the AnimFace capture, resampled in time to T frames; the
synthetic face when the data is absent) and one ε-graph (``--eps-factor`` × the smallest
connecting threshold), prints in one run the median time of ≥ 3 runs of

- ours, called as users call it (eager, ``method="auto"``, on one JAX device unless
  ``--all-cores``): `floyd_warshall` (distances; an undirected graph runs the folded
  Floyd), `geodesic_distances` (distances + the next-hop matrix that rebuilds every
  shortest path), the general (directed) blocked Floyd for reference, and the whole
  chain graph → geodesic → MDS → Pearson r (from the pairwise matrix);
- scipy `shortest_path` given the ε-graph as a CSR matrix (float64, no self-loops), with
  Dijkstra as scikit-learn's Isomap calls it (``directed=False``) and as a caller who
  knows the graph is symmetric can (``directed=True``: the same distances, no
  symmetrisation, faster), each without and with ``return_predecessors``; FW on the
  same graph up to ``--fw-max`` frames;
- scikit-learn `Isomap` end to end on the same neighbourhood graph (radius = ε);

and the ratios — against the *faster* of scipy's two Dijkstra calls — with compile time
reported separately, the max relative difference to scipy's distances, and a check of
every next hop against scipy's distances (``W[i,k] + D[k,j]`` vs ``D[i,j]``, and each
hop strictly closer to ``j``, so no walk can cycle). Also the min-plus rate our Floyd
reaches (updates performed / time: T³, or T³/2 folded) against the machine's peak for an
add-then-min stream, measured in the same run by a streaming kernel on in-cache tiles
(`stream_peak`, before and after), and a row on the real capture's own frames
(``--real-frames``, thinned, not resampled) at the connecting ε.

Usage: ``python experiments/bench_geodesic.py [--sizes 1000 2400 4800] [--repeats 3]
[--fw-max 2400] [--real-frames 2461] [--no-isomap] [--quick] [--all-cores] [--json out.json]``.
The real-capture figure of issue 31: ``--sizes --real-frames 2461 --no-isomap``.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

_FLAG = "xla_force_host_platform_device_count"
if "--all-cores" in sys.argv and _FLAG not in os.environ.get("XLA_FLAGS", ""):
    # every core as a JAX device, as FXSPACE_CPU_DEVICES=1 fxspace does (before JAX starts)
    os.environ["XLA_FLAGS"] = os.environ.get("XLA_FLAGS", "") + f" --{_FLAG}={os.cpu_count() or 1}"


def _median_time(fn, repeats):
    ts = []
    out = None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        jax.block_until_ready(out)
        ts.append(time.perf_counter() - t0)
    return statistics.median(ts), out


def _median_times(fns: dict, repeats: int) -> tuple[dict, dict]:
    """Median time of each of ``fns`` over ``repeats`` rounds, the calls *interleaved*
    (one of each per round), so that a shared machine's load falls on every entry alike.
    Returns ``(times, last outputs)``."""
    ts = {k: [] for k in fns}
    outs = {}
    for _ in range(repeats):
        for k, fn in fns.items():
            t0 = time.perf_counter()
            outs[k] = jax.block_until_ready(fn())
            ts[k].append(time.perf_counter() - t0)
    return {k: statistics.median(v) for k, v in ts.items()}, outs


def stream_peak(repeats: int = 3, rows: int = 64, cols: int = 512, steps: int = 2048) -> float:
    """The machine's add-then-min rate (updates/s): every local device streams
    ``d = min(d, c[:, k] + r[k])`` over ``steps`` pivots on its own ``rows × cols`` tile
    (in cache), the inner loop of min-plus Floyd without its memory traffic. Median."""
    nd = jax.local_device_count()

    @jax.pmap
    def kern(d, c, r):
        def body(k, d):
            return jnp.minimum(d, c[:, k, None] + r[k][None, :])

        return jax.lax.fori_loop(0, steps, body, d, unroll=8)

    key = jax.random.split(jax.random.key(0), 3)
    d = jax.random.uniform(key[0], (nd, rows, cols)) + 2.0
    c = jax.random.uniform(key[1], (nd, rows, steps))
    r = jax.random.uniform(key[2], (nd, steps, cols))
    kern(d, c, r).block_until_ready()
    t, _ = _median_time(lambda: kern(d, c, r), repeats)
    return nd * rows * cols * steps / t


def _frames(T: int, seed: int = 0, real: bool = False) -> tuple[np.ndarray, str]:
    from fxspace.datasets import FaceData, load_face

    if real:  # the capture's own frames, evenly thinned to at most T (no resampling)
        face = load_face(FaceData(source="animface", max_frames=T), seed)
        return face.positions, "AnimFace (real frames)"
    try:
        face = load_face(FaceData(source="animface", target_frames=T), seed)
        return face.positions, "AnimFace (resampled)"
    except (ValueError, FileNotFoundError):
        face = load_face(FaceData(source="synthetic", synthetic_frames=T), seed)
        return face.positions, "synthetic face"


def check_next_hops(W: np.ndarray, nxt: np.ndarray, ref: np.ndarray) -> tuple[float, bool]:
    """Every next hop ``k = nxt[i, j]`` against scipy's float64 distances ``ref``: the max
    relative gap of ``W[i,k] + ref[k,j]`` to ``ref[i,j]`` (0 for an exact shortest path)
    and whether every hop is an edge strictly closer to ``j`` (so no walk can cycle)."""
    n = len(W)
    worst, progress = 0.0, True
    for s in range(0, n, 256):  # row blocks: bounded memory
        i, j = np.nonzero((ref[s : s + 256] > 0) & np.isfinite(ref[s : s + 256]))
        i = i + s
        k = nxt[i, j]
        if np.any(k < 0):
            return float("inf"), False
        step = W[i, k].astype(np.float64)
        worst = max(worst, float(np.max(np.abs(step + ref[k, j] - ref[i, j]) / ref[i, j])))
        progress &= bool(np.all(np.isfinite(step)) and np.all(ref[k, j] < ref[i, j]))
    return worst, progress


def bench_one(
    T: int, repeats: int, fw_max: int, eps_factor: float, isomap: bool, real: bool = False
) -> dict:
    from scipy.sparse.csgraph import csgraph_from_dense, shortest_path

    import fxspace as fx

    X, source = _frames(T, real=real)
    T = len(X)
    F = fx.distance_features(jnp.asarray(X, jnp.float32))
    P = jax.block_until_ready(fx.pairwise_distances(F))
    eps = float(fx.connecting_threshold(P)) * eps_factor
    W = jax.block_until_ready(fx.epsilon_graph(P, eps))
    Wn = np.asarray(W)
    deg = float((np.isfinite(Wn).sum() - T) / T)
    sym = bool(np.array_equal(Wn, Wn.T))
    res = {"T": T, "source": source, "epsilon": eps, "mean_degree": deg, "undirected": sym}

    # scipy is given the same graph as a CSR matrix (float64, as scipy computes; no
    # self-loops); explicit zero-weight edges (repeated frames) must stay edges: from dense
    Pn = np.asarray(P, np.float64)
    dense = np.where(np.isfinite(Wn), Pn, np.inf)
    np.fill_diagonal(dense, np.inf)
    csr = csgraph_from_dense(dense, null_value=np.inf)
    res["scipy_nnz"] = int(csr.nnz)

    # ours, called as users call it (eager, method="auto"); the first calls compile
    t0 = time.perf_counter()
    jax.block_until_ready(fx.floyd_warshall(W))
    res["ours_compile_s"] = time.perf_counter() - t0
    jax.block_until_ready(fx.geodesic_distances(W))
    # the headline: ours and scipy's Dijkstra interleaved, round by round
    peak0 = stream_peak(repeats)  # the machine's rate right before and after
    times, outs = _median_times(
        {
            "ours_fw_s": lambda: fx.floyd_warshall(W),
            "ours_fw_nexthop_s": lambda: fx.geodesic_distances(W),
            "scipy_dijkstra_s": lambda: shortest_path(csr, method="D", directed=False),
            "scipy_dijkstra_pred_s": lambda: shortest_path(
                csr, method="D", directed=False, return_predecessors=True
            ),
            "scipy_dijkstra_dir_s": lambda: shortest_path(csr, method="D", directed=True),
            "scipy_dijkstra_dir_pred_s": lambda: shortest_path(
                csr, method="D", directed=True, return_predecessors=True
            ),
        },
        repeats,
    )
    res["peaks"] = [peak0, stream_peak(repeats)]
    res["peak"] = float(np.mean(res["peaks"]))
    res.update(times)
    D, geo, Dd = outs["ours_fw_s"], outs["ours_fw_nexthop_s"], outs["scipy_dijkstra_s"]
    fw_dir = jax.jit(lambda w: fx.floyd_warshall(w, method="blocked", symmetric=False))
    fw_dir(W).block_until_ready()
    res["ours_fw_directed_s"], _ = _median_time(lambda: fw_dir(W), repeats)
    res["ours_nexthop_only_s"], _ = _median_time(lambda: fx.next_hops(W, D), repeats)

    @jax.jit
    def chain(P, eps):
        Wc = fx.epsilon_graph(P, eps)
        Dc = fx.floyd_warshall(Wc, symmetric=True)  # an ε-graph of a distance matrix
        mds = fx.classical_mds(Dc, 2)
        return mds.embedding, fx.pearson_score(Dc, mds.embedding)

    t0 = time.perf_counter()
    jax.block_until_ready(chain(P, eps))
    res["chain_compile_s"] = time.perf_counter() - t0
    res["ours_chain_s"], (Y, r) = _median_time(lambda: chain(P, eps), repeats)
    res["r"] = float(r)

    Dn = np.asarray(D, np.float64)
    Ddir = outs["scipy_dijkstra_dir_s"]  # directed=True: the same distances on this graph
    res["scipy_directed_equal"] = bool(np.allclose(Dd, Ddir, rtol=1e-12, atol=0))
    fin = np.isfinite(Dd) & (Dd > 0)
    res["max_rel_diff_vs_scipy"] = float(np.max(np.abs(Dn[fin] - Dd[fin]) / Dd[fin]))
    res["same_unreachable"] = bool(np.array_equal(np.isinf(Dn), np.isinf(Dd)))
    res["max_rel_path_err"], res["hops_closer"] = check_next_hops(Wn, np.asarray(geo.next_hop), Dd)
    if T <= fw_max:
        res["scipy_fw_s"], _ = _median_time(
            lambda: shortest_path(csr, method="FW", directed=False), repeats
        )
    if isomap:
        from sklearn.manifold import Isomap

        Fn = np.asarray(F, np.float64)

        def iso():
            return Isomap(
                n_neighbors=None, radius=eps, n_components=2, path_method="D", eigen_solver="arpack"
            ).fit_transform(Fn)

        res["sklearn_isomap_s"], _ = _median_time(iso, repeats)
    # against the faster of scipy's two Dijkstra calls (directed=True needs no symmetrising)
    res["scipy_best_s"] = min(res["scipy_dijkstra_s"], res["scipy_dijkstra_dir_s"])
    res["scipy_best_pred_s"] = min(res["scipy_dijkstra_pred_s"], res["scipy_dijkstra_dir_pred_s"])
    res["ratio_dijkstra"] = res["scipy_best_s"] / res["ours_fw_s"]
    res["ratio_dijkstra_paths"] = res["scipy_best_pred_s"] / res["ours_fw_nexthop_s"]
    res["ratio_dijkstra_isomap_call"] = res["scipy_dijkstra_s"] / res["ours_fw_s"]
    res["ratio_dijkstra_paths_isomap_call"] = (
        res["scipy_dijkstra_pred_s"] / res["ours_fw_nexthop_s"]
    )
    # min-plus updates performed (padding not counted): T³, or T³/2 folded (undirected)
    res["ours_kernel"] = "folded" if sym and T >= 256 else "blocked/scan"
    res["minplus_rate"] = float(T) ** 3 / (2 if sym and T >= 256 else 1) / res["ours_fw_s"]
    if "scipy_fw_s" in res:
        res["ratio_fw"] = res["scipy_fw_s"] / res["ours_fw_s"]
    if "sklearn_isomap_s" in res:
        res["ratio_isomap"] = res["sklearn_isomap_s"] / res["ours_chain_s"]
    return res


def _row_text(r: dict) -> str:
    def f(k, w=7, d=3):
        return f"{r[k]:>{w}.{d}f}" if k in r else f"{'—':>{w}}"

    label = f"{r['T']}{'r' if r.get('real') else ''}"
    return (
        f"{label:>6} {r['mean_degree']:>5.0f} {f('ours_fw_s', 8)} {f('ours_fw_directed_s')} "
        f"{f('ours_fw_nexthop_s')} {f('ours_nexthop_only_s')} {f('ours_chain_s')} "
        f"{f('ours_compile_s', 8, 2)} {f('scipy_dijkstra_s', 9)} {f('scipy_dijkstra_pred_s')} "
        f"{f('scipy_dijkstra_dir_s', 8)} {f('scipy_dijkstra_dir_pred_s')} {f('scipy_fw_s', 9)} "
        f"{f('sklearn_isomap_s', 8)} {f('ratio_dijkstra', 6, 2)} "
        f"{f('ratio_dijkstra_paths', 6, 2)} {f('ratio_fw', 6, 1)} {f('ratio_isomap', 6, 2)} "
        f"{r['minplus_rate'] / 1e9:>7.2f} {100 * r['minplus_rate'] / r['peak']:>5.0f}% "
        f"{r['max_rel_diff_vs_scipy']:>8.1e} {r['max_rel_path_err']:>8.1e}"
    )


def _record(rows: list[dict], argv) -> None:
    """The docs' record (`fxspace.runs.write_bench`): distances and distances + paths
    against the faster scipy Dijkstra call, per size."""
    from fxspace.runs import write_bench

    out = []
    for r in rows:
        case = f"{r['T']} real frames" if r["real"] else f"{r['T']} frames (resampled)"
        size = None if r["real"] else r["T"]
        out += [
            {"case": f"{case}: distances", "size": size, "ours": "floyd_warshall",
             "ours_s": r["ours_fw_s"], "peer": "scipy Dijkstra (CSR)",
             "peer_s": r["scipy_best_s"]},
            {"case": f"{case}: + paths", "size": size, "ours": "geodesic_distances",
             "ours_s": r["ours_fw_nexthop_s"], "peer": "scipy Dijkstra + predecessors",
             "peer_s": r["scipy_best_pred_s"]},
        ]  # fmt: skip
    if out:
        args = " ".join(sys.argv[1:] if argv is None else argv)
        write_bench("geodesic", out, title="Geodesics: all pairs, ε-graph of AnimFace",
                    command=f"python experiments/bench_geodesic.py {args}".strip())  # fmt: skip


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sizes", type=int, nargs="*", default=[1000, 2400, 4800])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument(
        "--fw-max",
        type=int,
        default=2400,
        help="skip scipy FW above this many frames (it is O(T³) in Python-free C but ~6 s at 2400)",
    )
    ap.add_argument("--eps-factor", type=float, default=1.05)
    ap.add_argument(
        "--real-frames",
        type=int,
        default=2461,
        help="also the real AnimFace capture thinned to this many frames (0: skip)",
    )
    ap.add_argument("--no-isomap", action="store_true")
    ap.add_argument("--quick", action="store_true", help="T = 600 and 1000, 3 repeats")
    ap.add_argument("--json", default=None, help="also write the results here")
    ap.add_argument(
        "--all-cores",
        action="store_true",
        help="expose every CPU core as a JAX device (default: one device, as issue 31 measures)",
    )  # read before JAX starts, at the top of this file
    ap.add_argument(
        "--single-device", action="store_true", help="the default; kept for old commands"
    )
    a = ap.parse_args(argv)
    if a.repeats < 3:
        ap.error("--repeats must be at least 3 (figures are medians of >= 3 runs)")
    sizes = [600, 1000] if a.quick else a.sizes
    print(
        f"devices: {jax.device_count()} × {jax.devices()[0].platform}, float32, "
        f"median of {a.repeats} runs, ε = {a.eps_factor} × connecting threshold; scipy given "
        "the ε-graph as CSR (float64); ×Dijk / ×Dpath: the faster of scipy's Dijkstra calls "
        "(directed=False as Isomap calls it, or directed=True) over ours (distances / "
        "distances + next hops); 'peak' = ours FW's min-plus rate (updates performed / "
        "time) over the add-then-min stream peak measured right before and after it "
        "(in-cache tiles); the machine may be shared: every figure is noisy",
        flush=True,
    )
    hdr = (
        f"{'T':>6} {'deg':>5} {'ours FW':>8} {'dir FW':>7} {'+next':>7} {'next':>7} "
        f"{'chain':>7} {'compile':>8} {'Dijkstra':>9} {'+pred':>7} {'Dij dir':>8} {'+pred':>7} "
        f"{'scipy FW':>9} {'Isomap':>8} "
        f"{'×Dijk':>6} {'×Dpath':>6} {'×FW':>6} {'×Iso':>6} {'Gupd/s':>7} {'peak':>6} "
        f"{'maxrel':>8} {'path err':>8}"
    )
    print(hdr)
    rows = []
    runs = [(T, False) for T in sizes] + ([(a.real_frames, True)] if a.real_frames > 0 else [])
    for T, real in runs:
        try:
            r = bench_one(T, a.repeats, a.fw_max, a.eps_factor, not a.no_isomap, real=real)
        except (ValueError, FileNotFoundError) as e:  # no capture under the data root
            print(f"real capture skipped: {e}")
            continue
        r["real"] = real
        rows.append(r)
        print(_row_text(r), flush=True)
    print(
        "T ending in r: the real capture's own frames (thinned, not resampled); ours FW: "
        "floyd_warshall (auto); dir FW: the general (directed) blocked kernel; +next: "
        "geodesic_distances (distances + next hops); next: next_hops alone; Dijkstra / Dij "
        "dir: scipy directed=False / True; Gupd/s: ours FW's min-plus updates per second; "
        "path err: max |W[i,k] + D[k,j] - D[i,j]| / D[i,j] over every next hop k, scipy's D"
    )
    for r in rows:
        r["peak_fraction"] = r["minplus_rate"] / r["peak"]
        if r["real"]:
            print(
                f"real capture T = {r['T']} (mean degree {r['mean_degree']:.0f}, ε = "
                f"{r['epsilon']:.4g}, {jax.device_count()} device): distances: ours "
                f"{r['ours_fw_s']:.3f} s vs scipy Dijkstra {r['scipy_best_s']:.3f} s = "
                f"{r['ratio_dijkstra']:.2f}x; distances + paths: ours "
                f"{r['ours_fw_nexthop_s']:.3f} s vs scipy Dijkstra + predecessors "
                f"{r['scipy_best_pred_s']:.3f} s = {r['ratio_dijkstra_paths']:.2f}x "
                f"(as Isomap calls scipy, directed=False: {r['scipy_dijkstra_s']:.3f} / "
                f"{r['scipy_dijkstra_pred_s']:.3f} s = {r['ratio_dijkstra_isomap_call']:.2f}x / "
                f"{r['ratio_dijkstra_paths_isomap_call']:.2f}x); distances within "
                f"{r['max_rel_diff_vs_scipy']:.1e} of scipy, every next hop within "
                f"{r['max_rel_path_err']:.1e} and closer to its target: {r['hops_closer']}; "
                f"min-plus rate {r['minplus_rate'] / 1e9:.2f} G updates/s = "
                f"{100 * r['peak_fraction']:.0f}% of the measured peak "
                f"({r['peak'] / 1e9:.2f} G updates/s)"
            )
    _record(rows, argv)
    if a.json:
        from fxspace.runs import write_json_atomic

        write_json_atomic(a.json, {"device": str(jax.devices()[0]), "rows": rows})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
