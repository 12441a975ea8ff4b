"""Benchmark: the whole fuzzy c-means hierarchy (c = 10, 20, …, up to n) on 2-D points.

Ours (``fxspace.build_hierarchy``: jitted while-loop, float32, warm start by splitting)
against ``skfuzzy.cluster.cmeans`` and the ``fuzzy-c-means`` package (``fcmeans.FCM``),
each cold-started at every level, all at m = 2, the same tolerance value and iteration
cap, in one run; medians of ``--repeats`` runs (compile time reported separately).

Data: 2400 frames of the AnimFace capture (``$FXSPACE_DATA``) projected to 2-D by classical
MDS of the pairwise-distance state (= PCA of the features), or the synthetic face when the
data is absent. The peers stop on ‖ΔU‖_F < tol, ours on max |Δu_ik| < tol; the table also
shows ours with the peers' Frobenius rule (cold, k-means++), so the comparison holds either
way. Objectives are compared level by level.

    python experiments/bench_fcm.py            # n = 2400, 3 repeats (several minutes)
    python experiments/bench_fcm.py --quick    # n = 600, 3 repeats
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
import warnings

import numpy as np


def _points(n: int, seed: int) -> tuple[np.ndarray, str]:
    from fxspace.data import data_root
    from fxspace.datasets import FaceData, load_face

    src = "animface" if data_root() is not None else "synthetic"
    face = load_face(FaceData(source=src, max_frames=n, synthetic_frames=max(n, 10)), seed)
    T, M, _ = face.positions.shape
    i, j = np.triu_indices(M, 1)
    F = np.linalg.norm(face.positions[:, i] - face.positions[:, j], axis=-1)
    F = F - F.mean(0)
    U, S, _ = np.linalg.svd(F, full_matrices=False)
    return (U[:, :2] * S[:2]).astype(np.float32), f"{src} ({T} frames, {M} markers, PCA 2-D)"


def _time(fn, repeats: int):
    out, times = None, []
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return out, statistics.median(times), times


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="n = 600 points")
    ap.add_argument("--n", type=int, default=None, help="number of points (default 2400)")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--tol", type=float, default=1e-4)
    ap.add_argument("--max-steps", type=int, default=300)
    ap.add_argument("--c0", type=int, default=10)
    ap.add_argument("--skip-peers", action="store_true")
    args = ap.parse_args(argv)
    os.environ.setdefault("FXSPACE_QUIET", "1")

    import jax

    from fxspace import build_hierarchy, fuzzy_cmeans, level_sizes

    n = args.n or (600 if args.quick else 2400)
    X, desc = _points(n, 0)
    sizes = level_sizes(len(X), args.c0)
    print(
        f"FCM hierarchy benchmark: {desc}; levels c = {list(sizes)}; m = 2, tol = {args.tol}, "
        f"max_steps = {args.max_steps}; float32; {jax.devices()[0]}; medians of "
        f"{args.repeats} runs"
    )

    def ours(restarts=1, split=True):
        return build_hierarchy(
            X,
            None,
            c0=args.c0,
            tol=args.tol,
            max_steps=args.max_steps,
            key=jax.random.PRNGKey(0),
            restarts=restarts,
            split=split,
        )

    def ours_fro():
        out = []
        for k, c in enumerate(sizes):
            r = fuzzy_cmeans(
                X,
                c,
                key=jax.random.PRNGKey(k),
                tol=args.tol,
                max_steps=args.max_steps,
                criterion="fro",
            )
            out.append(jax.block_until_ready(r))
        return out

    t0 = time.perf_counter()
    ours()
    first = time.perf_counter() - t0
    h, t_ours, _ = _time(ours, args.repeats)
    compile_s = max(first - t_ours, 0.0)
    t0 = time.perf_counter()
    ours_fro()
    first_fro = time.perf_counter() - t0
    fro, t_fro, _ = _time(ours_fro, args.repeats)
    ours(0)
    h0, t_split, _ = _time(lambda: ours(0), args.repeats)
    ours(1, False)
    h1, t_ext, _ = _time(lambda: ours(1, False), args.repeats)
    rows = [
        (
            "fxspace warm: split + k-means++-extend",
            t_ours,
            [lv.objective for lv in h.levels],
            [lv.total_steps for lv in h.levels],
        ),
        (
            "fxspace warm: k-means++-extend only",
            t_ext,
            [lv.objective for lv in h1.levels],
            [lv.num_steps for lv in h1.levels],
        ),
        (
            "fxspace warm: split only",
            t_split,
            [lv.objective for lv in h0.levels],
            [lv.num_steps for lv in h0.levels],
        ),
        (
            "fxspace cold (Frobenius tol)",
            t_fro,
            [float(r.objective) for r in fro],
            [int(r.num_steps) for r in fro],
        ),
    ]
    print(
        f"compile (first call minus median): ours {compile_s:.2f} s, "
        f"cold {max(first_fro - t_fro, 0):.2f} s"
    )

    if not args.skip_peers:
        import skfuzzy

        def sk():
            out = []
            for k, c in enumerate(sizes):
                _, _, _, _, jm, p, _ = skfuzzy.cluster.cmeans(
                    X.T.astype(np.float64), c, 2.0, error=args.tol, maxiter=args.max_steps, seed=k
                )
                out.append((float(jm[-1]), int(p)))
            return out

        def fcm_pkg():
            from fcmeans import FCM

            out = []
            for k, c in enumerate(sizes):
                model = FCM(
                    n_clusters=c,
                    m=2.0,
                    max_iter=min(args.max_steps, 1000),
                    error=args.tol,
                    random_state=k,
                    init="k-means++",
                )
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    model.fit(X.astype(np.float64))
                out.append((float(model._objective(X.astype(np.float64))), -1))
            return out

        try:
            import fcmeans  # noqa: F401  (pins numpy<2: installed apart, see README)

            peers = (("scikit-fuzzy cmeans", sk), ("fuzzy-c-means FCM", fcm_pkg))
        except ImportError:
            print("fuzzy-c-means not installed (pip install --no-deps fuzzy-c-means): skipped")
            peers = (("scikit-fuzzy cmeans", sk),)
        for name, fn in peers:
            res, t, _ = _time(fn, args.repeats)
            rows.append((name, t, [o for o, _ in res], [s for _, s in res]))

    print()
    w = 40
    print(f"{'implementation':{w}s} {'time (s)':>9s} {'vs ours':>8s}  objective per level")
    for name, t, objs, steps in rows:
        ratio = t / t_ours
        print(
            f"{name:{w}s} {t:9.2f} {ratio:7.2f}x  "
            + " ".join(f"{o:.4g}" for o in objs)
            + f"  (sum {sum(objs[:-1]):.5g})"
        )
        if any(s >= 0 for s in steps):
            print(f"{'':{w}s} {'':9s} {'':8s}  iterations: {steps}")
    print()
    ref = np.asarray(rows[0][2])
    for name, t, objs, _ in rows[1:]:
        rel = (ref - np.asarray(objs)) / np.maximum(np.abs(np.asarray(objs)), 1e-30)
        worst = float(np.max(rel[:-1])) if len(rel) > 1 else float(rel[0])
        tot = (ref[:-1].sum() - np.sum(objs[:-1])) / np.sum(objs[:-1])
        print(
            f"ours vs {name}: speed-up {t / t_ours:.1f}x; objective vs theirs: worst level "
            f"{worst:+.2%}, sum over levels {tot:+.2%} (c < n; negative = ours lower)"
        )
    print("\nNote: the machine may be shared; timings are noisy.")
    from fxspace.runs import write_bench

    write_bench("fcm", [
        {"case": f"all levels vs {name}", "ours": rows[0][0], "ours_s": t_ours, "peer": name,
         "peer_s": t} for name, t, _, _ in rows[1:]
    ], title="Fuzzy c-means: every level of the hierarchy",
        command="python experiments/bench_fcm.py " + " ".join(argv or sys.argv[1:]))  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
