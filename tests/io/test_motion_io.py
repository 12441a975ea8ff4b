"""Readers/writers for body motion: BVH round trip (channel order kept), ASF/AMC units,
malformed files → errors naming the line, Euler conventions against scipy."""

import dataclasses
import gzip

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import fxspace as fx
from fxspace.errors import CorruptFileError
from fxspace.motion import euler_to_quat, quat_to_euler, quat_to_matrix

INCH_PER_UNIT_M = 0.0254 / 0.45

BVH = """HIERARCHY
ROOT Hips
{
\tOFFSET 0.0 0.0 0.0
\tCHANNELS 6 Xposition Yposition Zposition Zrotation Yrotation Xrotation
\tJOINT Spine
\t{
\t\tOFFSET 0.0 1.0 0.0
\t\tCHANNELS 3 Zrotation Xrotation Yrotation
\t\tJOINT Head
\t\t{
\t\t\tOFFSET 0.0 0.5 0.1
\t\t\tCHANNELS 3 Xrotation Yrotation Zrotation
\t\t\tEnd Site
\t\t\t{
\t\t\t\tOFFSET 0.0 0.2 0.0
\t\t\t}
\t\t}
\t}
\tJOINT Leg
\t{
\t\tOFFSET 0.3 -0.2 0.0
\t\tCHANNELS 3 Yrotation Xrotation Zrotation
\t\tEnd Site
\t\t{
\t\t\tOFFSET 0.0 -1.0 0.0
\t\t}
\t}
}
MOTION
Frames: 3
Frame Time: 0.0333333
1.0 2.0 3.0 10.0 20.0 30.0 5.0 -15.0 25.0 40.0 -30.0 10.0 12.0 -80.0 5.0
1.5 2.0 3.5 -10.0 45.0 170.0 0.0 0.0 0.0 1.0 2.0 3.0 -60.0 10.0 20.0
2.0 2.1 4.0 0.0 0.0 0.0 90.0 30.0 -45.0 -5.0 5.0 5.0 0.0 0.0 0.0
"""


@pytest.mark.parametrize("order", ["ZYX", "XYZ", "ZXY", "YXZ", "YZX", "XZY"])
def test_euler_matches_scipy_intrinsic(order, rng):
    ang = rng.uniform(-170, 170, size=(20, 3))
    ang[:, 1] = rng.uniform(-85, 85, size=20)
    q = euler_to_quat(ang, order)
    ref = Rotation.from_euler(order, ang, degrees=True).as_matrix()  # upper case = intrinsic
    np.testing.assert_allclose(quat_to_matrix(q), ref, atol=1e-12)
    np.testing.assert_allclose(quat_to_euler(q, order), ang, atol=1e-9)


def test_bvh_read_known_values(tmp_path):
    p = tmp_path / "t.bvh"
    p.write_text(BVH)
    m = fx.io.read_bvh(p)
    assert m.names == ("Hips", "Spine", "Head", "Head_end", "Leg", "Leg_end")
    assert m.parents == (-1, 0, 1, 2, 0, 4)
    assert m.channels[1] == ("Zrotation", "Xrotation", "Yrotation")
    assert m.channels[3] == ()
    assert m.rate == pytest.approx(30.0, rel=1e-5)
    np.testing.assert_allclose(m.root_translation[0], [1.0, 2.0, 3.0])
    ref = Rotation.from_euler("ZXY", [5.0, -15.0, 25.0], degrees=True).as_matrix()
    np.testing.assert_allclose(quat_to_matrix(m.rotations[0, 1]), ref, atol=1e-12)


@pytest.mark.parametrize("suffix", [".bvh", ".bvh.gz"])
def test_bvh_write_read_round_trip_keeps_channel_order(tmp_path, suffix):
    p = tmp_path / "t.bvh"
    p.write_text(BVH)
    m = fx.io.read_bvh(p, scale=0.5)
    q = tmp_path / f"out{suffix}"
    fx.io.write_bvh(q, m, scale=0.5)
    m2 = fx.io.read_bvh(q, scale=0.5)
    assert m2.names == m.names and m2.parents == m.parents and m2.channels == m.channels
    np.testing.assert_allclose(m2.offsets, m.offsets, atol=1e-6)
    np.testing.assert_allclose(m2.root_translation, m.root_translation, atol=1e-6)
    np.testing.assert_allclose(quat_to_matrix(m2.rotations), quat_to_matrix(m.rotations), atol=1e-6)
    # file units and each joint's Euler order come back: the original values (middle < 90°)
    lines = gzip.decompress(q.read_bytes()).decode() if suffix.endswith(".gz") else q.read_text()
    assert "CHANNELS 3 Yrotation Xrotation Zrotation" in lines
    row = [float(v) for v in lines.strip().splitlines()[-3].split()]
    np.testing.assert_allclose(
        row,
        [1.0, 2.0, 3.0, 10.0, 20.0, 30.0, 5.0, -15.0, 25.0, 40.0, -30.0, 10.0, 12.0, -80.0, 5.0],
        atol=1e-5,
    )


def _bad(tmp_path, text, name="bad.bvh"):
    p = tmp_path / name
    p.write_text(text)
    return p


def test_bvh_malformed_errors_name_the_line(tmp_path):
    lines = BVH.splitlines()
    bad = lines.copy()
    bad[3] = "\tOFFSET 0.0 zero 0.0"
    with pytest.raises(CorruptFileError, match=r"line 4: expected a number"):
        fx.io.read_bvh(_bad(tmp_path, "\n".join(bad)))
    bad = lines.copy()
    bad[-2] = "1.5 2.0 3.5"
    with pytest.raises(CorruptFileError, match=rf"line {len(lines) - 1}: 3 values"):
        fx.io.read_bvh(_bad(tmp_path, "\n".join(bad)))
    with pytest.raises(CorruptFileError, match=r"header says 3 frames, found 2"):
        fx.io.read_bvh(_bad(tmp_path, "\n".join(lines[:-1])))
    bad = lines.copy()
    bad[8] = "\t\tCHANNELS 3 Zrotation Xrotation Wrotation"
    with pytest.raises(CorruptFileError, match=r"line 9: unknown channel 'Wrotation'"):
        fx.io.read_bvh(_bad(tmp_path, "\n".join(bad)))
    with pytest.raises(CorruptFileError, match="no MOTION section"):
        fx.io.read_bvh(_bad(tmp_path, "HIERARCHY\nROOT a\n{\n"))
    p = tmp_path / "x.bvh.gz"
    p.write_bytes(b"\x1f\x8bnot gzip")
    with pytest.raises(CorruptFileError, match="gzip"):
        fx.io.read_bvh(p)


ASF = """:version 1.10
:units
  mass 1.0
  length 0.45
  angle deg
:root
   order TX TY TZ RX RY RZ
   axis XYZ
   position 0 0 0
   orientation 0 0 0
:bonedata
  begin
     id 1
     name a
     direction 0 1 0
     length 2.0
     axis 0 0 90  XYZ
    dof rx ry rz
    limits (-160.0 20.0)
           (-70.0 70.0)
           (-60.0 70.0)
  end
  begin
     id 2
     name b
     direction 1 0 0
     length 1.0
     axis 0 0 0  XYZ
    dof rz
  end
:hierarchy
  begin
    root a
    a b
  end
"""
AMC = """:FULLY-SPECIFIED
:DEGREES
1
root 1 2 3 0 0 0
a 0 0 0
b 90
2
root 1 2 3 0 90 0
a 0 0 0
b 0
"""


def test_amc_units_and_hand_computed_positions(tmp_path):
    asf, amc = tmp_path / "s.asf", tmp_path / "s.amc"
    asf.write_text(ASF.replace("\n", "\r\n"))  # CMU files are CRLF
    amc.write_text(AMC.replace("\n", "\r\n"))
    m = fx.io.read_amc(asf, amc)
    assert m.names == ("root", "a", "b", "b_end")
    k = INCH_PER_UNIT_M
    np.testing.assert_allclose(m.offsets[2], [0.0, 2.0 * k, 0.0], atol=1e-12)
    X = np.asarray(fx.forward_kinematics(m))
    root = np.asarray([1.0, 2.0, 3.0]) * k
    # frame 1: b rotated 90° about z (its axis is the world frame): tip of b at +y
    np.testing.assert_allclose(X[0, 3], root + [0.0, 3.0 * k, 0.0], atol=1e-12)
    # frame 2: root turned 90° about y: b's direction +x becomes -z
    np.testing.assert_allclose(X[1, 3], root + [0.0, 2.0 * k, -1.0 * k], atol=1e-12)


def test_amc_malformed_errors_name_the_line(tmp_path):
    asf, amc = tmp_path / "s.asf", tmp_path / "s.amc"
    asf.write_text(ASF)
    amc.write_text(AMC.replace("b 90", "b 90 1"))
    with pytest.raises(CorruptFileError, match=r"line 6: bone 'b' has 2 values"):
        fx.io.read_amc(asf, amc)
    amc.write_text(AMC.replace("a 0 0 0\nb 0", "a 0 0 0\nzz 0"))
    with pytest.raises(CorruptFileError, match=r"line 10: unknown bone 'zz'"):
        fx.io.read_amc(asf, amc)
    amc.write_text(AMC.replace("b 90", "b ninety"))
    with pytest.raises(CorruptFileError, match=r"line 6: non-numeric"):
        fx.io.read_amc(asf, amc)
    asf.write_text(ASF.replace("    a b\n", "    a c\n"))
    amc.write_text(AMC)
    with pytest.raises(CorruptFileError, match=r"line 34: hierarchy names unknown bone 'c'"):
        fx.io.read_amc(asf, amc)
    asf.write_text(ASF.replace("length 1.0", "length one"))
    with pytest.raises(CorruptFileError, match=r"line 27: expected a number for length"):
        fx.io.read_amc(asf, amc)


def test_real_cmu_files(data_dir):
    body = data_dir / "body"
    m = fx.io.read_amc(body / "cmu" / "131" / "131.asf", body / "cmu" / "131" / "131_01.amc.gz")
    assert m.num_frames == 994 and m.rate == 120.0
    # lfemur's rest offset from lhipjoint = lhipjoint's direction * length (2.18388 units)
    np.testing.assert_allclose(
        np.linalg.norm(m.offsets[m.index("lfemur")]), 2.18388 * INCH_PER_UNIT_M, rtol=1e-6
    )
    b = fx.io.read_bvh(body / "bvh" / "131_01.bvh.gz", scale=INCH_PER_UNIT_M)
    assert b.num_frames == 994
    assert b.channels[b.index("LeftShoulder")] == ("Zrotation", "Xrotation", "Yrotation")
    assert b.channels[0][:3] == ("Xposition", "Yposition", "Zposition")


# ----------------------------------------------------------------- position channels on any joint
BVH6 = """HIERARCHY
ROOT Root
{
\tOFFSET 0.0 0.0 0.0
\tCHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation
\tJOINT Hips
\t{
\t\tOFFSET 0.0 90.0 0.0
\t\tCHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation
\t\tJOINT Spine
\t\t{
\t\t\tOFFSET 15.0 0.0 0.0
\t\t\tCHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation
\t\t\tEnd Site
\t\t\t{
\t\t\t\tOFFSET 0.0 10.0 0.0
\t\t\t}
\t\t}
\t\tJOINT Leg
\t\t{
\t\t\tOFFSET 0.0 -10.0 8.0
\t\t\tCHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation
\t\t\tEnd Site
\t\t\t{
\t\t\t\tOFFSET 0.0 -40.0 0.0
\t\t\t}
\t\t}
\t}
}
MOTION
Frames: 3
Frame Time: 0.0333333
0 0 0 0 0 0 1.0 91.0 -50.0 80.0 -6.0 1.0 16.0 0.5 0.0 10.0 20.0 -30.0 0.0 -10.0 8.0 5.0 5.0 5.0
0 0 0 0 0 0 2.0 92.0 -45.0 85.0 -4.0 2.0 16.0 0.5 0.0 -20.0 40.0 15.0 0.0 -10.0 8.0 0.0 -30.0 0.0
0 0 0 0 0 0 3.0 90.5 -40.0 90.0 -2.0 3.0 16.0 0.5 0.0 0.0 0.0 0.0 0.0 -10.0 8.0 45.0 0.0 10.0
"""


def _reference_fk(parents, channels, offsets, data):
    """Independent BVH forward kinematics with scipy: position channels replace the OFFSET,
    rotation channels compose intrinsically in file order."""
    T = data.shape[0]
    J = len(parents)
    X = np.zeros((T, J, 3))
    Rw = [None] * J
    col = 0
    for j, chans in enumerate(channels):
        t = np.tile(np.asarray(offsets[j], float), (T, 1))
        rot_cols, order = [], ""
        for i, c in enumerate(chans):
            if c.endswith("position"):
                t[:, "XYZ".index(c[0])] = data[:, col + i]
            else:
                rot_cols.append(col + i)
                order += c[0]
        col += len(chans)
        R = (
            Rotation.from_euler(order.upper(), data[:, rot_cols], degrees=True)
            if order
            else Rotation.identity(T)
        )
        p = parents[j]
        if p < 0:
            X[:, j], Rw[j] = t, R
        else:
            X[:, j] = X[:, p] + Rw[p].apply(t)
            Rw[j] = Rw[p] * R
    return X


def test_bvh_position_channels_on_every_joint(tmp_path):
    p = _bad(tmp_path, BVH6, "six.bvh")
    m = fx.io.read_bvh(p, scale=0.01)
    assert m.names == ("Root", "Hips", "Spine", "Spine_end", "Leg", "Leg_end")
    data = np.asarray([[float(x) for x in ln.split()] for ln in BVH6.splitlines()[-3:]])
    offsets = [[0, 0, 0], [0, 90, 0], [15, 0, 0], [0, 10, 0], [0, -10, 8], [0, -40, 0]]
    ref = _reference_fk(m.parents, m.channels, offsets, data) * 0.01
    X = np.asarray(fx.motion.forward_kinematics(m))
    # every joint below the root exactly; the root's varying child translation is folded into
    # the root, which therefore sits at the child's position minus its rest OFFSET
    np.testing.assert_allclose(X[:, 1:], ref[:, 1:], atol=1e-6)
    np.testing.assert_allclose(X[:, 0], ref[:, 1] - [0.0, 0.9, 0.0], atol=1e-6)
    # constant per-joint translations became the offsets (replacing the file's OFFSET)
    np.testing.assert_allclose(m.offsets[m.index("Spine")], [0.16, 0.005, 0.0], atol=1e-12)
    # write → read keeps every joint's world position
    q = fx.io.read_bvh(fx.io.write_bvh(tmp_path / "six_out.bvh", m, scale=0.01), scale=0.01)
    np.testing.assert_allclose(fx.motion.forward_kinematics(q)[:, 1:], ref[:, 1:], atol=1e-5)


def test_bvh_varying_translation_off_the_root_chain_is_an_error(tmp_path):
    lines = BVH6.splitlines()
    lines[-1] = lines[-1].replace("16.0 0.5 0.0", "17.0 0.5 0.0")  # Spine stretches
    with pytest.raises(CorruptFileError, match="'Spine' has time-varying position"):
        fx.io.read_bvh(_bad(tmp_path, "\n".join(lines) + "\n"))


def test_real_bandai_file(data_dir):
    p = data_dir / "body" / "bandai" / "dataset-2_walk_normal_001.bvh.gz"
    m = fx.io.read_bvh(p, scale=0.01)
    assert m.num_frames == 273 and len(m.names) == 27 and m.rate == pytest.approx(30.0, 1e-4)
    assert all(len(c) == 6 for c in m.channels if c)
    text = gzip.decompress(p.read_bytes()).decode().splitlines()
    offsets = [[float(v) for v in ln.split()[1:]] for ln in text if ln.strip().startswith("OFFSET")]
    k = next(i for i, ln in enumerate(text) if ln.startswith("Frame Time"))
    data = np.asarray([[float(v) for v in ln.split()] for ln in text[k + 1 :] if ln.strip()])
    ref = _reference_fk(m.parents, m.channels, offsets, data) * 0.01
    np.testing.assert_allclose(fx.motion.forward_kinematics(m)[:, 1:], ref[:, 1:], atol=1e-5)
    # dropping the static root keeps the world positions of all other joints
    d = fx.motion.drop_root(m)
    np.testing.assert_allclose(fx.motion.forward_kinematics(d), ref[:, 1:], atol=1e-5)


@pytest.mark.parametrize("scale", [0.0, -1.0, float("nan"), float("inf")])
def test_bvh_scale_must_be_finite_positive(tmp_path, scale):
    p = tmp_path / "a.bvh"
    p.write_text(BVH)
    with pytest.raises(fx.FxspaceError, match="scale"):
        fx.io.read_bvh(p, scale=scale)
    m = fx.io.read_bvh(p)
    with pytest.raises(fx.FxspaceError, match="scale"):
        fx.io.write_bvh(tmp_path / "b.bvh", m, scale=scale)


@pytest.mark.parametrize("rate", [0.0, -30.0, float("nan")])
def test_amc_rate_refused_and_no_raw_traceback_on_write(tmp_path, rate):
    asf, amc = tmp_path / "s.asf", tmp_path / "s.amc"
    asf.write_text(ASF)
    amc.write_text(AMC)
    with pytest.raises(fx.FxspaceError, match="rate"):
        fx.io.read_amc(asf, amc, rate=rate)
    # a Motion whose rate was set to 0 by hand: writing it is a clear error, not a traceback
    m = dataclasses.replace(fx.io.read_amc(asf, amc), rate=rate)
    with pytest.raises(fx.FxspaceError, match="rate"):
        fx.io.write_bvh(tmp_path / "out.bvh", m)
