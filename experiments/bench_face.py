"""Benchmark: expression weights of the ICT head from the AnimFace markers
(`fx.face.solve_weights`) against scipy's bounded least squares (`scipy.optimize.lsq_linear`)
on the same frames.

For each real take: bind the markers to the ICT Face Model from the first frame, solve
every frame (weights in [0, 1] + the head's rigid motion), and print

* the per-marker residual after the solve beside the rigid-only residual (the head
  moved rigidly, no expression), mean over markers and frames, in millimetres;
* our time per frame, warm (compiled), median of ``--repeats`` runs of the whole take;
* scipy's ``lsq_linear`` (bounded, ``method="bvls"``) per frame on the same problem:
  the rigid motion fixed at ours, no temporal term (``temporal=0`` for ours too), the
  same ridge; its time per frame (median of the repeats) and the objective gap
  (ours − scipy's, relative; ≤ 0 means ours is at least as low) and the weight MAE.

    python experiments/bench_face.py            # every take, 3 repeats
    python experiments/bench_face.py --quick    # the jaw take, 300 frames
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time

import numpy as np

TAKES = ("animface_jaw.c3d", "animface_cheeks.c3d", "animface_eyebrows.trc.gz")


def _scipy_frames(b, A, v, ridge_abs, frames):
    """Per-frame lsq_linear on the frames' problems; returns weights, objective, seconds."""
    from scipy.optimize import lsq_linear

    K = A.shape[0]
    Af = A.reshape(K, -1).T  # (3M, K)
    W, obj = [], []
    t0 = time.perf_counter()
    for t in frames:
        m = np.repeat(v[t], 3).astype(bool)
        M = np.vstack([Af[m], np.sqrt(ridge_abs) * np.eye(K)])
        z = np.concatenate([b[t][m], np.zeros(K)])
        r = lsq_linear(M, z, bounds=(0.0, 1.0), method="bvls", tol=1e-12)
        W.append(r.x)
        obj.append(float(np.sum((M @ r.x - z) ** 2)))
    return np.asarray(W), np.asarray(obj), (time.perf_counter() - t0) / len(frames)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="the jaw take, 300 frames")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--scipy-frames", type=int, default=200, help="frames scipy solves")
    args = ap.parse_args(argv)
    os.environ.setdefault("FXSPACE_QUIET", "1")
    import jax
    import jax.numpy as jnp

    jax.config.update("jax_enable_x64", True)
    import fxspace as fx
    from fxspace.data import data_path

    t0 = time.perf_counter()
    rig = fx.face.read_rig(data_path("face", "ict"))
    read_s = time.perf_counter() - t0
    print(f"ICT rig: {rig.num_vertices} vertices, {rig.num_shapes} shapes, read in "
          f"{read_s:.2f} s (cached after the first read); {jax.devices()[0]}")  # fmt: skip
    takes = TAKES[:1] if args.quick else TAKES
    record = []
    print(f"{'take':26s} {'frames':>6s} {'resid mm':>9s} {'rigid mm':>9s} {'ours ms/f':>10s} "
          f"{'scipy ms/f':>10s} {'ratio':>7s} {'obj gap':>9s} {'w MAE':>7s}")  # fmt: skip
    for name in takes:
        take = fx.io.read_markers(data_path("face", name))
        X = np.asarray(take.positions, np.float64)
        if args.quick:
            X = X[:300]
        b = fx.face.bind_markers(rig, X[0], take.names)
        jax.block_until_ready(fx.face.solve_weights(rig, b, X).weights)  # compile
        ts = []
        for _ in range(args.repeats):
            t0 = time.perf_counter()
            s = fx.face.solve_weights(rig, b, X)
            jax.block_until_ready(s.weights)
            ts.append((time.perf_counter() - t0) / len(X))
        s0 = fx.face.solve_weights(rig, b, X, expressions=False)
        # like with like: no temporal term, scipy on the same frames at our rigid motion
        ridge = 1e-4
        ind = fx.face.solve_weights(rig, b, X, temporal=0.0, ridge=ridge, outer=6, inner=300)
        seen = np.all(np.isfinite(X), axis=-1)
        Y = np.asarray(b.to_rig(np.where(seen[..., None], X, 0.0)))
        R, tau = np.asarray(ind.rotation), np.asarray(ind.translation)
        Z = np.einsum("tmc,tcd->tmd", Y - tau[:, None], R) - b.points[None]
        z = (seen[..., None] * Z).reshape(len(X), -1)
        A = np.asarray(b.basis)
        scale = float(np.trace(A.reshape(len(A), -1) @ A.reshape(len(A), -1).T) / len(A))
        frames = np.linspace(0, len(X) - 1, min(args.scipy_frames, len(X))).astype(int)
        Ws, obj_s, sec = [], [], []
        for _ in range(args.repeats):
            Ws, obj_s, t_s = _scipy_frames(z, A, seen, ridge * scale, frames)
            sec.append(t_s)
        w = np.asarray(ind.weights)[frames]
        Af = A.reshape(len(A), -1).T
        ours = []
        for i, t in enumerate(frames):
            m = np.repeat(seen[t], 3)
            ours.append(np.sum((Af[m] @ w[i] - z[t][m]) ** 2) + ridge * scale * np.sum(w[i] ** 2))
        gap = float(np.median((np.asarray(ours) - obj_s) / np.maximum(obj_s, 1e-30)))
        mae = float(np.mean(np.abs(w - Ws)))
        ours_ms, sp_ms = 1e3 * statistics.median(ts), 1e3 * statistics.median(sec)
        print(f"{name:26s} {len(X):6d} {float(jnp.nanmean(s.residual)):9.3f} "
              f"{float(jnp.nanmean(s0.residual)):9.3f} {ours_ms:10.3f} {sp_ms:10.3f} "
              f"{sp_ms / ours_ms:6.1f}x {gap:9.2e} {mae:7.4f}")  # fmt: skip
        record.append({"case": f"{name} ({len(X)} frames), per frame", "ours": "solve_weights",
                       "ours_s": ours_ms / 1e3, "peer": "scipy lsq_linear (bvls) per frame",
                       "peer_s": sp_ms / 1e3})  # fmt: skip
    print("resid / rigid: mean marker residual after the solve / with the rigid motion alone "
          "(mm); ratio: scipy's time per frame / ours; obj gap: (ours - scipy) / scipy, "
          "median over the compared frames (temporal=0, same rigid motion and ridge)")  # fmt: skip
    from fxspace.runs import write_bench

    cmd = "python experiments/bench_face.py " + " ".join(argv or sys.argv[1:])
    write_bench("face", record, title="ICT head: expression weights from markers", command=cmd)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
