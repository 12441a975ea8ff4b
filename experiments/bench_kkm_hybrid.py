"""Kernel k-means to the end (the default, Hirose & Higuchi) vs the hybrid (kernel k-means on
a 1 000-vertex subset, Euclidean k-means on all): eq. (1) error ratio and time per segment.

    python experiments/bench_kkm_hybrid.py [--n 3000] [--frames 40] [--repeats 3]

Prints medians over ``--repeats`` warm runs (first call compiles and is not counted)."""

import argparse
import time

import jax
import numpy as np

import fxspace as fx


def segment(rng, T, N):
    t = np.linspace(0, 1, T)[:, None, None]
    f = rng.uniform(1, 3, (1, N, 1))
    ph = rng.uniform(size=(1, N, 1))
    base = rng.normal(size=(1, N, 3))
    return base + 0.1 * np.sin(2 * np.pi * (f * t + ph)) + 0.01 * rng.normal(size=(T, N, 3))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, default=3000)
    ap.add_argument("--frames", type=int, default=40)
    ap.add_argument("--clusters", type=int, default=25)
    ap.add_argument("--repeats", type=int, default=3)
    a = ap.parse_args()
    X = segment(np.random.default_rng(0), a.frames, a.n)
    lin = np.asarray(fx.reconstruct(fx.fit_control_points(X, 1, n_init=1)[0]))
    for method in ("kernel", "hybrid"):

        def fit(method=method):
            m, _ = fx.fit_control_points(
                X, a.clusters, key=jax.random.key(0), n_init=20, method=method
            )
            return np.asarray(fx.reconstruct(m))

        fit()
        ts = []
        for _ in range(a.repeats):
            t0 = time.perf_counter()
            Xh = fit()
            ts.append(time.perf_counter() - t0)
        err = np.sum((X - Xh) ** 2) / np.sum((X - lin) ** 2)
        print(
            f"{method:7s} N={a.n} T={a.frames} c={a.clusters}: eq.(1) error / 1-cluster "
            f"error {err:.4f}, median {np.median(ts):.3f} s"
        )


if __name__ == "__main__":
    main()
