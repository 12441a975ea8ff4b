"""A character driven by the capture through the control points (issue 21): the artist's
first/last frames are met exactly, the capture's own face driven as a 'character'
reproduces the control-point model, and the animated glTF reads back."""

import jax
import numpy as np
import pytest
from helpers import face_like

import fxspace as fx
from fxspace.controlpoints import character, drive_character, standin_character


@pytest.fixture(scope="module")
def capture():
    _, pos = face_like(n=40, m=12, seed=3)
    surf = fx.face_surface(pos[0], 200)
    X = np.asarray(fx.rbf_deform(surf.vertices, pos[0], pos))
    fit = fx.fit_scene(X, 4, boundaries=[0, 13, 26, 39], key=jax.random.PRNGKey(0), n_init=3)
    return pos, surf, X, fit.model


def test_own_face_as_character_reproduces_the_model(capture):
    pos, surf, X, scene = capture
    ch = character(surf.vertices, surf.faces, surf.marker_vertex)
    Y = drive_character(ch, scene, pos, X[0])
    model = np.asarray(fx.reconstruct_scene(scene))
    err = np.sqrt(np.mean((Y - model) ** 2)) / np.sqrt(np.mean((X - X[0]) ** 2))
    assert err < 0.1, err


def test_the_character_carries_the_edits(capture):
    """Issue 30.5: the animator's face-anchored key moves the character too; the own face
    as the character takes exactly the edited scene's displacement at its vertices, and
    nothing moves outside the key's frames and region."""
    pos, surf, X, scene = capture
    ch = character(surf.vertices, surf.faces, surf.marker_vertex)
    key = fx.controlpoints.FaceKey(20, int(surf.marker_vertex[3]), (0.0, 0.05, 0.02))
    Y0 = drive_character(ch, scene, pos, X[0])
    Y = drive_character(ch, scene, pos, X[0], edits=[key])
    D = fx.controlpoints.edit_displacements(scene, [key])
    nn = np.argmin(((surf.vertices[:, None] - X[0][None]) ** 2).sum(-1), 1)
    from fxspace.rigid import fit_similarity

    Q, s, _ = fit_similarity(pos[0], surf.vertices[surf.marker_vertex])
    np.testing.assert_allclose(Y - Y0, s * D[:, nn] @ Q.T, atol=1e-9)
    assert np.linalg.norm(Y[20] - Y0[20], axis=1).max() > 0.01
    still = np.linalg.norm(D, axis=2).max(0)[nn] == 0
    np.testing.assert_allclose(Y[:, still], Y0[:, still], atol=1e-12)


def test_standin_meets_the_artist_frames_and_moves_like_the_actor(capture):
    pos, surf, X, scene = capture
    st = standin_character(pos[0], 150, proportions=(1.2, 0.85, 1.3))
    assert st.vertices.shape[0] > 50 and st.first is None
    rng = np.random.default_rng(0)
    first = st.vertices + 0.01 * rng.standard_normal(st.vertices.shape)
    last = st.vertices + 0.02 * rng.standard_normal(st.vertices.shape)
    ch = character(st.vertices, st.faces, st.marker_vertex, first, last)
    Y = drive_character(ch, scene, pos, X[0])
    np.testing.assert_allclose(Y[0], first, atol=1e-9)
    np.testing.assert_allclose(Y[-1], last, atol=1e-9)
    # same proportions at another resolution: the character's motion is the capture
    # model's motion at the nearest capture vertices (up to the coarse meshes' mismatch)
    same = standin_character(pos[0], 150, proportions=(1.0, 1.0, 1.0))
    Ys = drive_character(same, scene, pos, X[0])
    model = np.asarray(fx.reconstruct_scene(scene))
    nn = np.argmin(((same.vertices[:, None] - X[0][None]) ** 2).sum(-1), 1)
    dm = model[:, nn] - model[0, nn]
    rel = np.sqrt(np.mean((Ys - Ys[0] - dm) ** 2) / np.mean(dm**2))
    assert rel < 0.35, rel
    with pytest.raises(fx.FxspaceError, match="markers"):
        drive_character(ch, scene, pos[:, :5], X[0])
    with pytest.raises(fx.FxspaceError, match="same shape|shape"):
        character(st.vertices, st.faces, st.marker_vertex, first[:5])


def test_animated_gltf_and_obj_read_back(capture, tmp_path):
    pos, surf, X, scene = capture
    p = fx.io.write_gltf_morph(tmp_path / "c.glb", X, surf.faces, 30.0, name="character")
    back = fx.io.read_gltf_morph(p)
    np.testing.assert_allclose(back.vertices, X, atol=1e-4)
    np.testing.assert_array_equal(back.faces, surf.faces)
    assert back.fps == pytest.approx(30.0, rel=1e-5) and back.name == "character"
    (obj,) = fx.io.write_obj_sequence(tmp_path / "o", X[:1], surf.faces)
    V, F = fx.io.read_obj(obj)
    np.testing.assert_allclose(V, X[0], atol=1e-4)
    np.testing.assert_array_equal(F, surf.faces)
    (tmp_path / "bad.glb").write_bytes(b"nope")
    with pytest.raises(fx.errors.CorruptFileError, match="bad.glb"):
        fx.io.read_gltf_morph(tmp_path / "bad.glb")
    (tmp_path / "bad.obj").write_text("v 1 2 x\n")
    with pytest.raises(fx.errors.CorruptFileError, match="bad.obj:1"):
        fx.io.read_obj(tmp_path / "bad.obj")
