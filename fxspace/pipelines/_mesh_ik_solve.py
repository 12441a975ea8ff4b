"""The mesh IK experiment's solving and timing (`fxspace.pipelines.mesh_ik`): a mesh spec
loaded with its animation, markers' view, IK solved frame by frame (and replayed for the
naive gradient), gradient evaluations timed."""

from __future__ import annotations

import time
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from fxspace.data import data_path
from fxspace.mesh import (
    BFGS,
    LevenbergMarquardt,
    Pose,
    animation_vertices,
    chain_mesh,
    ik_gradient_factored,
    ik_gradient_naive,
    solve_ik,
    subdivide_mesh,
    visible_triangles,
)
from fxspace.pipelines._mesh_ik_config import Config, _parse_spec


def median_time(fn, repeats: int) -> tuple[float, float]:
    """(median, min) wall time in seconds of ``fn()`` over ``repeats`` calls (already compiled)."""
    ts = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(fn())
        ts.append(time.perf_counter() - t0)
    return float(np.median(ts)), float(np.min(ts))


def random_view(vertices, faces, need: int, rng: np.random.Generator) -> np.ndarray:
    """A random unit viewing direction from which at least ``need`` triangles face the
    camera (the one with the most, after 16 tries, when none has enough)."""
    best, best_n = None, -1
    for _ in range(16):
        d = rng.normal(size=3)
        d /= np.linalg.norm(d)
        n = int(np.asarray(visible_triangles(vertices, faces, d)).sum())
        if n >= need:
            return d
        if n > best_n:
            best, best_n = d, n
    return best


def _solver_opts(cfg: Config, name: str) -> dict:
    if name == "lm":
        return dict(solver=LevenbergMarquardt(rtol=cfg.lm_rtol, max_steps=cfg.lm_steps))
    grad = name.split("_", 1)[1]
    return dict(solver=BFGS(rtol=cfg.bfgs_rtol, max_steps=cfg.bfgs_steps, gradient=grad))


def _per_frame(model, targets, rest, start: str, **kw):
    """Seconds per frame of jitted ``solve_ik`` calls along the frames, and the results."""
    jax.block_until_ready(solve_ik(model, targets[0], rest, **kw))  # compile
    n = targets.shape[0]
    times = np.empty(n)
    out = []
    pose = rest
    for t in range(n):
        t0 = time.perf_counter()
        res = jax.block_until_ready(solve_ik(model, targets[t], pose, **kw))
        times[t] = time.perf_counter() - t0
        out.append(res)
        if start == "warm":
            pose = res.pose
    stacked = jax.tree_util.tree_map(lambda *a: jnp.stack(a), *out)
    return times, stacked


def _per_frame_replay(model, targets, rest, start, frames, poses, **kw):
    """Per-frame times on ``frames`` only, each started where the full run started it (rest,
    or the given run's pose of the frame before): the same solves as that run's, so a
    solver taking identical steps (naive vs factored gradient) is timed like for like."""
    jax.block_until_ready(solve_ik(model, targets[0], rest, **kw))  # compile
    times = np.empty(len(frames))
    dev = 0.0
    for i, t in enumerate(frames):
        init = rest if start == "cold" or t == 0 else _frame(poses, t - 1)
        t0 = time.perf_counter()
        res = jax.block_until_ready(solve_ik(model, targets[t], init, **kw))
        times[i] = time.perf_counter() - t0
        dev = max(dev, float(jnp.max(jnp.abs(res.pose.angles - poses.angles[t]))))
    return times, dev


def _gradient_us(model, pose, targets, repeats: int, loop: int = 100) -> dict:
    """Microseconds per gradient evaluation (forward pass + gradient), per form:

    - ``call``: one jitted call per evaluation with the model bound into the function
      (``jax.jit(partial(grad, model))``, as an interactive solver holds it), 200 calls;
    - ``loop``: ``loop`` evaluations inside one jitted loop (how the solvers call it; each
      pose moved by ``-1e-9 ∇E`` so none can be hoisted), no per-call cost.
    """
    out = {}
    for name, g in (("naive", ik_gradient_naive), ("factored", ik_gradient_factored)):
        f = jax.jit(partial(g, model))

        def body(_, q, g=g):
            d = g(model, q, targets)
            return jax.tree_util.tree_map(lambda a, b: a - 1e-9 * b, q, d)

        in_loop = jax.jit(lambda p, body=body: jax.lax.fori_loop(0, loop, body, p))
        jax.block_until_ready((f(pose, targets), in_loop(pose)))
        med, _ = median_time(lambda f=f: [f(pose, targets) for _ in range(200)][-1], repeats)
        out[f"call_{name}"] = 1e6 * med / 200
        med, _ = median_time(lambda in_loop=in_loop: in_loop(pose), repeats)
        out[f"loop_{name}"] = 1e6 * med / loop
    return out


def _load(spec: str, num_frames: int, dtype):
    from fxspace.io import read_gltf

    kind, n, anim = _parse_spec(spec)
    if kind == "chain":
        mesh, stem = chain_mesh(n), f"chain{n}"
    else:
        mesh, stem = read_gltf(data_path("mesh", f"{kind}.glb")), kind
        if n:
            mesh, stem = subdivide_mesh(mesh, num_vertices=n), f"{kind}+{n}"
    anim = anim or mesh.animation_names[0]
    times = np.linspace(*mesh.animation_range(anim), num_frames)
    truth = jnp.asarray(animation_vertices(mesh, anim, times), dtype)  # (T, V, 3)
    return stem, mesh, anim, truth


def _frame(pose: Pose, t: int) -> Pose:
    return Pose(pose.angles[t], pose.translation[t])


def _cast(model, dtype):
    return jax.tree_util.tree_map(
        lambda a: a.astype(dtype) if jnp.issubdtype(a.dtype, jnp.floating) else a, model
    )
