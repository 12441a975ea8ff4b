"""Face rigs (issue 30): OBJ and glTF rigs as data, binding markers, solving weights
against scipy's bounded least squares, exports. A small synthetic rig runs everywhere;
the ICT head (``face/ict``) where the data is present."""

from __future__ import annotations

import gzip

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.optimize import lsq_linear
from scipy.spatial.transform import Rotation

import fxspace as fx
from fxspace.errors import CorruptFileError, FxspaceError


def grid_rig(n=14, K=6, seed=0):
    """A bumpy square sheet (n × n vertices) with K smooth named shapes."""
    rng = np.random.default_rng(seed)
    u, v = np.meshgrid(np.linspace(-1, 1, n), np.linspace(-1, 1, n))
    V = np.stack([u.ravel(), v.ravel(), 0.3 * np.exp(-(u**2 + v**2)).ravel()], 1) * 10
    F = []
    for i in range(n - 1):
        for j in range(n - 1):
            a, b, c, d = i * n + j, i * n + j + 1, (i + 1) * n + j + 1, (i + 1) * n + j
            F += [(a, b, c), (a, c, d)]
    D = []
    for _ in range(K):
        c = rng.uniform(-0.7, 0.7, 2)
        g = np.exp(-((u.ravel() - c[0]) ** 2 + (v.ravel() - c[1]) ** 2) / 0.15)
        D.append(g[:, None] * rng.normal(0, 1.0, 3)[None] * 2.0)
    names = [f"shape{k}" for k in range(K)]
    return fx.face.rig_from_arrays(V, np.asarray(D), names, np.asarray(F))


def synthetic_take(rig, ids, T=40, noise=0.05, seed=1, sparse=False):
    """Known smooth weights in [0, 1], a known rigid motion, markers at vertices ``ids``
    (``sparse``: each shape active about a third of the time, as in a performance, so
    that opposing shapes, eyeLookIn/eyeLookOut, are rarely on together)."""
    rng = np.random.default_rng(seed)
    t = np.linspace(0, 1, T)[:, None]
    K = rig.num_shapes
    phase = t * rng.uniform(0.5, 1.5, K) + rng.uniform(0, 1, K)
    wave = np.sin(2 * np.pi * phase)
    W = np.clip(1.6 * wave - 0.6, 0, 1) if sparse else np.clip(0.5 + 0.6 * wave, 0, 1)
    W[:, 0] = 0.0  # a shape at its bound
    V = np.asarray(rig.neutral)[None] + np.einsum("tk,knc->tnc", W, np.asarray(rig.deltas))
    rot = Rotation.from_rotvec(np.c_[0.2 * np.sin(3 * t), 0.1 * t, 0.05 * np.cos(2 * t)])
    R = rot.as_matrix()
    tau = np.c_[t, -0.5 * t, 0.2 * t] * 3.0
    X = np.einsum("tij,tmj->tmi", R, V[:, ids]) + tau[:, None]
    return X + rng.normal(0, noise, X.shape), W, R, tau


def test_synthetic_take_recovers_weights_and_matches_lsq_linear():
    rig = grid_rig()
    ids = np.arange(0, rig.num_vertices, 3)
    X, W, _, _ = synthetic_take(rig, ids)
    b = fx.face.bind_markers(rig, vertex_ids=ids)
    s = fx.face.solve_weights(rig, b, X, temporal=0.0)
    assert s.weights.shape == W.shape and s.residual.shape == X.shape[:2]
    assert float(jnp.min(s.weights)) >= 0.0 and float(jnp.max(s.weights)) <= 1.0
    assert float(np.mean(np.abs(np.asarray(s.weights) - W))) <= 0.03
    assert bool(jnp.all(s.converged)), np.asarray(s.stats["optimality"]).max()
    # scipy's bounded solver on the same frames at our head motion: the same optimum
    Y = np.asarray(b.to_rig(X))
    Z = np.einsum("tmc,tcd->tmd", Y - np.asarray(s.translation)[:, None], np.asarray(s.rotation))
    z = (Z - b.points[None]).reshape(len(X), -1)
    A = np.asarray(b.basis).reshape(rig.num_shapes, -1)
    mu = 1e-4 * np.trace(A @ A.T) / len(A)
    M = np.vstack([A.T, np.sqrt(mu) * np.eye(len(A))])
    for t in range(0, len(X), 5):
        ref = lsq_linear(M, np.r_[z[t], np.zeros(len(A))], bounds=(0, 1), method="bvls")
        ours = np.asarray(s.weights[t])
        f_ours = np.sum((A.T @ ours - z[t]) ** 2) + mu * ours @ ours
        assert f_ours <= 2.0 * ref.cost * (1 + 1e-3) + 1e-9
        np.testing.assert_allclose(ours, ref.x, atol=0.02)
    # the residual is reported in the capture's units and the rigid-only baseline is worse
    s0 = fx.face.solve_weights(rig, b, X, expressions=False)
    assert float(jnp.mean(s.residual)) < 0.1 < float(jnp.mean(s0.residual))
    assert float(jnp.max(jnp.abs(s0.weights))) == 0.0


def test_missing_markers_drop_out_and_grad_flows():
    rig = grid_rig()
    ids = np.arange(0, rig.num_vertices, 3)
    X, W, _, _ = synthetic_take(rig, ids, T=20)
    X[3, :5] = np.nan  # occluded markers
    X[7] = np.nan  # a frame with none seen
    b = fx.face.bind_markers(rig, vertex_ids=ids)
    s = fx.face.solve_weights(rig, b, X, temporal=0.0)
    assert np.all(np.isnan(np.asarray(s.residual[3, :5])))
    assert np.all(np.isfinite(np.asarray(s.residual[3, 5:])))
    assert np.all(np.isnan(np.asarray(s.weights[7])))
    assert bool((s.result == fx.RESULTS.nonfinite_input)[7]) and not bool(s.converged[7])
    ok = np.r_[0:7, 8:20]
    assert float(np.mean(np.abs(np.asarray(s.weights)[ok] - W[ok]))) <= 0.03
    with pytest.raises(FxspaceError, match="solve_weights"):
        fx.face.solve_weights(rig, b, X, throw=True)
    # differentiable: the gradient of the weights wrt the markers is finite and non-zero
    from fxspace.face._solve import _solve

    Y = jnp.asarray(b.to_rig(X[8:12]))
    v = jnp.ones(Y.shape[:2])
    B, A = jnp.asarray(b.points), jnp.asarray(b.basis)

    def f(Y):
        w = _solve(B, A, Y, v, 0.0, 1e-4, 1e-2, jnp.zeros((4, 6)), True, 3, 10, False)[0]
        return jnp.sum(w @ jnp.arange(6.0))

    g = jax.grad(f)(Y)
    assert np.all(np.isfinite(np.asarray(g))) and float(jnp.abs(g).sum()) > 0


def test_obj_folder_rig_cache_and_errors(tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    rig = grid_rig(n=5, K=3)
    folder = tmp_path / "rig"
    folder.mkdir()
    F = np.asarray(rig.faces)

    def write(path, V, gz=False, quads=False):
        lines = [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in V]
        lines += [f"vt {i / 10:.3f} 0.5" for i in range(3)]
        if quads:  # the first two triangles as one quad, with UVs
            a, b, c = F[0]
            d = F[1][2]
            lines.append(f"f {a + 1}/1 {b + 1}/2 {c + 1}/3 {d + 1}/1")
            tris = F[2:]
        else:
            tris = F
        lines += [f"f {a + 1}/1 {b + 1}/2 {c + 1}/3" for a, b, c in tris]
        text = "\n".join(lines) + "\n"
        if gz:
            path.write_bytes(gzip.compress(text.encode()))
        else:
            path.write_text(text)

    N0 = np.asarray(rig.neutral)
    write(folder / "generic_neutral_mesh.obj.gz", N0, gz=True, quads=True)
    for k, n in enumerate(rig.names):
        write(folder / f"{n}.obj", N0 + np.asarray(rig.deltas[k]))
    a = fx.face.read_rig(folder)
    assert a.names == rig.names and a.faces.shape == rig.faces.shape
    np.testing.assert_allclose(a.deltas, rig.deltas, atol=1e-5)
    assert a.uvs.shape == (3, 2) and a.face_uvs.shape == a.faces.shape
    cached = list((tmp_path / "cache" / "fxspace" / "rigs").glob("*.npz"))
    assert len(cached) == 1
    b = fx.face.read_rig(folder)  # from the cache
    np.testing.assert_array_equal(a.deltas, b.deltas)
    write(folder / "shape1.obj", N0 + 2 * np.asarray(rig.deltas[1]))  # an edited shape
    c = fx.face.read_rig(folder)
    np.testing.assert_allclose(c.deltas[1], 2 * rig.deltas[1], atol=1e-5)
    assert len(list((tmp_path / "cache" / "fxspace" / "rigs").glob("*.npz"))) == 2
    # errors name the file and the fix
    write(folder / "bad.obj", N0[:-1])
    with pytest.raises(FxspaceError, match="bad.obj.*(neutral's topology|missing vertex)"):
        fx.face.read_rig(folder)
    (folder / "bad.obj").write_text("v 1 2 x\n")
    with pytest.raises(CorruptFileError, match="bad.obj:1"):
        fx.face.read_rig(folder)
    (folder / "bad.obj").write_text("v 1 2 nan\n" * len(N0))
    with pytest.raises(FxspaceError, match="NaN"):
        fx.face.read_rig(folder, cache=False)
    (folder / "bad.obj").unlink()
    (tmp_path / "empty").mkdir()
    with pytest.raises(FxspaceError, match="no .obj"):
        fx.face.read_rig(tmp_path / "empty")
    write(folder / "other_neutral.obj", N0)
    with pytest.raises(FxspaceError, match="exactly one neutral"):
        fx.face.read_rig(folder)
    with pytest.raises(FxspaceError, match="no such rig"):
        fx.face.read_rig(tmp_path / "nope")


def test_gltf_rig_and_csv_round_trip(tmp_path):
    rig = grid_rig(n=6, K=4)
    W = np.random.default_rng(0).uniform(0, 1, (12, 4))
    p = fx.face.write_rig_gltf(tmp_path / "face.glb", rig, W, fps=24.0)
    back = fx.face.read_rig(p)
    assert back.names == rig.names
    np.testing.assert_allclose(back.deltas, rig.deltas, atol=1e-5)
    bs = fx.io.read_gltf_blendshapes(p)
    np.testing.assert_allclose(bs.weights, W, atol=1e-6)
    assert bs.fps == pytest.approx(24.0)
    # the same weights onto a rig whose shapes carry the same names, in another order
    other = fx.face.rig_from_arrays(rig.neutral, rig.deltas[::-1], rig.names[::-1], rig.faces)
    w2, missing = fx.face.transfer_weights(W, rig.names, other)
    np.testing.assert_allclose(w2, W[:, ::-1])
    assert missing == []
    _, missing = fx.face.transfer_weights(np.c_[W, W[:, :1]], (*rig.names, "tongueOut"), other)
    assert missing == ["tongueOut"]
    W[3, 1] = np.nan
    c = fx.face.write_weights_csv(tmp_path / "w.csv", W, rig.names, fps=24.0)
    header = c.read_text().splitlines()[0]
    assert header == "frame,time," + ",".join(rig.names)
    W2, names, times = fx.face.read_weights_csv(c)
    assert names == rig.names and np.isnan(W2[3, 1])
    np.testing.assert_allclose(np.nan_to_num(W2), np.nan_to_num(W), atol=1e-5)
    np.testing.assert_allclose(times, np.arange(12) / 24.0, atol=1e-6)


def test_obj_reader_quads_uvs_and_errors(tmp_path):
    p = tmp_path / "q.obj"
    p.write_text(
        "# a quad and a triangle\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 2 0 0\n"
        "vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\n"
        "f 1/1 2/2 3/3 4/4\nf 2/2 5/1 3/3\n"
    )
    m = fx.io.read_obj_mesh(p)
    np.testing.assert_array_equal(m.faces, [[0, 1, 2], [0, 2, 3], [1, 4, 2]])
    np.testing.assert_array_equal(m.face_uvs, [[0, 1, 2], [0, 2, 3], [1, 0, 2]])
    assert m.vertices.shape == (5, 3) and m.uvs.shape == (4, 2)
    V, F = fx.io.read_obj(p)
    np.testing.assert_array_equal(F, m.faces)
    p.write_text("v 0 0 0\nv 1 0 0\nf 1 2 9\n")
    with pytest.raises(CorruptFileError, match="missing vertex"):
        fx.io.read_obj_mesh(p)
    with pytest.raises(FxspaceError, match="not a regular file"):
        fx.io.read_obj_mesh(tmp_path)


def test_binding_refuses_far_markers_and_bad_input():
    rig = grid_rig()
    with pytest.raises(FxspaceError, match="landmarks"):
        fx.face.bind_markers(rig, np.random.default_rng(0).normal(size=(5, 3)), list("abcde"))
    with pytest.raises(FxspaceError, match="vertex_ids"):
        fx.face.bind_markers(rig, vertex_ids=[0, 1, 10**6])
    b = fx.face.bind_markers(rig, vertex_ids=[0, 5, 9, 30])
    with pytest.raises(FxspaceError, match=r"markers must be \(frames, 4, 3\)"):
        fx.face.solve_weights(rig, b, np.zeros((3, 5, 3)))
    with pytest.raises(FxspaceError, match="temporal"):
        fx.face.solve_weights(rig, b, np.zeros((3, 4, 3)), temporal=-1.0)


@pytest.fixture(scope="module")
def ict(data_dir):
    p = data_dir / "face" / "ict"
    if not (p / "generic_neutral_mesh.obj.gz").is_file():
        pytest.skip(f"the ICT Face Model is not under {p}")
    return fx.face.read_rig(p)


def test_ict_rig_synthetic_take(ict):
    """The issue's check: a take made from the ICT rig itself (known weights and rigid
    motion, markers at chosen vertices, noise 0.05 rig units = 0.5 mm): MAE <= 0.03."""
    assert ict.neutral.shape == (26719, 3) and ict.deltas.shape == (53, 26719, 3)
    assert "jawOpen" in ict.names and len(ict.vertex_sets["landmarks"]) == 68
    assert len(ict.vertex_sets["face"]) == 9409
    D = np.linalg.norm(np.asarray(ict.deltas), axis=-1)
    # markers where the shapes move: each shape's 4 most displaced vertices, 80 spread
    skull = np.asarray(ict.vertex_sets["rigid"])[::25]  # head markers fix the rigid motion
    ids = np.unique(np.r_[np.argsort(-D, axis=1)[:, :4].ravel(), np.arange(0, 9409, 118), skull])
    X, W, _, _ = synthetic_take(ict, ids, T=30, noise=0.05, sparse=True)
    b = fx.face.bind_markers(ict, vertex_ids=ids)
    s = fx.face.solve_weights(ict, b, X, temporal=0.0, outer=60, inner=100)
    mae = float(np.mean(np.abs(np.asarray(s.weights) - W)))
    assert mae <= 0.03, mae


def test_ict_binds_a_real_capture(ict, data_dir):
    take = fx.io.read_markers(data_dir / "face" / "animface_jaw.c3d")
    X = np.asarray(take.positions)
    b = fx.face.bind_markers(ict, X[0], take.names)
    mm = b.distance / b.scale
    assert 0.05 < b.scale < 0.15  # mm → cm, with the performer's size
    assert float(np.median(mm)) < 6.0
    s = fx.face.solve_weights(ict, b, X[:200])
    s0 = fx.face.solve_weights(ict, b, X[:200], expressions=False)
    assert float(jnp.nanmean(s.residual)) < float(jnp.nanmean(s0.residual))
    assert float(np.mean(np.asarray(s.converged))) > 0.8
    bad = X[0].copy()
    bad[take.names.index("Chin")] += np.array([0.0, 0.0, 300.0])  # 30 cm off the face
    with pytest.raises(FxspaceError, match="Chin"):
        fx.face.bind_markers(ict, bad, take.names)


def test_posed_vertices_put_the_head_where_the_markers_are():
    """The posed rig at the solved weights and motion: at the marker vertices it is the
    markers (up to the noise), in the capture's frame; the whole take, one frame, a
    vertex subset and the rig's frame agree; NaN frames stay NaN; jit and grad run."""
    rig = grid_rig()
    ids = np.arange(0, rig.num_vertices, 3)
    X, W, R, tau = synthetic_take(rig, ids, T=12)
    # the capture in other units and frame: a known similarity away from the rig's
    Q = Rotation.from_rotvec([0.3, -0.2, 0.1]).as_matrix()
    Xc = (X - 1.5) @ Q / 10.0  # rig y = 10 Q x + 1.5
    Xc[4] = np.nan
    b = fx.face.bind_markers(rig, vertex_ids=ids)
    b = b._replace(scale=10.0, rotation=Q, translation=np.full(3, 1.5))
    s = fx.face.solve_weights(rig, b, Xc, temporal=0.0)
    V = np.asarray(fx.face.posed_vertices(rig, b, s))
    assert V.shape == (12, rig.num_vertices, 3)
    ok = np.r_[0:4, 5:12]
    err = np.abs(V[ok][:, ids] - Xc[ok])
    assert float(err.max()) < 0.03  # the noise is 0.05 rig units = 0.005 capture units
    assert np.all(np.isnan(V[4]))
    # the true pose, from the known weights and motion, matches too (not just the markers)
    true = np.einsum("tij,tnj->tni", R, np.asarray(rig.shape_vertices(W))) + tau[:, None]
    np.testing.assert_allclose(V[ok], ((true[ok] - 1.5) @ Q / 10.0), atol=0.03)
    one = np.asarray(fx.face.posed_vertices(rig, b, s, frames=2, vertices=ids[:5]))
    np.testing.assert_allclose(one, V[2, ids[:5]], atol=1e-5)
    rigf = np.asarray(fx.face.posed_vertices(rig, b, s, frames=[2], capture_frame=False))
    np.testing.assert_allclose(rigf[0], 10.0 * V[2] @ Q.T + 1.5, atol=1e-4)
    s1 = fx.face.solve_weights(rig, b, Xc[3])  # a one-frame solve gives one mesh
    assert fx.face.posed_vertices(rig, b, s1).shape == (rig.num_vertices, 3)
    f = jax.jit(lambda w: fx.face.posed_vertices(rig, b, s._replace(weights=w), frames=[0]))
    np.testing.assert_allclose(np.asarray(f(s.weights))[0], V[0], atol=1e-5)
    g = jax.grad(lambda w: fx.face.posed_vertices(rig, b, s._replace(weights=w), frames=[0]).sum())
    assert float(jnp.abs(g(s.weights)).sum()) > 0
    with pytest.raises(FxspaceError, match="frames"):
        fx.face.posed_vertices(rig, b, s, frames=[99])
    with pytest.raises(FxspaceError, match="weights"):
        fx.face.posed_vertices(rig, b, s._replace(weights=s.weights[:, :2]))
