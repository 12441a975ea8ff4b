"""Marker tables (CSV/TSV) through ``fx.io.read_markers``, the unit checks every marker
reader shares, and BVH units (issue 44 items 1–2; issue 43 item 3)."""

from __future__ import annotations

import gzip
import logging

import numpy as np
import pytest

import fxspace as fx
from fxspace.errors import CorruptFileError, FxspaceError
from fxspace.io import MarkerSequence, read_markers, write_table

LOG = "fxspace"


def _face(rng, T=40, M=6, scale=1.0, units="mm"):
    """A face-sized marker set (about 200 mm across) moving a little."""
    base = rng.uniform(-90.0, 90.0, (M, 3))
    pos = base[None] + rng.normal(0.0, 2.0, (T, M, 3))
    return MarkerSequence(pos * scale, tuple(f"mk{i}" for i in range(M)), 60.0, units)


def _notes(caplog, level=logging.INFO):
    return [r.getMessage() for r in caplog.records if r.name == LOG and r.levelno == level]


def _semicolon_na_label_table(seq: MarkerSequence, tmp_path):
    """The reported layout: ';' separated, NA for missing, a trailing label column."""
    pos = np.array(seq.positions)
    pos[3, 1] = np.nan
    pos[10:14, 4] = np.nan
    cut = MarkerSequence(pos, seq.names, seq.rate, seq.units)
    labels = ["neutral"] * 20 + ["smile"] * (seq.n_frames - 20)
    path = write_table(tmp_path / "export.csv", cut, sep=";", missing="NA",
                       columns={"label": labels})  # fmt: skip
    return path, cut


def _check_semicolon_table(path, cut, caplog):
    text = path.read_text()
    head = text.splitlines()[0]
    assert head.startswith("Frame;Time;") and head.endswith(";label")
    assert ";NA;" in text
    with caplog.at_level(logging.INFO, logger=LOG):
        got = read_markers(path)
    assert got.names == cut.names and got.n_frames == cut.n_frames
    assert got.rate == 60.0 and got.units == "mm"
    np.testing.assert_array_equal(got.missing_mask(), cut.missing_mask())  # NA is NaN
    assert got.missing_mask()[3, 1] and got.missing_mask()[10:14, 4].all()
    np.testing.assert_allclose(got.positions, cut.positions, atol=1e-6, equal_nan=True)
    (msg,) = [m for m in _notes(caplog) if path.name in m]
    assert "separator ';'" in msg
    assert "1 non-marker column(s) ignored: 'label'" in msg
    assert "rate 60 Hz from the time column 'Time'" in msg
    assert "units inferred as 'mm'" in msg


def test_semicolon_na_label_synthetic(rng, tmp_path, caplog):
    path, cut = _semicolon_na_label_table(_face(rng), tmp_path)
    _check_semicolon_table(path, cut, caplog)


@pytest.mark.data
def test_semicolon_na_label_cut_from_shared_capture(data_dir, tmp_path, caplog):
    """The issue's case made from a shared capture: 8 markers × 60 frames of AnimFace."""
    seq = read_markers(data_dir / "face" / "animface_eyebrows.trc.gz")
    cut = seq.select(seq.names[:8]).slice(0, 60)
    path, cut = _semicolon_na_label_table(cut, tmp_path)
    _check_semicolon_table(path, cut, caplog)


@pytest.mark.parametrize(
    ("style", "sep", "suffix"),
    [
        ("{name}_{axis}", ",", ".csv"),
        ("{name}.{AXIS}", "\t", ".tsv"),
        ("{name}:{AXIS}", ";", ".txt"),
        ("{name} {AXIS}", ",", ".csv.gz"),
        ("{name}_{AXIS}", "\t", ".txt"),
    ],
)
def test_header_styles_and_separators(rng, tmp_path, style, sep, suffix):
    seq = _face(rng, T=12, M=4)
    p = write_table(tmp_path / f"t{suffix}", seq, sep=sep, style=style)
    got = read_markers(p, units="mm")
    assert got.names == seq.names
    np.testing.assert_allclose(got.positions, seq.positions, atol=1e-6)


def test_missing_tokens_are_nan_never_zero(tmp_path):
    rows = ["frame,time,a_x,a_y,a_z,b_x,b_y,b_z,c_x,c_y,c_z"]
    toks = ["", "NA", "nan", "-", "N/A", "null"]
    for t, tok in enumerate(toks):
        rows.append(f"{t + 1},{t / 100},{tok},1,2,100,0,0,0,150,{tok or 'NaN'}")
    p = tmp_path / "m.csv"
    p.write_text("\n".join(rows) + "\n")
    got = read_markers(p, units="mm")
    assert got.rate == 100.0
    assert got.missing_mask()[:, 0].all() and got.missing_mask()[:, 2].all()
    assert not got.missing_mask()[:, 1].any()
    assert not (got.positions == 0).all(axis=-1)[got.missing_mask()].any()


def test_decimal_commas_bracket_units_and_frame_gaps(tmp_path, caplog):
    p = tmp_path / "eu.csv"
    p.write_text(
        "Frame;a_x (m);a_y (m);a_z (m);b_x (m);b_y (m);b_z (m);Sub Frame\n"
        "1;0,01;0,02;0,03;0,2;0,1;0,05;0\n"
        "2;0,011;0,02;0,03;0,2;0,1;0,05;0\n"
        "4;0,012;0,02;0,03;0,2;0,1;0,05;0\n"
    )
    with caplog.at_level(logging.INFO, logger=LOG):
        got = read_markers(p, rate=120.0)
    assert got.units == "m" and got.rate == 120.0 and got.n_frames == 4
    assert got.missing_mask()[2].all() and not got.missing_mask()[[0, 1, 3]].any()
    np.testing.assert_allclose(got.positions[3, 0], [0.012, 0.02, 0.03])
    (msg,) = _notes(caplog)
    assert "decimal commas" in msg and "1 frame(s) absent" in msg
    assert "units 'm' from the header" in msg and "'Sub Frame'" in msg


def test_rate_needed_or_consistent(rng, tmp_path):
    p = tmp_path / "norate.csv"
    p.write_text("a_x,a_y,a_z,b_x,b_y,b_z\n0,0,0,100,0,0\n1,0,0,100,0,0\n")
    with pytest.raises(FxspaceError, match=r"no time column.*rate=.*\[data\] rate"):
        read_markers(p)
    assert read_markers(p, rate=50.0, units="mm").rate == 50.0
    q = write_table(tmp_path / "t.csv", _face(rng, T=5))
    with pytest.raises(FxspaceError, match=r"rate=120 Hz disagrees with the time column"):
        read_markers(q, rate=120.0)
    uneven = tmp_path / "uneven.csv"
    uneven.write_text("time,a_x,a_y,a_z\n0,1,2,3\n0.01,1,2,3\n0.02,1,2,3\n0.06,1,2,3\n")
    with pytest.raises(CorruptFileError, match=r"uneven\.csv, line 5: the time column is not"):
        read_markers(uneven, units="mm")


def test_malformed_tables_name_file_and_line(tmp_path):
    bad = tmp_path / "ragged.csv"
    bad.write_text("time,a_x,a_y,a_z\n0,1,2,3\n0.1,1,2\n")
    with pytest.raises(CorruptFileError, match=r"ragged\.csv, line 3: 3 cells, the header has 4"):
        read_markers(bad)
    word = tmp_path / "word.csv"
    word.write_text("time,a_x,a_y,a_z\n0,1,2,3\n0.1,1,two,3\n")
    with pytest.raises(CorruptFileError, match=r"word\.csv, line 3: column 'a_y'"):
        read_markers(word)
    none = tmp_path / "none.csv"
    none.write_text("time,left,right\n0,1,2\n")
    with pytest.raises(CorruptFileError, match=r"no marker columns"):
        read_markers(none)
    gz = tmp_path / "torn.csv.gz"
    gz.write_bytes(gzip.compress(b"time,a_x,a_y,a_z\n0,1,2,3\n")[:15])
    with pytest.raises(CorruptFileError, match=r"torn\.csv\.gz: not a readable gzip"):
        read_markers(gz)
    with pytest.raises(FxspaceError, match="units must be one of"):
        read_markers(word, units="furlongs")


# -- units inferred and judged -----------------------------------------------------------------
def test_units_inferred_from_extent_and_said(rng, tmp_path, caplog):
    metres = _face(rng, scale=0.001, units="m")
    p = write_table(tmp_path / "metres.csv", metres, decimals=9)
    with caplog.at_level(logging.INFO, logger=LOG):
        got = read_markers(p)
    assert got.units == "m"
    np.testing.assert_allclose(got.to_units("mm").positions, metres.to_units("mm").positions,
                               atol=1e-5)  # fmt: skip
    assert any("units inferred as 'm'" in m for m in _notes(caplog))


def test_metre_values_labelled_mm_warn_with_the_fix(rng, tmp_path, caplog, capsys):
    """Issue 43 item 3: metre values labelled "mm" gave ε = 0.0059 "mm" without a word."""
    wrong = _face(rng, scale=0.001, units="mm")  # a face 0.2 across, labelled mm
    p = fx.io.write_trc(tmp_path / "wrong.trc", wrong)
    with caplog.at_level(logging.INFO, logger=LOG):
        got = read_markers(p)
    assert got.units == "mm"  # read as labelled, but said
    (w,) = _notes(caplog, logging.WARNING)
    assert "wrong.trc" in w and "implausible" in w and "look like m " in w
    assert "units='m'" in w and "[data] units = 'm'" in w
    assert "warning: wrong.trc" in capsys.readouterr().err  # on the console even when quiet
    caplog.clear()
    with caplog.at_level(logging.INFO, logger=LOG):
        fixed = read_markers(p, units="m")  # the fix the warning names
    assert fixed.units == "m" and not _notes(caplog, logging.WARNING)
    assert any("read as 'm' as asked (the file says 'mm')" in m for m in _notes(caplog))


def test_plausible_units_say_nothing(rng, tmp_path, caplog):
    p = fx.io.write_trc(tmp_path / "ok.trc", _face(rng))
    with caplog.at_level(logging.INFO, logger=LOG):
        read_markers(p)
    assert not _notes(caplog, logging.WARNING)


def test_inch_file_conversion_is_said(rng, tmp_path, caplog):
    inches = _face(rng, scale=1 / 25.4, units="in")
    p = fx.io.write_trc(tmp_path / "inch.trc", inches)
    with caplog.at_level(logging.INFO, logger=LOG):
        got = read_markers(p)
    assert got.units == "mm" and got.file_units == "in"
    assert any("converted from 'in' to 'mm'" in m for m in _notes(caplog))


# -- BVH: units and frame time -----------------------------------------------------------------
_BVH = """HIERARCHY
ROOT Hips
{{
  OFFSET 0 0 0
  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation
  JOINT Head
  {{
    OFFSET 0 {h} 0
    CHANNELS 3 Zrotation Xrotation Yrotation
    End Site
    {{
      OFFSET 0 {e} 0
    }}
  }}
  JOINT LeftUpLeg
  {{
    OFFSET {w} 0 0
    CHANNELS 3 Zrotation Xrotation Yrotation
    End Site
    {{
      OFFSET 0 -{h} 0
    }}
  }}
}}
MOTION
Frames: 2
Frame Time: {dt}
0 {h} 0 0 0 0 0 0 0 0 0 0
0 {h} 0 0 0 10 0 0 0 0 0 0
"""


def _bvh(tmp_path, cm=True, dt="0.0083333"):
    h, e, w = (80.0, 20.0, 15.0) if cm else (0.8, 0.2, 0.15)
    p = tmp_path / ("cm.bvh" if cm else "m.bvh")
    p.write_text(_BVH.format(h=h, e=e, w=w, dt=dt))
    return p


def test_bvh_frame_time_nan_refused(tmp_path):
    for dt in ("nan", "inf", "-0.01"):
        with pytest.raises(CorruptFileError, match=r"line 27: the frame time must be a finite"):
            fx.io.read_bvh(_bvh(tmp_path, dt=dt))


def test_bvh_units_declared_inferred_or_warned(tmp_path, caplog):
    cm = _bvh(tmp_path)
    with caplog.at_level(logging.INFO, logger=LOG):
        plain = fx.io.read_bvh(cm)  # metres assumed: a 1.8 m figure read as 180 m
    (w,) = _notes(caplog, logging.WARNING)
    assert "implausible for a body" in w and "units='cm'" in w
    caplog.clear()
    with caplog.at_level(logging.INFO, logger=LOG):
        declared = fx.io.read_bvh(cm, units="cm")
        auto = fx.io.read_bvh(cm, units="auto")
    notes = _notes(caplog)
    assert any("lengths in cm (declared)" in m for m in notes)
    assert any("lengths inferred to be cm" in m for m in notes)
    assert not _notes(caplog, logging.WARNING)
    np.testing.assert_allclose(np.asarray(declared.offsets), np.asarray(plain.offsets) / 100)
    np.testing.assert_allclose(np.asarray(auto.offsets), np.asarray(declared.offsets))
    np.testing.assert_allclose(np.asarray(fx.io.read_bvh(cm, scale=0.01).offsets),
                               np.asarray(declared.offsets))  # fmt: skip
    caplog.clear()
    with caplog.at_level(logging.INFO, logger=LOG):
        m = fx.io.read_bvh(_bvh(tmp_path, cm=False))  # metres: nothing to say
    assert not _notes(caplog, logging.WARNING)
    np.testing.assert_allclose(np.asarray(m.offsets), np.asarray(declared.offsets))
    with pytest.raises(FxspaceError, match="not both"):
        fx.io.read_bvh(cm, scale=0.01, units="cm")
    with pytest.raises(FxspaceError, match="units must be one of"):
        fx.io.read_bvh(cm, units="cubits")


@pytest.mark.data
def test_bandai_bvh_is_in_cm(data_dir, caplog):
    p = data_dir / "body" / "bandai" / "dataset-1_walk_normal_001.bvh.gz"
    with caplog.at_level(logging.INFO, logger=LOG):
        m = fx.io.read_bvh(p, units="auto")
    assert any("lengths inferred to be cm" in n for n in _notes(caplog))
    ref = fx.io.read_bvh(p, scale=0.01)
    np.testing.assert_allclose(np.asarray(m.offsets), np.asarray(ref.offsets))


def test_two_row_header_vicon_trajectories_export(tmp_path, caplog):
    """A Vicon Nexus "Trajectories" CSV: preamble with the rate, names over X/Y/Z."""
    p = tmp_path / "nexus.csv"
    p.write_text(
        "Trajectories\n"
        "100\n"
        ",,Anna:LFHD,,,Anna:RFHD,,,Anna:CHIN,,\n"
        "Frame,Sub Frame,X,Y,Z,X,Y,Z,X,Y,Z\n"
        ",,mm,mm,mm,mm,mm,mm,mm,mm,mm\n"
        "1,0,-70.1,80.2,1500.3,70.4,80.5,1500.6,0.0,-90.0,1420.0\n"
        "2,0,-70.2,80.2,1500.3,,,,0.1,-90.1,1420.1\n"
    )
    with caplog.at_level(logging.INFO, logger=LOG):
        got = read_markers(p)
    assert got.names == ("LFHD", "RFHD", "CHIN") and got.rate == 100.0 and got.units == "mm"
    assert got.missing_mask().tolist() == [[False, False, False], [False, True, False]]
    np.testing.assert_allclose(got.positions[1, 2], [0.1, -90.1, 1420.1])
    (msg,) = _notes(caplog)
    assert "two-row header" in msg and "rate 100 Hz from the preamble" in msg
    assert "units 'mm' from the header" in msg and "'Sub Frame'" in msg
