"""Squared distances and k-means++ seeding (Arthur & Vassilvitskii 2007), shared by the
fuzzy c-means solvers (`._fcm`, `._fcm_sparse`; re-exported there)."""

from __future__ import annotations

from functools import partial

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from fxspace._validate import as_float_array, check_int, checked
from fxspace.errors import FxspaceError

__all__ = ["squared_distances", "kmeanspp_init", "kmeanspp_extend", "pad_rows"]

_UNROLL_MAX_D = 8


def pad_rows(c: int) -> int:
    """Rows that ``c`` centres are padded to so that the levels of a hierarchy share one
    compiled kernel: the smallest of 80, 320, 1280, … (×4) that holds them. Independent
    of the number of points, so a padded pass costs at most 4 × its unpadded one.

    **Example:** ``fx.cluster.pad_rows(100)`` is 320."""
    c = check_int(c, "c", low=0)
    size = 80
    while size < c:
        size *= 4
    return size


@checked
def squared_distances(x: Float[Array, "n d"], v: Float[Array, "c d"]) -> Float[Array, "n c"]:
    """Squared Euclidean distances ``‖x_i − v_k‖²`` between two point sets, (n, c),
    without an (n, c, d) temporary (small d unrolled, large d by the Gram expansion)."""
    d = x.shape[1]
    if d <= _UNROLL_MAX_D:
        out = jnp.square(x[:, 0:1] - v[None, :, 0])
        for j in range(1, d):
            out = out + jnp.square(x[:, j : j + 1] - v[None, :, j])
        return out
    xx = jnp.sum(x * x, axis=1, keepdims=True)
    vv = jnp.sum(v * v, axis=1)[None, :]
    xv = jnp.einsum("nd,cd->nc", x, v, precision=jax.lax.Precision.HIGHEST)
    return jnp.maximum(xx - 2.0 * xv + vv, 0.0)


@checked
@partial(jax.jit, static_argnames=("n_clusters",))
def kmeanspp_init(x: Float[Array, "n d"], n_clusters: int, key: Array) -> Float[Array, "c d"]:
    """k-means++ seeding (Arthur & Vassilvitskii 2007): each new centre is a sample drawn
    with probability ∝ its squared distance to the nearest chosen centre. O(n c d)."""
    n = x.shape[0]
    if not 1 <= n_clusters <= n:  # static under jit: checked at trace time
        raise FxspaceError(f"n_clusters must lie in [1, {n}] (the points), got {n_clusters}")
    k0, key = jax.random.split(key)
    first = jax.random.randint(k0, (), 0, n)
    centers = jnp.zeros((n_clusters, x.shape[1]), x.dtype).at[0].set(x[first])
    closest = jnp.sum(jnp.square(x - x[first][None, :]), axis=1)

    def body(k, carry):
        centers, closest, key = carry
        key, sub = jax.random.split(key)
        total = jnp.sum(closest)
        # all remaining samples coincide with chosen centres: draw uniformly
        logits = jnp.where(total > 0, jnp.log(closest), jnp.zeros_like(closest))
        idx = jax.random.categorical(sub, logits)
        c = x[idx]
        closest = jnp.minimum(closest, jnp.sum(jnp.square(x - c[None, :]), axis=1))
        return centers.at[k].set(c), closest, key

    centers, _, _ = jax.lax.fori_loop(1, n_clusters, body, (centers, closest, key))
    return centers


@checked
def kmeanspp_extend(
    x: Float[Array, "n d"], centers: Float[Array, "c d"], n_new: int, key: Array
) -> Float[Array, "c2 d"]:
    """Keep ``centers`` and draw ``n_new`` more by the k-means++ rule (probability ∝ squared
    distance to the nearest centre so far): a warm start that adds centres where the
    current ones cover the data worst. O(n (c + n_new) d). jit/vmap compatible; the draws
    compile once per `pad_rows` size of ``max(c, n_new)`` (the hierarchy's levels share
    them)."""
    x = as_float_array(x, "x", ndim=2, finite="allow")
    centers = as_float_array(centers, "centers", shape=(None, x.shape[1]), finite="allow")
    if n_new < 0:
        raise FxspaceError(f"n_new must be >= 0, got {n_new}")
    if n_new == 0:
        return centers
    c = centers.shape[0]
    size = pad_rows(max(c, n_new))  # not the points: the first pass is (n, size)
    traced = any(isinstance(a, jax.core.Tracer) for a in (x, centers, key))
    xp = jnp if traced else np
    pad = xp.concatenate([xp.asarray(centers), xp.zeros((size - c, x.shape[1]), x.dtype)])
    idx = _kpp_draws(x, pad, jnp.asarray(c, jnp.int32), key, jnp.asarray(n_new, jnp.int32))
    out = xp.concatenate([xp.asarray(centers), xp.asarray(x)[xp.asarray(idx)[:n_new]]])
    bad = ~(xp.all(xp.isfinite(xp.asarray(x))) & xp.all(xp.isfinite(xp.asarray(centers))))
    return jnp.where(bad, jnp.nan, out) if traced else jnp.asarray(np.nan * out if bad else out)


@jax.jit
def _kpp_draws(x, centers, c, key, n_new):
    """``(size,)`` indices of ``n_new`` k-means++ draws (the rest 0), each with probability
    ∝ its squared distance to the nearest centre so far (the first ``c`` rows of
    ``centers``, then the draws): the shapes depend on ``c`` and ``n_new`` only through
    `pad_rows`, so the levels of a hierarchy share a few compiles."""
    valid = jnp.arange(centers.shape[0]) < c
    closest = jnp.min(jnp.where(valid[None, :], squared_distances(x, centers), jnp.inf), axis=1)

    def body(k, carry):
        closest, key, buf = carry
        key, sub = jax.random.split(key)
        total = jnp.sum(closest)
        logits = jnp.where(total > 0, jnp.log(closest), jnp.zeros_like(closest))
        i = jax.random.categorical(sub, logits)
        closest = jnp.minimum(closest, jnp.sum(jnp.square(x - x[i][None, :]), axis=1))
        return closest, key, buf.at[k].set(i.astype(jnp.int32))

    buf = jnp.zeros((centers.shape[0],), jnp.int32)
    return jax.lax.fori_loop(0, n_new, body, (closest, key, buf))[2]
