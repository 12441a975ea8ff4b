"""Readers and writers only: markers (C3D, TRC, NPZ, CSV/TSV tables), body motion (ASF/AMC, BVH) and
skinned glTF. The data types live with their system (`fxspace.motion.Motion`,
`fxspace.mesh.SkinnedMesh`) or in ``io/_types`` (`MarkerSequence`).

The seeded synthetic face lives in `fxspace.synthetic` (``fx.synthetic.synthetic_face``),
a layer above: io knows nothing of it (its old lazy aliases here made a circle).
"""

from fxspace.io._asfamc import read_amc as read_amc
from fxspace.io._asfamc import read_asf as read_asf
from fxspace.io._bvh import read_bvh as read_bvh
from fxspace.io._bvh import write_bvh as write_bvh
from fxspace.io._c3d import write_c3d as write_c3d
from fxspace.io._gltf import read_gltf as read_gltf
from fxspace.io._gltf_write import ik_poses_to_local as ik_poses_to_local
from fxspace.io._gltf_write import write_gltf as write_gltf
from fxspace.io._gltf_write import write_gltf_animation as write_gltf_animation
from fxspace.io._gltf_write import write_ik_gltf as write_ik_gltf
from fxspace.io._ik_bvh import ik_poses_to_motion as ik_poses_to_motion
from fxspace.io._ik_bvh import write_character_bvh as write_character_bvh
from fxspace.io._ik_bvh import write_ik_bvh as write_ik_bvh
from fxspace.io._markers import SUPPORTED_EXTENSIONS as SUPPORTED_EXTENSIONS
from fxspace.io._markers import read_markers as read_markers
from fxspace.io._markers import write_npz as write_npz
from fxspace.io._meshseq import BlendShapes as BlendShapes
from fxspace.io._meshseq import MorphAnimation as MorphAnimation
from fxspace.io._meshseq import read_gltf_blendshapes as read_gltf_blendshapes
from fxspace.io._meshseq import read_gltf_morph as read_gltf_morph
from fxspace.io._meshseq import read_obj as read_obj
from fxspace.io._meshseq import write_gltf_blendshapes as write_gltf_blendshapes
from fxspace.io._meshseq import write_gltf_morph as write_gltf_morph
from fxspace.io._meshseq import write_obj_sequence as write_obj_sequence
from fxspace.io._meshseq import write_ply_sequence as write_ply_sequence
from fxspace.io._obj import ObjMesh as ObjMesh
from fxspace.io._obj import read_obj_mesh as read_obj_mesh
from fxspace.io._obj import read_obj_vertices as read_obj_vertices
from fxspace.io._table import write_table as write_table
from fxspace.io._trc import write_trc as write_trc
from fxspace.io._types import UNIT_SCALES as UNIT_SCALES
from fxspace.io._types import MarkerSequence as MarkerSequence
from fxspace.mesh import Animation as Animation
from fxspace.mesh import LocalPose as LocalPose
from fxspace.mesh import SkinnedMesh as SkinnedMesh
from fxspace.motion import Motion as Motion

__all__ = [
    "read_amc",
    "read_asf",
    "read_bvh",
    "write_bvh",
    "write_c3d",
    "read_gltf",
    "ik_poses_to_local",
    "write_gltf",
    "write_ik_gltf",
    "write_gltf_animation",
    "ik_poses_to_motion",
    "write_ik_bvh",
    "write_character_bvh",
    "SUPPORTED_EXTENSIONS",
    "read_markers",
    "write_npz",
    "write_gltf_morph",
    "read_gltf_morph",
    "read_obj",
    "read_obj_mesh",
    "read_obj_vertices",
    "ObjMesh",
    "write_gltf_blendshapes",
    "read_gltf_blendshapes",
    "BlendShapes",
    "MorphAnimation",
    "write_obj_sequence",
    "write_ply_sequence",
    "write_trc",
    "write_table",
    "UNIT_SCALES",
    "MarkerSequence",
    "Animation",
    "LocalPose",
    "SkinnedMesh",
    "Motion",
]
