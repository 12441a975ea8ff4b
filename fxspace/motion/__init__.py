"""Decoupled parametric motion synthesis (Ha & Han): forward kinematics, DTW registration,
k-NN blending over sampled parameter spaces, incremental time-warping with two synchronised
clocks, upper/lower-body splicing and Horn re-placement.

Quaternions are ``(w, x, y, z)``; lengths are metres; see :class:`fxspace.io.Motion`.
"""

from ._blend import ExampleSet as ExampleSet
from ._blend import KNNResult as KNNResult
from ._blend import blend_pose as blend_pose
from ._blend import blend_quaternions as blend_quaternions
from ._blend import knn_blend_weights as knn_blend_weights
from ._blend import pose_at as pose_at
from ._blend import sample_blend_weights as sample_blend_weights
from ._blend import warp_times as warp_times
from ._dtw import DTWResult as DTWResult
from ._dtw import dtw as dtw
from ._dtw import dtw_batch as dtw_batch
from ._dtw import dtw_cost_matrix as dtw_cost_matrix
from ._dtw import dtw_padded as dtw_padded
from ._dtw import warp_from_path as warp_from_path
from ._fk import fk_arrays as fk_arrays
from ._fk import forward_kinematics as forward_kinematics
from ._horn import RigidTransform as RigidTransform
from ._horn import absolute_orientation as absolute_orientation
from ._horn import apply_rigid as apply_rigid
from ._quat import euler_to_quat as euler_to_quat
from ._quat import matrix_to_quat as matrix_to_quat
from ._quat import quat_conj as quat_conj
from ._quat import quat_mul as quat_mul
from ._quat import quat_nlerp as quat_nlerp
from ._quat import quat_rotate as quat_rotate
from ._quat import quat_slerp as quat_slerp
from ._quat import quat_to_euler as quat_to_euler
from ._quat import quat_to_matrix as quat_to_matrix
from ._space import extract_window as extract_window
from ._space import find_key_times as find_key_times
from ._space import stack_examples as stack_examples
from ._splice import align_start as align_start
from ._splice import heading_quat as heading_quat
from ._splice import splice_pose as splice_pose
from ._splice import upper_body_mask as upper_body_mask
from ._timewarp import Clocks as Clocks
from ._timewarp import advance_clock as advance_clock
from ._timewarp import interp_curve as interp_curve
from ._timewarp import keytime_warp as keytime_warp
from ._timewarp import sync_clocks as sync_clocks
from ._timewarp import warp_slopes as warp_slopes
