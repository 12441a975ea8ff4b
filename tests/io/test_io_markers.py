"""Marker I/O: MarkerSequence, read_markers (C3D, TRC, TRC.gz, NPZ), writers, corrupt files."""

from __future__ import annotations

import gzip
import io
import warnings

import c3d
import jax
import numpy as np
import pytest

import fxspace as fx
from fxspace.errors import CorruptFileError, FxspaceError
from fxspace.io import (
    MarkerSequence,
    read_markers,
    write_c3d,
    write_npz,
    write_trc,
)

FACE_TAKES = {
    "animface_cheeks.c3d": 1499,
    "animface_jaw.c3d": 1590,
    "animface_eyebrows.trc.gz": 902,
}


def _seq(rng, T=7, M=4, dtype=np.float64, missing=((1, 2), (3, 0), (6, 3))):
    pos = (rng.standard_normal((T, M, 3)) * 100.0 + 500.0).astype(dtype)
    for t, m in missing:
        if t < T and m < M:
            pos[t, m] = np.nan
    return MarkerSequence(pos, tuple(f"mk{i}" for i in range(M)), 60.0, "mm")


def _same(a: MarkerSequence, b: MarkerSequence, rtol=0.0, atol=0.0):
    assert a.names == b.names
    assert a.rate == b.rate
    assert a.units == b.units
    np.testing.assert_array_equal(a.missing_mask(), b.missing_mask())
    np.testing.assert_allclose(a.positions, b.positions, rtol=rtol, atol=atol)


# -- MarkerSequence ------------------------------------------------------------------------
def test_sequence_basics(rng):
    s = _seq(rng)
    assert (s.n_frames, s.n_markers) == (7, 4)
    assert s.positions.dtype == np.float64 and not s.positions.flags.writeable
    mask = s.missing_mask()
    assert mask.shape == (7, 4) and mask.sum() == 3 and mask[1, 2] and mask[3, 0]
    np.testing.assert_allclose(s.times, np.arange(7) / 60.0)
    assert "n_frames=7" in repr(s)


def test_sequence_copies_input_and_completes_partial_nan(rng):
    pos = rng.standard_normal((3, 2, 3))
    pos[0, 1, 2] = np.nan
    s = MarkerSequence(pos, ("a", "b"), 30.0)
    pos[1, 1, 1] = 1e9  # the sequence holds its own copy
    assert s.positions[1, 1, 1] != 1e9
    assert np.isnan(s.positions[0, 1]).all()
    assert s.missing_mask().tolist() == [[False, True], [False, False], [False, False]]
    assert MarkerSequence(np.ones((2, 1, 3), dtype=np.int32), ("a",), 1.0).positions.dtype == (
        np.float64
    )
    assert MarkerSequence(np.ones((2, 1, 3), np.float32), ("a",), 1.0).positions.dtype == (
        np.float32
    )


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"positions": np.zeros((2, 3))}, "positions must have shape"),
        ({"positions": np.zeros((2, 2, 2))}, "positions must have shape"),
        ({"positions": np.zeros((2, 2, 3), dtype=complex)}, "float32 or float64"),
        ({"positions": np.full((2, 2, 3), np.inf)}, "inf"),
        ({"names": ("a",)}, "names has 1 entries but positions has 2 markers"),
        ({"names": ("a", "a")}, "unique; duplicated: \\['a'\\]"),
        ({"names": ("a", "")}, "non-empty"),
        ({"names": "ab"}, "not one string"),
        ({"rate": 0.0}, "rate must be > 0"),
        ({"rate": float("nan")}, "rate must be a finite number"),
        ({"rate": "fast"}, "rate must be a real number"),
        ({"units": ""}, "units must be a non-empty string"),
    ],
)
def test_sequence_validation(kwargs, match):
    args = {"positions": np.zeros((2, 2, 3)), "names": ("a", "b"), "rate": 60.0, "units": "mm"}
    args.update(kwargs)
    with pytest.raises(FxspaceError, match=match):
        MarkerSequence(**args)


def test_select_slice_units_drop(rng):
    s = _seq(rng)
    sel = s.select(["mk3", "mk1"])
    assert sel.names == ("mk3", "mk1")
    np.testing.assert_array_equal(sel.positions, s.positions[:, [3, 1]])
    with pytest.raises(FxspaceError, match=r"\['nope'\] are not markers"):
        s.select(["mk0", "nope"])

    sl = s.slice(1, 6, 2)
    assert sl.n_frames == 3 and sl.rate == 30.0
    np.testing.assert_array_equal(sl.positions, s.positions[1:6:2])
    with pytest.raises(FxspaceError, match="step must be a positive"):
        s.slice(step=0)

    m = s.to_units("m")
    assert m.units == "m"
    np.testing.assert_allclose(m.positions, s.positions / 1000.0)
    _same(m.to_units("cm").to_units("mm"), s, rtol=1e-12)
    assert s.to_units("mm") is s
    with pytest.raises(FxspaceError, match="units must be one of"):
        s.to_units("furlong")
    inch = s.to_units("inches")  # a spelling of a known unit
    assert inch.units == "in"
    np.testing.assert_allclose(inch.positions * 25.4, s.positions, rtol=1e-12)
    with pytest.raises(FxspaceError, match="unknown units"):
        MarkerSequence(s.positions, s.names, 60.0, "furlong").to_units("mm")

    kept_seq, kept = s.drop_missing_frames()
    assert kept.tolist() == [0, 2, 4, 5]
    assert not kept_seq.missing_mask().any()
    np.testing.assert_array_equal(kept_seq.positions, s.positions[kept])


# -- round trips ---------------------------------------------------------------------------
@pytest.mark.parametrize("name", ["take.trc", "take.trc.gz", "TAKE.TRC"])
@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_trc_round_trip_exact(tmp_path, rng, name, dtype):
    s = _seq(rng, dtype=dtype)
    path = write_trc(tmp_path / name, s)
    back = read_markers(path)
    assert back.positions.dtype == np.float64
    _same(back, s)  # exact: shortest repr round-trips float64 (and float32 values)
    assert not list(tmp_path.glob(".*.tmp"))  # atomic write left no temp file


def test_trc_text_layout_and_empty_cells(tmp_path, rng):
    s = _seq(rng, T=3, M=2, missing=((1, 1),))
    text = write_trc(tmp_path / "x.trc", s, precision=3).read_text()
    lines = text.splitlines()
    assert lines[0] == "PathFileType\t4\t(X/Y/Z)\tx.trc"
    assert lines[2].split("\t")[2:5] == ["3", "2", "mm"]
    assert lines[3] == "Frame#\tTime\tmk0\t\t\tmk1\t\t"
    assert lines[4] == "\t\tX1\tY1\tZ1\tX2\tY2\tZ2"
    row = lines[7].split("\t")  # frame 2: marker mk1 missing
    assert row[:2] == ["2", "0.01667"] and row[5:] == ["", "", ""]
    # an independent parser agrees (numpy.genfromtxt; empty cells -> nan)
    ref = np.genfromtxt(io.StringIO(text), delimiter="\t", skip_header=6)
    back = read_markers(tmp_path / "x.trc")
    np.testing.assert_array_equal(ref[:, 2:].reshape(3, 2, 3), back.positions)
    np.testing.assert_allclose(back.positions, s.positions, atol=5e-4)


def test_trc_gz_is_gzip_and_deterministic(tmp_path, rng):
    s = _seq(rng)
    a = write_trc(tmp_path / "a.trc.gz", s).read_bytes()
    b = write_trc(tmp_path / "b.trc.gz", s).read_bytes()
    assert a[:2] == b"\x1f\x8b"
    assert gzip.decompress(a).replace(b"b.trc", b"a.trc") == gzip.decompress(b).replace(
        b"b.trc", b"a.trc"
    )


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_npz_round_trip_exact(tmp_path, rng, dtype):
    s = _seq(rng, dtype=dtype)
    back = read_markers(write_npz(tmp_path / "s.npz", s))
    assert back.positions.dtype == dtype
    _same(back, s)


def test_c3d_round_trip(tmp_path, rng):
    s = _seq(rng, T=9, M=5, missing=((0, 0), (4, 2), (8, 4)))
    back = read_markers(write_c3d(tmp_path / "s.c3d", s))
    _same(back, s, rtol=1e-7)  # float32 storage
    np.testing.assert_array_equal(back.positions, s.positions.astype(np.float32))


def test_writers_reject_bad_arguments(tmp_path, rng):
    s = _seq(rng)
    with pytest.raises(FxspaceError, match="must be a MarkerSequence"):
        write_trc(tmp_path / "a.trc", s.positions)
    with pytest.raises(FxspaceError, match=r"\.trc or \.trc\.gz"):
        write_trc(tmp_path / "a.txt", s)
    with pytest.raises(FxspaceError, match=r"\.npz"):
        write_npz(tmp_path / "a.trc", s)
    with pytest.raises(FxspaceError, match=r"\.c3d"):
        write_c3d(tmp_path / "a.trc", s)
    with pytest.raises(FxspaceError, match="precision"):
        write_trc(tmp_path / "a.trc", s, precision=-1)
    tabbed = MarkerSequence(s.positions, ("a\tb", "b", "c", "d"), 60.0)
    with pytest.raises(FxspaceError, match="tabs or line breaks"):
        write_trc(tmp_path / "a.trc", tabbed)


# -- C3D specifics -------------------------------------------------------------------------
def _c3d_bytes(points, labels, rate=60.0, units="mm"):
    w = c3d.Writer(point_rate=rate, point_units=units)
    w.set_point_labels(labels)
    w.add_frames([(p, np.zeros((0, 0), np.float32)) for p in points])
    buf = io.BytesIO()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        w.write(buf)
    return buf.getvalue()


def test_c3d_negative_residual_is_nan_not_zero(tmp_path, rng):
    T, M = 5, 3
    points = np.zeros((T, M, 5), np.float32)
    points[..., :3] = rng.uniform(100, 900, (T, M, 3))
    points[2, 1, 3] = -1.0  # invalid point
    points[..., 4] = 3.0  # camera mask
    path = tmp_path / "neg.c3d"
    path.write_bytes(_c3d_bytes(points, ["a ", "b", "ccc"], rate=100.0, units="cm"))
    s = read_markers(path)
    assert s.names == ("a", "b", "ccc") and s.rate == 100.0 and s.units == "cm"
    expected = points[..., :3].astype(np.float64)
    expected[2, 1] = np.nan
    np.testing.assert_array_equal(s.positions, expected)
    assert s.missing_mask().sum() == 1


def test_c3d_truncated_random_and_bad_magic(tmp_path, rng):
    points = np.zeros((40, 3, 5), np.float32)
    points[..., :3] = rng.uniform(100, 900, (40, 3, 3))
    good = _c3d_bytes(points, ["a", "b", "c"])
    cut = tmp_path / "cut.c3d"
    cut.write_bytes(good[: len(good) - 1000])
    with pytest.raises(CorruptFileError, match=r"cut\.c3d: truncated C3D data.*declares 40"):
        read_markers(cut)
    noise = tmp_path / "noise.c3d"
    noise.write_bytes(good[:2] + rng.bytes(3000))
    with pytest.raises(CorruptFileError, match=r"noise\.c3d"):
        read_markers(noise)
    magic = tmp_path / "magic.c3d"
    magic.write_bytes(b"\x02\x13" + rng.bytes(3000))
    with pytest.raises(CorruptFileError, match=r"magic\.c3d: not a C3D file"):
        read_markers(magic)
    tiny = tmp_path / "tiny.c3d"
    tiny.write_bytes(b"\x02\x50abc")
    with pytest.raises(CorruptFileError, match=r"tiny\.c3d: 5 bytes"):
        read_markers(tiny)


def test_c3d_random_bytes_never_escape_as_other_errors(tmp_path):
    r = np.random.default_rng(1)
    for k in range(20):
        p = tmp_path / f"r{k}.c3d"
        head = bytes([r.integers(1, 20), 0x50])
        p.write_bytes(head + r.bytes(int(r.integers(600, 5000))))
        with pytest.raises(CorruptFileError, match=rf"r{k}\.c3d"):
            read_markers(p)


# -- corrupt TRC / NPZ ---------------------------------------------------------------------
def _trc_lines(tmp_path, rng):
    path = write_trc(tmp_path / "ok.trc", _seq(rng, T=6, M=3, missing=((1, 2),)))
    return path.read_text().splitlines()


def _write(tmp_path, name, lines):
    p = tmp_path / name
    p.write_text("\n".join(lines) + "\n")
    return p


def test_trc_corrupt_cases(tmp_path, rng):
    lines = _trc_lines(tmp_path, rng)  # 6 header lines + 6 data rows (lines 7..12)

    cases = {
        "truncated_rows.trc": (
            lines[:-2],
            r"NumFrames declares 6 frames but the file has 4 data "
            r"rows \(truncated\?\)",
        ),
        "extra_rows.trc": (lines + [lines[-1]], "declares 6 frames but the file has 7"),
        "cut_mid_row.trc": (
            lines[:-1] + [lines[-1][: len(lines[-1]) // 2]],
            r"line 12: data row "
            r"has \d+ columns, "
            r"expected 11",
        ),
        "dropped_column.trc": (
            lines[:8] + ["\t".join(lines[8].split("\t")[:-1])] + lines[9:],
            "line 9: data row has 10 columns, expected 11",
        ),
        "garbled.trc": (
            lines[:9] + [lines[9].replace(".", "x", 2)] + lines[10:],
            r"line 10: non-numeric cell \(mk0 X\)",  # never the cell's text (issue 43.7)
        ),
        "no_magic.trc": (["Hello"] + lines[1:], "line 1: not a TRC file"),
        "bad_count.trc": (
            lines[:2] + [lines[2].replace("\t6\t", "\tsix\t", 1)] + lines[3:],
            "line 3: non-numeric DataRate/NumFrames/NumMarkers",
        ),
        "no_units.trc": (
            lines[:1] + [lines[1].replace("Units", "Unitz")] + lines[2:],
            r"line 3: TRC header lacks value\(s\) for \['Units'\]",
        ),
        "names.trc": (
            lines[:3] + ["\t".join(lines[3].split("\t")[:-3])] + lines[4:],
            "line 4: NumMarkers declares 3 markers but the name row has 2",
        ),
        "axes.trc": (
            lines[:4] + ["\t".join(lines[4].split("\t")[:-1])] + lines[5:],
            "line 5: the X1/Y1/Z1 row has 8 labels, expected 9",
        ),
        "header_only.trc": (lines[:3], "TRC header needs 5 lines"),
        "inf.trc": (
            lines[:7] + [lines[7].replace(lines[7].split("\t")[3], "inf", 1)] + lines[8:],
            "line 8: infinite coordinate",
        ),
    }
    for name, (content, match) in cases.items():
        p = _write(tmp_path, name, content)
        with pytest.raises(CorruptFileError, match=match) as exc:
            read_markers(p)
        assert name in str(exc.value), name


def test_trc_tolerates_crlf_and_trailing_empty_column(tmp_path, rng):
    s = _seq(rng, T=4, M=2)
    lines = write_trc(tmp_path / "a.trc", s).read_text().splitlines()
    lines = lines[:6] + [ln + "\t" for ln in lines[6:]]
    p = tmp_path / "crlf.trc"
    p.write_bytes(("\r\n".join(lines) + "\r\n").encode())
    _same(read_markers(p), s)


def test_trc_gz_truncated(tmp_path, rng):
    data = write_trc(tmp_path / "a.trc.gz", _seq(rng)).read_bytes()
    p = tmp_path / "cut.trc.gz"
    p.write_bytes(data[: len(data) // 2])
    with pytest.raises(CorruptFileError, match=r"cut\.trc\.gz: not a readable gzip file"):
        read_markers(p)


def test_npz_corrupt_and_missing_keys(tmp_path, rng):
    p = tmp_path / "bad.npz"
    p.write_bytes(rng.bytes(500))
    with pytest.raises(CorruptFileError, match=r"bad\.npz: not a readable NPZ"):
        read_markers(p)
    q = tmp_path / "keys.npz"
    np.savez(q, positions=np.zeros((2, 1, 3)), names=np.array(["a"]))
    with pytest.raises(
        CorruptFileError, match=r"keys\.npz: NPZ marker file lacks .*'rate', 'units'"
    ):
        read_markers(q)
    r = tmp_path / "shape.npz"
    np.savez(r, positions=np.zeros((2, 2, 3)), names=np.array(["a"]), rate=60.0, units="mm")
    with pytest.raises(CorruptFileError, match=r"shape\.npz: invalid marker data"):
        read_markers(r)
    data = write_npz(tmp_path / "ok.npz", _seq(rng)).read_bytes()
    c = tmp_path / "cut.npz"
    c.write_bytes(data[: len(data) // 2])
    with pytest.raises(CorruptFileError, match=r"cut\.npz"):
        read_markers(c)


def test_unknown_extension_and_missing_file(tmp_path):
    with pytest.raises(ValueError, match=r"unknown marker file extension; supported: \.c3d, \.trc"):
        read_markers(tmp_path / "take.xlsx")
    missing = tmp_path / "absent.trc"
    with pytest.raises(FileNotFoundError, match="absent.trc"):
        read_markers(missing)


def test_public_names():
    assert fx.io.read_markers is read_markers
    assert fx.io.MarkerSequence is MarkerSequence
    assert fx.io.SUPPORTED_EXTENSIONS[:4] == (".c3d", ".trc", ".trc.gz", ".npz")
    assert {".csv", ".tsv", ".txt", ".csv.gz"} <= set(fx.io.SUPPORTED_EXTENSIONS)


# -- real data -----------------------------------------------------------------------------
@pytest.mark.data
def test_real_face_takes(data_dir):
    seqs = {}
    for name, n_frames in FACE_TAKES.items():
        s = read_markers(data_dir / "face" / name)
        assert (s.n_frames, s.n_markers, s.rate, s.units) == (n_frames, 41, 60.0, "mm"), name
        assert not s.missing_mask().any(), name  # README: no frames are missing
        assert np.isfinite(s.positions).all()
        seqs[name] = s
    names = {s.names for s in seqs.values()}
    assert len(names) == 1  # the same markers in the same order in every take
    first = next(iter(names))
    assert first[:3] == ("ForeHead_M", "ForeHead_L", "ForeHead_R") and "Chin" in first
    # a face: every marker within ~0.3 m of the face's centroid, in millimetres
    for s in seqs.values():
        centred = s.positions - s.positions.mean(axis=1, keepdims=True)
        assert 20.0 < np.abs(centred).max() < 300.0


@pytest.mark.data
def test_real_trc_matches_independent_parser_and_round_trips(data_dir, tmp_path):
    path = data_dir / "face" / "animface_eyebrows.trc.gz"
    with gzip.open(path, "rt") as f:
        ref = np.genfromtxt(f, delimiter="\t", skip_header=6)
    s = read_markers(path)
    np.testing.assert_array_equal(ref[:, 2:].reshape(902, 41, 3), s.positions)
    part = s.slice(0, 60)
    _same(read_markers(write_trc(tmp_path / "p.trc.gz", part)), part)
    c = read_markers(write_c3d(tmp_path / "p.c3d", part))
    _same(c, part, rtol=1e-6)


# -- units: a file in inches is converted to millimetres (issue 19) -------------------------
def test_units_spellings_and_pytree(rng):
    from fxspace.io._types import canonical_units

    assert [canonical_units(u) for u in ("MM", " Inches ", "inch", "metres", "px")] == [
        "mm",
        "in",
        "in",
        "m",
        "px",
    ]
    s = _seq(rng)
    leaves, tree = jax.tree_util.tree_flatten(s)
    assert len(leaves) == 1 and leaves[0] is s.positions
    back = tree.unflatten(leaves)
    assert isinstance(back, MarkerSequence) and back.names == s.names and back.units == "mm"
    doubled = jax.tree_util.tree_map(lambda x: x * 2, s)
    np.testing.assert_array_equal(np.asarray(doubled.positions), s.positions * 2)


@pytest.mark.parametrize("ext", [".trc", ".trc.gz", ".c3d", ".npz"])
def test_inch_files_are_converted_to_mm(rng, tmp_path, ext):
    s = _seq(rng)
    inch = MarkerSequence(s.positions / 25.4, s.names, s.rate, "in")
    writer = {".trc": write_trc, ".trc.gz": write_trc, ".c3d": write_c3d, ".npz": write_npz}[ext]
    r = read_markers(writer(tmp_path / f"t{ext}", inch))
    assert r.units == "mm" and r.file_units == "in"
    rtol = 1e-6 if ext == ".c3d" else 1e-12
    np.testing.assert_allclose(r.positions, s.positions, rtol=rtol)
    assert np.array_equal(r.missing_mask(), s.missing_mask())
    m = read_markers(write_trc(tmp_path / "m.trc", s.to_units("m")))
    assert m.units == "m" and m.file_units is None  # metric files keep their unit


@pytest.mark.data
def test_real_trc_header_rewritten_to_inches(data_dir, tmp_path):
    """Cut the shared TRC to 40 frames and declare its unit as inches (temp file)."""
    src = data_dir / "face" / "animface_eyebrows.trc.gz"
    with gzip.open(src, "rt") as f:
        lines = f.read().splitlines()
    keys, vals = lines[1].split("\t"), lines[2].split("\t")
    vals[keys.index("Units")] = "in"
    vals[keys.index("NumFrames")] = "40"
    lines[2] = "\t".join(vals)
    p = tmp_path / "inch.trc"
    p.write_text("\n".join(lines[:6] + lines[6:46]) + "\n")
    ref = read_markers(src).slice(0, 40)
    r = read_markers(p)
    assert r.units == "mm" and r.file_units == "in" and ref.units == "mm"
    np.testing.assert_allclose(r.positions, ref.positions * 25.4, rtol=1e-12)


@pytest.mark.data
def test_real_c3d_point_units_rewritten_to_inches(data_dir, tmp_path):
    """Rewrite POINT:UNITS of the shared C3D ('mm  ' → 'in  ') in a temp copy."""
    raw = (data_dir / "face" / "animface_jaw.c3d").read_bytes()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        reader = c3d.Reader(io.BytesIO(raw))
        assert reader.get("POINT:UNITS").string_value.strip() == "mm"
        data_start = 512 * (reader.header.data_block - 1)
    at = raw.find(b"mm  ", 512, data_start)
    assert at > 0
    p = tmp_path / "inch.c3d"
    p.write_bytes(raw[:at] + b"in  " + raw[at + 4 :])
    ref = read_markers(data_dir / "face" / "animface_jaw.c3d")
    r = read_markers(p)
    assert r.units == "mm" and r.file_units == "in"
    np.testing.assert_allclose(r.positions, ref.positions * 25.4, rtol=1e-12)
