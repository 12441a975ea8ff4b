"""Seeded generators: the synthetic face (the embedded default data, and known answers
for tests)."""

from fxspace.synthetic._face import EXPRESSION_MODES as EXPRESSION_MODES
from fxspace.synthetic._face import SyntheticFace as SyntheticFace
from fxspace.synthetic._face import expression_displacement as expression_displacement
from fxspace.synthetic._face import face_layout as face_layout
from fxspace.synthetic._face import synthetic_face as synthetic_face

__all__ = [
    "EXPRESSION_MODES",
    "SyntheticFace",
    "expression_displacement",
    "face_layout",
    "synthetic_face",
]
