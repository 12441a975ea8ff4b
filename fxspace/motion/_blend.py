"""Example clips, random blend-weight samples, k-NN interpolation (Kovar & Gleicher 2004)
and normalised quaternion blending at registered times."""

from __future__ import annotations

from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float, Int

from fxspace._validate import check_int, check_key, check_scalar, checked
from fxspace.errors import FxspaceError
from fxspace.rotations import quat_nlerp, quat_normalize

__all__ = [
    "ExampleSet",
    "KNNResult",
    "sample_blend_weights",
    "knn_blend_weights",
    "blend_quaternions",
    "pose_at",
    "blend_pose",
]


class ExampleSet(NamedTuple):
    """``E`` registered example clips, padded to a common length ``T`` (last frame repeated).

    - ``rotations`` ``(E, T, J, 4)``: local joint quaternions.
    - ``root`` ``(E, T, 3)``: root translation (start-aligned: see `align_start`).
    - ``lengths`` ``(E,)`` int: valid frames per clip.
    - ``warps`` ``(E, N)``: time-warp functions ``C_i(u)`` sampled at the reference
      clip's frames ``u = 0..N-1`` (example frame, fractional, non-decreasing).
    """

    rotations: Float[Array, "E T J 4"]
    root: Float[Array, "E T 3"]
    lengths: Int[Array, " E"]
    warps: Float[Array, "E N"]


class KNNResult(NamedTuple):
    """``weights`` ``(E,)`` blend weights over the examples (sum to one); ``neighbours``
    ``(k,)`` indices of the nearest samples; ``distances`` ``(k,)``; ``sample_weights`` ``(k,)``
    the interpolation weights of those samples."""

    weights: Float[Array, " E"]
    neighbours: Int[Array, " k"]
    distances: Float[Array, " k"]
    sample_weights: Float[Array, " k"]


@checked
def sample_blend_weights(
    key: Array, n_examples: int, n_samples: int, concentration: float = 0.5, max_active: int = 3
) -> Float[Array, "S E"]:
    """Random convex blend weights for dense sampling of a parameter space.

    The first ``n_examples`` rows are the examples themselves (one-hot), so k-NN
    interpolation reproduces an example exactly at its own parameter. The other rows
    blend ``max_active`` randomly chosen examples with Dirichlet(``concentration``) weights
    (Kovar & Gleicher 2004 sample blends of nearby examples; sparse blends keep the
    samples on the motion manifold). Rows sum to one.
    """
    key = check_key(key, "key")
    n_examples = check_int(n_examples, "n_examples", low=1)
    n_samples = check_int(n_samples, "n_samples", low=1)
    if n_samples < n_examples:
        raise FxspaceError(f"n_samples ({n_samples}) must be at least n_examples ({n_examples})")
    max_active = check_int(max_active, "max_active", low=1)
    concentration = check_scalar(concentration, "concentration", low=0.0, low_open=True)
    return _sample_weights(key, n_examples, n_samples, concentration, min(max_active, n_examples))


@partial(jax.jit, static_argnums=(1, 2, 4))
def _sample_weights(key, n_examples: int, n_samples: int, concentration, m: int):
    k1, k2 = jax.random.split(key)
    n_rand = n_samples - n_examples
    order = jax.vmap(lambda k: jax.random.permutation(k, n_examples)[:m])(
        jax.random.split(k1, n_rand)
    )
    conc = jnp.full((m,), 1.0) * concentration
    w = jax.random.dirichlet(k2, conc, shape=(n_rand,))
    dense = jnp.zeros((n_rand, n_examples), w.dtype).at[jnp.arange(n_rand)[:, None], order].add(w)
    return jnp.concatenate([jnp.eye(n_examples, dtype=dense.dtype), dense], axis=0)


@checked
def knn_blend_weights(
    query: Float[Array, " p"],
    sample_params: Float[Array, "S p"],
    sample_weights: Float[Array, "S E"],
    k: int = 6,
) -> KNNResult:
    """k-NN interpolation of blend weights (Kovar & Gleicher 2004, "Automated extraction and
    parameterization of motions in large data sets").

    With ``d_1 ≤ … ≤ d_k`` the distances from ``query`` to its ``k`` nearest samples, the
    sample weights are ``ŵ_i = 1/d_i − 1/d_k`` normalised to sum to one (the k-th gets 0);
    the example weights are ``Σ_i ŵ_i · sample_weights[i]``. A query that hits a sample
    exactly (``d_1 = 0``) returns that sample's weights. A query holding NaN/inf gets NaN
    weights (never a plausible blend). O(S·p) per query; jittable, ``vmap`` over queries.
    """
    check_int(k, "k", low=1, high=sample_params.shape[0])  # 1 <= k <= number of samples
    d2 = jnp.sum((sample_params - query[None, :]) ** 2, axis=-1)
    neg, idx = jax.lax.top_k(-d2, k)
    d = jnp.sqrt(jnp.maximum(-neg, 0.0))
    tiny = 1e-12
    inv = 1.0 / jnp.maximum(d, tiny)
    w = jnp.maximum(inv - inv[-1], 0.0)
    tot = jnp.sum(w)
    w = jnp.where(tot > 0, w / jnp.where(tot > 0, tot, 1.0), jnp.full_like(w, 1.0 / k))
    exact = d[0] <= tiny
    w = jnp.where(exact, jnp.zeros_like(w).at[0].set(1.0), w)
    ew = jnp.einsum("k,ke->e", w, sample_weights[idx])
    bad = ~jnp.all(jnp.isfinite(query))  # NaN in → NaN out, never a plausible blend
    ew = jnp.where(bad, jnp.nan, ew)
    return KNNResult(ew, idx, d, jnp.where(bad, jnp.nan, w))


@checked
def blend_quaternions(q: Float[Array, "E ... 4"], w: Float[Array, " E"]) -> Float[Array, "... 4"]:
    """Normalised weighted quaternion blend: each example's quaternion is flipped into the
    hemisphere of the highest-weighted example, summed with weights ``w``, normalised
    (exact for a one-hot ``w``)."""
    ref = q[jnp.argmax(w)]
    sign = jnp.where(jnp.sum(q * ref[None], axis=-1, keepdims=True) < 0, -1.0, 1.0)
    wb = w.reshape((-1,) + (1,) * (q.ndim - 1))
    return quat_normalize(jnp.sum(wb * sign * q, axis=0))


@checked
def pose_at(
    ex: ExampleSet, times: Float[Array, " E"]
) -> tuple[Float[Array, "E J 4"], Float[Array, "E 3"]]:
    """Each example's pose at its own fractional frame ``times[i]`` (nlerp / lerp between
    neighbouring frames, clamped to the clip)."""
    t = jnp.clip(times, 0.0, (ex.lengths - 1).astype(times.dtype))
    f0 = jnp.floor(t).astype(jnp.int32)
    f1 = jnp.minimum(f0 + 1, ex.lengths - 1)
    s = t - f0
    e = jnp.arange(ex.rotations.shape[0])
    q0, q1 = ex.rotations[e, f0], ex.rotations[e, f1]
    q = quat_nlerp(q0, q1, jnp.broadcast_to(s[:, None], q0.shape[:-1]))
    r = ex.root[e, f0] * (1 - s[:, None]) + ex.root[e, f1] * s[:, None]
    return q, r


@checked
def warp_times(warps: Float[Array, "E N"], u: Float[Array, ""]) -> Float[Array, " E"]:
    """``C_i(u)`` for every example (linear interpolation of the sampled warps)."""
    n = warps.shape[1]
    uc = jnp.clip(u, 0.0, n - 1.0)
    i0 = jnp.floor(uc).astype(jnp.int32)
    i1 = jnp.minimum(i0 + 1, n - 1)
    s = uc - i0
    return warps[:, i0] * (1 - s) + warps[:, i1] * s


@checked
def blend_pose(
    ex: ExampleSet, w: Float[Array, " E"], u: Float[Array, ""]
) -> tuple[Float[Array, "J 4"], Float[Array, " 3"]]:
    """The blended pose at generic time ``u``: every example sampled at its registered time
    ``C_i(u)``, joint quaternions blended by `blend_quaternions`, root translations
    averaged with ``w``."""
    q, r = pose_at(ex, warp_times(ex.warps, u))
    return blend_quaternions(q, w), jnp.einsum("e,ea->a", w, r)
