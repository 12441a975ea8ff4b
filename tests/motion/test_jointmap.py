"""The joint-name map (issue 44, build item 3): canonical roles resolved from CMU ASF,
CMU BVH, Bandai Namco, ``LeftUpLeg``-style (Mixamo), VRM, SMPL, Unreal and Biped names;
missing roles named with the config key that fixes them; overrides from a config."""

import numpy as np
import pytest

import fxspace as fx
from fxspace import motion as M
from fxspace.config import ConfigError, config_from_dict

SIDES = (("Left", "L", "l", "left"), ("Right", "R", "r", "right"))
LIMBS = ("shoulder", "upper_arm", "lower_arm", "hand", "upper_leg", "lower_leg", "foot", "toes")


def _names(trunk, limb):
    return list(trunk) + [limb.format(Side=a, S=b, s=c, side=d, x=x) for a, b, c, d in SIDES
                          for x in LIMBS]  # fmt: skip


CMU = ["root", "lhipjoint", "lfemur", "ltibia", "lfoot", "ltoes", "rhipjoint", "rfemur",
       "rtibia", "rfoot", "rtoes", "lowerback", "upperback", "thorax", "lowerneck", "upperneck",
       "head", "lclavicle", "lhumerus", "lradius", "lwrist", "lhand", "rclavicle", "rhumerus",
       "rradius", "rwrist", "rhand"]  # fmt: skip
CMU_BVH = ["Hips", "LHipJoint", "LeftHip", "LeftKnee", "LeftAnkle", "LeftToe", "RHipJoint",
           "RightHip", "RightKnee", "RightAnkle", "RightToe", "lowerback", "Chest", "Chest2",
           "lowerneck", "Neck", "Head", "LeftCollar", "LeftShoulder", "LeftElbow",
           "LeftWrist", "lhand", "RightCollar", "RightShoulder", "RightElbow", "RightWrist",
           "rhand"]  # fmt: skip
BANDAI = ["joint_Root", "Hips", "Spine", "Chest", "Neck", "Head"] + [
    f"{p}_{s}" for s in "LR" for p in ("Shoulder", "UpperArm", "LowerArm", "Hand", "UpperLeg",
                                       "LowerLeg", "Foot", "Toes")]  # fmt: skip
MIXAMO = ["mixamorig:" + n for n in ["Hips", "Spine", "Spine1", "Spine2", "Neck", "Head"] + [
    f"{s}{p}" for s in ("Left", "Right") for p in ("Shoulder", "Arm", "ForeArm", "Hand", "UpLeg",
                                                   "Leg", "Foot", "ToeBase")]]  # fmt: skip
VRM = ["hips", "spine", "chest", "upperChest", "neck", "head"] + [
    f"{s}{p}" for s in ("left", "right")
    for p in ("Shoulder", "UpperArm", "LowerArm", "Hand", "UpperLeg", "LowerLeg", "Foot", "Toes")
]  # fmt: skip
SMPL = ("Pelvis L_Hip R_Hip Spine1 L_Knee R_Knee Spine2 L_Ankle R_Ankle Spine3 L_Foot R_Foot "
        "Neck L_Collar R_Collar Head L_Shoulder R_Shoulder L_Elbow R_Elbow L_Wrist R_Wrist "
        "L_Hand R_Hand").split()  # fmt: skip


@pytest.mark.parametrize(
    ("names", "convention", "expect"),
    [
        (CMU, "cmu", {"hips": "root", "spine": "lowerback", "upper_chest": "thorax",
                      "left_upper_leg": "lfemur", "left_lower_leg": "ltibia",
                      "left_foot": "lfoot", "left_toes": "ltoes", "left_upper_arm": "lhumerus",
                      "left_lower_arm": "lradius", "left_hand": "lhand"}),
        (CMU_BVH, "cmu_bvh", {"left_upper_arm": "LeftShoulder", "left_shoulder": "LeftCollar",
                              "left_foot": "LeftAnkle", "left_hand": "lhand"}),
        (BANDAI, "bandai", {"hips": "Hips", "left_upper_leg": "UpperLeg_L",
                            "right_toes": "Toes_R", "left_shoulder": "Shoulder_L"}),
        (MIXAMO, "mixamo", {"left_upper_leg": "mixamorig:LeftUpLeg",
                            "left_lower_leg": "mixamorig:LeftLeg",
                            "left_shoulder": "mixamorig:LeftShoulder",
                            "left_upper_arm": "mixamorig:LeftArm",
                            "right_toes": "mixamorig:RightToeBase", "chest": "mixamorig:Spine1"}),
        (VRM, "vrm", {"left_upper_leg": "leftUpperLeg", "left_toes": "leftToes",
                      "upper_chest": "upperChest", "left_upper_arm": "leftUpperArm"}),
        (SMPL, "smpl", {"hips": "Pelvis", "left_foot": "L_Ankle", "left_toes": "L_Foot",
                        "left_upper_arm": "L_Shoulder", "left_shoulder": "L_Collar"}),
    ],
)  # fmt: skip
def test_each_convention_resolves_its_own_names(names, convention, expect):
    jm = fx.motion.joint_map_for(names)
    assert jm.convention == convention
    for role, name in expect.items():
        assert jm[role] == name, role
    assert not jm.missing(M.BODY_ROLES)
    assert len(set(jm.as_dict().values())) == len(jm.roles)  # one joint, one role


def test_conventions_that_share_a_spelling_do_not_mix():
    """``LeftShoulder`` is the upper arm in the CMU BVH conversion and the clavicle in a
    Mixamo rig; ``L_Foot`` (SMPL toes) normalises to CMU's ``lfoot``: the whole-name-set
    match keeps each skeleton in its own convention."""
    assert fx.motion.joint_map_for(CMU_BVH)["left_upper_arm"] == "LeftShoulder"
    assert fx.motion.joint_map_for(MIXAMO)["left_shoulder"] == "mixamorig:LeftShoulder"
    assert fx.motion.joint_map_for(SMPL)["left_toes"] == "L_Foot"
    assert fx.motion.joint_map_for(CMU)["left_foot"] == "lfoot"


def test_plain_leftupleg_names_and_other_prefixes():
    plain = [n.split(":")[1] for n in MIXAMO]
    assert fx.motion.joint_map_for(plain)["left_upper_leg"] == "LeftUpLeg"
    lafan = [n.replace("ToeBase", "Toe") for n in plain]  # LaFAN1-style
    assert fx.motion.joint_map_for(lafan)["right_toes"] == "RightToe"
    blender = ["Armature|" + n for n in plain]
    assert fx.motion.joint_map_for(blender)["left_hand"] == "Armature|LeftHand"
    unreal = ["pelvis", "spine_01", "neck_01", "head"] + [
        f"{p}_{s}" for s in "lr" for p in ("clavicle", "upperarm", "lowerarm", "hand", "thigh",
                                          "calf", "foot", "ball")]  # fmt: skip
    jm = fx.motion.joint_map_for(unreal)
    assert jm.convention == "unreal" and jm["left_toes"] == "ball_l"


def test_missing_roles_are_named_with_the_config_key():
    names = [n for n in MIXAMO if "LeftFoot" not in n and "LeftHand" not in n]
    with pytest.raises(M.JointMapError) as e:
        fx.motion.joint_map_for(names, what="walk.bvh")
    msg = str(e.value)
    assert "walk.bvh" in msg and "left_hand" in msg and "left_foot" in msg
    assert "[skeleton] map" in msg and "mixamo" in msg and "\n" not in msg
    assert isinstance(e.value, ValueError)
    jm = fx.motion.joint_map_for(names, required=())  # a partial map when asked
    assert jm.missing(["left_foot", "right_foot"]) == ("left_foot",)
    with pytest.raises(M.JointMapError, match="left_foot"):
        jm["left_foot"]


def test_overrides_name_joints_no_convention_knows():
    names = [n.replace("mixamorig:LeftFoot", "L_Ankle") for n in MIXAMO]
    jm = fx.motion.joint_map_for(names, {"left_foot": "L_Ankle"})
    assert jm["left_foot"] == "L_Ankle" and jm.overridden == ("left_foot",)
    assert "1 from the config map" in jm.describe()
    # VRM-style role spellings, lists (the first present wins), pelvis for hips
    over = {"leftFoot": ["Ankle_L", "L_Ankle"], "pelvis": "mixamorig:Hips"}
    jm = fx.motion.joint_map_for(names, over)
    assert jm["left_foot"] == "L_Ankle" and jm["hips"] == "mixamorig:Hips"
    # the map wins over the convention: a joint keeps one role
    jm = fx.motion.joint_map_for(MIXAMO, {"left_toes": "mixamorig:LeftFoot"}, required=())
    assert jm["left_toes"] == "mixamorig:LeftFoot" and "left_foot" not in jm
    with pytest.raises(M.JointMapError, match="names no joint"):
        fx.motion.joint_map_for(MIXAMO, {"left_foot": "L_Ankle"})
    with pytest.raises(M.JointMapError, match="not a joint role"):
        fx.motion.joint_map_for(MIXAMO, {"left_paw": "mixamorig:LeftHand"})
    with pytest.raises(M.JointMapError, match="convention"):
        fx.motion.joint_map_for(MIXAMO, convention="daz")


def test_skeleton_table_from_a_config():
    spec = config_from_dict(M.SkeletonSpec, {"map": {"left_foot": "L_Ankle"}})
    assert spec.map == {"left_foot": "L_Ankle"} and hash(spec) == hash(M.SkeletonSpec(
        map={"left_foot": "L_Ankle"}))  # fmt: skip
    names = [n.replace("mixamorig:LeftFoot", "L_Ankle") for n in MIXAMO]
    assert spec.joint_map(names)["left_foot"] == "L_Ankle"
    with pytest.raises(ConfigError, match="not a joint role"):
        config_from_dict(M.SkeletonSpec, {"map": {"paw": "x"}})
    with pytest.raises(ConfigError, match="skeleton.convention"):
        config_from_dict(M.SkeletonSpec, {"convention": "daz"})
    forced = config_from_dict(M.SkeletonSpec, {"convention": "vrm"})
    assert forced.joint_map(VRM).convention == "vrm"


def test_correspondences_between_two_skeletons():
    a, b = fx.motion.joint_map_for(CMU), fx.motion.joint_map_for(MIXAMO)
    pairs = {r: (x, y) for r, x, y in a.correspondences(b)}
    assert pairs["left_upper_leg"] == ("lfemur", "mixamorig:LeftUpLeg")
    assert "upper_chest" in pairs and len(pairs) == 22


def test_length_unit_inferred_from_the_leg():
    names = ["Hips", "LeftUpLeg", "LeftLeg", "LeftFoot", "RightUpLeg", "RightLeg", "RightFoot"]
    off = np.zeros((7, 3))
    off[[2, 3, 5, 6], 1] = -0.41  # thigh and shin: a 0.82 m leg
    units = (("m", 1.0), ("cm", 0.01), ("mm", 0.001), ("in", 0.0254), ("cmu", 0.0254 / 0.45))
    for unit, s in units:
        got = fx.motion.infer_length_unit(off / s, names)
        assert got[0] == unit and got[1] == s and np.isclose(got[2], 0.82 / s)
    with pytest.raises(M.JointMapError, match="declare it"):
        fx.motion.infer_length_unit(off * 0.25, names, what="doll.bvh")  # a 20 cm leg
    with pytest.raises(M.JointMapError, match="no lower leg"):
        fx.motion.infer_length_unit(off[:2], names[:2])
