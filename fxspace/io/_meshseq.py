"""Writers for animated triangle meshes (a vertex sequence over fixed triangles):
an OBJ or PLY file per frame, or one binary glTF (.glb) with one morph target per frame.

The glTF holds the first frame as the base positions, frame ``t``'s displacement from it as
morph target ``t`` and an animation whose weights step through the targets one-hot at
``fps`` (glTF 2.0 §3.7.2.2 morph targets, §3.11 ``weights`` animation path, STEP
interpolation).

Readers: `read_gltf_morph` loads such a .glb back (a static .glb mesh is one frame) and
`read_obj` a static OBJ mesh (polygons fanned into triangles), e.g. a user's character.
"""

from __future__ import annotations

import json
import struct
from pathlib import Path
from typing import NamedTuple

import numpy as np
from jaxtyping import Array, Float, Int

from fxspace._validate import checked
from fxspace.errors import CorruptFileError, FxspaceError
from fxspace.io._obj import read_obj_mesh
from fxspace.runs import write_bytes_atomic

__all__ = [
    "write_obj_sequence",
    "write_ply_sequence",
    "write_gltf_morph",
    "read_gltf_morph",
    "read_obj",
    "MorphAnimation",
    "write_gltf_blendshapes",
    "read_gltf_blendshapes",
    "BlendShapes",
]


def _check(vertices, faces) -> tuple[np.ndarray, np.ndarray]:
    V = np.asarray(vertices, dtype=np.float32)
    F = np.asarray(faces, dtype=np.int64)
    if V.ndim != 3 or V.shape[2] != 3 or len(V) < 1:
        raise FxspaceError(f"vertices must be (frames, N, 3); got {V.shape}")
    if F.ndim != 2 or F.shape[1] != 3 or (len(F) and (F.min() < 0 or F.max() >= V.shape[1])):
        raise FxspaceError(f"faces must be (F, 3) indices into {V.shape[1]} vertices")
    if not np.all(np.isfinite(V)):
        raise FxspaceError("vertices contain NaN/inf")
    return V, F


@checked
def write_obj_sequence(
    out_dir: str | Path, vertices: Float[Array, "T N 3"], faces: Int[Array, "F 3"],
    stem: str = "frame",
) -> list[Path]:
    """``stem_0000.obj`` … one Wavefront OBJ per frame (1-based face indices)."""
    V, F = _check(vertices, faces)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    ftxt = "".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in F)
    paths = []
    for t, v in enumerate(V):
        p = out / f"{stem}_{t:04d}.obj"
        vtxt = "".join(f"v {x:.6g} {y:.6g} {z:.6g}\n" for x, y, z in v)
        p.write_text(vtxt + ftxt)
        paths.append(p)
    return paths


@checked
def write_ply_sequence(
    out_dir: str | Path, vertices: Float[Array, "T N 3"], faces: Int[Array, "F 3"],
    stem: str = "frame",
) -> list[Path]:
    """``stem_0000.ply`` … one binary little-endian PLY per frame."""
    V, F = _check(vertices, faces)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    tri = np.empty(len(F), dtype=[("n", "u1"), ("i", "<i4", (3,))])
    tri["n"] = 3
    tri["i"] = F
    paths = []
    for t, v in enumerate(V):
        head = (
            "ply\nformat binary_little_endian 1.0\n"
            f"element vertex {len(v)}\nproperty float x\nproperty float y\nproperty float z\n"
            f"element face {len(F)}\nproperty list uchar int vertex_indices\nend_header\n"
        )
        p = out / f"{stem}_{t:04d}.ply"
        p.write_bytes(head.encode() + v.astype("<f4").tobytes() + tri.tobytes())
        paths.append(p)
    return paths


@checked
def write_gltf_morph(
    path: str | Path,
    vertices: Float[Array, "T N 3"],
    faces: Int[Array, "F 3"],
    fps: float = 30.0,
    name: str = "edited",
) -> Path:
    """One ``.glb``: base = frame 0, morph target ``t`` = frame ``t`` − frame 0, and an
    animation stepping the weights one-hot through the frames at ``fps``."""
    V, F = _check(vertices, faces)
    if not fps > 0:
        raise FxspaceError(f"fps must be > 0; got {fps}")
    T = len(V)
    return write_gltf_blendshapes(
        path, V[0], F, V - V[0], None, np.eye(T, dtype=np.float32), fps, name, "STEP"
    )


@checked
def write_gltf_blendshapes(
    path: str | Path,
    neutral: Float[Array, "N 3"],
    faces: Int[Array, "F 3"],
    deltas: Float[Array, "K N 3"],
    names=None,
    weights=None,
    fps: float = 30.0,
    name: str = "weights",
    interpolation: str = "LINEAR",
) -> Path:
    """One ``.glb`` of a blend-shape rig: the ``neutral`` ``(N, 3)`` mesh, one morph target
    per shape (``deltas`` ``(K, N, 3)``, named by ``names`` in ``mesh.extras.targetNames``,
    as Blender and three.js read them) and, with ``weights`` ``(T, K)``, an animation of
    the morph weights at ``fps`` (``LINEAR``, or ``STEP``)."""
    base = np.asarray(neutral, np.float32)
    D = np.asarray(deltas, np.float32)
    _, F = _check(base[None], faces)
    N = len(base)
    if D.ndim != 3 or D.shape[1:] != (N, 3):
        raise FxspaceError(f"deltas must be (K, {N}, 3) for this mesh; got {D.shape}")
    if not np.all(np.isfinite(D)):
        raise FxspaceError("deltas contain NaN/inf")
    K = len(D)
    if names is not None and len(names) != K:
        raise FxspaceError(f"names must have one entry per shape ({K}); got {len(names)}")
    W = None if weights is None else np.asarray(weights, np.float32)
    if W is not None and (W.ndim != 2 or W.shape[1] != K or len(W) < 1):
        raise FxspaceError(f"weights must be (frames, {K}); got {W.shape}")
    if W is not None and not np.all(np.isfinite(W)):
        raise FxspaceError("weights contain NaN/inf: fill or drop those frames first")
    if not fps > 0:
        raise FxspaceError(f"fps must be > 0; got {fps}")
    if interpolation not in ("LINEAR", "STEP"):
        raise FxspaceError(f"interpolation must be 'LINEAR' or 'STEP'; got {interpolation!r}")
    chunks: list[bytes] = []
    views, accessors = [], []

    def add(arr: np.ndarray, target: int | None, acc: dict) -> int:
        data = np.ascontiguousarray(arr).tobytes()
        off = sum(len(c) for c in chunks)
        chunks.append(data + b"\0" * ((-len(data)) % 4))
        view = {"buffer": 0, "byteOffset": off, "byteLength": len(data)}
        if target is not None:
            view["target"] = target
        views.append(view)
        accessors.append({"bufferView": len(views) - 1, **acc})
        return len(accessors) - 1

    def vec3(a: np.ndarray) -> dict:
        return {"componentType": 5126, "count": N, "type": "VEC3",
                "min": a.min(0).tolist(), "max": a.max(0).tolist()}  # fmt: skip

    pos = add(base, 34962, vec3(base))
    idx = add(F.astype("<u4").reshape(-1), 34963,
              {"componentType": 5125, "count": int(F.size), "type": "SCALAR"})  # fmt: skip
    targets = [{"POSITION": add(d, 34962, vec3(d))} for d in D]
    mesh: dict = {"primitives": [{"attributes": {"POSITION": pos}, "indices": idx,
                                  "targets": targets}]}  # fmt: skip
    if names is not None:
        mesh["extras"] = {"targetNames": [str(n) for n in names]}
    gltf: dict = {
        "asset": {"version": "2.0", "generator": "fxspace"},
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0, "name": "face"}],
        "meshes": [mesh],
    }
    if W is not None:
        mesh["weights"] = W[0].tolist()
        T = len(W)
        times = (np.arange(T) / fps).astype(np.float32)
        t_acc = add(times, None, {"componentType": 5126, "count": T, "type": "SCALAR",
                                  "min": [0.0], "max": [float(times[-1])]})  # fmt: skip
        w_acc = add(W.reshape(-1), None,
                    {"componentType": 5126, "count": T * K, "type": "SCALAR"})  # fmt: skip
        gltf["animations"] = [{"name": str(name), "samplers": [
            {"input": t_acc, "output": w_acc, "interpolation": interpolation}],
            "channels": [{"sampler": 0, "target": {"node": 0, "path": "weights"}}]}]  # fmt: skip
    else:
        mesh["weights"] = [0.0] * K
    gltf["buffers"] = [{"byteLength": sum(len(c) for c in chunks)}]
    gltf["bufferViews"] = views
    gltf["accessors"] = accessors
    js = json.dumps(gltf, separators=(",", ":")).encode()
    js += b" " * ((-len(js)) % 4)
    binary = b"".join(chunks)
    total = 12 + 8 + len(js) + 8 + len(binary)
    blob = (
        struct.pack("<4sII", b"glTF", 2, total)
        + struct.pack("<I4s", len(js), b"JSON") + js
        + struct.pack("<I4s", len(binary), b"BIN\0") + binary
    )  # fmt: skip
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    return write_bytes_atomic(p, blob)


class BlendShapes(NamedTuple):
    """A blend-shape mesh read from a ``.glb``: ``neutral`` ``(N, 3)``, ``faces``
    ``(F, 3)``, ``deltas`` ``(K, N, 3)`` (one per morph target), ``names`` (``K``, from
    ``mesh.extras.targetNames``, else ``target_0`` …), ``weights`` ``(T, K)`` of the first
    animation (``None`` when none) and its ``fps`` (0 when none)."""

    neutral: np.ndarray
    faces: np.ndarray
    deltas: np.ndarray
    names: tuple[str, ...]
    weights: np.ndarray | None
    fps: float


def _first_primitive(path: str | Path):
    """``(path, gltf, binary, mesh, positions, triangles, morph targets)`` of a ``.glb``'s
    first mesh primitive (the one home of that reading for both morph readers)."""
    p = Path(path)
    if not p.is_file():
        raise FxspaceError(f"{p}: no such file")
    gltf, binary = _glb_parts(p)
    try:
        gmesh = gltf["meshes"][0]
        prim = gmesh["primitives"][0]
        pos_i, idx_i = prim["attributes"]["POSITION"], prim["indices"]
    except (KeyError, IndexError, TypeError) as e:
        raise CorruptFileError(
            f"{p}: no mesh primitive with POSITION and indices ({e!r})"
        ) from None
    base = _accessor(gltf, binary, pos_i, p).astype(np.float64)
    F = _accessor(gltf, binary, idx_i, p).astype(np.int64).reshape(-1, 3)
    return p, gltf, binary, gmesh, base, F, prim.get("targets") or []


@checked
def read_gltf_blendshapes(path: str | Path) -> BlendShapes:
    """The first mesh primitive of a ``.glb`` with its morph targets as blend shapes
    (see `BlendShapes`). A damaged file raises `CorruptFileError` naming it."""
    p, gltf, binary, gmesh, base, F, targets = _first_primitive(path)
    D = (
        np.stack([_accessor(gltf, binary, t["POSITION"], p) for t in targets]).astype(np.float64)
        if targets
        else np.zeros((0,) + base.shape)
    )
    names = (gmesh.get("extras") or {}).get("targetNames") or [
        f"target_{k}" for k in range(len(targets))
    ]
    W, fps = None, 0.0
    for anim in gltf.get("animations") or []:
        for ch in anim.get("channels", []):
            if ch.get("target", {}).get("path") == "weights" and targets:
                smp = anim["samplers"][ch["sampler"]]
                times = _accessor(gltf, binary, smp["input"], p)
                W = _accessor(gltf, binary, smp["output"], p).reshape(len(times), len(targets))
                fps = float(1.0 / np.median(np.diff(times))) if len(times) > 1 else 0.0
                break
        if W is not None:
            break
    return BlendShapes(base, F, D, tuple(str(n) for n in names), W, fps)


class MorphAnimation(NamedTuple):
    """A vertex animation read back: ``vertices`` ``(T, N, 3)``, ``faces`` ``(F, 3)``,
    ``fps`` (0 for a static mesh), ``name`` of the animation ("" when none)."""

    vertices: np.ndarray
    faces: np.ndarray
    fps: float
    name: str


_COMPONENTS = {5126: "<f4", 5125: "<u4", 5123: "<u2", 5121: "u1"}
_WIDTH = {"SCALAR": 1, "VEC3": 3, "VEC4": 4}


def _glb_parts(p: Path) -> tuple[dict, bytes]:
    raw = p.read_bytes()
    if len(raw) < 20 or raw[:4] != b"glTF":
        raise CorruptFileError(f"{p}: not a binary glTF (.glb) file (no 'glTF' header)")
    (jlen,) = struct.unpack_from("<I", raw, 12)
    try:
        gltf = json.loads(raw[20 : 20 + jlen])
    except (UnicodeDecodeError, json.JSONDecodeError) as e:
        raise CorruptFileError(f"{p}: damaged glTF JSON chunk ({e})") from None
    off = 20 + jlen
    binary = raw[off + 8 :] if len(raw) >= off + 8 else b""
    return gltf, binary


def _accessor(gltf: dict, binary: bytes, i: int, p: Path) -> np.ndarray:
    try:
        acc = gltf["accessors"][i]
        view = gltf["bufferViews"][acc["bufferView"]]
        dt = np.dtype(_COMPONENTS[acc["componentType"]])
        width = _WIDTH[acc["type"]]
        start = view.get("byteOffset", 0) + acc.get("byteOffset", 0)
        a = np.frombuffer(binary, dt, acc["count"] * width, start)
    except (KeyError, IndexError, ValueError, TypeError) as e:
        raise CorruptFileError(f"{p}: damaged or unsupported accessor {i} ({e!r})") from None
    return a.reshape(acc["count"], width) if width > 1 else a


@checked
def read_gltf_morph(path: str | Path) -> MorphAnimation:
    """Read a .glb written by `write_gltf_morph` (or any .glb whose first mesh primitive
    has positions, triangle indices and optionally one morph target per frame): frame
    ``t`` = base + target ``t``. A damaged file raises `CorruptFileError` naming it."""
    p, gltf, binary, _, base, F, targets = _first_primitive(path)
    V = np.stack([base] + [base + _accessor(gltf, binary, t["POSITION"], p) for t in targets])
    V = V[1:] if targets else V
    fps, name = 0.0, ""
    anims = gltf.get("animations") or []
    if anims and targets:
        times = _accessor(gltf, binary, anims[0]["samplers"][0]["input"], p)
        fps = float(1.0 / np.median(np.diff(times))) if len(times) > 1 else 0.0
        name = str(anims[0].get("name", ""))
    return MorphAnimation(V, F, fps, name)


@checked
def read_obj(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """``(vertices (N, 3), faces (F, 3))`` of a static OBJ mesh (``.obj`` or ``.obj.gz``);
    polygons are fanned into triangles (`fxspace.io.read_obj_mesh` keeps the texture
    coordinates too). A malformed file raises `CorruptFileError` naming it."""
    m = read_obj_mesh(path)
    return m.vertices, m.faces
