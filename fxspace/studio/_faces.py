"""The heads the studio apps show: the template head driven by the markers
(`DenseFace`), a blend-shape rig solved from them (`RigFace`), and `studio_face`, which
picks one for an app's markers and says why."""

from __future__ import annotations

import hashlib
import os
import threading
from pathlib import Path

import numpy as np

from fxspace.errors import FxspaceError

__all__ = ["DenseFace", "RigFace", "RIG_COLOURS", "studio_face"]


class DenseFace:
    """The face the studio apps show: a smooth, closed, shaded head (`fxspace.head_model`:
    a template head fitted to the neutral markers, with eyes, lips and a mouth opening)
    driven only by the markers through the RBF transfer, ``v(t) = v(0) + A (m(t) − m(0))``;
    one ``(N × M)·(M × 3)`` product per frame. The lips part when the jaw markers open.

    `parts` lists ``(name, colour)``; `meshes(V)` splits posed vertices into one compact
    mesh per part (viser meshes take one colour each). `axes` rows are the face's right,
    up and out directions (to show it from the front)."""

    def __init__(self, rest_markers: np.ndarray, n_vertices: int = 2500, names=None):
        from fxspace.controlpoints import HEAD_COLOURS, head_model

        res = max(24, int(np.sqrt(max(int(n_vertices), 1) / 1.5)))
        m = head_model(np.asarray(rest_markers, np.float64), names, res)
        self.model = m
        self.rest_markers = m.rest_markers
        self.rest = m.rest
        self.faces = m.faces
        self.A = m.transfer
        self.axes = m.axes
        self.colors = m.colors
        self.parts = [(name, HEAD_COLOURS[name]) for name in m.parts]
        self._split = []
        for k, (name, colour) in enumerate(self.parts):
            f = m.faces[m.part == k]
            used, inv = np.unique(f, return_inverse=True)
            if len(f):
                self._split.append((name, colour, used, inv.reshape(f.shape).astype(np.int32)))

    def vertices(self, markers: np.ndarray) -> np.ndarray:
        """``(N, 3)`` surface for one frame of markers ``(M, 3)``."""
        return self.rest + self.A @ (np.asarray(markers, np.float64) - self.rest_markers)

    def trimesh(self, V: np.ndarray):
        """The posed head as one ``trimesh.Trimesh`` with smooth per-vertex colours."""
        import trimesh

        return trimesh.Trimesh(V, self.faces, vertex_colors=self.colors, process=False)

    def meshes(self, V: np.ndarray) -> list[tuple[str, np.ndarray, np.ndarray, tuple]]:
        """``(name, vertices, faces, colour)`` per part of the posed vertices ``V``."""
        return [(name, V[used], f, colour) for name, colour, used, f in self._split]


RIG_COLOURS = {
    "skin": (226, 186, 160),
    "mouth": (120, 40, 44),
    "gums": (196, 110, 112),
    "teeth": (238, 232, 214),
    "eyes": (246, 246, 242),
    "irises": (60, 44, 32),
    "lashes": (96, 74, 58),
}
"""The colour of each part of a rig's head (RGB)."""

# the ICT Face Model's parts (`fxspace.face.ICT_PARTS`) by what they show; its lacrimal
# fluid, eye blend and eye occlusion are see-through shells, not drawn
_RIG_PARTS = {
    "skin": ("face", "head_and_neck", "eye_sockets"),
    "mouth": ("mouth_socket",),
    "gums": ("gums_and_tongue",),
    "teeth": ("teeth",),
    "eyes": ("eyes",),
    "lashes": ("eyelashes",),
}


class RigFace:
    """A real head for the apps: a blend-shape rig (`fxspace.face`: the ICT Face Model by
    default) bound to the capture's neutral markers, each shown frame's expression weights
    and head motion solved from that frame's markers (`fxspace.face.solve_weights`, one
    frame, ~10 ms) and the rig posed where the markers are (`fxspace.face.posed_vertices`).

    Same use as `DenseFace`: ``vertices(markers)`` → posed vertices, ``meshes(V)`` → one
    mesh per part (skin, mouth, gums, teeth, eyes, irises, lashes; a rig without the ICT
    parts is all skin); ``axes`` the face's right, up and out directions in the capture's
    frame. ``last`` is the last frame's `FaceSolve` (its weights are what the page shows).
    """

    def __init__(self, rig, rest_markers: np.ndarray, names):
        from fxspace.face import bind_markers

        self.rig = rig
        self.binding = bind_markers(rig, np.asarray(rest_markers, np.float64), list(names))
        self.rest_markers = np.asarray(rest_markers, np.float64)
        self.names = tuple(rig.names)
        self.axes = np.asarray(self.binding.rotation, np.float64)  # rig x, y, z in capture
        F = np.asarray(rig.faces)
        sets = {k: np.asarray(v) for k, v in rig.vertex_sets.items()}
        parts: list[tuple[str, np.ndarray]] = []
        if all(p in sets for ps in _RIG_PARTS.values() for p in ps):
            for name, ps in _RIG_PARTS.items():
                keep = np.zeros(rig.num_vertices, bool)
                keep[np.concatenate([sets[p] for p in ps])] = True
                tri = F[keep[F].all(axis=1)]
                if name == "eyes":  # the iris: the front cap of each eyeball
                    front = self._iris(np.asarray(rig.neutral, np.float64), tri)
                    parts += [("eyes", tri[~front]), ("irises", tri[front])]
                else:
                    parts.append((name, tri))
        else:
            parts = [("skin", F)]
        self.used = np.unique(np.concatenate([t.reshape(-1) for _, t in parts]))
        remap = np.full(rig.num_vertices, -1, np.int64)
        remap[self.used] = np.arange(len(self.used))
        self._split = []
        for name, tri in parts:
            used, inv = np.unique(remap[tri], return_inverse=True)
            if len(tri):
                self._split.append((name, RIG_COLOURS[name], used,
                                    inv.reshape(tri.shape).astype(np.int32)))  # fmt: skip
        self.parts = [(n, c) for n, c, _, _ in self._split]
        self.last = None
        self.rest = self.vertices(self.rest_markers)

    @staticmethod
    def _iris(V: np.ndarray, tri: np.ndarray) -> np.ndarray:
        """Triangles on the front cap (within ~23° of straight ahead, +z) of each eyeball
        (the two eyeballs told apart by the side of the face, x)."""
        c = V[tri].mean(1)
        front = np.zeros(len(tri), bool)
        for side in (c[:, 0] < 0, c[:, 0] >= 0):
            if side.any():
                ctr = c[side].mean(0)
                d = c[side] - ctr
                d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-12)
                front[np.flatnonzero(side)] = d[:, 2] > 0.92
        return front

    def solve(self, markers: np.ndarray):
        """`FaceSolve` of markers ``(M, 3)`` (one frame) or ``(T, M, 3)`` (a take)."""
        from fxspace.face import solve_weights

        return solve_weights(self.rig, self.binding, np.asarray(markers, np.float64))

    def pose(self, solve, frame: int | None = None) -> np.ndarray:
        """``(N, 3)`` shown vertices of a solve (one frame, or ``frame`` of a take)."""
        from fxspace.face import posed_vertices

        return np.asarray(posed_vertices(self.rig, self.binding, solve, frames=frame,
                                         vertices=self.used), np.float64)  # fmt: skip

    def vertices(self, markers: np.ndarray) -> np.ndarray:
        """``(N, 3)`` shown vertices for one frame of markers ``(M, 3)`` (the rest pose
        when the frame has fewer than three markers seen)."""
        s = self.solve(markers)
        if not np.all(np.isfinite(np.asarray(s.weights))):
            return self.rest
        self.last = s
        return self.pose(s)

    def meshes(self, V: np.ndarray) -> list[tuple[str, np.ndarray, np.ndarray, tuple]]:
        """``(name, vertices, faces, colour)`` per part of the posed vertices ``V``."""
        return [(name, V[used], f, colour) for name, colour, used, f in self._split]


_FACES: dict = {}  # the faces studio_face made last (an app's warm-up, then the app)
_FACES_LOCK = threading.Lock()


def studio_face(rest_markers: np.ndarray, names=None, rig: str | Path | None = "face/ict",
                n_vertices: int = 2500):  # fmt: skip
    """``(face, note)``: the head an app shows for these neutral markers — a `RigFace`
    of ``rig`` (a path under the data root or anywhere; default the ICT Face Model) when
    it is there and the markers are named so that they bind, else the template
    `DenseFace` — and one line saying which and why (shown on the page).

    The last two are kept (keyed by the markers' values, names, rig, size and data
    root): an app's warm-up (`fxspace.studio.serve_config`) makes the face while the
    stages are prepared, and the app takes it; a second caller waits for the first."""
    rest = np.ascontiguousarray(rest_markers, np.float64)
    key = (hashlib.sha256(rest.tobytes()).hexdigest(), rest.shape,
           None if names is None else tuple(map(str, names)), None if rig is None else str(rig),
           int(n_vertices), os.environ.get("FXSPACE_DATA"))  # fmt: skip
    with _FACES_LOCK:
        hit = _FACES.get(key)
        if hit is None:
            hit = _make_face(rest_markers, names, rig, n_vertices)
            while len(_FACES) >= 2:
                _FACES.pop(next(iter(_FACES)))
            _FACES[key] = hit
    return hit


def _make_face(rest_markers, names, rig, n_vertices):
    from fxspace.data import data_path

    if rig is None or not names:
        why = "no rig asked for" if rig is None else "the markers have no names to bind"
        return DenseFace(rest_markers, n_vertices, names or None), f"template head ({why})"
    from fxspace.face import LANDMARKS

    if sum(str(n).lower() in LANDMARKS for n in names) < 4:
        why = "fewer than 4 markers named as face landmarks (fx.face.LANDMARKS)"
        return DenseFace(rest_markers, n_vertices, names), f"template head ({why})"
    p = Path(rig)
    p = p if p.exists() else data_path(*Path(rig).parts)
    if not p.exists():
        return DenseFace(rest_markers, n_vertices, names), f"template head (no rig at {p})"
    try:
        from fxspace.face import read_rig

        face = RigFace(read_rig(p), rest_markers, names)
    except FxspaceError as e:
        return DenseFace(rest_markers, n_vertices, names), f"template head ({e})"
    return face, f"{p.name} head: {face.rig.num_shapes} shapes solved from the markers"
