"""Issue 43 items 2, 7 and 8 (the face part): a face solve whose ``result`` means the fit
is good (units, marker order and names, outliers, degenerate bindings), the rig reader's
bad files named, and issue 47 item 8's warm start. Each case is its reproduction: a
small synthetic rig everywhere, the ICT head and an AnimFace take where present."""

from __future__ import annotations

import gzip
import json

import numpy as np
import pytest
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


def take(rig, ids, T=20, noise=0.05, seed=1):
    rng = np.random.default_rng(seed)
    t = np.linspace(0, 1, T)[:, None]
    K = rig.num_shapes
    phase = t * rng.uniform(0.5, 1.5, K) + rng.uniform(0, 1, K)
    W = np.clip(0.5 + 0.6 * np.sin(2 * np.pi * phase), 0, 1)
    V = np.asarray(rig.neutral)[None] + np.einsum("tk,knc->tnc", W, np.asarray(rig.deltas))
    R = Rotation.from_rotvec(np.c_[0.2 * np.sin(3 * t), 0.1 * t, 0.05 * np.cos(2 * t)]).as_matrix()
    X = np.einsum("tij,tmj->tmi", R, V[:, ids]) + (np.c_[t, -0.5 * t, 0.2 * t] * 3.0)[:, None]
    return X + rng.normal(0, noise, X.shape), W


@pytest.fixture(scope="module")
def setup():
    rig = grid_rig()
    ids = np.arange(0, rig.num_vertices, 3)
    X, W = take(rig, ids)
    return rig, ids, X, W, fx.face.bind_markers(rig, vertex_ids=ids, units="mm")


def test_good_take_is_successful_and_notes_are_empty(setup):
    rig, ids, X, W, b = setup
    s = fx.face.solve_weights(rig, b, X, temporal=0.0)
    assert bool(np.all(np.asarray(s.converged))) and s.notes == () and len(s.bad_frames) == 0
    assert float(np.max(np.asarray(s.stats["fit"]))) < 0.08
    assert not bool(np.any(np.asarray(s.outliers)))


@pytest.mark.parametrize("factor,like", [(0.001, "bound in mm, solved in m"),
                                         (0.1, "bound in mm, solved in cm"),
                                         (10.0, "bound in cm, solved in mm")])  # fmt: skip
def test_a_take_in_other_units_is_refused_with_the_fix(setup, factor, like):
    """Issue 43.2: bound in mm, solved in m or cm — was "converged" on every frame."""
    rig, ids, X, W, b = setup
    with pytest.raises(FxspaceError, match=like + r".*units="):
        fx.face.solve_weights(rig, b, X * factor)


def test_a_take_that_says_its_units_is_converted(setup):
    rig, ids, X, W, b = setup
    names = b.names
    seq = fx.io.MarkerSequence(X / 1000.0, names, 60.0, "m")
    s = fx.face.solve_weights(rig, b, seq, temporal=0.0)
    ref = fx.face.solve_weights(rig, b, X, temporal=0.0)
    np.testing.assert_allclose(np.asarray(s.weights), np.asarray(ref.weights), atol=1e-6)
    assert bool(np.all(np.asarray(s.converged)))


def test_markers_in_another_order_matched_by_name_or_caught(setup):
    """Issue 43.2: a take with markers in another order was "converged"."""
    rig, ids, X, W, b = setup
    perm = np.random.default_rng(0).permutation(len(ids))
    names = [b.names[i] for i in perm]
    s = fx.face.solve_weights(rig, b, X[:, perm], names=names, temporal=0.0)
    assert bool(np.all(np.asarray(s.converged)))  # by name: re-ordered
    s = fx.face.solve_weights(rig, b, X[:, perm], temporal=0.0)  # no names: geometry
    assert bool(np.all(np.asarray(s.result == fx.RESULTS.poor_fit)))
    assert any("RMS residual" in n for n in s.notes)
    with pytest.raises(FxspaceError, match="not the binding's.*missing"):
        fx.face.solve_weights(rig, b, X, names=[*b.names[:-1], "Nope"])
    with pytest.raises(FxspaceError, match="solve_weights: the solve finished but"):
        fx.face.solve_weights(rig, b, X[:, perm], throw=True)


def test_two_swapped_markers_are_named(setup):
    """Issue 43.2: just two markers (the mouth corners) swapped."""
    rig, ids, X, W, b = setup
    Xs = X.copy()
    Xs[:, [10, 11]] = Xs[:, [11, 10]]
    s = fx.face.solve_weights(rig, b, Xs, temporal=0.0)
    assert bool(np.all(np.asarray(s.result == fx.RESULTS.poor_fit)))
    out = np.asarray(s.outliers)
    assert out[:, 10].all() and out[:, 11].all()
    joined = " ".join(s.notes)
    assert f"{b.names[10]!r} sits where {b.names[11]!r} belongs" in joined


def test_one_marker_far_off_in_one_frame_is_named_and_left_out(setup):
    """Issue 43.2: one marker 500 mm off in one frame (50 units on a 9-unit face)."""
    rig, ids, X, W, b = setup
    Xo = X.copy()
    Xo[5, 7, 2] += 50.0
    s = fx.face.solve_weights(rig, b, Xo, temporal=0.0)
    res = np.asarray(s.result == fx.RESULTS.poor_fit)
    assert res[5] and res.sum() == 1 and list(s.bad_frames) == [5]
    assert np.flatnonzero(np.asarray(s.outliers)[5]).tolist() == [7]
    assert any(f"frame 5: marker {b.names[7]!r}" in n for n in s.notes)
    # left out of the frame's solve: its weights are as good as the clean frames'
    assert float(np.abs(np.asarray(s.weights)[5] - W[5]).mean()) < 0.05


def test_degenerate_and_duplicated_bindings_are_refused():
    """Issue 43.2 (all neutral markers at one point) and 43.8 (a duplicated marker name
    blamed other markers)."""
    rig = grid_rig()
    names = list(fx.face.LANDMARKS)[:6]
    with pytest.raises(FxspaceError, match="at one point"):
        fx.face.bind_markers(rig, np.ones((6, 3)), names)
    line = np.c_[np.arange(6.0), np.zeros(6), np.zeros(6)]
    with pytest.raises(FxspaceError, match="on one line"):
        fx.face.bind_markers(rig, line, names)
    with pytest.raises(FxspaceError, match=r"repeated: \['chin'\]"):
        fx.face.bind_markers(rig, np.random.default_rng(0).normal(size=(6, 3)),
                             ["chin", *names[1:5], "chin"])  # fmt: skip
    with pytest.raises(FxspaceError, match="distinct"):
        fx.face.bind_markers(rig, vertex_ids=[0, 5, 5, 30])
    with pytest.raises(FxspaceError, match="units must be a length unit"):
        fx.face.bind_markers(rig, vertex_ids=[0, 5, 9, 30], units="parsecs")


def test_warm_start_needs_fewer_steps(setup):
    """Issue 47.8: the edited solve starts from the unedited weights."""
    rig, ids, X, W, b = setup
    plain = fx.face.solve_weights(rig, b, X)
    Xe = X.copy()
    Xe[8:12, 3] += 0.3  # a small edit
    cold = fx.face.solve_weights(rig, b, Xe)
    warm = fx.face.solve_weights(rig, b, Xe, init=np.asarray(plain.weights))
    assert int(np.sum(np.asarray(warm.num_steps))) < int(np.sum(np.asarray(cold.num_steps)))
    np.testing.assert_allclose(np.asarray(warm.weights), np.asarray(cold.weights), atol=0.02)


# -- the rig reader (issue 43.8) ---------------------------------------------------------
def _write(path, V, F, gz=False):
    text = "\n".join([f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in V]
                     + [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in F]) + "\n"  # fmt: skip
    path.write_bytes(gzip.compress(text.encode()) if gz else text.encode())


@pytest.fixture()
def folder(tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    rig = grid_rig(n=5, K=3)
    d = tmp_path / "rig"
    d.mkdir()
    N0, F = np.asarray(rig.neutral), np.asarray(rig.faces)
    _write(d / "neutral.obj", N0, F)
    for k, n in enumerate(rig.names):
        _write(d / f"{n}.obj.gz", N0 + np.asarray(rig.deltas[k]), F, gz=True)
    return d, rig, N0, F


def test_corrupt_gz_shape_names_the_file(folder):
    d, *_ = folder
    raw = (d / "shape1.obj.gz").read_bytes()
    (d / "shape1.obj.gz").write_bytes(raw[:10] + b"\xff" * 8 + raw[18:])
    with pytest.raises(CorruptFileError, match="shape1.obj.gz: damaged gzip"):
        fx.face.read_rig(d, cache=False)


def test_nan_in_one_shape_names_the_file(folder):
    d, rig, N0, F = folder
    V = N0 + np.asarray(rig.deltas[2])
    V[3, 1] = np.nan
    _write(d / "shape2.obj.gz", V, F, gz=True)
    with pytest.raises(CorruptFileError, match="shape2.obj.gz: 1 vertices hold NaN"):
        fx.face.read_rig(d, cache=False)


def test_two_files_for_one_shape_are_refused(folder):
    d, rig, N0, F = folder
    _write(d / "shape0.obj", N0, F)
    with pytest.raises(FxspaceError, match="shape0.obj and shape0.obj.gz are both shape"):
        fx.face.read_rig(d, cache=False)


def test_other_faces_with_the_same_vertex_count_are_refused(folder):
    d, rig, N0, F = folder
    _write(d / "shape1.obj.gz", N0, F[:, ::-1], gz=True)  # flipped triangles
    with pytest.raises(FxspaceError, match="shape1.obj.gz: its triangles differ"):
        fx.face.read_rig(d, cache=False)


def test_vertex_indices_json_checked_and_says_the_shapes_it_leaves_out(folder, capsys):
    """The rig's own list is the rig (ICT: its 53 ARKit shapes, while its folder also
    holds PupilDilate_L/R and, in the shared copy, cheekRaiser_L/R): a shape file the
    list lacks is left out, and said by name with the fix; without a list, every file."""
    d, rig, N0, F = folder
    assert fx.face.read_rig(d, cache=False).names == ("shape0", "shape1", "shape2")
    meta = d / "vertex_indices.json"
    meta.write_text(json.dumps({"expressions": ["shape2", "shape0"]}))
    capsys.readouterr()
    r = fx.face.read_rig(d, cache=False)
    assert r.names == ("shape2", "shape0")  # the list, in its order
    out = capsys.readouterr().out
    assert "1 shape file(s) not in vertex_indices.json's 'expressions' left out" in out
    assert "(shape1); list them there to use them" in out
    for bad, msg in [([1, 2], "JSON object"), ({"expressions": "shape2"}, "list of distinct"),
                     ({"idx_to_landmark_verts": [[1, 2]]}, "vertex indices"),
                     ({"idx_to_landmark_verts": list(range(10))}, "68"),
                     ({"expressions": ["smile"]}, "no .obj")]:  # fmt: skip
        meta.write_text(json.dumps(bad))
        with pytest.raises(FxspaceError, match=msg):
            fx.face.read_rig(d, cache=False)
    meta.write_text("{not json")
    with pytest.raises(CorruptFileError, match="not JSON"):
        fx.face.read_rig(d, cache=False)


def test_truncated_cache_entry_is_recomputed(folder, tmp_path):
    d, rig, *_ = folder
    a = fx.face.read_rig(d)
    (entry,) = (tmp_path / "cache" / "fxspace" / "rigs").glob("*.npz")
    entry.write_bytes(entry.read_bytes()[:200])
    b = fx.face.read_rig(d)  # was BadZipFile on every rerun
    np.testing.assert_array_equal(np.asarray(a.deltas), np.asarray(b.deltas))
    c = fx.face.read_rig(d)  # and the entry was rewritten whole
    np.testing.assert_array_equal(np.asarray(a.deltas), np.asarray(c.deltas))


def test_case_twins_and_gltf_suffix_refused(tmp_path):
    rig = grid_rig(n=5, K=2)
    with pytest.raises(FxspaceError, match="differ only in case"):
        fx.face.rig_from_arrays(rig.neutral, rig.deltas, ["Smile", "smile"], rig.faces)
    with pytest.raises(FxspaceError, match=r"name the file with \.glb"):
        fx.face.write_rig_gltf(tmp_path / "x.gltf", rig, None)
    assert not (tmp_path / "x.gltf").exists()


# -- the real head (ICT) and a real take -------------------------------------------------
@pytest.fixture(scope="module")
def ict(data_dir):
    p = data_dir / "face" / "ict"
    if not (p / "generic_neutral_mesh.obj.gz").is_file():
        pytest.skip(f"the ICT Face Model is not under {p}")
    return fx.face.read_rig(p)


@pytest.mark.slow
def test_real_take_mouth_corners_swapped_and_units(ict, data_dir):
    """Issue 43.2 on the real head: the AnimFace jaw take, bound in mm."""
    seq = fx.io.read_markers(data_dir / "face" / "animface_jaw.c3d")
    X = np.asarray(seq.positions)[:60]
    b = fx.face.bind_markers(ict, X[0], seq.names, units=seq.units)
    s = fx.face.solve_weights(ict, b, X)
    assert float(np.mean(np.asarray(s.converged))) > 0.8
    assert not bool(np.any(np.asarray(s.result == fx.RESULTS.poor_fit)))
    i, j = seq.names.index("Mouth_Lend"), seq.names.index("Mouth_Rend")
    Xs = X.copy()
    Xs[:, [i, j]] = Xs[:, [j, i]]
    bad = fx.face.solve_weights(ict, b, Xs)
    assert bool(np.all(np.asarray(bad.result == fx.RESULTS.poor_fit)))
    assert "'Mouth_Lend' sits where 'Mouth_Rend' belongs" in " ".join(bad.notes)
    with pytest.raises(FxspaceError, match="bound in mm, solved in m"):
        fx.face.solve_weights(ict, fx.face.bind_markers(ict, X[0], seq.names), X / 1000.0)
    metres = fx.io.MarkerSequence(X / 1000.0, seq.names, seq.rate, "m")
    conv = fx.face.solve_weights(ict, b, metres)  # the take says its units: converted
    np.testing.assert_allclose(np.asarray(conv.weights), np.asarray(s.weights), atol=1e-5)


# -- reads that leak (issue 43.7) --------------------------------------------------------
def test_trc_and_obj_errors_never_echo_file_content(tmp_path):
    """A ``.trc`` name on another file printed its first line into the error (and so into
    a run's world-readable status.json); the OBJ reader echoed a face line."""
    secret = "TOPSECRET root:$6$hash"
    p = tmp_path / "x.trc"
    p.write_text(secret + "\nmore\nlines\nhere\nstill\n")
    with pytest.raises(CorruptFileError, match="x.trc, line 1: not a TRC file") as e:
        fx.io.read_markers(p)
    assert "TOPSECRET" not in str(e.value)
    head = ["PathFileType\t4\t(X/Y/Z)\tx.trc",
            "DataRate\tCameraRate\tNumFrames\tNumMarkers\tUnits",
            f"60\t60\t{secret}\t1\tmm", "Frame#\tTime\ta\t\t", "\t\tX1\tY1\tZ1", ""]  # fmt: skip
    p.write_text("\n".join(head) + "\n")
    with pytest.raises(CorruptFileError, match="line 3: non-numeric") as e:
        fx.io.read_markers(p)
    assert "TOPSECRET" not in str(e.value)
    head[2] = "60\t60\t1\t1\tmm"
    p.write_text("\n".join([*head, f"1\t0\t{secret}\t2\t3"]) + "\n")
    with pytest.raises(CorruptFileError, match=r"line 7: non-numeric cell \(a X\)") as e:
        fx.io.read_markers(p)
    assert "TOPSECRET" not in str(e.value)
    o = tmp_path / "m.obj"
    for body in (f"v 0 0 0\nv 1 0 0\nf 1 {secret}\n", f"v 0 0 {secret}\n"):
        o.write_text(body)
        with pytest.raises(CorruptFileError, match="m.obj") as e:
            fx.io.read_obj_mesh(o)
        assert "TOPSECRET" not in str(e.value)


@pytest.mark.slow
def test_editor_edited_head_solve_warm_starts(ict, data_dir):
    """Issue 47.8: the editor's edited head solve starts from the unedited weights: fewer
    steps to the tolerance than from zero, the same weights."""
    import jax

    from fxspace.studio import EditorController, EditorData
    from fxspace.studio._server import RigFace

    seq = fx.io.read_markers(data_dir / "face" / "animface_cheeks.c3d")
    M = np.asarray(seq.positions[300:380:2], np.float64)
    surf = fx.face_surface(M[0], 600)
    X = np.asarray(fx.rbf_deform(surf.vertices, M[0], M))
    fit = fx.fit_scene(X, 6, boundaries=[0, 20, 39], key=jax.random.PRNGKey(0), n_init=2)
    data = EditorData(X, surf.faces, fit.model, rate=30.0, gamma=0.5,
                      marker_vertex=np.asarray(surf.marker_vertex), marker_names=seq.names,
                      markers=M)  # fmt: skip
    ctl = EditorController(data, face=RigFace(ict, M[0], seq.names))
    ctl.set_frame(10)
    assert ctl.nudge_control(2, (0.25, -0.3, 0.0))
    warm = ctl.head_solve("edited")
    markers = M + (ctl.sequence("edited") - ctl.sequence("control points"))[:, data.marker_vertex]
    cold = fx.face.solve_weights(ict, ctl.face.binding, markers)
    n_warm = int(np.sum(np.asarray(warm.num_steps)))
    n_cold = int(np.sum(np.asarray(cold.num_steps)))
    print(f"editor edited head solve: {n_cold} steps from zero, {n_warm} warm-started")
    assert n_warm < n_cold
    # the same fit (the weights need not be equal: the rig's shapes are redundant)
    assert float(warm.stats["objective"]) <= 1.01 * float(cold.stats["objective"])


@pytest.mark.slow
def test_real_take_residual_half_the_rigid_only_when_bound_at_the_neutral(ict, data_dir):
    """Issue 47.8: on the reconstruction's window (cheeks, frames 300–600, every 2nd) the
    solved residual was 0.515–0.54 of the rigid-only one (goal ≤ 0.5): the head was bound
    at the window's first frame, an expression. Bound at the take's neutral frame (its
    first), the ratio is below 0.5; bound at frame 300 it is not, whatever the solver's
    settings (the optimum itself)."""
    seq = fx.io.read_markers(data_dir / "face" / "animface_cheeks.c3d")
    P = np.asarray(seq.positions)
    M = P[300:600:2]
    ratios = {}
    for at in (0, 300):
        b = fx.face.bind_markers(ict, P[at], seq.names, units=seq.units)
        s = fx.face.solve_weights(ict, b, M)
        s0 = fx.face.solve_weights(ict, b, M, expressions=False)
        ratios[at] = float(np.nanmean(np.asarray(s.residual))
                           / np.nanmean(np.asarray(s0.residual)))  # fmt: skip
    print(f"solved / rigid-only residual: bound at frame 0 {ratios[0]:.3f}, "
          f"at 300 {ratios[300]:.3f}")
    assert ratios[0] <= 0.5 < ratios[300]


@pytest.mark.slow
def test_weights_mae_on_60_random_face_vertices_is_at_the_noise_floor(ict):
    """Issue 47.8's second figure: markers at 60 random face vertices, 12 active shapes,
    0.05 rig-unit noise — MAE 0.033 against a goal of 0.03. The floor is the problem's,
    not the solver's: the 53 shapes seen at 60 random vertices are ill-conditioned (the
    basis' condition number runs to thousands), and an oracle — exact bounded least
    squares per frame at the *true* head motion — does worse than our solve."""
    from scipy.optimize import lsq_linear

    face = np.asarray(ict.vertex_sets["face"])
    D = np.asarray(ict.deltas)
    ours, oracle = [], []
    for seed in range(2):
        rng = np.random.default_rng(seed)
        ids = np.sort(rng.choice(face, 60, replace=False))
        active = np.sort(rng.choice(ict.num_shapes, 12, replace=False))
        sub = fx.face.rig_from_arrays(ict.neutral, D[active], [ict.names[i] for i in active],
                                      ict.faces)  # fmt: skip
        X, Wa = take(sub, ids, T=30, noise=0.05, seed=seed)
        W = np.zeros((30, ict.num_shapes))
        W[:, active] = Wa
        b = fx.face.bind_markers(ict, vertex_ids=ids)
        s = fx.face.solve_weights(ict, b, X)
        ours.append(float(np.mean(np.abs(np.asarray(s.weights) - W))))
        t = np.linspace(0, 1, 30)[:, None]
        R = Rotation.from_rotvec(np.c_[0.2 * np.sin(3 * t), 0.1 * t, 0.05 * np.cos(2 * t)])
        tau = np.c_[t, -0.5 * t, 0.2 * t] * 3.0
        Z = np.einsum("tmc,tcd->tmd", X - tau[:, None], R.as_matrix()) - b.points[None]
        A = np.asarray(b.basis).reshape(ict.num_shapes, -1).T
        Wo = np.array([lsq_linear(A, z.ravel(), bounds=(0, 1), method="bvls").x for z in Z])
        oracle.append(float(np.mean(np.abs(Wo - W))))
    print(f"weights MAE: ours {np.round(ours, 4)}, oracle at the true motion {np.round(oracle, 4)}")
    assert np.all(np.asarray(ours) <= np.asarray(oracle))


@pytest.mark.slow  # compiles the solve under vmap and grad
def test_numerical_solve_still_jits_vmaps_and_differentiates(setup):
    """The quality judgement sits outside the jitted solve: `_solve` still runs under
    jit, vmap (two takes at once equal two calls) and grad."""
    import jax
    import jax.numpy as jnp

    from fxspace.face._solve import _solve

    rig, ids, X, W, b = setup
    B, A = jnp.asarray(b.points), jnp.asarray(b.basis)
    Ys = jnp.stack([jnp.asarray(b.to_rig(X[:6])), jnp.asarray(b.to_rig(X[6:12]))])
    v, w0 = jnp.ones(Ys.shape[1:3]), jnp.zeros((6, rig.num_shapes))

    def f(Y):
        return _solve(B, A, Y, v, 0.0, 1e-4, 1e-2, w0, True, 3, 10, True)

    both = jax.vmap(f)(Ys)
    for i in range(2):
        np.testing.assert_allclose(np.asarray(both[0][i]), np.asarray(f(Ys[i])[0]), atol=1e-6)
        assert np.asarray(both[6][i]).shape == (6,)  # steps to tolerance per frame
    g = jax.grad(lambda Y: jnp.sum(f(Y)[0]))(Ys[0])
    assert np.all(np.isfinite(np.asarray(g))) and float(jnp.abs(g).sum()) > 0
