"""Classical multidimensional scaling and the Pearson score (Kim & Jung, §3.3; Torgerson 1952).

Classical MDS embeds a distance matrix ``D`` by the top eigenpairs of the double-centred
matrix

    B = −½ J D⁽²⁾ J,   J = I − 11ᵀ/n,        X = V_k Λ_k^{1/2}.

For large ``n`` only the top ``k`` eigenpairs are computed (LOBPCG, O(n²k) per step,
instead of a full O(n³) ``eigh``). The eigensolver has a custom JVP — the first-order
perturbation of the top-k eigenpairs (``dλ_i = v_iᵀ dB v_i``; ``dv_i`` from the other
top-k pairs plus a linear solve on their orthogonal complement) — so the embedding
is differentiable without unrolling the iteration (the complement solve is dense,
O(n³) per embedding axis, and runs only when differentiating).
"""

from __future__ import annotations

from functools import partial
from typing import Any, Literal, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int

from fxspace._validate import _is_tracer, as_float_array, check_distance_matrix, check_int
from fxspace.errors import DisconnectedGraphError, FxspaceError
from fxspace.results import RESULTS, is_successful, result_from_flags, where_result

__all__ = ["MDSResult", "classical_mds", "double_centre", "top_eigh", "pearson_score"]

_EXTRA = 4  # extra Ritz vectors for LOBPCG's convergence
_LOBPCG_FROM = 400
_LOBPCG_STEPS = 300


EigMethod = Literal["auto", "eigh", "lobpcg"]


class MDSResult(NamedTuple):
    """Classical MDS output.

    - `embedding`: ``(n, dim)`` coordinates ``V_k Λ_k^{1/2}``.
    - `eigenvalues`: ``(dim,)`` top eigenvalues of ``B`` (descending).
    - `num_steps`: eigensolver iterations (0 for the dense ``eigh``).
    - `result`: a `fxspace.RESULTS` member: ``disconnected`` when ``D`` holds ``+inf``
      and no NaN (the geodesics of a graph in several components: embed each component,
      or raise the threshold), ``nonfinite_input`` / ``nonfinite_output`` when the input
      or the output holds NaN/inf (checked under ``jit``, where no error can be raised),
      ``max_steps_reached`` when the eigensolver ran out of iterations.
    - `converged` (derived): ``result == RESULTS.successful``.
    """

    embedding: Float[Array, "n dim"]
    eigenvalues: Float[Array, " dim"]
    num_steps: Int[Array, ""]
    result: Any

    @property
    def converged(self) -> Bool[Array, ""]:
        return is_successful(self.result)


def double_centre(D: Float[Array, "n n"]) -> Float[Array, "n n"]:
    """``B = −½ J D⁽²⁾ J`` without forming ``J``."""
    D2 = D * D
    r = jnp.mean(D2, axis=0)
    c = jnp.mean(D2, axis=1)
    return -0.5 * (D2 - c[:, None] - r[None, :] + jnp.mean(r))


def _fix_signs(V: Array) -> Array:
    """Make each eigenvector's largest-magnitude entry positive (deterministic output)."""
    idx = jnp.argmax(jnp.abs(V), axis=0)
    s = jnp.sign(V[idx, jnp.arange(V.shape[1])])
    return V * jnp.where(s == 0, 1.0, s)[None, :]


def _top_eigh_primal(B: Array, k: int, method: str) -> tuple[Array, Array, Array]:
    n = B.shape[0]
    if method == "auto":
        method = "lobpcg" if n >= max(_LOBPCG_FROM, 5 * (k + _EXTRA)) else "eigh"
    if method == "eigh":
        w, V = jnp.linalg.eigh(B)
        return w[::-1][:k], _fix_signs(V[:, ::-1][:, :k]), jnp.zeros((), jnp.int32)
    if method == "lobpcg" and n < 5 * (k + _EXTRA):
        raise FxspaceError(
            f"method='lobpcg' needs at least {5 * (k + _EXTRA)} points for {k} dimensions "
            f"(got n={n}); use method='eigh' or 'auto' for small matrices"
        )
    if method == "lobpcg":
        # imported here: jax.experimental.sparse loads scipy.sparse (import fxspace stays light)
        from jax.experimental.sparse.linalg import lobpcg_standard

        m = k + _EXTRA
        X0 = jax.random.normal(jax.random.PRNGKey(0), (n, m), B.dtype)
        theta, U, steps = lobpcg_standard(B, X0, m=_LOBPCG_STEPS)
        order = jnp.argsort(-theta)[:k]
        return theta[order], _fix_signs(U[:, order]), jnp.asarray(steps, jnp.int32)
    raise FxspaceError(f"method must be 'auto', 'eigh' or 'lobpcg', got {method!r}")


@partial(jax.custom_jvp, nondiff_argnums=(1, 2))
def top_eigh(B: Float[Array, "n n"], k: int, method: EigMethod = "auto"):
    """Top-``k`` eigenpairs ``(λ (k,), V (n, k), num_steps)`` of a symmetric matrix."""
    return _top_eigh_primal(B, k, method)


@top_eigh.defjvp
def _top_eigh_jvp(k, method, primals, tangents):
    (B,), (dB,) = primals, tangents
    lam, V, steps = _top_eigh_primal(B, k, method)
    dB = 0.5 * (dB + dB.T)
    dBV = dB @ V  # (n, k)
    dlam = jnp.sum(V * dBV, axis=0)
    # part inside the top-k subspace
    M = V.T @ dBV  # (k, k): v_jᵀ dB v_i
    gap = lam[None, :] - lam[:, None]  # λ_i − λ_j at [j, i]
    safe = jnp.where(jnp.eye(k, dtype=bool) | (gap == 0), 1.0, gap)
    coef = jnp.where(jnp.eye(k, dtype=bool) | (gap == 0), 0.0, M / safe)
    dV_in = V @ coef
    # part in the orthogonal complement: x_i = P (λ_i I − B)⁺ P dB v_i. On the complement
    # λ_i I − B is positive definite; shifting the top-k subspace by c makes it invertible.
    n = B.shape[0]
    P = jnp.eye(n, dtype=B.dtype) - V @ V.T
    rhs = P @ dBV
    c = jnp.abs(lam[0]) + 1.0
    eye = jnp.eye(n, dtype=B.dtype)
    shifted = c * (V @ V.T) - B
    dV_out = jnp.stack(
        [P @ jnp.linalg.solve(lam[i] * eye + shifted, rhs[:, i]) for i in range(k)], axis=1
    )
    return (lam, V, steps), (dlam, dV_in + dV_out, np.zeros((), dtype=jax.dtypes.float0))


def classical_mds(D: Float[Array, "n n"], dim: int = 2, method: EigMethod = "auto") -> MDSResult:
    """Classical (Torgerson) MDS of a distance matrix.

    **Arguments:**
    - `D`: ``(n, n)`` symmetric distances, finite (check connectivity first): NaN/inf
      raise a `fxspace.errors.FxspaceError` (``+inf`` alone, the geodesics of a
      disconnected graph, a `fxspace.errors.DisconnectedGraphError`), or under ``jit``
      give ``result`` ``nonfinite_input`` / ``disconnected``.
    - `dim`: embedding dimension (2 for the expression space).
    - `method`: ``"eigh"`` (dense, O(n³)), ``"lobpcg"`` (top-k, O(n²k) per step) or
      ``"auto"`` (LOBPCG from 400 points on).

    **Returns:** `MDSResult`. Negative eigenvalues (non-Euclidean ``D``) give zero
    coordinates on that axis. jit/vmap/grad compatible.
    """
    if not _is_tracer(D):  # +inf and no NaN: the geodesics of a disconnected graph
        a = np.asarray(D)
        if a.dtype.kind == "f" and np.isposinf(a).any() and not np.isnan(a).any():
            n = int(np.sum(np.isposinf(a)))
            raise DisconnectedGraphError(
                f"D holds +inf between {n} pairs: the geodesics of a graph in several "
                "components cannot be embedded together; raise the threshold "
                "(fxspace.connecting_threshold) or embed each component"
            )
    D = as_float_array(D, "D", ndim=2, min_frames=2)  # NaN/inf rejected when concrete
    if D.shape[0] != D.shape[1]:
        raise FxspaceError(f"D must be a square (n, n) distance matrix, got shape {D.shape}")
    check_distance_matrix(D, "D")
    dim = check_int(dim, "dim", low=1, high=D.shape[0] - 1)
    if method not in ("auto", "eigh", "lobpcg"):
        raise FxspaceError(f"method must be 'auto', 'eigh' or 'lobpcg', got {method!r}")
    lam, V, steps = top_eigh(double_centre(D), dim, method)
    pos = lam > 0
    scale = jnp.where(pos, jnp.sqrt(jnp.where(pos, lam, 1.0)), 0.0)
    X = V * scale[None, :]
    out_ok = jnp.all(jnp.isfinite(X)) & jnp.all(jnp.isfinite(lam))
    result = result_from_flags(
        converged=steps < _LOBPCG_STEPS,
        nonfinite_input=~jnp.all(jnp.isfinite(D)),
        nonfinite_output=~out_ok,
    )
    # geodesics of a disconnected graph: +inf between components and no NaN — say so
    split = jnp.any(jnp.isposinf(D)) & ~jnp.any(jnp.isnan(D))
    result = where_result(split, RESULTS.disconnected, result)
    return MDSResult(X, lam, steps, result)


def pearson_score(D: Float[Array, "n n"], embedding: Float[Array, "n dim"]) -> Array:
    """Pearson correlation ``r`` between ``D[i,j]`` and ``‖y_i − y_j‖`` over pairs ``i < j``.

    The seed paper's criterion for the quality of the 2-D expression space (r = 0.9647 at
    its chosen threshold). Differentiable and jit/vmap compatible; both sides are scaled
    by their largest entry before squaring (``r`` is scale-invariant), so tiny (1e-25) or
    huge (1e19) float32 inputs neither underflow nor overflow.

    ``r`` is NaN — by definition, not a failure of the computation — when it is undefined:
    ``D`` has non-finite entries, fewer than 2 points, or either side is constant over the
    pairs (all ``D[i, j]`` equal, or all embedding distances equal, e.g. a collapsed
    embedding). Check ``jnp.isfinite(r)`` before comparing scores.
    """
    D = as_float_array(D, "D", ndim=2, finite="allow")
    if D.shape[0] != D.shape[1]:
        raise FxspaceError(f"D must be a square (n, n) distance matrix, got shape {D.shape}")
    n = D.shape[0]
    Y = as_float_array(embedding, "embedding", shape=(n, None), finite="allow")
    sD = jnp.max(jnp.abs(D))
    D = D / jnp.where(sD > 0, sD, 1.0)
    sY = jnp.max(jnp.abs(Y))
    Y = Y / jnp.where(sY > 0, sY, 1.0)
    diff = Y[:, None, :] - Y[None, :, :]
    sq = jnp.sum(diff * diff, axis=-1)
    mask = jnp.triu(jnp.ones((n, n), dtype=bool), k=1)
    pos = (sq > 0) & mask
    E = jnp.where(pos, jnp.sqrt(jnp.where(pos, sq, 1.0)), 0.0)
    cnt = n * (n - 1) / 2
    Dm = jnp.where(mask, D, 0.0)
    mx = jnp.sum(Dm) / cnt
    my = jnp.sum(E) / cnt
    dx = jnp.where(mask, D - mx, 0.0)
    dy = jnp.where(mask, E - my, 0.0)
    return jnp.sum(dx * dy) / jnp.sqrt(jnp.sum(dx * dx) * jnp.sum(dy * dy))
