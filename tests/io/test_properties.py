"""Property-based tests of the readers (issue 10): write → read round trips (TRC, BVH) and
a fuzz test — random or truncated bytes into every reader give a clear CorruptFileError,
never another exception."""

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

import fxspace as fx
from fxspace.errors import CorruptFileError

SETTINGS = settings(
    max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)

BVH = """HIERARCHY
ROOT Hips
{
\tOFFSET 0.0 0.0 0.0
\tCHANNELS 6 Xposition Yposition Zposition Zrotation Yrotation Xrotation
\tJOINT Spine
\t{
\t\tOFFSET 0.0 1.0 0.0
\t\tCHANNELS 3 Zrotation Xrotation Yrotation
\t\tEnd Site
\t\t{
\t\t\tOFFSET 0.0 0.2 0.0
\t\t}
\t}
}
MOTION
Frames: 2
Frame Time: 0.04
1.0 2.0 3.0 10.0 20.0 30.0 5.0 -15.0 25.0
1.5 2.0 3.5 -10.0 45.0 170.0 0.0 0.0 0.0
"""

coord = st.floats(-1e4, 1e4, allow_nan=False, allow_infinity=False, width=64)


@st.composite
def marker_sequences(draw):
    T = draw(st.integers(1, 6))
    M = draw(st.integers(1, 4))
    pos = np.asarray(draw(st.lists(coord, min_size=T * M * 3, max_size=T * M * 3)), float)
    pos = pos.reshape(T, M, 3)
    missing = np.asarray(draw(st.lists(st.booleans(), min_size=T * M, max_size=T * M)))
    pos[missing.reshape(T, M)] = np.nan
    names = tuple(f"m{i}_" + draw(st.sampled_from(["a", "Lip", "brow.L", "x-1"])) for i in range(M))
    rate = draw(st.floats(1.0, 1000.0, allow_nan=False))
    units = draw(st.sampled_from(["mm", "cm", "m"]))
    return fx.io.MarkerSequence(pos, names, rate, units)


@SETTINGS
@given(seq=marker_sequences(), gz=st.booleans())
def test_trc_write_read_round_trip(tmp_path, seq, gz):
    p = tmp_path / ("t.trc.gz" if gz else "t.trc")
    fx.io.write_trc(p, seq)
    back = fx.io.read_markers(p)
    np.testing.assert_array_equal(np.isnan(back.positions), np.isnan(seq.positions))
    np.testing.assert_array_equal(
        np.nan_to_num(back.positions, nan=0.0), np.nan_to_num(seq.positions, nan=0.0)
    )
    assert back.names == seq.names and back.units == seq.units
    assert back.rate == pytest.approx(seq.rate, rel=1e-9)


angle = st.floats(-179.0, 179.0, allow_nan=False)
pitch = st.floats(-85.0, 85.0, allow_nan=False)


@SETTINGS
@given(
    data=st.lists(
        st.tuples(coord, coord, coord, angle, pitch, angle, angle, pitch, angle),
        min_size=1,
        max_size=5,
    )
)
def test_bvh_write_read_round_trip(tmp_path, data):
    src = tmp_path / "src.bvh"
    rows = "\n".join(" ".join(repr(v) for v in r) for r in data)
    head = BVH.split("MOTION")[0]
    src.write_text(f"{head}MOTION\nFrames: {len(data)}\nFrame Time: 0.04\n{rows}\n")
    m = fx.io.read_bvh(src)
    out = tmp_path / "out.bvh"
    fx.io.write_bvh(out, m)
    m2 = fx.io.read_bvh(out)
    assert m2.names == m.names and m2.channels == m.channels and m2.num_frames == len(data)
    # the writer keeps 6 decimals (degrees / file units): agreement to 1e-6
    np.testing.assert_allclose(m2.root_translation, m.root_translation, atol=1e-6)
    # rotations agree as rotations (a quaternion and its negative are the same rotation)
    R1 = Rotation.from_quat(np.asarray(m.rotations).reshape(-1, 4)[:, [1, 2, 3, 0]])
    R2 = Rotation.from_quat(np.asarray(m2.rotations).reshape(-1, 4)[:, [1, 2, 3, 0]])
    np.testing.assert_allclose(R1.as_matrix(), R2.as_matrix(), atol=1e-6)
    # and both match the Euler angles of the file (intrinsic, file order), against scipy
    arr = np.asarray(data, float)
    ref_root = Rotation.from_euler("ZYX", arr[:, 3:6], degrees=True).as_matrix()
    ref_spine = Rotation.from_euler("ZXY", arr[:, 6:9], degrees=True).as_matrix()
    got = R1.as_matrix().reshape(len(data), -1, 3, 3)
    np.testing.assert_allclose(got[:, 0], ref_root, atol=1e-9)
    np.testing.assert_allclose(got[:, 1], ref_spine, atol=1e-9)


# --- fuzz: every reader fails with CorruptFileError on bad bytes ---------------------------


def _valid_files(tmp_path):
    """One valid file per reader, as (suffix, bytes, read)."""
    seq = fx.io.MarkerSequence(
        np.arange(24, dtype=float).reshape(2, 4, 3), ("a", "b", "c", "d"), 60.0, "mm"
    )
    out = {}
    for name in ("v.trc", "v.c3d", "v.npz"):
        p = tmp_path / name
        {"v.trc": fx.io.write_trc, "v.c3d": fx.io.write_c3d, "v.npz": fx.io.write_npz}[name](p, seq)
        out[name] = (p.read_bytes(), fx.io.read_markers)
    out["v.bvh"] = (BVH.encode(), fx.io.read_bvh)
    return out


def _read(tmp_path, name, data, read):
    p = tmp_path / f"fuzz_{name}"
    p.write_bytes(data)
    return read(p)


READERS = ["v.trc", "v.c3d", "v.npz", "v.bvh"]


@pytest.mark.parametrize("name", READERS)
@SETTINGS
@given(cut=st.floats(0.0, 0.999), junk=st.binary(max_size=64))
def test_truncated_or_garbled_files_raise_corrupt(tmp_path, name, cut, junk):
    valid, read = _valid_files(tmp_path)[name]
    data = valid[: int(len(valid) * cut)] + junk
    try:
        _read(tmp_path, name, data, read)
    except CorruptFileError:
        pass  # the one allowed failure
    # a prefix that happens to parse (e.g. a BVH truncated after a whole frame with the
    # right frame count) is fine: what may never happen is another exception type


@pytest.mark.parametrize("name", READERS + ["v.glb", "v.asf"])
@SETTINGS
@given(data=st.binary(max_size=600))
def test_random_bytes_raise_corrupt(tmp_path, name, data):
    if name == "v.glb":
        read = fx.io.read_gltf
    elif name == "v.asf":
        read = fx.io.read_asf
    else:
        read = _valid_files(tmp_path)[name][1]
    with pytest.raises(CorruptFileError):
        _read(tmp_path, name, data, read)


def test_directory_and_missing_are_said_as_such(tmp_path):
    d = tmp_path / "take.c3d"
    d.mkdir()
    with pytest.raises(IsADirectoryError, match="is a directory, not a marker file"):
        fx.io.read_markers(d)
    with pytest.raises(FileNotFoundError, match="not found"):
        fx.io.read_markers(tmp_path / "none.trc")
    with pytest.raises(IsADirectoryError):
        fx.io.read_bvh(tmp_path)
    with pytest.raises(IsADirectoryError):
        fx.io.read_gltf(tmp_path)


def test_bvh_more_frames_than_header_is_not_called_truncated(tmp_path):
    p = tmp_path / "more.bvh"
    p.write_text(BVH.replace("Frames: 2", "Frames: 1"))
    with pytest.raises(CorruptFileError, match="header says 1 frames, found 2") as e:
        fx.io.read_bvh(p)
    assert "truncated" not in str(e.value)
    p.write_text(BVH.replace("Frames: 2", "Frames: 3"))
    with pytest.raises(CorruptFileError, match="truncated"):
        fx.io.read_bvh(p)


def test_gltf_permission_error_is_not_corrupt(tmp_path, monkeypatch):
    p = tmp_path / "m.glb"
    p.write_bytes(b"glTF")
    real_open = type(p).open

    def deny(self, *a, **k):
        if self == p:
            raise PermissionError(13, "Permission denied", str(self))
        return real_open(self, *a, **k)

    monkeypatch.setattr(type(p), "open", deny)
    with pytest.raises(PermissionError, match="permission denied"):
        fx.io.read_gltf(p)
