"""Issue 44 item 4: `load_face` says every drop, resample, unit conversion and marker
intersection on the console as it happens (and keeps it for the metrics), and refuses
what the user must decide (takes at different rates)."""

from __future__ import annotations

import dataclasses
import logging

import numpy as np
import pytest

import fxspace as fx
from fxspace.config import ConfigError, config_from_dict, config_to_dict, dumps_toml
from fxspace.datasets import ANIMFACE_TAKES, FaceData, load_face
from fxspace.io import MarkerSequence


def _take(n_frames=200, n_markers=41, rate=60.0, seed=0, units="mm", scale=1.0):
    face = fx.synthetic.synthetic_face(n_markers=n_markers, n_frames=n_frames, seed=seed)
    s = face.sequence
    names = tuple(f"m{i:02d}" for i in range(n_markers))
    return MarkerSequence(np.asarray(s.positions) * scale, names, rate, units)


def _said(caplog):
    return [r.getMessage() for r in caplog.records if r.name == "fxspace"]


@pytest.fixture
def console(monkeypatch, caplog):
    monkeypatch.setenv("FXSPACE_QUIET", "0")  # the console lines as a user sees them
    caplog.set_level(logging.INFO, logger="fxspace")
    return caplog


def test_second_take_missing_and_renamed_markers_is_cut_and_said(tmp_path, console, capsys):
    """The issue's case: take 2 lacks 5 markers and renames 1 → the 35 shared, named."""
    a = _take()
    b = _take(seed=1)
    names = list(b.names)
    names[7] = "m07_renamed"
    keep = [i for i in range(41) if i not in (1, 2, 3, 4, 5)]
    b = MarkerSequence(b.positions[:, keep], tuple(names[i] for i in keep), 60.0)
    pa = fx.io.write_trc(tmp_path / "a.trc", a)
    pb = fx.io.write_trc(tmp_path / "b.trc", b)
    face = load_face(FaceData(source="files", paths=(str(pa), str(pb))))
    assert face.positions.shape[1] == 35
    said = _said(console)
    assert "b.trc: lacks 6 of a.trc's markers (m01, m02, m03, m04, m05, m07); 1 of its " \
           "markers are not in every take, dropped (m07_renamed)" in said  # fmt: skip
    assert "markers: using the 35 shared by every take" in said
    assert "[fxspace] markers: using the 35 shared by every take" in capsys.readouterr().err
    r = face.reading
    assert r["markers_dropped"] == {"a.trc": ["m01", "m02", "m03", "m04", "m05", "m07"],
                                    "b.trc": ["m07_renamed"]}  # fmt: skip
    assert r["markers_lacking"] == {"b.trc": ["m01", "m02", "m03", "m04", "m05", "m07"]}
    assert len(r["markers_used"]) == 35 and r["notes"][-1].startswith("markers: using")


def test_mixed_rates_refused_unless_resampling_is_asked(tmp_path, console):
    fast = fx.io.write_trc(tmp_path / "fast.trc", _take(n_frames=240, rate=120.0))
    slow = fx.io.write_trc(tmp_path / "slow.trc", _take(n_frames=120, seed=1))
    paths = (str(fast), str(slow))
    with pytest.raises(ConfigError, match=r"different frame rates \(fast\.trc 120 Hz, "
                                          r"slow\.trc 60 Hz\); set \[data\] resample_hz"):
        load_face(FaceData(source="files", paths=paths))
    face = load_face(FaceData(source="files", paths=paths, resample_hz=60.0))
    assert face.rate == 60.0 and (face.take == 0).sum() == 120
    assert ("fast.trc: resampled 120 → 60 Hz (240 → 120 frames, linear in time; "
            "[data] resample_hz)") in _said(console)  # fmt: skip
    assert face.reading["resampled"] == {"fast.trc": {
        "from_hz": 120.0, "to_hz": 60.0, "from_frames": 240, "to_frames": 120}}
    assert face.reading["rates_hz"] == {"fast.trc": 120.0, "slow.trc": 60.0}


def test_resampling_keeps_missing_as_nan():
    from fxspace.datasets import _resample_seq

    s = _take(n_frames=80, n_markers=12, rate=120.0).slice(0, 9)
    pos = np.array(s.positions)
    pos[4, 1] = np.nan
    r = _resample_seq(MarkerSequence(pos, s.names, 120.0), 60.0)
    assert r.n_frames == 5 and r.rate == 60.0
    assert np.isnan(r.positions[2, 1]).all() and not np.isnan(r.positions[2, 0]).any()
    np.testing.assert_array_equal(r.positions[1], pos[2])


def test_gap_fill_drops_are_said_per_take(tmp_path, console):
    """141 of 962 frames dropped by gap filling were reported only in metrics.json."""
    a = _take(n_frames=300)
    pos = np.array(a.positions)
    pos[50:80, 3] = np.nan  # 30 frames: longer than max_gap → dropped
    pos[100:104, 5] = np.nan  # 4 frames: filled
    p = fx.io.write_trc(tmp_path / "gappy.trc", MarkerSequence(pos, a.names, 60.0))
    face = load_face(FaceData(source="files", paths=(str(p),), max_gap=10))
    assert len(face.positions) == 270
    (msg,) = [m for m in _said(console) if m.startswith("gappy.trc: gaps")]
    assert msg == ("gappy.trc: gaps of at most max_gap = 10 frames filled in 4 frames; "
                   "30 of 300 frames dropped (gaps longer than max_gap = 10 frames or at a "
                   "take's end: m03 frames 50–79)")  # fmt: skip
    assert face.missing["dropped_frames_per_take"] == {"gappy.trc": 30}


def test_unit_conversion_and_thinning_are_said(tmp_path, console):
    m = _take(scale=0.001, units="m")
    p = fx.io.write_trc(tmp_path / "metres.trc", m)
    face = load_face(FaceData(source="files", paths=(str(p),), stride=2, max_frames=50))
    np.testing.assert_allclose(face.positions[0], m.positions[0] * 1000.0)
    said = _said(console)
    assert "metres.trc: converted from m to mm" in said
    assert "stride = 2: every 2th frame kept (200 → 100 frames)" in said
    assert "max_frames = 50: thinned evenly from 100 to 50 frames" in said
    assert face.reading["converted"] == {"metres.trc": "m -> mm"}


def test_units_key_fixes_a_wrong_label(tmp_path, console):
    """Issue 43 item 3: metre values labelled "mm" — warned, and [data] units = "m" fixes."""
    wrong = _take(scale=0.001, units="mm")
    p = fx.io.write_trc(tmp_path / "wrong.trc", wrong)
    load_face(FaceData(source="files", paths=(str(p),)))
    warned = [r.getMessage() for r in console.records if r.levelno == logging.WARNING]
    assert len(warned) == 1 and "units='m'" in warned[0] and "[data] units = 'm'" in warned[0]
    console.clear()
    face = load_face(FaceData(source="files", paths=(str(p),), units="m"))
    assert not [r for r in console.records if r.levelno == logging.WARNING]
    P = np.linalg.norm(face.positions[0] - face.positions[0, 0], axis=-1)
    assert 50.0 < P.max() < 400.0  # a face in millimetres again


def test_resolved_config_records_what_was_read(tmp_path):
    p = fx.io.write_trc(tmp_path / "a.trc", _take(n_frames=80))
    cfg = config_from_dict(FaceData, {"source": "files", "paths": [str(p)]})
    assert cfg.takes == ()  # not the AnimFace takes
    text = dumps_toml({"data": config_to_dict(cfg)})
    assert "takes = []" in text and str(p) in text
    assert FaceData().takes == ANIMFACE_TAKES
    with pytest.raises(ConfigError, match="data.takes names AnimFace files"):
        FaceData(source="files", paths=(str(p),), takes=("x.c3d",)).validate()
    with pytest.raises(ConfigError, match="data.paths is read only with source = 'files'"):
        FaceData(source="animface", paths=(str(p),)).validate()
    with pytest.raises(ConfigError, match="data.units must be one of"):
        dataclasses.replace(cfg, units="furlong").validate()
    with pytest.raises(ConfigError, match="data.resample_hz must be"):
        dataclasses.replace(cfg, resample_hz=-1.0).validate()


@pytest.mark.parametrize("n", [10, 4, 201])
def test_synthetic_markers_outside_the_layout_refused_by_the_config(n):
    """Issue 43.8: `synthetic_markers = 10` passed validation and failed mid-run."""
    with pytest.raises(ConfigError, match=r"data.synthetic_markers must lie in \[12, 200\]"):
        FaceData(source="synthetic", synthetic_markers=n).validate()


def test_a_synthetic_take_is_made_once_a_process_and_never_written(monkeypatch):
    """`fxspace studio` reads its synthetic take three times (stages, warm-up, app): the
    take is made once (a second reader waits for the first), and what `load_face` gives
    is each caller's own copy; a change of any key field makes a new take, and a take past
    `_SYNTHETIC_KEEP` positions is not kept."""
    import fxspace.datasets as D

    calls = []
    real = D.synthetic_face

    def counted(**kw):
        calls.append(kw)
        return real(**kw)

    monkeypatch.setattr(D, "synthetic_face", counted)
    monkeypatch.setattr(D, "_SYNTHETIC", {})
    cfg = FaceData(source="synthetic", synthetic_frames=300, synthetic_markers=20)
    a = load_face(cfg, 0)
    a.positions[:] = 0.0  # the caller's own copy
    b = load_face(cfg, 0)
    assert len(calls) == 1 and np.abs(b.positions).max() > 1.0
    np.testing.assert_array_equal(b.positions, load_face(cfg, 0).positions)
    load_face(cfg, 1)  # another seed: another take
    load_face(FaceData(source="synthetic", synthetic_frames=300, synthetic_markers=20,
                       synthetic_noise_mm=0.5), 0)  # fmt: skip
    assert len(calls) == 3
    monkeypatch.setattr(D, "_SYNTHETIC_KEEP", 100)  # too big to keep
    load_face(cfg, 0)
    load_face(cfg, 0)
    assert len(calls) == 5
