"""Benchmark: mesh-IK gradients (factored eq. (13) vs naive eq. (9) vs jax.grad) and the
per-frame solve, on CesiumMan with 120 markers (Park, Kang & Kwon).

Measured in one run, float64, jitted, compile time reported separately; every number is
the median of ``--repeats`` runs of ``--inner`` calls (``jax.block_until_ready``); the
gradient cases run round-robin and speed-ups are medians of per-round ratios:

* the full gradient call (shared forward pass + gradient), per form: the headline, one
  jitted call per evaluation, so it includes JAX's fixed per-call cost (argument
  handling, output buffers), shown on its own as "call overhead" (a jitted function of
  the same arguments that computes nothing), identical for every form;
* the full gradient as one call with the model bound into the jitted function
  (``jax.jit(partial(fx.ik_gradient_factored, model))``, as an interactive solver holds
  it): only the pose and the targets cross the call;
* the full gradient evaluated inside one jitted loop (``--loop`` evaluations, each pose
  moved by ``-1e-9 ∇E`` so that none can be hoisted): forward pass + gradient per
  evaluation as a solver sees it, without the per-call cost;
* the forward pass alone, and the gradient arithmetic alone given the forward pass
  (what eq. (9) vs eq. (13) changes);
* per-frame solves along the animation, cold (from rest, as the paper) and warm (from the
  previous frame), one jitted call per frame: Levenberg–Marquardt (the default solver)
  and BFGS on each gradient form at rtol 1e-3 and run to LM's accuracy (vertex error
  against the true posed mesh printed beside each; target ≤ 3 ms per frame).

The "peer" is the paper's naive three-loop gradient (the baseline its speed-up is
measured against) and ``jax.grad``. The numbers are wall-clock on a shared machine: read
the min column too.

The issue-23 target (≤ 1 ms per frame warm, ≤ 2 ms cold, LM at 120 markers on
CesiumMan, median over 300 frames) is measured first, with the vertex error beside each
median, for the default LM (``tau`` automatic: 1e-6 warm, 1e-3 cold) and the previous
default (``tau = 1e-3``):

    python experiments/bench_ik.py            # LM target + 120 markers, 15 rounds, 120 frames
    python experiments/bench_ik.py --lm-only  # the LM per-frame target only (300 frames)
    python experiments/bench_ik.py --quick    # 5 rounds, 30 frames
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from functools import partial

# One BLAS thread: LM's Cholesky of the 60×60 normal equations goes to LAPACK, and a
# threaded OpenBLAS on a loaded machine spends more time handing the work out than doing
# it (measured under load: potrf at n = 60 0.71 ms threaded vs 0.14 ms on one thread; at
# n = 147, the 48-joint chain, 655 ms vs 0.34 ms). Set before numpy loads OpenBLAS.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import numpy as np  # noqa: E402


def _bench(fn, repeats: int, inner: int) -> tuple[float, float]:
    import jax

    ts = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        for _ in range(inner):
            r = fn()
        jax.block_until_ready(r)
        ts.append((time.perf_counter() - t0) / inner)
    return statistics.median(ts), min(ts)


def lm_target(fx, mesh, anim, ms, model, frames: int) -> None:
    """Median ms per frame of ``fx.solve_ik`` (LM, rtol 1e-3, one jitted call per frame)
    along ``frames`` frames, warm (previous frame) and cold (rest), with the mean vertex
    error against the true posed mesh; the default LM and the previous default."""
    import jax
    import jax.numpy as jnp

    t = np.linspace(*mesh.animation_range(anim), frames)
    truth = jnp.asarray(fx.mesh.animation_vertices(mesh, anim, t))
    targets = fx.marker_positions(truth, mesh.faces, ms)
    posed = jax.jit(jax.vmap(lambda q: fx.pose_vertices(mesh, q)))
    rest = fx.rest_pose(mesh)
    print(
        f"LM per frame, {model.marker_joints.shape[0]} markers on {mesh.name}, {frames} frames "
        "(target: <= 1 ms warm, <= 2 ms cold; shared machine, wall clock):"
    )
    for label, lm in (
        ("default (tau auto)", fx.mesh.LevenbergMarquardt(rtol=1e-3)),
        ("previous (tau 1e-3)", fx.mesh.LevenbergMarquardt(rtol=1e-3, tau=1e-3)),
    ):
        for start in ("warm", "cold"):
            jax.block_until_ready(fx.solve_ik(model, targets[0], rest, solver=lm))
            p, ts, steps, poses = rest, [], [], []
            for i in range(frames):
                t0 = time.perf_counter()
                r = jax.block_until_ready(fx.solve_ik(model, targets[i], p, solver=lm))
                ts.append(time.perf_counter() - t0)
                steps.append(int(r.num_steps))
                poses.append(r.pose)
                p = r.pose if start == "warm" else rest
            P = jax.tree_util.tree_map(lambda *a: jnp.stack(a), *poses)
            verr = float(jnp.mean(jnp.linalg.norm(posed(P) - truth, axis=-1)))
            print(
                f"  LM {label:20s} {start}: median {1e3 * statistics.median(ts):.3f} ms/frame "
                f"(min {1e3 * min(ts):.3f}), {np.mean(steps):.2f} iterations, "
                f"vertex error {verr:.4g}",
                flush=True,
            )


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="5 rounds, 30 frames")
    ap.add_argument("--mesh", default="CesiumMan")
    ap.add_argument("--markers", type=int, default=120)
    ap.add_argument("--repeats", type=int, default=None)
    ap.add_argument("--inner", type=int, default=200)
    ap.add_argument("--loop", type=int, default=100, help="evaluations per in-loop call")
    ap.add_argument("--frames", type=int, default=None)
    ap.add_argument("--lm-frames", type=int, default=300, help="frames of the LM target")
    ap.add_argument("--lm-only", action="store_true", help="only the LM per-frame target")
    args = ap.parse_args(argv)
    os.environ.setdefault("FXSPACE_QUIET", "1")
    repeats = args.repeats or (5 if args.quick else 15)
    frames = args.frames or (30 if args.quick else 120)

    import jax
    import jax.numpy as jnp

    jax.config.update("jax_enable_x64", True)
    import fxspace as fx
    from fxspace.data import data_path
    from fxspace.mesh import gradient_factored_from_forward, gradient_naive_from_forward

    mesh = fx.io.read_gltf(data_path("mesh", f"{args.mesh}.glb"))
    anim = mesh.animation_names[0]
    ms = fx.place_markers(mesh.vertices, mesh.faces, args.markers, seed=0)
    model = fx.ik_model(mesh, ms)
    lm_target(fx, mesh, anim, ms, model, args.lm_frames)
    if args.lm_only:
        return 0
    t = np.linspace(*mesh.animation_range(anim), frames)
    targets = fx.marker_positions(
        jnp.asarray(fx.mesh.animation_vertices(mesh, anim, t)), mesh.faces, ms
    )
    pose = fx.rest_pose(mesh)
    tg = targets[frames // 2]
    print(
        f"mesh IK benchmark: {args.mesh} ({mesh.num_joints} joints, depth "
        f"{model.ancestors.shape[1]}), {args.markers} markers ({model.marker_joints.shape[1]} "
        f"joints/marker max), float64, {jax.devices()[0]}; median (min) of {repeats} x "
        f"{args.inner} calls (in-loop rows: {max(1, args.inner // args.loop)} calls of "
        f"{args.loop} evaluations, per evaluation); shared machine, wall clock"
    )

    rows = []
    fw = jax.jit(fx.ik_forward)(model, pose)
    delta = fw.markers - tg
    jn, jf, ja = (
        jax.jit(g) for g in (fx.ik_gradient_naive, fx.ik_gradient_factored, fx.ik_gradient_autodiff)
    )
    kn = jax.jit(gradient_naive_from_forward)
    kf = jax.jit(gradient_factored_from_forward)
    fwd = jax.jit(fx.ik_forward)
    floor = jax.jit(lambda m, p, t: p)  # same arguments and outputs, no work
    # the model bound into the jitted function (a constant of the computation), as an
    # interactive solver holds it: one call per evaluation with only (pose, targets) passed
    bn, bf = (jax.jit(partial(g, model)) for g in (fx.ik_gradient_naive, fx.ik_gradient_factored))

    def in_loop(grad):
        def run(m, p, t):
            def body(_, q):
                g = grad(m, q, t)
                return jax.tree_util.tree_map(lambda a, b: a - 1e-9 * b, q, g)

            return jax.lax.fori_loop(0, args.loop, body, p)

        return jax.jit(run)

    ln, lf, la = (
        in_loop(g) for g in (fx.ik_gradient_naive, fx.ik_gradient_factored, fx.ik_gradient_autodiff)
    )
    cases = {
        "gradient, full: naive (eq. 9)": lambda: jn(model, pose, tg),
        "gradient, full: factored (eq. 13)": lambda: jf(model, pose, tg),
        "gradient, full: jax.grad": lambda: ja(model, pose, tg),
        "call overhead (same arguments, no work)": lambda: floor(model, pose, tg),
        "gradient, one call, model bound: naive": lambda: bn(pose, tg),
        "gradient, one call, model bound: factored": lambda: bf(pose, tg),
        "forward pass alone": lambda: fwd(model, pose),
        "gradient arithmetic: naive": lambda: kn(model, fw, delta),
        "gradient arithmetic: factored": lambda: kf(model, fw, delta),
        "in a jitted loop, per evaluation: naive": lambda: ln(model, pose, tg),
        "in a jitted loop, per evaluation: factored": lambda: lf(model, pose, tg),
        "in a jitted loop, per evaluation: jax.grad": lambda: la(model, pose, tg),
    }
    # calls per timing sample, and evaluations per call (the in-loop cases run --loop)
    shape = {
        n: (max(1, args.inner // args.loop), args.loop) if "loop" in n else (args.inner, 1)
        for n in cases
    }
    compile_s = {}
    for name, fn in cases.items():
        t0 = time.perf_counter()
        jax.block_until_ready(fn())
        compile_s[name] = time.perf_counter() - t0
    # round-robin, so load from other processes hits every case alike
    samples = {name: [] for name in cases}
    for _ in range(repeats):
        for name, fn in cases.items():
            calls, evals = shape[name]
            samples[name].append(_bench(fn, 1, calls)[0] / evals)
    for name in cases:
        rows.append((name, statistics.median(samples[name]), min(samples[name]), compile_s[name]))

    def ratio(a, b):  # median over rounds of the per-round ratio
        return statistics.median(x / y for x, y in zip(samples[a], samples[b], strict=True))

    posed = jax.jit(jax.vmap(lambda q: fx.pose_vertices(mesh, q)))
    truth = jnp.asarray(fx.mesh.animation_vertices(mesh, anim, t))

    def per_frame(start, **kw):
        p0 = fx.rest_pose(mesh)
        jax.block_until_ready(fx.solve_ik(model, targets[0], p0, **kw))
        ts, steps, poses = [], [], []
        p = p0
        for i in range(frames):
            t0 = time.perf_counter()
            r = jax.block_until_ready(fx.solve_ik(model, targets[i], p, **kw))
            ts.append(time.perf_counter() - t0)
            p = r.pose if start == "warm" else p0
            steps.append(int(r.num_steps))
            poses.append(r.pose)
        P = jax.tree_util.tree_map(lambda *a: jnp.stack(a), *poses)
        verr = float(jnp.mean(jnp.linalg.norm(posed(P) - truth, axis=-1)))
        return statistics.median(ts), min(ts), float(np.mean(steps)), verr

    # the paper's method first (BFGS on the factored gradient, eq. 13), LM beside it
    solvers = [
        ("paper: BFGS factored, rtol 1e-3", dict(solver=fx.mesh.BFGS(rtol=1e-3))),
        ("LM (analytic J), rtol 1e-3", dict(solver=fx.mesh.LevenbergMarquardt(rtol=1e-3))),
        ("BFGS naive, rtol 1e-3", dict(solver=fx.mesh.BFGS(rtol=1e-3, gradient="naive"))),
        ("BFGS jax.grad, rtol 1e-3", dict(solver=fx.mesh.BFGS(rtol=1e-3, gradient="autodiff"))),
        ("BFGS factored, to LM accuracy", dict(solver=fx.mesh.BFGS(rtol=1e-10, max_steps=1000))),
        (
            "BFGS naive, to LM accuracy",
            dict(solver=fx.mesh.BFGS(rtol=1e-10, max_steps=1000, gradient="naive")),
        ),
    ]
    solve_rows = []
    for start in ("cold", "warm"):
        for name, kw in solvers:
            solve_rows.append((f"{name} [{start}]", *per_frame(start, **kw)))

    public_rows = public_call(fx, model, targets, frames)

    print(f"{'what':44s} {'median':>10s} {'min':>10s} {'compile':>9s}")
    for name, med, mn, c in rows:
        print(f"{name:44s} {med * 1e6:8.1f}us {mn * 1e6:8.1f}us {c:8.2f}s")
    print(
        "speed-up factored vs naive, full gradient call: "
        f"{ratio('gradient, full: naive (eq. 9)', 'gradient, full: factored (eq. 13)'):.2f}x  "
        "(median of per-round ratios; paper: 3.14x mean, 2.78x human; target >= 3x)"
    )
    print(
        "speed-up factored vs naive, one call with the model bound (jax.jit(partial(grad, "
        "model))): "
        f"{ratio('gradient, one call, model bound: naive', 'gradient, one call, model bound: factored'):.2f}x"  # noqa: E501
    )
    print(
        "speed-up factored vs naive, gradient arithmetic: "
        f"{ratio('gradient arithmetic: naive', 'gradient arithmetic: factored'):.2f}x"
    )
    loop_n, loop_f, loop_a = (
        f"in a jitted loop, per evaluation: {g}" for g in ("naive", "factored", "jax.grad")
    )
    print(
        "speed-up factored vs naive, full gradient in a jitted loop (no per-call cost): "
        f"{ratio(loop_n, loop_f):.2f}x; factored vs jax.grad there: {ratio(loop_a, loop_f):.2f}x"
    )
    print(
        "speed-up factored vs jax.grad, full gradient call: "
        f"{ratio('gradient, full: jax.grad', 'gradient, full: factored (eq. 13)'):.2f}x"
    )
    print(
        f"\nper-frame solve along {frames} frames of {anim!r}, one jitted call per frame, "
        "cold (from rest, as the paper) and warm (previous frame):"
    )
    print(f"{'solver':44s} {'median':>10s} {'min':>10s} {'steps':>6s} {'vertex err':>11s}")
    for name, med, mn, st, ve in solve_rows:
        print(f"{name:44s} {med * 1e3:8.3f}ms {mn * 1e3:8.3f}ms {st:6.1f} {ve:11.3g}")
    row = {r[0]: r[1] for r in solve_rows}
    for start in ("cold", "warm"):
        f = row[f"paper: BFGS factored, rtol 1e-3 [{start}]"]
        n = row[f"BFGS naive, rtol 1e-3 [{start}]"]
        fa = row[f"BFGS factored, to LM accuracy [{start}]"]
        na = row[f"BFGS naive, to LM accuracy [{start}]"]
        lm = row[f"LM (analytic J), rtol 1e-3 [{start}]"]
        print(
            f"{start}: BFGS per-frame speed-up factored vs naive {n / f:.2f}x (rtol 1e-3), "
            f"{na / fa:.2f}x (to LM accuracy); LM {lm * 1e3:.2f} ms vs BFGS factored at LM "
            f"accuracy {fa * 1e3:.2f} ms = LM {fa / lm:.2f}x faster (target <= 3 ms; paper "
            "32.5 ms accelerated / 90.6 ms naive on its human model)"
        )
    print(
        "\nthe call a user makes, cold, default solver, one call per frame: public "
        "fx.solve_ik(model, targets) against the same solve jitted whole (float64, no "
        "per-call Python):"
    )
    for name, med, mn, st in public_rows:
        print(f"{name:44s} {med * 1e3:8.3f}ms {mn * 1e3:8.3f}ms {st:6.1f}")
    (_, k_med, _, k_st), *users = public_rows
    for name, med, _, st in users:
        print(
            f"{name}: {med / k_med:.2f}x the jitted kernel's time, {st / k_st:.2f}x its "
            "iterations (target <= 1.3x both)"
        )
    med = {r[0]: r[1] for r in rows}
    full = "gradient, full: factored (eq. 13)"
    record = [
        {"case": "full gradient call", "ours": "factored (eq. 13)", "ours_s": med[full],
         "peer": "naive (eq. 9)", "peer_s": med["gradient, full: naive (eq. 9)"]},
        {"case": "full gradient call, vs autodiff", "ours": "factored (eq. 13)",
         "ours_s": med[full], "peer": "jax.grad", "peer_s": med["gradient, full: jax.grad"]},
    ] + [
        {"case": f"solved frame, {start}", "ours": "BFGS factored, rtol 1e-3",
         "ours_s": row[f"paper: BFGS factored, rtol 1e-3 [{start}]"],
         "peer": "BFGS naive, rtol 1e-3", "peer_s": row[f"BFGS naive, rtol 1e-3 [{start}]"]}
        for start in ("cold", "warm")
    ] + [
        {"case": f"the per-frame call a user makes, {name.split(', ')[1]}",
         "ours": "fx.solve_ik (public)", "ours_s": med_s,
         "peer": "jax.jit(solve_ik), float64", "peer_s": k_med}
        for name, med_s, _, _ in users
    ]  # fmt: skip
    from fxspace.runs import write_bench

    cmd = "python experiments/bench_ik.py " + " ".join(argv or sys.argv[1:])
    write_bench("ik", record, title="Mesh IK: the factored gradient (eq. 13)", command=cmd)
    return 0


def public_call(fx, model, targets, frames: int) -> list[tuple]:
    """Median and min seconds per frame and mean iterations of the per-frame call a user
    makes (`fx.solve_ik(model, targets)`, the default solver, from rest) with float32
    targets (JAX's default dtype) and float64 ones, beside the whole solve jitted once
    with the model bound (float64): what the public entry costs on top of the kernel."""
    import jax
    import jax.numpy as jnp

    kernel = jax.jit(lambda t: fx.solve_ik(model, t))
    cases = [
        ("kernel: jax.jit(solve_ik), float64", kernel, targets),
        ("public solve_ik, float32 targets", lambda t: fx.solve_ik(model, t), targets),
        ("public solve_ik, float64 targets", lambda t: fx.solve_ik(model, t), targets),
    ]
    cases[1] = (cases[1][0], cases[1][1], targets.astype(jnp.float32))
    out = []
    for name, call, tg in cases:
        jax.block_until_ready(call(tg[0]))
        ts, steps = [], []
        for i in range(frames):
            t0 = time.perf_counter()
            r = jax.block_until_ready(call(tg[i]))
            ts.append(time.perf_counter() - t0)
            steps.append(int(r.num_steps))
        out.append((name, statistics.median(ts), min(ts), float(np.mean(steps))))
    return out


if __name__ == "__main__":
    raise SystemExit(main())
