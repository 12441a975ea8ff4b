"""Benchmark: fxspace.dtw (JAX wavefront) vs dtaidistance and dtw-python on 300×65 pairs.

    python experiments/bench_dtw.py [--quick] [--batch B] [--repeats R]
    fxspace bench dtw [--quick]

Prints medians of R runs (compile time reported separately) for one pair and for a batch
of B pairs (ours: one ``jit(vmap(dtw_padded))`` call; peers: a Python loop), with paths,
and checks that our cost equals ``dtaidistance.dtw_ndim.distance`` (float64).
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time

os.environ.setdefault("TF_CPP_MIN_LOG_LEVEL", "2")

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402

from fxspace.motion import dtw_batch, dtw_padded  # noqa: E402


def _median_time(f, repeats: int) -> float:
    ts = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        f()
        ts.append(time.perf_counter() - t0)
    return statistics.median(ts)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="small batch, 3 repeats")
    ap.add_argument(
        "--batch", type=int, default=None, help="pairs per batch (default 64; quick 16)"
    )
    ap.add_argument("--repeats", type=int, default=None, help="timing repeats (default 5; quick 3)")
    ap.add_argument("--n", type=int, default=300, help="frames per sequence")
    ap.add_argument("--d", type=int, default=65, help="features per frame")
    args = ap.parse_args(argv)
    B = args.batch or (16 if args.quick else 64)
    R = args.repeats or (3 if args.quick else 5)
    try:
        from dtaidistance import dtw_ndim
        from dtw import dtw as dtw_python
    except ImportError as e:  # pragma: no cover
        print(f"bench_dtw needs the dev extras (dtaidistance, dtw-python): {e}")
        return 2

    rng = np.random.default_rng(0)
    A = rng.standard_normal((B, args.n, args.d)).cumsum(axis=1) * 0.1
    Bs = rng.standard_normal((B, args.n, args.d)).cumsum(axis=1) * 0.1
    a, b = A[0], Bs[0]

    single = jax.jit(dtw_padded)
    batched = jax.jit(dtw_batch)  # lax.map on CPU, vmap on GPU ("auto")
    vmapped = jax.jit(lambda x, y: dtw_batch(x, y, method="vmap"))
    t0 = time.perf_counter()
    jax.block_until_ready(single(a, b))
    c_single = time.perf_counter() - t0
    t0 = time.perf_counter()
    jax.block_until_ready(batched(A, Bs))
    c_batch = time.perf_counter() - t0

    ours_1 = _median_time(lambda: jax.block_until_ready(single(a, b)), R)
    ours_b = _median_time(lambda: jax.block_until_ready(batched(A, Bs)), R)
    jax.block_until_ready(vmapped(A, Bs))
    ours_v = _median_time(lambda: jax.block_until_ready(vmapped(A, Bs)), R)
    dta_1 = _median_time(lambda: dtw_ndim.distance(a, b, use_c=True), R)
    dta_p1 = _median_time(lambda: dtw_ndim.warping_path(a, b, use_c=True), R)
    dtp_1 = _median_time(lambda: dtw_python(a, b), R)
    dta_b = _median_time(
        lambda: [dtw_ndim.distance(x, y, use_c=True) for x, y in zip(A, Bs, strict=True)], R
    )
    dtp_b = _median_time(lambda: [dtw_python(x, y) for x, y in zip(A, Bs, strict=True)], R)

    res = batched(A, Bs)
    ref = np.asarray([dtw_ndim.distance(x, y, use_c=True) for x, y in zip(A, Bs, strict=True)])
    ours_cost = np.asarray(res.cost)
    rel = float(np.max(np.abs(ours_cost - ref) / ref))
    p_ours = np.asarray(res.path[0][: int(res.path_length[0])])
    same_path = bool(np.array_equal(p_ours, np.asarray(dtw_ndim.warping_path(a, b))))

    print(
        f"DTW on {args.n}x{args.d} float64 pairs, batch of {B}, medians of {R} runs "
        f"(device {jax.devices()[0]}; timings on a shared machine are noisy)"
    )
    print(f"  compile: single {c_single:.2f} s, batched {c_batch:.2f} s (excluded below)")
    print(f"  {'':38s} {'ms/pair':>10s} {'ratio peer/ours':>16s}")
    rows = [
        ("ours single (cost + path)", 1e3 * ours_1, None),
        ("dtaidistance C single (cost only)", 1e3 * dta_1, dta_1 / ours_1),
        ("dtaidistance single (warping_path, C)", 1e3 * dta_p1, dta_p1 / ours_1),
        ("dtw-python single (with path)", 1e3 * dtp_1, dtp_1 / ours_1),
        ("ours batched, auto (cost + path)", 1e3 * ours_b / B, None),
        ("ours batched, vmap (cost + path)", 1e3 * ours_v / B, None),
        ("dtaidistance C batched (cost only)", 1e3 * dta_b / B, dta_b / ours_b),
        ("dtw-python batched (with path)", 1e3 * dtp_b / B, dtp_b / ours_b),
    ]
    for name, ms, ratio in rows:
        print(f"  {name:38s} {ms:10.3f} {'' if ratio is None else f'{ratio:16.2f}'}")
    print(
        f"  throughput batched: ours {B / ours_b:.0f} pairs/s, dtw-python {B / dtp_b:.0f} pairs/s "
        f"→ target (ours ≥ dtw-python): {'met' if ours_b <= dtp_b else 'NOT met'}"
    )
    print(
        f"  max relative cost difference vs dtaidistance.dtw_ndim.distance: {rel:.2e}; "
        f"path identical to dtaidistance.warping_path (pair 0): {same_path}"
    )
    from fxspace.runs import write_bench

    write_bench("dtw", [
        {"case": "single pair", "ours": "dtw (cost + path)", "ours_s": ours_1,
         "peer": "dtaidistance C (cost only)", "peer_s": dta_1},
        {"case": "single pair, with path", "ours": "dtw (cost + path)", "ours_s": ours_1,
         "peer": "dtw-python (with path)", "peer_s": dtp_1},
        {"case": f"batch of {B}", "ours": "dtw batched (cost + path)", "ours_s": ours_b,
         "peer": "dtaidistance C (cost only)", "peer_s": dta_b},
        {"case": f"batch of {B}, with paths", "ours": "dtw batched (cost + path)",
         "ours_s": ours_b, "peer": "dtw-python (with path)", "peer_s": dtp_b},
    ], title=f"DTW: {args.n} x {args.d} float64 pairs",
        command="python experiments/bench_dtw.py " + " ".join(argv or sys.argv[1:]))  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
