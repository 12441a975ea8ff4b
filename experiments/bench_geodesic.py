"""Geodesic benchmark (issue 2): fxspace vs scipy (FW, Dijkstra) and scikit-learn Isomap.

For T frames of realistic data (the AnimFace capture, resampled in time to T frames; the
synthetic face when the data is absent) and one ε-graph (``--eps-factor`` × the smallest
connecting threshold), prints in one run the median time of ≥ 3 runs of

- ours: `floyd_warshall` (distances), `geodesic_distances` (+ next-hop matrix),
  and the whole chain graph → geodesic → MDS → Pearson r (from the pairwise matrix);
- scipy `shortest_path` with method FW and with Dijkstra on the sparse graph (+
  predecessors for the path-comparable row);
- scikit-learn `Isomap` end to end on the same neighbourhood graph (radius = ε);

and the ratios, with compile time reported separately and the max relative difference
to scipy. Also the min-plus rate our Floyd reaches (T³ updates / time) against the
machine's peak for an add-then-min stream, measured in the same run by a streaming kernel
on in-cache tiles (`stream_peak`, before and after), and a row on the real capture's own
frames (``--real-frames``, thinned, not resampled) at the connecting ε.

Usage: ``python experiments/bench_geodesic.py [--sizes 1000 2400 4800] [--repeats 3]
[--fw-max 2400] [--real-frames 2461] [--quick] [--json out.json]``.
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
if "--single-device" not in sys.argv and _FLAG not in os.environ.get("XLA_FLAGS", ""):
    # every core as a JAX device, as the fxspace command does (before JAX starts its backends)
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
    res = {"T": T, "source": source, "epsilon": eps, "mean_degree": deg}

    # ours: compile separately
    t0 = time.perf_counter()
    method = "sharded" if jax.device_count() > 1 else "blocked"
    res["ours_method"] = method
    fw = jax.jit(lambda w: fx.floyd_warshall(w, method=method)).lower(W).compile()
    res["ours_compile_s"] = time.perf_counter() - t0
    fw(W).block_until_ready()
    peak0 = stream_peak(repeats)  # the machine's rate right before and after our Floyd
    res["ours_fw_s"], D = _median_time(lambda: fw(W), repeats)
    res["peaks"] = [peak0, stream_peak(repeats)]
    res["peak"] = float(np.mean(res["peaks"]))
    fw1 = jax.jit(lambda w: fx.floyd_warshall(w, method="blocked"))
    fw1(W).block_until_ready()
    res["ours_fw_1dev_s"], _ = _median_time(lambda: fw1(W), repeats)
    fx.geodesic_distances(W, method=method)  # compile
    res["ours_fw_nexthop_s"], geo = _median_time(
        lambda: fx.geodesic_distances(W, method=method), repeats
    )

    @jax.jit
    def chain(P, eps):
        Wc = fx.epsilon_graph(P, eps)
        Dc = fx.floyd_warshall(Wc)
        mds = fx.classical_mds(Dc, 2)
        return mds.embedding, fx.pearson_score(Dc, mds.embedding)

    t0 = time.perf_counter()
    jax.block_until_ready(chain(P, eps))
    res["chain_compile_s"] = time.perf_counter() - t0
    res["ours_chain_s"], (Y, r) = _median_time(lambda: chain(P, eps), repeats)
    res["r"] = float(r)

    # scipy on the same sparse graph (float64, as scipy computes)
    Pn = np.asarray(P, np.float64)
    # explicit zero-weight edges (repeated frames) must stay edges: build from dense with inf
    csr = csgraph_from_dense(np.where(np.isfinite(Wn), Pn, np.inf), null_value=np.inf)
    res["scipy_dijkstra_s"], Dd = _median_time(
        lambda: shortest_path(csr, method="D", directed=False), repeats
    )
    res["scipy_dijkstra_pred_s"], _ = _median_time(
        lambda: shortest_path(csr, method="D", directed=False, return_predecessors=True), repeats
    )
    Dn = np.asarray(D, np.float64)
    fin = np.isfinite(Dd) & (Dd > 0)
    res["max_rel_diff_vs_scipy"] = float(np.max(np.abs(Dn[fin] - Dd[fin]) / Dd[fin]))
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
    res["ratio_dijkstra"] = res["scipy_dijkstra_s"] / res["ours_fw_s"]
    res["minplus_rate"] = float(T) ** 3 / res["ours_fw_s"]  # updates/s (padding not counted)
    res["ratio_dijkstra_paths"] = res["scipy_dijkstra_pred_s"] / res["ours_fw_nexthop_s"]
    if "scipy_fw_s" in res:
        res["ratio_fw"] = res["scipy_fw_s"] / res["ours_fw_s"]
        res["ratio_fw_1dev"] = res["scipy_fw_s"] / res["ours_fw_1dev_s"]
    res["ratio_dijkstra_1dev"] = res["scipy_dijkstra_s"] / res["ours_fw_1dev_s"]
    if "sklearn_isomap_s" in res:
        res["ratio_isomap"] = res["sklearn_isomap_s"] / res["ours_chain_s"]
    return res


def _row_text(r: dict) -> str:
    def f(k, w=7, d=3):
        return f"{r[k]:>{w}.{d}f}" if k in r else f"{'—':>{w}}"

    label = f"{r['T']}{'r' if r.get('real') else ''}"
    return (
        f"{label:>6} {r['mean_degree']:>5.0f} {f('ours_fw_s', 8)} {f('ours_fw_1dev_s')} "
        f"{f('ours_fw_nexthop_s')} {f('ours_chain_s')} {f('ours_compile_s', 8, 2)} "
        f"{f('scipy_dijkstra_s', 9)} {f('scipy_dijkstra_pred_s')} {f('scipy_fw_s', 9)} "
        f"{f('sklearn_isomap_s', 8)} {f('ratio_dijkstra', 6, 2)} "
        f"{f('ratio_dijkstra_paths', 6, 2)} {f('ratio_fw', 6, 1)} {f('ratio_isomap', 6, 2)} "
        f"{r['minplus_rate'] / 1e9:>7.2f} {100 * r['minplus_rate'] / r['peak']:>5.0f}% "
        f"{r['max_rel_diff_vs_scipy']:>8.1e}"
    )


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
        "--single-device", action="store_true", help="do not expose every CPU core as a JAX device"
    )  # read before JAX starts, at the top of this file
    a = ap.parse_args(argv)
    sizes = [600, 1000] if a.quick else a.sizes
    print(
        f"devices: {jax.device_count()} × {jax.devices()[0].platform}, float32, "
        f"median of {a.repeats} runs, ε = {a.eps_factor} × connecting threshold; 'peak' = "
        "ours FW's min-plus rate (T³ / time) over the add-then-min stream peak measured "
        "right before and after it (all devices, in-cache tiles); the machine may be "
        "shared: every figure is noisy",
        flush=True,
    )
    hdr = (
        f"{'T':>6} {'deg':>5} {'ours FW':>8} {'1 dev':>7} {'+next':>7} {'chain':>7} "
        f"{'compile':>8} "
        f"{'Dijkstra':>9} {'+pred':>7} {'scipy FW':>9} {'Isomap':>8} "
        f"{'×Dijk':>6} {'×Dpath':>6} {'×FW':>6} {'×Iso':>6} {'Gupd/s':>7} {'peak':>6} "
        f"{'maxrel':>8}"
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
        "T ending in r: the real capture's own frames (thinned, not resampled); Gupd/s: "
        "ours FW's min-plus updates per second"
    )
    for r in rows:
        r["peak_fraction"] = r["minplus_rate"] / r["peak"]
        if r["real"]:
            print(
                f"real capture T = {r['T']} (mean degree {r['mean_degree']:.0f}, ε = "
                f"{r['epsilon']:.4g}): ours FW {r['ours_fw_s']:.3f} s vs scipy Dijkstra "
                f"{r['scipy_dijkstra_s']:.3f} s = {r['ratio_dijkstra']:.2f}x; min-plus rate "
                f"{r['minplus_rate'] / 1e9:.2f} G updates/s = {100 * r['peak_fraction']:.0f}% "
                f"of the measured peak ({r['peak'] / 1e9:.2f} G updates/s)"
            )
    if a.json:
        from fxspace.runs import write_json_atomic

        write_json_atomic(a.json, {"device": str(jax.devices()[0]), "rows": rows})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
