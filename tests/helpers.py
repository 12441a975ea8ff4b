"""Shared test helpers: tree_allclose and finite-difference checks."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np


def tree_allclose(a, b, rtol=1e-6, atol=1e-8) -> bool:
    la, ta = jax.tree_util.tree_flatten(a)
    lb, tb = jax.tree_util.tree_flatten(b)
    if ta != tb:
        return False
    return all(
        np.allclose(np.asarray(x), np.asarray(y), rtol=rtol, atol=atol, equal_nan=True)
        for x, y in zip(la, lb, strict=True)
    )


def finite_difference_jvp(f, x, v, eps=1e-6):
    """Central difference of scalar/array f at x along direction v (float64)."""
    x = jnp.asarray(x, dtype=jnp.float64)
    v = jnp.asarray(v, dtype=jnp.float64)
    return (f(x + eps * v) - f(x - eps * v)) / (2 * eps)


def check_grad(f, x, rng, n_dirs=3, eps=1e-6, rtol=1e-4, atol=1e-7):
    """Compare jax.grad of scalar f with central differences along random directions."""
    g = jax.grad(f)(x)
    for _ in range(n_dirs):
        v = jnp.asarray(rng.standard_normal(np.shape(x)))
        fd = float(finite_difference_jvp(f, x, v, eps))
        an = float(jnp.vdot(g, v))
        assert np.isclose(an, fd, rtol=rtol, atol=atol), (an, fd)


def face_like(n=100, m=12, seed=1):
    """2-D expression coordinates on three arms plus marker frames that follow them."""
    rng = np.random.default_rng(seed)
    arm = rng.integers(0, 3, n)
    t = rng.uniform(0, 1, n)
    ang = np.array([0.3, 2.4, 4.4])[arm]
    xy = np.stack([t * 10 * np.cos(ang), t * 10 * np.sin(ang)], 1)
    xy += rng.normal(scale=0.15, size=(n, 2))
    base = (
        np.stack(
            [
                np.cos(np.linspace(0, 2 * np.pi, m, endpoint=False)),
                np.sin(np.linspace(0, 2 * np.pi, m, endpoint=False)),
                0.1 * rng.normal(size=m),
            ],
            1,
        )
        * 50
    )
    modes = rng.normal(size=(2, m, 3))
    pos = base[None] + xy[:, 0, None, None] * modes[0] + xy[:, 1, None, None] * modes[1]
    return xy, pos


# a toy 8-joint skeleton (legs + one arm) and smooth random clips, for the motion tests
TOY_NAMES = ("pelvis", "lhip", "lknee", "lfoot", "lowerback", "chest", "lshoulder", "lhand")
TOY_PARENTS = (-1, 0, 1, 2, 0, 4, 5, 6)
TOY_OFFSETS = np.asarray(
    [[0, 0.9, 0], [0.1, -0.05, 0], [0, -0.4, 0], [0, -0.4, 0.05], [0, 0.1, 0], [0, 0.3, 0],
     [0.2, 0.2, 0], [0.3, 0, 0.1]], float,
)  # fmt: skip


def toy_clips(rng, E, T, amp):
    """Smooth random local rotations (axis-angle sinusoids) and a forward-moving root."""
    t = np.arange(T)[:, None, None]
    ax = rng.standard_normal((E, 1, len(TOY_NAMES), 3)) * amp
    ph = rng.uniform(0, 2 * np.pi, (E, 1, len(TOY_NAMES), 1))
    aa = ax * np.sin(2 * np.pi * t[None] / T + ph)
    ang = np.linalg.norm(aa, axis=-1, keepdims=True)
    q = np.concatenate([np.cos(ang / 2), np.sin(ang / 2) * aa / np.maximum(ang, 1e-12)], -1)
    root = np.zeros((E, T, 3))
    root[..., 2] = np.linspace(0, 1, T)[None] * rng.uniform(0.5, 1.5, (E, 1))
    return q, root
