"""Decoupled parametric motion synthesis (Ha & Han): forward kinematics, DTW registration,
k-NN blending over sampled parameter spaces, incremental time-warping (eq. 1) with the two
clocks aligned by eqs. 2–3, upper/lower-body splicing and the §3.2 Horn re-placement, all in
one pure per-frame step (`synthesize_step`); continuous, steerable locomotion on top
(`locomotion_step`, `run_session`), joints found by role on any humanoid skeleton
(`joint_map_for`: CMU, Bandai Namco, Mixamo-style, VRM, SMPL names). The config-level
session that reads a TOML and its clips is `fxspace.pipelines.scripted_session`, a layer
above.

Quaternions are ``(w, x, y, z)``; lengths are metres; see `Motion`. The rotation helpers
re-exported here live in `fxspace.rotations`.
"""

from fxspace.joints import BODY_ROLES as BODY_ROLES
from fxspace.joints import CONVENTIONS as CONVENTIONS
from fxspace.joints import LENGTH_UNITS as LENGTH_UNITS
from fxspace.joints import ROLES as ROLES
from fxspace.joints import JointMap as JointMap
from fxspace.joints import JointMapError as JointMapError
from fxspace.joints import SkeletonSpec as SkeletonSpec
from fxspace.joints import infer_length_unit as infer_length_unit
from fxspace.joints import joint_map_for as joint_map_for
from fxspace.motion._blend import ExampleSet as ExampleSet
from fxspace.motion._blend import KNNResult as KNNResult
from fxspace.motion._blend import blend_pose as blend_pose
from fxspace.motion._blend import blend_quaternions as blend_quaternions
from fxspace.motion._blend import knn_blend_weights as knn_blend_weights
from fxspace.motion._blend import pose_at as pose_at
from fxspace.motion._blend import sample_blend_weights as sample_blend_weights
from fxspace.motion._blend import warp_times as warp_times
from fxspace.motion._dtw import DTWResult as DTWResult
from fxspace.motion._dtw import dtw as dtw
from fxspace.motion._dtw import dtw_batch as dtw_batch
from fxspace.motion._dtw import dtw_cost_matrix as dtw_cost_matrix
from fxspace.motion._dtw import dtw_padded as dtw_padded
from fxspace.motion._dtw import warp_from_path as warp_from_path
from fxspace.motion._fk import fk_arrays as fk_arrays
from fxspace.motion._fk import forward_kinematics as forward_kinematics
from fxspace.motion._horn import RigidTransform as RigidTransform
from fxspace.motion._horn import absolute_orientation as absolute_orientation
from fxspace.motion._horn import absolute_rotation as absolute_rotation
from fxspace.motion._horn import apply_rigid as apply_rigid
from fxspace.motion._joint_guard import example_joint_steps as example_joint_steps
from fxspace.motion._locomotion import JOINT_GUARD_STEPS as JOINT_GUARD_STEPS
from fxspace.motion._locomotion import JOINT_GUARD_TARGET as JOINT_GUARD_TARGET
from fxspace.motion._locomotion import WRAP_BLEND_FRAMES as WRAP_BLEND_FRAMES
from fxspace.motion._locomotion import LocomotionState as LocomotionState
from fxspace.motion._locomotion import TurnTable as TurnTable
from fxspace.motion._locomotion import heading_angle as heading_angle
from fxspace.motion._locomotion import init_locomotion as init_locomotion
from fxspace.motion._locomotion import locomotion as locomotion
from fxspace.motion._locomotion import locomotion_step as locomotion_step
from fxspace.motion._locomotion import locomotion_stepper as locomotion_stepper
from fxspace.motion._locomotion import turn_table as turn_table
from fxspace.motion._locomotion import turn_to_lower_param as turn_to_lower_param
from fxspace.motion._locomotion import world_positions as world_positions
from fxspace.motion._metrics import CycleCoupling as CycleCoupling
from fxspace.motion._metrics import cadence as cadence
from fxspace.motion._metrics import cycle_coupling as cycle_coupling
from fxspace.motion._metrics import cycle_events as cycle_events
from fxspace.motion._metrics import foot_sliding as foot_sliding
from fxspace.motion._metrics import ground_speed as ground_speed
from fxspace.motion._metrics import joint_speeds as joint_speeds
from fxspace.motion._metrics import swing_signal as swing_signal
from fxspace.motion._register import RegistrationResult as RegistrationResult
from fxspace.motion._register import alignment_curve as alignment_curve
from fxspace.motion._register import drop_root as drop_root
from fxspace.motion._register import gait_window as gait_window
from fxspace.motion._register import pose_features as pose_features
from fxspace.motion._register import register_dtw as register_dtw
from fxspace.motion._register import register_examples as register_examples
from fxspace.motion._register import smooth_warp as smooth_warp
from fxspace.motion._session import control_defaults as control_defaults
from fxspace.motion._session import controls_to_params as controls_to_params
from fxspace.motion._session import run_session as run_session
from fxspace.motion._session import session_controls as session_controls
from fxspace.motion._session import session_turn_table as session_turn_table
from fxspace.motion._session import smooth_controls as smooth_controls
from fxspace.motion._setup_config import SETUPS as SETUPS
from fxspace.motion._setup_config import SetupClip as SetupClip
from fxspace.motion._setup_config import SetupData as SetupData
from fxspace.motion._setup_config import SetupSpace as SetupSpace
from fxspace.motion._setup_config import setup_labels as setup_labels
from fxspace.motion._setup_config import setup_takes as setup_takes
from fxspace.motion._setup_examples import setup_roles as setup_roles
from fxspace.motion._setups import Setup as Setup
from fxspace.motion._setups import prepare_setup as prepare_setup
from fxspace.motion._space import extract_window as extract_window
from fxspace.motion._space import find_key_times as find_key_times
from fxspace.motion._space import stack_examples as stack_examples
from fxspace.motion._splice import align_start as align_start
from fxspace.motion._splice import heading_quat as heading_quat
from fxspace.motion._splice import heck_splice as heck_splice
from fxspace.motion._splice import splice_pose as splice_pose
from fxspace.motion._splice import torso_joints as torso_joints
from fxspace.motion._splice import upper_body_mask as upper_body_mask
from fxspace.motion._synth_clocks import clock_bounds as clock_bounds
from fxspace.motion._synth_clocks import clock_cycle_rate as clock_cycle_rate
from fxspace.motion._synth_types import Pose as Pose
from fxspace.motion._synth_types import SynthesisSpaces as SynthesisSpaces
from fxspace.motion._synth_types import SynthState as SynthState
from fxspace.motion._synthesis import build_spaces as build_spaces
from fxspace.motion._synthesis import exact_upper_params as exact_upper_params
from fxspace.motion._synthesis import init_state as init_state
from fxspace.motion._synthesis import lower_param_of as lower_param_of
from fxspace.motion._synthesis import replace_samples as replace_samples
from fxspace.motion._synthesis import splice_frame as splice_frame
from fxspace.motion._synthesis import synthesize as synthesize
from fxspace.motion._synthesis import synthesize_step as synthesize_step
from fxspace.motion._synthesis import upper_param_of as upper_param_of
from fxspace.motion._timewarp import Clocks as Clocks
from fxspace.motion._timewarp import advance_clock as advance_clock
from fxspace.motion._timewarp import advance_clock_duration as advance_clock_duration
from fxspace.motion._timewarp import align_clocks as align_clocks
from fxspace.motion._timewarp import interp_curve as interp_curve
from fxspace.motion._timewarp import invert_curve as invert_curve
from fxspace.motion._timewarp import keytime_warp as keytime_warp
from fxspace.motion._timewarp import sync_clocks as sync_clocks
from fxspace.motion._timewarp import warp_slopes as warp_slopes
from fxspace.motion._types import Motion as Motion
from fxspace.rotations import euler_to_quat as euler_to_quat
from fxspace.rotations import matrix_to_quat as matrix_to_quat
from fxspace.rotations import quat_conj as quat_conj
from fxspace.rotations import quat_mul as quat_mul
from fxspace.rotations import quat_nlerp as quat_nlerp
from fxspace.rotations import quat_rotate as quat_rotate
from fxspace.rotations import quat_slerp as quat_slerp
from fxspace.rotations import quat_to_euler as quat_to_euler
from fxspace.rotations import quat_to_matrix as quat_to_matrix

__all__ = [
    "ExampleSet",
    "KNNResult",
    "blend_pose",
    "blend_quaternions",
    "knn_blend_weights",
    "pose_at",
    "sample_blend_weights",
    "warp_times",
    "DTWResult",
    "dtw",
    "dtw_batch",
    "dtw_cost_matrix",
    "dtw_padded",
    "warp_from_path",
    "fk_arrays",
    "forward_kinematics",
    "RigidTransform",
    "absolute_orientation",
    "absolute_rotation",
    "apply_rigid",
    "BODY_ROLES",
    "CONVENTIONS",
    "LENGTH_UNITS",
    "ROLES",
    "JointMap",
    "JointMapError",
    "SkeletonSpec",
    "infer_length_unit",
    "joint_map_for",
    "euler_to_quat",
    "matrix_to_quat",
    "quat_conj",
    "quat_mul",
    "quat_nlerp",
    "quat_rotate",
    "quat_slerp",
    "quat_to_euler",
    "quat_to_matrix",
    "SETUPS",
    "Setup",
    "SetupClip",
    "SetupData",
    "SetupSpace",
    "prepare_setup",
    "setup_takes",
    "setup_labels",
    "setup_roles",
    "extract_window",
    "find_key_times",
    "stack_examples",
    "align_start",
    "heading_quat",
    "splice_pose",
    "heck_splice",
    "splice_frame",
    "torso_joints",
    "upper_body_mask",
    "foot_sliding",
    "ground_speed",
    "CycleCoupling",
    "cadence",
    "cycle_coupling",
    "cycle_events",
    "joint_speeds",
    "swing_signal",
    "clock_bounds",
    "clock_cycle_rate",
    "example_joint_steps",
    "alignment_curve",
    "drop_root",
    "gait_window",
    "pose_features",
    "register_dtw",
    "RegistrationResult",
    "register_examples",
    "smooth_warp",
    "Pose",
    "SynthesisSpaces",
    "SynthState",
    "build_spaces",
    "exact_upper_params",
    "init_state",
    "lower_param_of",
    "replace_samples",
    "synthesize",
    "synthesize_step",
    "upper_param_of",
    "Clocks",
    "advance_clock",
    "advance_clock_duration",
    "align_clocks",
    "interp_curve",
    "invert_curve",
    "keytime_warp",
    "sync_clocks",
    "warp_slopes",
    "Motion",
    "WRAP_BLEND_FRAMES",
    "JOINT_GUARD_STEPS",
    "JOINT_GUARD_TARGET",
    "LocomotionState",
    "TurnTable",
    "heading_angle",
    "init_locomotion",
    "locomotion_stepper",
    "locomotion",
    "locomotion_step",
    "turn_table",
    "turn_to_lower_param",
    "world_positions",
    "control_defaults",
    "controls_to_params",
    "run_session",
    "session_controls",
    "session_turn_table",
    "smooth_controls",
]
