"""Float32 pairwise-distance benchmark (issue 10): accuracy and time of `pairwise_distances`.

On the frames of a real AnimFace take (the synthetic face when the data is absent), in
float32, prints the median time of several interleaved runs of

- ours: `fx.pairwise_distances` (float64 blocks on the host for float32 features),
- the float32 Gram expansion it replaced (one XLA matrix product, centred features),
- scikit-learn `euclidean_distances` on float32 (also float64 blocks),

with the ratios, and the max relative error of each against scipy's float64 `cdist` over
every off-diagonal pair. Usage: ``python experiments/bench_distances.py [--repeats 9]
[--take animface_cheeks.c3d]``.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np
from scipy.spatial.distance import cdist

import fxspace as fx
from fxspace.data import data_path, data_root
from fxspace.expression._features import _gram_distances
from fxspace.io import read_markers
from fxspace.synthetic import synthetic_face


def _frames(take: str) -> tuple[np.ndarray, str]:
    if data_root() is None:
        syn = synthetic_face(n_frames=1500, seed=0)
        return np.asarray(syn.sequence.positions), "synthetic face (data absent)"
    seq = read_markers(data_path("face", take))
    pos = np.asarray(seq.to_units("mm").positions)
    return pos[np.isfinite(pos).all(axis=(1, 2))], take


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=9)
    ap.add_argument("--take", default="animface_cheeks.c3d")
    args = ap.parse_args()
    pos, name = _frames(args.take)
    F = jnp.asarray(fx.distance_features(pos.astype(np.float32)), jnp.float32)
    Fn = np.asarray(F)
    print(f"{name}: {F.shape[0]} frames, {F.shape[1]} features, float32")
    ref = cdist(Fn.astype(np.float64), Fn.astype(np.float64))
    off = ~np.eye(len(Fn), dtype=bool)
    ours = jax.jit(fx.pairwise_distances)
    gram = jax.jit(_gram_distances)
    from sklearn.metrics.pairwise import euclidean_distances

    fns = {
        "ours (float64 blocks)": lambda: np.asarray(ours(F)),
        "float32 Gram (before)": lambda: np.asarray(gram(F)),
        "sklearn euclidean_distances": lambda: euclidean_distances(Fn),
    }
    times = {k: [] for k in fns}
    errs = {}
    for k, f in fns.items():  # warm up (compile) and measure the error
        D = f()
        errs[k] = float(np.max(np.abs(D.astype(np.float64) - ref)[off] / ref[off]))
    for _ in range(args.repeats):  # interleaved, so load from other processes hits all alike
        for k, f in fns.items():
            t0 = time.perf_counter()
            f()
            times[k].append(time.perf_counter() - t0)
    base = statistics.median(times["float32 Gram (before)"])
    print(f"{'method':30s} {'median s':>9s} {'vs before':>9s} {'max rel err':>12s}")
    for k in fns:
        m = statistics.median(times[k])
        print(f"{k:30s} {m:9.4f} {m / base:9.2f} {errs[k]:12.2e}")
    from fxspace.runs import write_bench

    t = {k: statistics.median(v) for k, v in times.items()}
    ours_k = "ours (float64 blocks)"
    write_bench("distances", [
        {"case": f"{name}, {F.shape[0]} frames: vs scikit-learn", "ours": "pairwise_distances",
         "ours_s": t[ours_k], "peer": "sklearn euclidean_distances",
         "peer_s": t["sklearn euclidean_distances"]},
        {"case": f"{name}, {F.shape[0]} frames: vs float32 Gram", "ours": "pairwise_distances",
         "ours_s": t[ours_k], "peer": "float32 Gram (before)",
         "peer_s": t["float32 Gram (before)"]},
    ], title="Pairwise frame distances (the state matrix)",
        command="python experiments/bench_distances.py " + " ".join(sys.argv[1:]))  # fmt: skip


if __name__ == "__main__":
    main()
