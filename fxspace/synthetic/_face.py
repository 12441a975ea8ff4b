"""Seeded synthetic face: the embedded default data and the source of known answers.

``synthetic_face`` places ``n_markers`` named markers on a face-like surface (the front
of an ellipsoid with a nose, brow ridge and lips; regions forehead, brows, eyes, nose,
cheeks, mouth, chin, jaw), animates a performance of expression modes — each a smooth
displacement field over the face, played neutral → peak → neutral one mode at a time,
a few repetitions with varying peak intensity — then applies a smooth rigid head
motion and Gaussian measurement noise, optionally dropping random markers (NaN).

Known answers it provides (tested in ``tests/test_synthetic.py``):

- the noiseless pairwise-distance features (``local_positions``) of the frames of one
  mode lie on a 1-D curve parametrised by the intensity; their distance to the neutral
  features grows monotonically with the intensity;
- the pairwise-distance features of the noiseless positions are invariant to the head
  motion: ``positions = local_positions @ R(t).T + t(t) + noise``;
- different modes move different regions, so their feature curves are separable.

Pure numpy and deterministic for a seed: independent random streams drive the
performance, the head motion, the noise and the missing markers, so switching one of
them off (``head_motion=False``, ``noise_mm=0``) leaves the others unchanged.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import NamedTuple

import numpy as np
from jaxtyping import Float, Int

from fxspace._validate import as_float_array, check_int, check_scalar
from fxspace.errors import FxspaceError
from fxspace.io import MarkerSequence

__all__ = [
    "SyntheticFace",
    "synthetic_face",
    "EXPRESSION_MODES",
    "face_layout",
    "expression_displacement",
]

# -- face geometry (millimetres; x = subject's left, y = up, z = forward) -----------------
_A, _B, _C = 75.0, 105.0, 85.0  # ellipsoid half-width, half-height, depth

# Named landmarks (u, v) on the frontal projection, in priority order: any prefix of
# 15 or more covers every region; left/right pairs are adjacent.
_LANDMARKS: tuple[tuple[str, float, float], ...] = (
    ("forehead_c", 0.0, 78.0),
    ("brow_l_mid", 32.0, 50.0),
    ("brow_r_mid", -32.0, 50.0),
    ("nose_tip", 0.0, -5.0),
    ("eye_l_upper", 32.0, 33.0),
    ("eye_r_upper", -32.0, 33.0),
    ("mouth_corner_l", 25.0, -42.0),
    ("mouth_corner_r", -25.0, -42.0),
    ("lip_upper_c", 0.0, -34.0),
    ("lip_lower_c", 0.0, -50.0),
    ("cheek_l_upper", 42.0, 5.0),
    ("cheek_r_upper", -42.0, 5.0),
    ("chin_c", 0.0, -75.0),
    ("jaw_l", 50.0, -55.0),
    ("jaw_r", -50.0, -55.0),
    ("brow_l_inner", 14.0, 46.0),
    ("brow_r_inner", -14.0, 46.0),
    ("brow_l_outer", 50.0, 44.0),
    ("brow_r_outer", -50.0, 44.0),
    ("nose_bridge", 0.0, 28.0),
    ("eye_l_lower", 32.0, 19.0),
    ("eye_r_lower", -32.0, 19.0),
    ("cheek_l_lower", 40.0, -25.0),
    ("cheek_r_lower", -40.0, -25.0),
    ("lip_upper_l", 12.0, -36.0),
    ("lip_upper_r", -12.0, -36.0),
    ("lip_lower_l", 12.0, -48.0),
    ("lip_lower_r", -12.0, -48.0),
    ("forehead_l", 30.0, 75.0),
    ("forehead_r", -30.0, 75.0),
    ("nostril_l", 12.0, -12.0),
    ("nostril_r", -12.0, -12.0),
    ("eye_l_inner", 20.0, 26.0),
    ("eye_r_inner", -20.0, 26.0),
    ("eye_l_outer", 45.0, 26.0),
    ("eye_r_outer", -45.0, 26.0),
    ("cheek_l_outer", 58.0, -8.0),
    ("cheek_r_outer", -58.0, -8.0),
    ("chin_l", 16.0, -70.0),
    ("chin_r", -16.0, -70.0),
    ("chin_low", 0.0, -90.0),
    ("glabella", 0.0, 45.0),
    ("temple_l", 62.0, 40.0),
    ("temple_r", -62.0, 40.0),
)
_MIN_MARKERS, _MAX_MARKERS = 12, 200


def _surface_z(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Depth of the face surface at (u, v): ellipsoid + nose + brow ridge + lips − eye sockets."""
    r2 = np.clip(1.0 - (u / _A) ** 2 - (v / _B) ** 2, 0.05, None)
    z = _C * np.sqrt(r2)
    z += 22.0 * np.exp(-(u**2) / (2 * 9.0**2) - (v + 2.0) ** 2 / (2 * 16.0**2))  # nose
    z += 4.0 * np.exp(-((v - 47.0) ** 2) / (2 * 6.0**2))  # brow ridge
    z += 5.0 * np.exp(-(u**2) / (2 * 16.0**2) - (v + 42.0) ** 2 / (2 * 8.0**2))  # lips
    for s in (1.0, -1.0):
        z -= 7.0 * np.exp(-((u - s * 32.0) ** 2) / (2 * 9.0**2) - (v - 26.0) ** 2 / (2 * 7.0**2))
    return z


def _region(name: str) -> str:
    head = name.split("_")[0]
    return {"lip": "mouth", "nostril": "nose", "glabella": "brow"}.get(head, head)


def face_layout(n_markers: int = 60) -> tuple[tuple[str, ...], Float[np.ndarray, "markers 3"]]:
    """Names and neutral positions ``(M, 3)`` (mm) of the synthetic face's markers.

    The first markers are the named landmarks (``brow_l_inner``, ``mouth_corner_r``,
    ``chin_c``, …; 44 of them, in priority order); beyond 44, markers fill the face by
    farthest-point sampling of a grid (named ``<region>_<side>_<k>``, e.g.
    ``cheek_l_2``). Deterministic: the layout does not depend on any seed.
    """
    n = check_int(n_markers, "n_markers", low=_MIN_MARKERS, high=_MAX_MARKERS)
    base = _LANDMARKS[: min(n, len(_LANDMARKS))]
    names = [b[0] for b in base]
    uv = np.array([[b[1], b[2]] for b in base], dtype=np.float64)
    if n > len(_LANDMARKS):
        g = np.arange(-70.0, 70.5, 2.5)
        gu, gv = (a.ravel() for a in np.meshgrid(g, np.arange(-95.0, 90.5, 2.5)))
        inside = (gu / 66.0) ** 2 + (gv / 96.0) ** 2 <= 1.0
        for s in (1.0, -1.0):  # not on the eyeballs
            inside &= ((gu - s * 32.0) / 11.0) ** 2 + ((gv - 26.0) / 6.0) ** 2 > 1.0
        inside &= (gu / 22.0) ** 2 + ((gv + 42.0) / 5.0) ** 2 > 1.0  # not in the mouth slit
        cand = np.stack([gu[inside], gv[inside]], axis=1)
        dmin = np.min(np.linalg.norm(cand[:, None] - uv[None], axis=-1), axis=1)
        lm_uv = uv.copy()
        counters: dict[str, int] = {}
        for _ in range(n - len(_LANDMARKS)):
            k = int(np.argmax(dmin))
            pu, pv = cand[k]
            nearest = int(np.argmin(np.linalg.norm(lm_uv - cand[k], axis=-1)))
            side = "l" if pu > 3.0 else ("r" if pu < -3.0 else "c")
            stem = f"{_region(names[nearest])}_{side}"
            counters[stem] = counters.get(stem, 0) + 1
            names.append(f"{stem}_{counters[stem]}")
            uv = np.vstack([uv, cand[k]])
            dmin = np.minimum(dmin, np.linalg.norm(cand - cand[k], axis=-1))
    pos = np.stack([uv[:, 0], uv[:, 1], _surface_z(uv[:, 0], uv[:, 1])], axis=1)
    return tuple(names), pos


# -- expression modes: displacement fields over the neutral face -------------------------
def _gauss(u: np.ndarray, v: np.ndarray, cu: float, cv: float, sigma: float) -> np.ndarray:
    return np.exp(-((u - cu) ** 2 + (v - cv) ** 2) / (2.0 * sigma**2))


def _sigmoid(x: np.ndarray) -> np.ndarray:
    return 1.0 / (1.0 + np.exp(-x))


def _linear_field(field: Callable[[np.ndarray, np.ndarray], np.ndarray]):
    def apply(neutral: np.ndarray, s: np.ndarray) -> np.ndarray:
        d = field(neutral[:, 0], neutral[:, 1])  # (M, 3) at intensity 1
        return s[:, None, None] * d[None]

    return apply


def _jaw_open(neutral: np.ndarray, s: np.ndarray) -> np.ndarray:
    # Rotation of the lower face about a left-right jaw axis behind the mouth, the
    # angle fading smoothly from the lower lip/chin (full) to the upper lip (none).
    u, v = neutral[:, 0], neutral[:, 1]
    w = _sigmoid((-42.0 - v) / 3.0) * _sigmoid((70.0 - np.abs(u)) / 6.0)
    pivot = np.array([0.0, -15.0, -40.0])
    ang = np.deg2rad(12.0) * s[:, None] * w[None]  # (T, M)
    rel = neutral - pivot
    cm1, sn = -2.0 * np.sin(ang / 2.0) ** 2, np.sin(ang)  # cos - 1 without cancellation
    dy = rel[None, :, 1] * cm1 - rel[None, :, 2] * sn
    dz = rel[None, :, 1] * sn + rel[None, :, 2] * cm1
    return np.stack([np.zeros_like(dy), dy, dz], axis=-1)


def _smile(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    d = np.zeros((u.size, 3))
    for s in (1.0, -1.0):
        g = _gauss(u, v, s * 25.0, -42.0, 13.0)
        d += g[:, None] * np.array([s * 7.0, 7.0, -3.0])
        d += _gauss(u, v, s * 42.0, -12.0, 15.0)[:, None] * np.array([s * 1.0, 4.0, 2.0])
        d += _gauss(u, v, s * 32.0, 19.0, 6.0)[:, None] * np.array([0.0, 2.0, 0.0])
    return d


def _brow_raise(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    w = np.exp(-((v - 48.0) ** 2) / (2 * 14.0**2)) * _sigmoid((v - 30.0) / 3.0)
    w *= _sigmoid((70.0 - np.abs(u)) / 5.0)
    return w[:, None] * np.array([0.0, 8.0, 1.0])


def _pucker(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    g = _gauss(u, v, 0.0, -42.0, 18.0)
    return g[:, None] * np.stack([-0.45 * u, np.zeros_like(u), np.full_like(u, 9.0)], axis=1)


def _frown(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    d = np.zeros((u.size, 3))
    for s in (1.0, -1.0):
        d += _gauss(u, v, s * 18.0, 46.0, 12.0)[:, None] * np.array([-s * 4.0, -5.0, 1.5])
        d += _gauss(u, v, s * 25.0, -44.0, 12.0)[:, None] * np.array([s * 1.0, -6.0, 0.0])
    return d


def _eye_close(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    d = np.zeros((u.size, 3))
    for s in (1.0, -1.0):
        d += _gauss(u, v, s * 32.0, 33.0, 6.0)[:, None] * np.array([0.0, -9.0, 1.0])
        d += _gauss(u, v, s * 32.0, 19.0, 6.0)[:, None] * np.array([0.0, 1.5, 0.0])
    return d


def _cheek_puff(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    d = np.zeros((u.size, 3))
    for s in (1.0, -1.0):
        d += _gauss(u, v, s * 42.0, -25.0, 15.0)[:, None] * np.array([s * 6.0, 0.0, 5.0])
    d += _gauss(u, v, 0.0, -42.0, 12.0)[:, None] * np.array([0.0, 0.0, 2.5])
    return d


_MODES: dict[str, Callable[[np.ndarray, np.ndarray], np.ndarray]] = {
    "jaw_open": _jaw_open,
    "smile": _linear_field(_smile),
    "brow_raise": _linear_field(_brow_raise),
    "pucker": _linear_field(_pucker),
    "frown": _linear_field(_frown),
    "eye_close": _linear_field(_eye_close),
    "cheek_puff": _linear_field(_cheek_puff),
}

#: Names of the expression modes ``synthetic_face`` can play.
EXPRESSION_MODES: tuple[str, ...] = tuple(_MODES)


def expression_displacement(
    mode: str,
    neutral: Float[np.ndarray, "markers 3"],
    intensity: Float[np.ndarray, " frames"],
) -> Float[np.ndarray, "frames markers 3"]:
    """Displacement ``(T, M, 3)`` (mm, head frame) of expression ``mode`` at ``intensity``.

    ``jaw_open`` rotates the lower face about a jaw axis (up to 12° at intensity 1,
    fading from chin/lower lip to the upper lip); the others are smooth linear fields
    of Gaussian bumps: ``smile`` pulls the mouth corners up and out and lifts the
    cheeks, ``brow_raise`` lifts brows and forehead, ``pucker`` pulls the lips to the
    midline and forward, ``frown`` lowers and knits the inner brows and drops the mouth
    corners, ``eye_close`` lowers the upper lids, ``cheek_puff`` pushes the cheeks out.
    Zero at intensity 0; peak displacements 6–25 mm at intensity 1.
    """
    if not isinstance(mode, str) or mode not in _MODES:
        raise FxspaceError(f"unknown expression mode {mode!r}; available: {list(EXPRESSION_MODES)}")
    neutral = as_float_array(neutral, "neutral", shape=(None, 3), dtype=np.float64, xp="numpy")
    s = np.atleast_1d(
        as_float_array(intensity, "intensity", min_frames=0, dtype=np.float64, xp="numpy")
    )
    if s.ndim != 1:
        raise FxspaceError(f"intensity must be a scalar or 1-D (frames,), got shape {s.shape}")
    return _MODES[mode](neutral, s)


# -- performance, head motion ------------------------------------------------------------
def _ease(x: np.ndarray) -> np.ndarray:
    return 0.5 - 0.5 * np.cos(np.pi * x)


def _timeline(
    rng: np.random.Generator,
    n_frames: int,
    n_modes: int,
    repetitions: int,
    peak_range: tuple[float, float],
) -> tuple[np.ndarray, np.ndarray]:
    order = np.concatenate([rng.permutation(n_modes) for _ in range(repetitions)])
    n_events = order.size
    # relative durations per event: gap before, ramp up, hold, ramp down; then a final gap
    rel = np.column_stack(
        [
            rng.uniform(0.6, 1.2, n_events),
            rng.uniform(0.8, 1.4, n_events),
            rng.uniform(0.3, 0.9, n_events),
            rng.uniform(0.8, 1.4, n_events),
        ]
    )
    peaks = rng.uniform(peak_range[0], peak_range[1], n_events)
    minimum = np.array([1, 2, 1, 2])
    free = n_frames - n_events * minimum.sum() - 1
    weights = np.append(rel.ravel(), rng.uniform(0.6, 1.2))
    edges = np.round(np.cumsum(weights) / weights.sum() * free).astype(np.int64)
    extra = np.diff(np.concatenate([[0], edges]))
    lengths = extra[:-1].reshape(n_events, 4) + minimum

    mode = np.full(n_frames, -1, dtype=np.int64)
    intensity = np.zeros(n_frames)
    t = 0
    for e in range(n_events):
        gap, up, hold, down = (int(x) for x in lengths[e])
        t += gap
        ramp_up = peaks[e] * _ease(np.arange(1, up + 1) / (up + 1))
        ramp_down = peaks[e] * _ease(np.arange(down, 0, -1) / (down + 1))
        seg = np.concatenate([ramp_up, np.full(hold, peaks[e]), ramp_down])
        intensity[t : t + seg.size] = seg
        mode[t : t + seg.size] = order[e]
        t += seg.size
    return mode, intensity


def _rodrigues(w: np.ndarray) -> np.ndarray:
    """Rotation matrices ``(T, 3, 3)`` from axis-angle vectors ``(T, 3)``."""
    theta = np.linalg.norm(w, axis=-1)[:, None, None]
    safe = np.where(theta > 0, theta, 1.0)
    k = w / safe[:, :, 0]
    K = np.zeros((w.shape[0], 3, 3))
    K[:, 0, 1], K[:, 0, 2], K[:, 1, 2] = -k[:, 2], k[:, 1], -k[:, 0]
    K = K - np.swapaxes(K, 1, 2)
    return np.eye(3) + np.sin(theta) * K + (1 - np.cos(theta)) * (K @ K)


def _head_motion(rng: np.random.Generator, n_frames: int, rate: float):
    t = np.arange(n_frames) / rate

    def smooth(amplitude: float) -> np.ndarray:  # (T, 3): two sinusoids per axis
        freq = rng.uniform(0.05, 0.35, (2, 3))
        phase = rng.uniform(0.0, 2 * np.pi, (2, 3))
        amp = amplitude * rng.uniform(0.4, 1.0, (2, 3)) / 2.0
        return np.sum(
            amp[None] * np.sin(2 * np.pi * freq[None] * t[:, None, None] + phase[None]), axis=1
        )

    rot = _rodrigues(smooth(np.deg2rad(5.0)))
    drift = smooth(8.0)
    pivot = np.array([0.0, -110.0, -60.0])  # the neck: the head turns about it
    trans = pivot[None] - rot @ pivot + drift
    return rot, trans


# -- public generator --------------------------------------------------------------------
class SyntheticFace(NamedTuple):
    """Result of `synthetic_face`.

    - ``sequence``: the markers as a `MarkerSequence` (mm), with head
      motion, noise and missing markers (NaN) applied.
    - ``mode``: ``(T,)`` int, index into ``mode_names`` of the active expression, −1 on
      neutral frames (``intensity == 0``).
    - ``intensity``: ``(T,)`` float in ``[0, 1]``.
    - ``mode_names``: the modes played, in index order.
    - ``neutral``: ``(M, 3)`` neutral face in the head frame.
    - ``local_positions``: ``(T, M, 3)`` noiseless expression in the head frame, so
      ``sequence.positions == local_positions @ head_rotation.T + head_translation
      + noise`` (NaN where missing).
    - ``head_rotation``: ``(T, 3, 3)`` rotations; ``head_translation``: ``(T, 3)``.
    """

    sequence: MarkerSequence
    mode: Int[np.ndarray, " frames"]
    intensity: Float[np.ndarray, " frames"]
    mode_names: tuple[str, ...]
    neutral: Float[np.ndarray, "markers 3"]
    local_positions: Float[np.ndarray, "frames markers 3"]
    head_rotation: Float[np.ndarray, "frames 3 3"]
    head_translation: Float[np.ndarray, "frames 3"]


def synthetic_face(
    n_markers: int = 60,
    n_frames: int = 600,
    modes: Sequence[str] = ("jaw_open", "smile", "brow_raise", "pucker", "frown"),
    seed: int = 0,
    noise_mm: float = 0.3,
    head_motion: bool = True,
    rate: float = 60.0,
    repetitions: int = 2,
    peak_range: tuple[float, float] = (0.5, 1.0),
    missing_fraction: float = 0.0,
) -> SyntheticFace:
    """A seeded synthetic facial performance with known expression labels.

    **Arguments:**

    - ``n_markers``: markers on the face, 12–200 (see `face_layout`).
    - ``n_frames``: frames; must leave at least 7 frames per played expression.
    - ``modes``: expression modes to play (from `EXPRESSION_MODES`), each
      ``repetitions`` times in a seeded random order, one at a time: neutral gap →
      smooth (raised-cosine) ramp up → hold at the peak → ramp down → neutral.
    - ``seed``: seed of every random choice (timeline, peaks, head motion, noise,
      missing markers; independent streams).
    - ``noise_mm``: standard deviation of the i.i.d. Gaussian measurement noise (mm).
    - ``head_motion``: smooth rigid head motion (±5° rotation about the neck, ±8 mm
      drift, 0.05–0.35 Hz); ``False`` gives identity rotations and zero translations.
    - ``rate``: frame rate (Hz).
    - ``peak_range``: the peak intensity of each repetition is uniform in this range
      (within ``[0, 1]``).
    - ``missing_fraction``: fraction of (frame, marker) entries set to NaN at random.

    **Returns:** a `SyntheticFace`.
    """
    names, neutral = face_layout(n_markers)
    seed = check_int(seed, "seed", low=0, high=2**63 - 1)
    if not isinstance(modes, str | list | tuple):
        raise FxspaceError(f"modes must be a sequence of mode names, got {modes!r}")
    modes = (modes,) if isinstance(modes, str) else tuple(modes)
    unknown = [m for m in modes if m not in _MODES]
    if not modes or unknown:
        raise FxspaceError(
            f"modes must be a non-empty sequence of {list(EXPRESSION_MODES)}; got {list(modes)}"
        )
    if len(set(modes)) != len(modes):
        raise FxspaceError(f"modes must not repeat a mode, got {list(modes)}")
    repetitions = check_int(repetitions, "repetitions", low=1)
    need = 7 * len(modes) * repetitions + 2
    n_frames = check_int(n_frames, "n_frames")
    if n_frames < need:
        raise FxspaceError(
            f"n_frames must be an integer >= {need} for {len(modes)} modes x {repetitions} "
            f"repetitions, got {n_frames!r}; raise n_frames or lower repetitions"
        )
    if not isinstance(peak_range, list | tuple) or len(peak_range) != 2:
        raise FxspaceError(f"peak_range must be a pair (low, high), got {peak_range!r}")
    lo = check_scalar(peak_range[0], "peak_range[0]", low=0.0, low_open=True, high=1.0)
    hi = check_scalar(peak_range[1], "peak_range[1]", low=lo, high=1.0)
    noise_mm = check_scalar(noise_mm, "noise_mm", low=0.0)
    missing_fraction = check_scalar(
        missing_fraction, "missing_fraction", low=0.0, high=1.0, high_open=True
    )
    rate = check_scalar(rate, "rate", low=0.0, low_open=True)
    if not isinstance(head_motion, bool | np.bool_):
        raise FxspaceError(f"head_motion must be True or False, got {head_motion!r}")

    streams = [np.random.default_rng(s) for s in np.random.SeedSequence(int(seed)).spawn(4)]
    mode, intensity = _timeline(streams[0], n_frames, len(modes), repetitions, (lo, hi))

    local = np.broadcast_to(neutral, (n_frames, *neutral.shape)).copy()
    for k, name in enumerate(modes):
        frames = np.flatnonzero(mode == k)
        if frames.size:
            local[frames] += _MODES[name](neutral, intensity[frames])

    if head_motion:
        rot, trans = _head_motion(streams[1], n_frames, float(rate))
    else:
        rot = np.broadcast_to(np.eye(3), (n_frames, 3, 3)).copy()
        trans = np.zeros((n_frames, 3))
    pos = np.einsum("tij,tmj->tmi", rot, local) + trans[:, None, :]
    pos += float(noise_mm) * streams[2].standard_normal(pos.shape)
    if missing_fraction > 0:
        pos[streams[3].random(pos.shape[:2]) < missing_fraction] = np.nan

    seq = MarkerSequence(pos, names, float(rate), "mm")
    return SyntheticFace(seq, mode, intensity, modes, neutral, local, rot, trans)
