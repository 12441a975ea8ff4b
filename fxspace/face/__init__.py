"""Face rigs: a real head driven by the capture (blend shapes with ARKit names).

Both face papers end at an animated face: Kim & Jung's navigator plays an avatar, Hirose
& Higuchi map the actor's edited motion onto an artist's character. This subpackage
reads a blend-shape rig (`read_rig`: the ICT Face Model's OBJ folder, any rig in that
layout, or a glTF file's morph targets), binds a capture's markers to it
(`bind_markers`: similarity from landmark markers, refined by closest points, every
marker on a face triangle), solves per-frame expression weights in ``[0, 1]`` and the
head's rigid motion (`solve_weights`: bounded least squares with a temporal term, all
frames in one jitted batch, differentiable; a frame's ``result`` says whether the fit
is good: ``RESULTS.poor_fit`` with the markers named when it is not), and writes the
weights out
(`write_rig_gltf`: morph targets + weight animation; `write_weights_csv`;
`transfer_weights` onto any rig with the same shape names), and poses the head where
the capture is (`posed_vertices`: what the apps show).

Layer: above `fxspace.io` (it reads OBJ and glTF through it), below the pipelines and
apps.

Example:

```python
rig = fx.face.read_rig(fx.data.data_path("face", "ict"))
take = fx.io.read_markers(fx.data.data_path("face", "animface_jaw.c3d"))
b = fx.face.bind_markers(rig, take.positions[0], take.names, units=take.units)
s = fx.face.solve_weights(rig, b, take)                  # .weights (T, 53), .residual (T, 41)
s.result == fx.RESULTS.successful                        # per frame: the fit is good
s.notes                                                  # which frames and markers are not
fx.face.write_rig_gltf("jaw.glb", rig, s.weights, fps=take.fps)
V = fx.face.posed_vertices(rig, b, s, frames=0)         # (N, 3): the head where the markers are
```
"""

from fxspace.face._bind import LANDMARKS as LANDMARKS
from fxspace.face._bind import Binding as Binding
from fxspace.face._bind import bind_markers as bind_markers
from fxspace.face._bind import closest_points as closest_points
from fxspace.face._bind import similarity_fit as similarity_fit
from fxspace.face._export import read_weights_csv as read_weights_csv
from fxspace.face._export import transfer_weights as transfer_weights
from fxspace.face._export import write_rig_gltf as write_rig_gltf
from fxspace.face._export import write_weights_csv as write_weights_csv
from fxspace.face._pose import posed_vertices as posed_vertices
from fxspace.face._pose import rest_vertices as rest_vertices
from fxspace.face._rig import ICT_PARTS as ICT_PARTS
from fxspace.face._rig import Rig as Rig
from fxspace.face._rig import read_rig as read_rig
from fxspace.face._rig import rig_cache_dir as rig_cache_dir
from fxspace.face._rig import rig_from_arrays as rig_from_arrays
from fxspace.face._solve import FaceSolve as FaceSolve
from fxspace.face._solve import kabsch as kabsch
from fxspace.face._solve import solve_weights as solve_weights

__all__ = [
    "Rig",
    "read_rig",
    "rig_from_arrays",
    "rig_cache_dir",
    "ICT_PARTS",
    "Binding",
    "bind_markers",
    "LANDMARKS",
    "closest_points",
    "similarity_fit",
    "FaceSolve",
    "solve_weights",
    "kabsch",
    "posed_vertices",
    "rest_vertices",
    "transfer_weights",
    "write_rig_gltf",
    "write_weights_csv",
    "read_weights_csv",
]
