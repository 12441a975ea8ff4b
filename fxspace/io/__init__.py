"""Readers and writers: markers (C3D, TRC, NPZ), body motion (ASF/AMC, BVH), skinned glTF,
and the seeded synthetic face (the embedded default data)."""

from ._asfamc import read_amc as read_amc
from ._asfamc import read_asf as read_asf
from ._bvh import read_bvh as read_bvh
from ._bvh import write_bvh as write_bvh
from ._c3d import write_c3d as write_c3d
from ._gltf import Animation as Animation
from ._gltf import LocalPose as LocalPose
from ._gltf import SkinnedMesh as SkinnedMesh
from ._gltf import read_gltf as read_gltf
from ._markers import SUPPORTED_EXTENSIONS as SUPPORTED_EXTENSIONS
from ._markers import MarkerSequence as MarkerSequence
from ._markers import read_markers as read_markers
from ._markers import write_npz as write_npz
from ._motion import Motion as Motion
from ._synthetic import EXPRESSION_MODES as EXPRESSION_MODES
from ._synthetic import SyntheticFace as SyntheticFace
from ._synthetic import expression_displacement as expression_displacement
from ._synthetic import face_layout as face_layout
from ._synthetic import synthetic_face as synthetic_face
from ._trc import write_trc as write_trc
