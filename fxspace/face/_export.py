"""Weights out: onto any rig whose shapes carry the same names, into a glTF with morph
targets and the weight animation (Blender, three.js), and into a CSV with ARKit column
names (one row per frame).

Example:

```python
w, missing = fx.face.transfer_weights(s.weights, s.names, my_rig)   # by shape name
fx.face.write_rig_gltf("face.glb", my_rig, w, fps=take.fps)
fx.face.write_weights_csv("weights.csv", s.weights, s.names, fps=take.fps)
```
"""

from __future__ import annotations

import csv
import io
from pathlib import Path

import numpy as np

from fxspace.errors import FxspaceError
from fxspace.face._rig import Rig
from fxspace.io import write_gltf_blendshapes
from fxspace.runs import write_text_atomic

__all__ = ["transfer_weights", "write_rig_gltf", "write_weights_csv", "read_weights_csv"]


def _weights(weights, names) -> np.ndarray:
    W = np.asarray(weights, np.float64)
    W = W[None] if W.ndim == 1 else W
    if W.ndim != 2 or W.shape[1] != len(names):
        raise FxspaceError(f"weights must be (frames, {len(names)}) for these names; got {W.shape}")
    return W


def transfer_weights(weights, names, rig: Rig) -> tuple[np.ndarray, list[str]]:
    """``weights`` ``(T, K)`` named by ``names``, re-ordered onto ``rig``'s shapes by name
    (case-insensitive; a shape the source lacks gets 0); returns the weights
    ``(T, rig.num_shapes)`` and the source names ``rig`` has no shape for."""
    if not isinstance(rig, Rig):
        raise FxspaceError("rig must be a fx.face.Rig (from fx.face.read_rig)")
    W = _weights(weights, names)
    src = {str(n).lower(): i for i, n in enumerate(names)}
    out = np.zeros((len(W), rig.num_shapes))
    for j, n in enumerate(rig.names):
        i = src.get(n.lower())
        if i is not None:
            out[:, j] = W[:, i]
    dst = {n.lower() for n in rig.names}
    missing = [str(n) for n in names if str(n).lower() not in dst]
    return out, missing


def write_rig_gltf(path: str | Path, rig: Rig, weights, fps: float = 30.0,
                   name: str = "face") -> Path:  # fmt: skip
    """A ``.glb`` of ``rig`` with one morph target per shape (named) and, with
    ``weights`` ``(T, K)`` (NaN frames hold the previous frame's weights), the weight
    animation at ``fps``: opens in Blender and three.js, plays the take. The file is
    binary glTF: `path` must end in ``.glb`` (a ``.gltf`` name is refused, since a
    ``.gltf`` file is JSON and readers, ours too, would refuse GLB bytes under it)."""
    if not isinstance(rig, Rig):
        raise FxspaceError("rig must be a fx.face.Rig (from fx.face.read_rig)")
    if Path(path).suffix.lower() != ".glb":
        raise FxspaceError(
            f"{path}: write_rig_gltf writes binary glTF; name the file with .glb "
            f"(got {Path(path).suffix or 'no suffix'!r})"
        )
    W = None if weights is None else _weights(weights, rig.names).copy()
    if W is not None:
        for t in range(len(W)):  # hold the last good frame over missing ones
            bad = ~np.isfinite(W[t])
            W[t, bad] = W[t - 1, bad] if t else 0.0
    return write_gltf_blendshapes(path, np.asarray(rig.neutral), np.asarray(rig.faces),
                                  np.asarray(rig.deltas), rig.names, W, fps, name)  # fmt: skip


def write_weights_csv(path: str | Path, weights, names, fps: float = 30.0) -> Path:
    """A CSV of per-frame weights: a ``frame`` and a ``time`` column, then one column per
    shape named as the shape (ARKit's names for ICT-like rigs); empty cells where a frame
    was not solved (NaN)."""
    W = _weights(weights, names)
    if not fps > 0:
        raise FxspaceError(f"fps must be > 0; got {fps}")
    buf = io.StringIO()
    wr = csv.writer(buf, lineterminator="\n")
    wr.writerow(["frame", "time", *[str(n) for n in names]])
    for t, row in enumerate(W):
        cells = ["" if not np.isfinite(x) else f"{x:.6g}" for x in row]
        wr.writerow([t, f"{t / fps:.6g}", *cells])
    return write_text_atomic(path, buf.getvalue())


def read_weights_csv(path: str | Path) -> tuple[np.ndarray, tuple[str, ...], np.ndarray]:
    """``(weights (T, K), names, times)`` of a CSV written by `write_weights_csv`."""
    p = Path(path)
    if not p.is_file():
        raise FxspaceError(f"{p}: no such file")
    rows = list(csv.reader(p.read_text().splitlines()))
    if len(rows) < 1 or rows[0][:2] != ["frame", "time"]:
        raise FxspaceError(f"{p}: not a weights CSV (first columns must be frame, time)")
    body = rows[1:]
    W = np.array([[float(x) if x else np.nan for x in r[2:]] for r in body]).reshape(len(body), -1)
    times = np.array([float(r[1]) for r in body])
    return W, tuple(rows[0][2:]), times
