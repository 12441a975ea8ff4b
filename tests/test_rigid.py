"""Issue 46, item 3: one rigid / similarity fit and one best-fit plane (`fxspace.rigid`),
checked against scipy's ``align_vectors``, known similarity transforms (Umeyama), numpy's
SVD, and finite differences; and a grep that no other module writes its own."""

from __future__ import annotations

import ast
import re
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import check_grad
from scipy.spatial.transform import Rotation

from fxspace.errors import FxspaceError
from fxspace.rigid import best_fit_plane, fit_rotation, fit_similarity, principal_axes

PKG = Path(__file__).resolve().parents[1] / "fxspace"


def _similarity(rng, n=12, scale=1.7):
    x = rng.normal(size=(n, 3))
    R = Rotation.random(random_state=rng.integers(1 << 30)).as_matrix()
    t = rng.normal(size=3) * 3.0
    return x, R, scale, t, scale * x @ R.T + t


@pytest.mark.parametrize("xp", ["numpy", "jax"])
def test_known_similarity_is_recovered_exactly(rng, xp):
    x, R, s, t, y = _similarity(rng)
    a, b = (x, y) if xp == "numpy" else (jnp.asarray(x), jnp.asarray(y))
    fit = fit_similarity(a, b)
    assert isinstance(fit.rotation, np.ndarray) == (xp == "numpy")
    np.testing.assert_allclose(fit.rotation, R, atol=1e-12)
    np.testing.assert_allclose(fit.scale, s, rtol=1e-12)
    np.testing.assert_allclose(fit.translation, t, atol=1e-12)


def _umeyama(x, y):
    """Umeyama 1991 eqs. (38)–(42), written out independently (unweighted)."""
    mx, my = x.mean(0), y.mean(0)
    sig = (y - my).T @ (x - mx) / len(x)
    U, D, Vt = np.linalg.svd(sig)
    S = np.eye(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0:
        S[2, 2] = -1
    R = U @ S @ Vt
    c = np.trace(np.diag(D) @ S) / np.mean(np.sum((x - mx) ** 2, 1))
    return R, c, my - c * R @ mx


def test_noisy_similarity_matches_umeyama_and_is_near_the_truth(rng):
    x, R, s, t, y = _similarity(rng, n=200)
    y = y + 0.01 * rng.normal(size=y.shape)
    fit = fit_similarity(x, y)
    Ru, su, tu = _umeyama(x, y)
    np.testing.assert_allclose(fit.rotation, Ru, atol=1e-12)
    np.testing.assert_allclose(fit.scale, su, rtol=1e-12)
    np.testing.assert_allclose(fit.translation, tu, atol=1e-12)
    assert np.abs(fit.rotation - R).max() < 1e-2 and abs(fit.scale - s) < 1e-2


def test_weighted_rotation_matches_scipy_align_vectors(rng):
    a = rng.normal(size=(9, 3))
    R = Rotation.random(random_state=7).as_matrix()
    b = a @ R.T + 0.05 * rng.normal(size=a.shape)
    w = rng.uniform(0.1, 2.0, size=9)
    ref, _ = Rotation.align_vectors(b, a, weights=w)
    got = fit_rotation(a, b, w)
    np.testing.assert_allclose(got.rotation, ref.as_matrix(), atol=1e-10)
    np.testing.assert_allclose(fit_rotation(jnp.asarray(a), jnp.asarray(b), w).rotation,
                               ref.as_matrix(), atol=1e-10)  # fmt: skip
    assert np.all(np.diff(got.singular_values) <= 0)


def test_weighted_rigid_fit_equals_repeating_points(rng):
    x, _, _, _, y = _similarity(rng, n=8, scale=1.0)
    y = y + 0.1 * rng.normal(size=y.shape)
    k = np.array([1, 3, 1, 2, 1, 1, 4, 2])
    a = fit_similarity(x, y, k.astype(float), scale=False)
    b = fit_similarity(np.repeat(x, k, 0), np.repeat(y, k, 0), scale=False)
    for u, v in zip(a, b, strict=True):
        np.testing.assert_allclose(u, v, atol=1e-12)


def test_mirrored_data_gives_a_proper_rotation(rng):
    x = rng.normal(size=(20, 3))
    y = x * np.array([1.0, 1.0, -1.0])  # a reflection: the unconstrained fit has det −1
    for fit in (fit_similarity(x, y), fit_similarity(jnp.asarray(x), jnp.asarray(y))):
        assert np.linalg.det(np.asarray(fit.rotation)) == pytest.approx(1.0, abs=1e-12)
    R = fit_rotation(x, y).rotation
    assert np.linalg.det(R) == pytest.approx(1.0, abs=1e-12)
    # it is the best proper rotation: scipy's align_vectors (a quaternion method) agrees
    np.testing.assert_allclose(R, Rotation.align_vectors(y, x)[0].as_matrix(), atol=1e-9)


def test_scale_false_is_the_rigid_fit(rng):
    x, R, _, t, _ = _similarity(rng, scale=1.0)
    y = 3.0 * x @ R.T + t  # a scale the rigid fit must not take
    fit = fit_similarity(x, y, scale=False)
    assert fit.scale == 1.0
    np.testing.assert_allclose(fit.rotation, R, atol=1e-12)  # the rotation does not care
    np.testing.assert_allclose(fit.translation, y.mean(0) - R @ x.mean(0), atol=1e-12)


def test_zero_weight_outliers_are_ignored(rng):
    x, R, s, t, y = _similarity(rng, n=10)
    xo = np.concatenate([x, 50 * rng.normal(size=(3, 3)), np.full((1, 3), np.nan)])
    yo = np.concatenate([y, 50 * rng.normal(size=(3, 3)), np.zeros((1, 3))])
    w = np.r_[np.ones(10), np.zeros(4)]
    for fit in (fit_similarity(xo, yo, w), jax.jit(fit_similarity)(xo, yo, w)):
        np.testing.assert_allclose(fit.rotation, R, atol=1e-10)
        np.testing.assert_allclose(fit.scale, s, rtol=1e-10)
        np.testing.assert_allclose(fit.translation, t, atol=1e-10)


def test_an_empty_fit_in_a_batch_is_the_identity(rng):
    x, R, s, t, y = _similarity(rng)
    w = np.ones((2, len(x)))
    w[1] = 0.0  # a frame with no marker seen
    for fit in (
        fit_similarity(np.stack([x, x]), np.stack([y, y]), w),
        jax.jit(fit_similarity)(np.stack([x, x]), np.stack([y, y]), w),
    ):
        np.testing.assert_allclose(fit.rotation[0], R, atol=1e-10)
        np.testing.assert_allclose(fit.rotation[1], np.eye(3))
        assert float(fit.scale[1]) == 1.0 and np.all(np.asarray(fit.translation[1]) == 0)
    g = jax.jit(jax.grad(lambda d: jnp.sum(fit_similarity(np.stack([x, x]), d, w).rotation)))(
        jnp.asarray(np.stack([y, y]))
    )
    assert np.all(np.isfinite(g)) and np.all(g[1] == 0)


def test_jit_and_vmap_match_the_loop(rng):
    pairs = [_similarity(rng) for _ in range(4)]
    X = jnp.asarray(np.stack([p[0] for p in pairs]))
    Y = jnp.asarray(np.stack([p[4] for p in pairs]))
    batched = jax.jit(jax.vmap(fit_similarity))(X, Y)
    leading = fit_similarity(X, Y)  # leading axes are batch axes too
    for k, (_, R, s, t, _) in enumerate(pairs):
        for fit in (batched, leading):
            np.testing.assert_allclose(fit.rotation[k], R, atol=1e-10)
            np.testing.assert_allclose(fit.scale[k], s, rtol=1e-10)
            np.testing.assert_allclose(fit.translation[k], t, atol=1e-10)


@pytest.mark.parametrize("scale", [True, False])
def test_grad_matches_finite_differences(rng, scale):
    x, _, _, _, y = _similarity(rng, n=7)
    y = jnp.asarray(y + 0.05 * rng.normal(size=y.shape))
    probe = jnp.asarray(rng.normal(size=(3, 3)))

    @jax.jit
    def f(d):
        R, s, t = fit_similarity(jnp.asarray(x), d, scale=scale)
        return jnp.sum(probe * R) + s + jnp.sum(t * t)

    check_grad(f, y, rng, eps=1e-6, rtol=1e-5, atol=1e-8)


def test_grad_is_finite_with_repeated_singular_values():
    # a regular tetrahedron onto itself: the cross-covariance is a multiple of I, where the
    # SVD's own derivative divides by zero; the rotation is unique, so is its derivative
    x = jnp.asarray([[1.0, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1]])

    @jax.jit
    def f(d):
        return jnp.sum(jnp.arange(9.0).reshape(3, 3) * fit_similarity(x, d).rotation)

    g = jax.grad(f)(x)
    assert np.all(np.isfinite(g))
    v = jnp.asarray(np.random.default_rng(1).normal(size=(4, 3)))
    fd = (f(x + 1e-6 * v) - f(x - 1e-6 * v)) / 2e-6
    assert float(jnp.vdot(g, v)) == pytest.approx(float(fd), rel=1e-5, abs=1e-8)


def test_bad_arguments_say_what_to_do():
    with pytest.raises(FxspaceError, match="same shape"):
        fit_similarity(np.zeros((4, 3)), np.zeros((5, 3)))
    with pytest.raises(FxspaceError, match=r"\(\.\.\., n, 3\)"):
        fit_similarity(np.zeros((4, 2)), np.zeros((4, 2)))
    with pytest.raises(FxspaceError, match=">= 0"):
        fit_similarity(np.ones((4, 3)), np.ones((4, 3)), -np.ones(4))
    with pytest.raises(FxspaceError, match="all 0"):
        fit_similarity(np.ones((4, 3)), np.ones((4, 3)), np.zeros(4))
    with pytest.raises(FxspaceError, match="weights must have shape"):
        fit_rotation(np.ones((4, 3)), np.ones((4, 3)), np.ones(3))
    with pytest.raises(FxspaceError, match="at least 3"):
        best_fit_plane(np.ones((2, 3)))


def test_best_fit_plane_matches_numpy_svd(rng):
    n = np.array([0.3, -0.5, 0.8])
    n /= np.linalg.norm(n)
    e1 = np.cross(n, [1.0, 0, 0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(n, e1)
    uv = rng.normal(size=(300, 2)) * [3.0, 1.5]
    c0 = np.array([1.0, 2.0, -1.0])
    p = c0 + uv[:, :1] * e1 + uv[:, 1:] * e2 + 0.01 * rng.normal(size=(300, 1)) * n
    c, normal = best_fit_plane(p)
    _, _, vt = np.linalg.svd(p - p.mean(0))
    np.testing.assert_allclose(c, p.mean(0), atol=1e-12)
    assert abs(normal @ vt[2]) == pytest.approx(1.0, abs=1e-12)
    assert abs(normal @ n) > 0.999 and np.linalg.norm(normal) == pytest.approx(1.0)
    cj, nj = best_fit_plane(jnp.asarray(p))
    np.testing.assert_allclose(cj, c, atol=1e-12)
    assert abs(float(nj @ normal)) == pytest.approx(1.0, abs=1e-10)


def test_weighted_plane_ignores_zero_weight_points(rng):
    p = np.c_[rng.normal(size=(50, 2)), 0.001 * rng.normal(size=50)]
    out = np.concatenate([p, 100 * rng.normal(size=(5, 3))])
    w = np.r_[np.ones(50), np.zeros(5)]
    c, normal = best_fit_plane(out, w)
    np.testing.assert_allclose(c, p.mean(0), atol=1e-12)
    assert abs(normal[2]) > 0.9999
    # integer weights are repeated points
    k = rng.integers(1, 4, size=50)
    mu, axes = principal_axes(p, k.astype(float))
    mu2, axes2 = principal_axes(np.repeat(p, k, 0))
    np.testing.assert_allclose(mu, mu2, atol=1e-12)
    np.testing.assert_allclose(np.abs(np.sum(axes * axes2, 1)), 1.0, atol=1e-10)


# -- one definition: nobody else writes a Kabsch / Umeyama / Horn fit --------------------
# Every SVD in the package outside `fxspace/rigid.py`, by (file, function), with why it is
# not a rigid fit or a plane. A new SVD anywhere fails the test until it is either routed
# through `fxspace.rigid` or listed here with its reason.
OTHER_SVDS = {
    ("expression/_sparse.py", "_principal_axes"): "randomised PCA of P-dim feature rows",
    ("face/_bind.py", "_check_spread"): "singular values only: a degenerate-frame check",
}
# the reflection guard of Kabsch/Umeyama (sign of det(U Vᵀ)) and Horn's 4×4 matrix
GUARD = re.compile(r"sign\([^()]*(?:\([^()]*\)[^()]*)*det\(")


def _svd_calls(root: Path) -> set[tuple[str, str]]:
    found = set()
    for path in sorted(root.rglob("*.py")):
        rel = path.relative_to(root).as_posix()
        if rel == "rigid.py":
            continue
        tree = ast.parse(path.read_text(encoding="utf-8"))
        for fn in ast.walk(tree):
            if not isinstance(fn, ast.FunctionDef | ast.AsyncFunctionDef):
                continue
            for node in ast.walk(fn):
                f = getattr(node, "func", None)
                name = getattr(f, "attr", getattr(f, "id", None))
                if isinstance(node, ast.Call) and name in ("svd", "orthogonal_procrustes"):
                    found.add((rel, fn.name))
    return found


def test_no_other_module_writes_its_own_rigid_fit_or_plane():
    found = _svd_calls(PKG)
    unexplained = sorted(found - set(OTHER_SVDS))
    assert not unexplained, (
        "an SVD outside fxspace/rigid.py (use fxspace.rigid.fit_similarity / fit_rotation "
        f"/ principal_axes / best_fit_plane, or list it in OTHER_SVDS with why): {unexplained}"
    )
    stale = sorted(set(OTHER_SVDS) - found)
    assert not stale, f"OTHER_SVDS lists SVDs that are gone: {stale}"
    guards, horn = [], []
    for path in sorted(PKG.rglob("*.py")):
        rel = path.relative_to(PKG).as_posix()
        text = path.read_text(encoding="utf-8")
        if rel != "rigid.py":
            guards += [rel for _ in GUARD.finditer(text)]
            horn += [rel for _ in re.finditer(r"horn_matrix|sxx \+ syy \+ szz", text)]
    assert not guards, f"a Kabsch reflection guard sign(det(...)) outside rigid.py: {guards}"
    assert not horn, f"Horn's quaternion matrix outside rigid.py: {horn}"


def test_the_grep_sees_a_private_kabsch(tmp_path):
    (tmp_path / "m.py").write_text(
        "import numpy as np\n\ndef align(a, b):\n    u, s, vt = np.linalg.svd(a.T @ b)\n"
        "    d = np.sign(np.linalg.det(u @ vt))\n    return u @ vt\n"
    )
    assert _svd_calls(tmp_path) == {("m.py", "align")}
    assert GUARD.search((tmp_path / "m.py").read_text())
