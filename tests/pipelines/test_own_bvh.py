"""Issue 44's done-when for skeletons: a BVH with ``LeftUpLeg``-style names drives a Ha &
Han set-up from a config that names the files by path — clip labels and the weight axis
from the config ("proud" / "tired", not "joy"), BVH units inferred and said, the resolved
``config.toml`` recording the files read. A synthetic walker (always runnable) and the
shared Bandai Namco walks renamed to Mixamo names (skipped without the data)."""

import dataclasses
import json
import tomllib
from pathlib import Path

import numpy as np
import pytest

import fxspace as fx
from fxspace import motion as M
from fxspace.config import ConfigError
from fxspace.pipelines import parametric_synthesis as ps

# --------------------------------------------------------------------- a synthetic walker
_J = [  # name, parent, rest offset (m; Y up, facing +Z, left = +X)
    ("Hips", -1, (0, 0.95, 0)),
    ("Spine", 0, (0, 0.10, 0)), ("Spine1", 1, (0, 0.15, 0)), ("Neck", 2, (0, 0.25, 0)),
    ("Head", 3, (0, 0.10, 0)), ("Head_end", 4, (0, 0.15, 0)),
]  # fmt: skip
for _s, _x in (("Left", 1.0), ("Right", -1.0)):  # arms, then legs: the order BVH keeps
    _c = len(_J)
    _J += [
        (f"{_s}Shoulder", 2, (0.05 * _x, 0.20, 0)), (f"{_s}Arm", _c, (0.12 * _x, 0, 0)),
        (f"{_s}ForeArm", _c + 1, (0, -0.28, 0)), (f"{_s}Hand", _c + 2, (0, -0.25, 0)),
        (f"{_s}Hand_end", _c + 3, (0, -0.08, 0)),
    ]  # fmt: skip
for _s, _x in (("Left", 1.0), ("Right", -1.0)):
    _c = len(_J)
    _J += [
        (f"{_s}UpLeg", 0, (0.09 * _x, -0.05, 0)), (f"{_s}Leg", _c, (0, -0.42, 0)),
        (f"{_s}Foot", _c + 1, (0, -0.42, 0)), (f"{_s}ToeBase", _c + 2, (0, -0.05, 0.12)),
        (f"{_s}ToeBase_end", _c + 3, (0, 0, 0.05)),
    ]  # fmt: skip


def _axis_angle(axis, angle):
    a = np.asarray(angle, np.float64)[..., None] / 2
    return np.concatenate([np.cos(a), np.sin(a) * np.asarray(axis, np.float64)], -1)


def walker(
    seconds=6.0, rate=30.0, cadence=1.0, turn_deg_s=0.0, arm=0.3, lean=0.0, names=None
) -> fx.motion.Motion:
    """A procedural walk: thighs swinging, knees flexing in swing, arms counter-swinging,
    the spine leaning by ``lean`` rad, the root turning at ``turn_deg_s``, the lowest toe
    or foot on the floor every frame."""
    T, J = int(seconds * rate), len(_J)
    t = np.arange(T) / rate
    phi = 2 * np.pi * cadence * t
    q = np.zeros((T, J, 4))
    q[..., 0] = 1.0
    idx = {n: i for i, (n, _, _) in enumerate(_J)}
    X, Y = (1.0, 0, 0), (0, 1.0, 0)
    for s, ph in (("Left", 0.0), ("Right", np.pi)):
        p = phi + ph
        q[:, idx[f"{s}UpLeg"]] = _axis_angle(X, -0.35 * np.sin(p))
        q[:, idx[f"{s}Leg"]] = _axis_angle(X, 1.0 * np.maximum(np.cos(p), 0) ** 1.5)
        q[:, idx[f"{s}Arm"]] = _axis_angle(X, arm * np.sin(p))
        q[:, idx[f"{s}ForeArm"]] = _axis_angle(X, -0.2 - 0.1 * np.sin(p))
    q[:, idx["Spine"]] = _axis_angle(X, np.full(T, lean))
    psi = np.deg2rad(turn_deg_s) * t
    q[:, 0] = _axis_angle(Y, psi)
    v = 1.2 * cadence
    root = np.zeros((T, 3))
    root[:, 0] = np.cumsum(v / rate * np.sin(psi))
    root[:, 2] = np.cumsum(v / rate * np.cos(psi))
    parents = tuple(p for _, p, _ in _J)
    offsets = np.asarray([o for _, _, o in _J], np.float64)
    P = np.asarray(fx.motion.fk_arrays(parents, offsets, root, q)[0])
    feet = [idx[n] for n in ("LeftFoot", "RightFoot", "LeftToeBase", "RightToeBase")]
    root[:, 1] -= P[:, feet, 1].min(axis=1)  # the lowest foot or toe on the floor
    rot = ("Zrotation", "Xrotation", "Yrotation")
    channels = tuple(
        ("Xposition", "Yposition", "Zposition", *rot) if p < 0
        else (() if n.endswith("_end") else rot)
        for n, p, _ in _J
    )
    return fx.motion.Motion(tuple(names or (n for n, _, _ in _J)), parents, offsets, root, q,
                            rate, channels)  # fmt: skip


CLIPS = {  # label: part, walker options (proud: upright, brisk, wide arm swing)
    "straight": ("lower", {}),
    "turning left": ("lower", {"turn_deg_s": 25.0}),
    "turning right": ("lower", {"turn_deg_s": -25.0}),
    "proud": ("upper", {"cadence": 1.15, "arm": 0.55, "lean": -0.1}),
    "tired": ("upper", {"cadence": 0.8, "arm": 0.1, "lean": 0.3}),
}


def _write_clips(folder: Path, rename=None) -> list[dict]:
    folder.mkdir(parents=True, exist_ok=True)
    out = []
    for label, (part, kw) in CLIPS.items():
        names = [rename(n) if rename else n for n, _, _ in _J]
        f = folder / f"{label.replace(' ', '_')}.bvh"
        fx.io.write_bvh(f, walker(names=names, **kw), scale=0.01)  # centimetres
        out.append({"path": f"{folder.name}/{f.name}", "part": part, "label": label})
    return out


def _toml(clips, extra: str = "") -> str:
    rows = ",\n  ".join(
        "{" + ", ".join(f'{k} = "{v}"' for k, v in c.items()) + "}" for c in clips
    )
    return (
        'experiment = "parametric_synthesis"\nseed = 0\nsetups = ["mood_walk"]\n\n'
        f'[data]\nsource = "files"\nclips = [\n  {rows},\n]\n{extra}'
    )


# --------------------------------------------------------------------- fast checks
def test_config_names_clips_by_path_and_the_resolved_config_records_them(tmp_path):
    clips = _write_clips(tmp_path / "takes")
    cfg_p = tmp_path / "own.toml"
    cfg_p.write_text(_toml(clips, '\n[skeleton]\nmap = {left_toes = "LeftToeBase"}\n'))
    (spec,) = fx.pipelines.resolve_config(cfg_p, tmp_path / "run")
    data = spec.config.data
    assert data.source == "files" and len(data.clips) == 5
    assert all(Path(c.path).is_absolute() and Path(c.path).is_file() for c in data.clips)
    assert M.setup_labels("mood_walk", data) == (
        ("straight", "turning left", "turning right"), ("proud", "tired"))  # fmt: skip
    resolved = tomllib.loads(spec.text)  # what config.toml holds: the files, parts, labels
    got = [(c["path"], c["part"], c["label"]) for c in resolved["data"]["clips"]]
    assert got == [(str(tmp_path / c["path"]), c["part"], c["label"]) for c in clips]
    assert resolved["skeleton"]["map"] == {"left_toes": "LeftToeBase"}
    assert [str(p) for p in ps.data_files(spec.config)] == [g[0] for g in got]


@pytest.mark.parametrize("name", ["mood_walk", "block_walk", "block_kick"])
def test_the_shipped_configs_show_keys_that_parse(tmp_path, name):
    """Each set-up's config shows its own-files block commented out: uncommented, its keys
    are known and only the example files are missing (named)."""
    text = (Path(__file__).resolve().parents[2] / "configs" / f"{name}.toml").read_text()
    lines = text.splitlines()
    start = lines.index("# [data]")
    end = next(i for i in range(start, len(lines)) if lines[i].startswith("# map ="))
    own = [ln[2:] if ln.startswith("# ") else ln for ln in lines[start : end + 1]]
    head = [ln for ln in lines[:start] if ln not in ("[data]",) and not ln.startswith("source")]
    cfg_p = tmp_path / f"{name}.toml"
    cfg_p.write_text("\n".join(head + own) + "\n")
    with pytest.raises(ConfigError, match="does not exist"):
        fx.pipelines.resolve_config(cfg_p)


@pytest.mark.parametrize(
    ("change", "match"),
    [
        (lambda c: c[:4], "two upper-body walks"),
        (lambda c: [c[0], c[3], c[4]] + [{**c[1], "path": "takes/missing.bvh"}],
         "missing.bvh does not exist"),
        (lambda c: [x for x in c if x["part"] == "lower"], "part = 'upper'"),
        (lambda c: c + [{**c[0], "part": "middle"}], "part"),
        (lambda c: c[:4] + [{**c[4], "units": "furlong"}], "units"),
    ],
)  # fmt: skip
def test_bad_clip_lists_are_refused_naming_the_key(tmp_path, change, match):
    clips = _write_clips(tmp_path / "takes")
    cfg_p = tmp_path / "own.toml"
    cfg_p.write_text(_toml(change(clips)))
    with pytest.raises(ConfigError, match=match):
        fx.pipelines.resolve_config(cfg_p)


def test_files_feed_one_setup(tmp_path):
    clips = _write_clips(tmp_path / "takes")
    cfg_p = tmp_path / "own.toml"
    cfg_p.write_text(_toml(clips).replace('["mood_walk"]', '["mood_walk", "block_walk"]'))
    with pytest.raises(ConfigError, match="feeds one set-up"):
        fx.pipelines.resolve_config(cfg_p)


def test_read_clip_infers_units_and_says_so(tmp_path, caplog):
    (clip,) = [c for c in _write_clips(tmp_path / "takes") if c["label"] == "proud"]
    sc = M.SetupClip(path=str(tmp_path / clip["path"]), part="upper", label="proud")
    with caplog.at_level("INFO", logger="fxspace"):
        m, rec = ps.read_clip(sc)
    said = " | ".join(r.getMessage() for r in caplog.records)
    assert "proud.bvh: lengths inferred to be cm" in said  # fxspace.io.read_bvh's inference
    assert "upper clip 'proud'" in said and "units auto" in said and "mixamo names" in said
    assert rec["units"] == "auto" and rec["label"] == "proud" and rec["part"] == "upper"
    assert np.isclose(rec["leg_m"], 0.84) and rec["frames"] == 180
    assert np.isclose(rec["rate_hz"], 30, rtol=1e-5)
    ref = walker(**CLIPS["proud"][1])
    np.testing.assert_allclose(np.asarray(m.offsets), ref.offsets, atol=1e-5)  # metres
    assert m.names == ref.names and m.num_frames == ref.num_frames
    # declared units win (and are said); a number is metres per file unit
    caplog.clear()
    with caplog.at_level("INFO", logger="fxspace"):
        m2, rec2 = ps.read_clip(dataclasses.replace(sc, units="mm"), data=M.SetupData())
    assert rec2["units"] == "mm" and rec2["units_from"] == "declared"
    assert rec2["metres_per_unit"] == 0.001 and "lengths in mm (declared)" in caplog.text
    np.testing.assert_allclose(np.asarray(m2.offsets), ref.offsets / 10, atol=1e-6)
    _, rec3 = ps.read_clip(dataclasses.replace(sc, units=0.01))
    assert rec3["metres_per_unit"] == 0.01 and np.isclose(rec3["leg_m"], 0.84)
    # inferred units that give no adult's leg are refused, asking for the unit
    fx.io.write_bvh(tmp_path / "small.bvh", ref, scale=0.0254 / 0.45)  # the CMU BVH unit
    small = dataclasses.replace(sc, path=str(tmp_path / "small.bvh"))
    try:
        _, rec4 = ps.read_clip(small)  # read_bvh may infer the CMU unit as inches
        assert 0.6 < rec4["leg_m"] < 1.1
    except ConfigError as e:
        assert "declare the file's unit" in str(e) and "'cmu'" in str(e)
    _, rec5 = ps.read_clip(dataclasses.replace(small, units="cmu"))
    assert np.isclose(rec5["leg_m"], 0.84, atol=1e-4)


def test_roles_drive_the_split_hands_and_feet_of_a_setup():
    r = M.setup_roles(walker(seconds=0.2))
    assert r["split"] == "Spine" and r["lfoot"] == "LeftFoot" and r["lhand"] == "LeftHand"
    assert r["feet"] == ("LeftToeBase", "RightToeBase") and r["rtoe"] == "RightToeBase"
    assert r["upper"] == ("LeftHand", "LeftForeArm", "LeftArm", "RightHand", "RightForeArm",
                          "Head")  # fmt: skip
    # a joint no convention knows: refused naming the role, accepted through the map
    odd = [n.replace("LeftFoot", "L_Ankle") for n, _, _ in _J]
    with pytest.raises(M.JointMapError, match=r"left_foot.*\[skeleton\] map"):
        M.setup_roles(walker(seconds=0.2, names=odd))
    r = M.setup_roles(walker(seconds=0.2, names=odd), M.SkeletonSpec(map={"left_foot": "L_Ankle"}))
    assert r["lfoot"] == "L_Ankle"
    no_toes = [n for n, _, _ in _J]
    sk = walker(seconds=0.2)
    jm = M.joint_map_for(no_toes, {"left_toes": "LeftToeBase_end"})  # any joint may be named
    assert jm["left_toes"] == "LeftToeBase_end" and sk.num_joints == len(no_toes)


# --------------------------------------------------------------------- end to end
@pytest.mark.slow
def test_synthetic_leftupleg_walks_run_the_pipeline_from_a_config(tmp_path):
    """No data needed: five synthetic ``LeftUpLeg``-style takes in cm, one of them with a
    foot joint only the config's ``[skeleton] map`` names, run through the whole
    ``parametric_synthesis`` pipeline (briefly)."""

    def rename(n):
        return "mixamorig:" + n.replace("LeftFoot", "L_Ankle")

    clips = _write_clips(tmp_path / "takes", rename)
    cfg_p = tmp_path / "own.toml"
    cfg_p.write_text(_toml(clips, (
        '\n[skeleton]\nmap = {left_foot = "mixamorig:L_Ankle"}\n'
        "\n[space]\nn_samples = 60\nk_replace = 4\n"
        "\n[synth]\nalphas = [0.0, 1.0]\nn_queries = 3\ntiming_repeats = 1\n"
        "joy_weights = [0.0, 1.0]\nsession_s = 4.0\n"
    )))  # fmt: skip
    (run,) = fx.pipelines.run_config(cfg_p, tmp_path / "run")
    m = json.loads((run / "metrics.json").read_text())["mood_walk"]
    assert m["upper_axis"] == "proud weight (tired = 1 − proud)"
    assert m["upper_labels"] == ["proud", "tired"]
    assert m["lower_labels"] == ["straight", "turning left", "turning right"]
    assert m["joint_convention"] == "mixamo"
    assert m["joint_map"]["left_foot"] == "mixamorig:L_Ankle"
    assert m["upper_root"] == "mixamorig:Spine"
    assert [c["label"] for c in m["clips"]] == list(CLIPS)
    assert all(c["units"] == "auto" and c["units_from"].startswith("inferred")
               and abs(c["leg_m"] - 0.84) < 1e-4 for c in m["clips"])  # fmt: skip
    assert "proud" in m["table1"]["clips"] and m["n_upper_examples"] == 2
    assert all(np.isfinite(v) for v in m["speed_vs_joy"]["alpha=1"])
    resolved = tomllib.loads((run / "config.toml").read_text())
    assert [c["path"] for c in resolved["data"]["clips"]] == [c["path"] for c in m["clips"]]
    # the session's BVH keeps the clips' joint names (in metres: their units were inferred)
    out = fx.io.read_bvh(run / "mood_walk_session.bvh")
    assert out.names[0] == "mixamorig:Hips" and "mixamorig:L_Ankle" in out.names
    assert m["session_distance_m"] > 1.0


@pytest.mark.slow
def test_bandai_walks_renamed_leftupleg_style_drive_the_mood_walk(data_dir, tmp_path):
    """The shared Bandai Namco walks, their joints renamed to Mixamo names by the
    project's own writer (cm), named by path in a config: the set-up is the one the
    Bandai names build (the same example parameters), and the session walks."""
    takes = {"straight": ("lower", "dataset-2_walk_normal_001"),
             "left": ("lower", "dataset-2_walk-turn-left_normal_001"),
             "right": ("lower", "dataset-2_walk-turn-right_normal_001"),
             "proud": ("upper", "dataset-1_walk_happy_001"),
             "tired": ("upper", "dataset-1_walk_sad_001")}  # fmt: skip
    rename = {"Chest": "Spine1"}
    for s, S in (("Left", "L"), ("Right", "R")):
        rename |= {f"Shoulder_{S}": f"{s}Shoulder", f"UpperArm_{S}": f"{s}Arm",
                   f"LowerArm_{S}": f"{s}ForeArm", f"Hand_{S}": f"{s}Hand",
                   f"UpperLeg_{S}": f"{s}UpLeg", f"LowerLeg_{S}": f"{s}Leg",
                   f"Foot_{S}": f"{s}Foot", f"Toes_{S}": f"{s}ToeBase"}  # fmt: skip
    (tmp_path / "takes").mkdir()
    clips = []
    for label, (part, take) in takes.items():
        m = ps.load_take(take)
        m = dataclasses.replace(m, names=tuple(rename.get(n, n) for n in m.names))
        fx.io.write_bvh(tmp_path / "takes" / f"{label}.bvh", m, scale=0.01)
        clips.append({"path": f"takes/{label}.bvh", "part": part, "label": label})
    assert "LeftUpLeg" in m.names and "UpperLeg_L" not in m.names
    space = 'units = "cm"\n\n[space]\nn_samples = 50\nk_replace = 4\n'  # Bandai: cm
    cfg_p = tmp_path / "own.toml"
    cfg_p.write_text(_toml(clips, space))
    st = ps.load_setup(cfg_p)
    assert st.info["joint_convention"] == "mixamo" and st.info["upper_root"] == "Spine"
    assert st.info["upper_axis"] == "proud weight (tired = 1 − proud)"
    assert st.scale == 0.01 and {c["units"] for c in st.info["clips"]} == {"cm"}
    # the Bandai names build the same set-up
    cfg = ps.Config(setups=("mood_walk",), data=M.SetupData(
        lower=tuple(t for p, t in takes.values() if p == "lower"),
        upper=tuple(t for p, t in takes.values() if p == "upper")),
        space=M.SetupSpace(n_samples=50, k_replace=4))  # fmt: skip
    ref = M.prepare_setup("mood_walk", ps.load_take, cfg.data, cfg.space, st_key(cfg_p))
    assert ref.info["joint_convention"] == "bandai" and st.feet == ref.feet
    EL = ref.spaces.lower.warps.shape[0]
    np.testing.assert_allclose(st.spaces.lower_params[:EL], ref.spaces.lower_params[:EL],
                               atol=1e-3)  # fmt: skip  (cm BVH text: ~1e-5 m rounding)
    params = fx.pipelines.session_parameters(cfg_p)
    assert set(params) == {"alpha", "turn", "joy"}
    X, fps, names = fx.pipelines.scripted_session(
        cfg_p, [(0.0, {"joy": 0.9, "turn": 15.0}), (2.0, {"joy": 0.1})], 4.0
    )
    assert names[0] == "Hips" and "LeftUpLeg" in names and np.isfinite(X).all()
    assert X.shape == (int(round(4.0 * fps)), len(names), 3)
    assert np.linalg.norm(X[-1, 0, [0, 2]] - X[0, 0, [0, 2]]) > 1.0  # it walked


def st_key(cfg_p):
    """The sampling key `load_setup` uses for the config's first set-up."""
    import jax

    return jax.random.fold_in(jax.random.fold_in(jax.random.PRNGKey(0), 0), 0)
