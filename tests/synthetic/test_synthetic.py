"""The seeded synthetic face: determinism, shapes, and its known answers."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.distance import pdist
from scipy.spatial.transform import Rotation
from scipy.stats import spearmanr

from fxspace.errors import FxspaceError
from fxspace.io import MarkerSequence, read_markers, write_trc
from fxspace.synthetic import (
    EXPRESSION_MODES,
    expression_displacement,
    face_layout,
    synthetic_face,
)


def features(p: np.ndarray) -> np.ndarray:
    """Pairwise marker distances, pairs i<j in row-major order (as fx.distance_features)."""
    i, j = np.triu_indices(p.shape[-2], 1)
    return np.linalg.norm(p[..., i, :] - p[..., j, :], axis=-1)


@pytest.fixture(scope="module")
def face():
    return synthetic_face(seed=3)


def test_shapes_and_types(face):
    s = face.sequence
    assert isinstance(s, MarkerSequence)
    assert (s.n_frames, s.n_markers, s.rate, s.units) == (600, 60, 60.0, "mm")
    assert face.mode.shape == (600,) and face.mode.dtype == np.int64
    assert face.intensity.shape == (600,)
    assert face.mode_names == ("jaw_open", "smile", "brow_raise", "pucker", "frown")
    assert face.neutral.shape == (60, 3)
    assert face.local_positions.shape == (600, 60, 3)
    assert face.head_rotation.shape == (600, 3, 3) and face.head_translation.shape == (600, 3)
    assert len(set(s.names)) == 60 and not s.missing_mask().any()


def test_deterministic_per_seed():
    a, b, c = synthetic_face(seed=7), synthetic_face(seed=7), synthetic_face(seed=8)
    np.testing.assert_array_equal(a.sequence.positions, b.sequence.positions)
    np.testing.assert_array_equal(a.mode, b.mode)
    np.testing.assert_array_equal(a.intensity, b.intensity)
    assert a.sequence.names == c.sequence.names  # the layout does not depend on the seed
    assert not np.array_equal(a.intensity, c.intensity)
    assert not np.allclose(a.sequence.positions, c.sequence.positions)


def test_performance_structure(face):
    mode, s = face.mode, face.intensity
    assert ((s >= 0) & (s <= 1)).all()
    np.testing.assert_array_equal(mode == -1, s == 0)  # neutral exactly when intensity 0
    assert mode[0] == -1 and mode[-1] == -1  # starts and ends neutral
    # each mode plays `repetitions` (2) separate neutral -> peak -> neutral events
    change = np.flatnonzero(np.diff(mode) != 0) + 1
    runs = [
        (mode[a], s[a:b]) for a, b in zip(np.r_[0, change], np.r_[change, mode.size], strict=True)
    ]
    events = [(m, seg) for m, seg in runs if m >= 0]
    assert sorted(m for m, _ in events) == [0, 0, 1, 1, 2, 2, 3, 3, 4, 4]
    peaks = []
    for _, seg in events:
        k = int(np.argmax(seg))
        assert (np.diff(seg[: k + 1]) >= 0).all() and (np.diff(seg[k:]) <= 0).all()
        assert seg[0] < 0.5 * seg[k] and seg[-1] < 0.5 * seg[k]  # smooth ramps
        peaks.append(seg[k])
    assert 0.5 <= min(peaks) and max(peaks) <= 1.0 and np.ptp(peaks) > 0.05  # peaks vary


def test_positions_are_rigid_motion_of_local_plus_noise(face):
    R, t = face.head_rotation, face.head_translation
    np.testing.assert_allclose(
        R @ np.swapaxes(R, 1, 2), np.broadcast_to(np.eye(3), R.shape), atol=1e-12
    )
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-12)
    angles = Rotation.from_matrix(R).magnitude()
    assert 0.005 < angles.max() < np.deg2rad(10)  # small, but real, head motion
    assert np.abs(np.diff(angles)).max() < 0.01  # smooth
    rigid = np.einsum("tij,tmj->tmi", R, face.local_positions) + t[:, None]
    resid = face.sequence.positions - rigid
    assert abs(resid.std() - 0.3) < 0.01 and abs(resid.mean()) < 0.01  # N(0, 0.3 mm) noise
    # neutral frames are the neutral face in the head frame
    neutral_frames = face.mode == -1
    np.testing.assert_array_equal(
        face.local_positions[neutral_frames],
        np.broadcast_to(face.neutral, (neutral_frames.sum(), 60, 3)),
    )


def test_noiseless_features_invariant_to_head_motion():
    moving = synthetic_face(seed=1, noise_mm=0.0, head_motion=True)
    still = synthetic_face(seed=1, noise_mm=0.0, head_motion=False)
    np.testing.assert_array_equal(moving.intensity, still.intensity)
    assert not np.allclose(moving.sequence.positions, still.sequence.positions, atol=1.0)
    np.testing.assert_allclose(
        features(moving.sequence.positions), features(still.sequence.positions), rtol=0, atol=1e-9
    )
    np.testing.assert_array_equal(still.sequence.positions, still.local_positions)


@pytest.mark.parametrize("mode", EXPRESSION_MODES)
def test_each_mode_is_a_monotone_1d_curve_in_feature_space(mode):
    names, neutral = face_layout(60)
    s = np.linspace(0.0, 1.0, 101)
    d = expression_displacement(mode, neutral, s)
    np.testing.assert_array_equal(d[0], 0.0)
    peak = np.linalg.norm(d[-1], axis=1).max()
    assert 5.0 < peak < 30.0, peak
    F = features(neutral + d)
    dist = np.linalg.norm(F - F[0], axis=1)
    assert (np.diff(dist) > 0).all()  # distance to neutral grows with intensity
    X = F - F.mean(axis=0)
    ev = np.linalg.eigvalsh(X @ X.T)  # squared singular values of X
    assert ev[-1] / ev.sum() > 0.995  # essentially a 1-D curve


def test_frames_of_one_mode_order_by_intensity_along_their_curve():
    f = synthetic_face(seed=2, noise_mm=0.0)
    F = features(f.local_positions)
    F0 = features(f.neutral)
    for k in range(len(f.mode_names)):
        sel = f.mode == k
        dist = np.linalg.norm(F[sel] - F0, axis=1)
        rho = spearmanr(f.intensity[sel], dist).statistic
        assert rho > 0.9999, (f.mode_names[k], rho)
        # one curve: a frame's features are those of the pure mode at its intensity
        names, neutral = face_layout(60)
        ref = neutral + expression_displacement(f.mode_names[k], neutral, f.intensity[sel])
        np.testing.assert_allclose(F[sel], features(ref), atol=1e-9)


def test_modes_are_separable_in_noisy_features(face):
    F = features(face.sequence.positions)
    F0 = features(face.neutral)
    names, neutral = face_layout(60)
    dirs = []
    for m in face.mode_names:
        g = features(neutral + expression_displacement(m, neutral, np.array([1.0])))[0] - F0
        dirs.append(g / np.linalg.norm(g))
    dirs = np.stack(dirs)
    assert np.abs(dirs @ dirs.T - np.eye(len(dirs))).max() < 0.6  # distinct directions
    active = face.intensity > 0.3
    pred = np.argmax((F[active] - F0) @ dirs.T, axis=1)
    np.testing.assert_array_equal(pred, face.mode[active])


def test_missing_fraction_and_round_trip(tmp_path):
    f = synthetic_face(n_markers=40, n_frames=300, seed=5, missing_fraction=0.1)
    mask = f.sequence.missing_mask()
    assert 0.08 < mask.mean() < 0.12
    clean = synthetic_face(n_markers=40, n_frames=300, seed=5)
    np.testing.assert_array_equal(f.sequence.positions[~mask], clean.sequence.positions[~mask])
    back = read_markers(write_trc(tmp_path / "synth.trc.gz", f.sequence))
    np.testing.assert_array_equal(back.positions, f.sequence.positions)
    assert back.names == f.sequence.names


@pytest.mark.parametrize("n", [12, 44, 45, 100, 200])
def test_layout_sizes_and_face_geometry(n):
    names, pos = face_layout(n)
    assert len(names) == n == len(set(names)) and pos.shape == (n, 3)
    assert pdist(pos).min() > 4.0  # no two markers on top of each other
    assert (pos[:, 2] > 0).all()  # on the front of the face
    assert np.ptp(pos[:, 1]) > 100 and np.ptp(pos[:, 0]) > 80  # face-sized (mm)
    if n >= 44:
        for region in ("forehead", "brow", "eye", "nose", "cheek", "mouth", "lip", "chin", "jaw"):
            assert any(nm.startswith(region) for nm in names), region
        mirror = {"l": "r", "r": "l"}
        for nm in names[:44]:
            assert "_".join(mirror.get(tok, tok) for tok in nm.split("_")) in names, nm


def test_nose_protrudes_and_jaw_opens_down():
    names, pos = face_layout(44)
    idx = {n: i for i, n in enumerate(names)}
    assert pos[idx["nose_tip"], 2] == pos[:, 2].max()
    d = expression_displacement("jaw_open", pos, np.array([1.0]))[0]
    assert d[idx["chin_c"], 1] < -10 and abs(d[idx["forehead_c"]]).max() < 1e-6
    assert abs(d[idx["lip_upper_c"], 1]) < 0.3 * abs(d[idx["lip_lower_c"], 1])
    sm = expression_displacement("smile", pos, np.array([1.0]))[0]
    assert sm[idx["mouth_corner_l"], 0] > 3 and sm[idx["mouth_corner_r"], 0] < -3
    assert sm[idx["mouth_corner_l"], 1] > 3 and sm[idx["mouth_corner_r"], 1] > 3
    br = expression_displacement("brow_raise", pos, np.array([1.0]))[0]
    assert br[idx["brow_l_mid"], 1] > 5 and abs(br[idx["chin_c"]]).max() < 1e-3


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"n_markers": 5}, "n_markers must lie in"),
        ({"modes": ("smile", "laugh")}, "modes must be a non-empty sequence"),
        ({"modes": ()}, "modes must be a non-empty sequence"),
        ({"modes": ("smile", "smile")}, "must not repeat"),
        ({"n_frames": 20}, "n_frames must be an integer >= 72"),
        ({"repetitions": 0}, "repetitions must be >= 1"),
        ({"peak_range": (0.5, 1.5)}, "peak_range"),
        ({"noise_mm": -1.0}, "noise_mm"),
        ({"missing_fraction": 1.0}, "missing_fraction"),
        ({"rate": 0.0}, "rate must be > 0"),
        ({"n_markers": 20.5}, "n_markers must be an integer, got 20.5"),
        ({"repetitions": 1.5}, "repetitions must be an integer"),
        ({"seed": -1}, "seed must lie in"),
        ({"seed": 1.5}, "seed must be an integer"),
        ({"noise_mm": float("nan")}, "noise_mm must be a finite number"),
        ({"rate": "60"}, "rate must be a real number"),
        ({"head_motion": "yes"}, "head_motion must be True or False"),
        ({"modes": 3}, "modes must be a sequence"),
    ],
)
def test_invalid_arguments(kwargs, match):
    with pytest.raises(FxspaceError, match=match):
        synthetic_face(**kwargs)
    with pytest.raises(FxspaceError, match="unknown expression mode"):
        expression_displacement("laugh", np.zeros((3, 3)), np.zeros(1))


def test_single_mode_string_and_small_sequences():
    f = synthetic_face(
        n_markers=20,
        n_frames=40,
        modes="smile",
        repetitions=3,
        seed=0,
        head_motion=False,
        noise_mm=0.0,
    )
    assert f.mode_names == ("smile",)
    assert sorted(set(f.mode.tolist())) == [-1, 0]
    assert f.sequence.n_frames == 40 and f.sequence.n_markers == 20
