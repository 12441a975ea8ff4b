"""Writers for animated triangle meshes (a vertex sequence over fixed triangles):
an OBJ or PLY file per frame, or one binary glTF (.glb) with one morph target per frame.

The glTF holds the first frame as the base positions, frame ``t``'s displacement from it as
morph target ``t`` and an animation whose weights step through the targets one-hot at
``fps`` (glTF 2.0 §3.7.2.2 morph targets, §3.11 ``weights`` animation path, STEP
interpolation).
"""

from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np

from fxspace.errors import FxspaceError

__all__ = ["write_obj_sequence", "write_ply_sequence", "write_gltf_morph"]


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


def write_obj_sequence(out_dir: str | Path, vertices, faces, stem: str = "frame") -> list[Path]:
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


def write_ply_sequence(out_dir: str | Path, vertices, faces, stem: str = "frame") -> list[Path]:
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


def write_gltf_morph(path: str | Path, vertices, faces, fps: float = 30.0) -> Path:
    """One ``.glb``: base = frame 0, morph target ``t`` = frame ``t`` − frame 0, and an
    animation stepping the weights one-hot through the frames at ``fps``."""
    V, F = _check(vertices, faces)
    if not fps > 0:
        raise FxspaceError(f"fps must be > 0; got {fps}")
    T, N, _ = V.shape
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

    base = V[0]
    pos = add(base, 34962, vec3(base))
    idx = add(F.astype("<u4").reshape(-1), 34963,
              {"componentType": 5125, "count": int(F.size), "type": "SCALAR"})  # fmt: skip
    targets = []
    for t in range(T):
        d = (V[t] - base).astype(np.float32)
        targets.append({"POSITION": add(d, 34962, vec3(d))})
    times = (np.arange(T) / fps).astype(np.float32)
    t_acc = add(times, None, {"componentType": 5126, "count": T, "type": "SCALAR",
                              "min": [0.0], "max": [float(times[-1])]})  # fmt: skip
    w_acc = add(np.eye(T, dtype=np.float32).reshape(-1), None,
                {"componentType": 5126, "count": T * T, "type": "SCALAR"})  # fmt: skip
    gltf = {
        "asset": {"version": "2.0", "generator": "fxspace"},
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0, "name": "face"}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": pos}, "indices": idx,
                                    "targets": targets}],
                    "weights": [1.0] + [0.0] * (T - 1)}],
        "animations": [{"name": "edited", "samplers": [
            {"input": t_acc, "output": w_acc, "interpolation": "STEP"}],
            "channels": [{"sampler": 0, "target": {"node": 0, "path": "weights"}}]}],
        "buffers": [{"byteLength": sum(len(c) for c in chunks)}],
        "bufferViews": views,
        "accessors": accessors,
    }  # fmt: skip
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
    tmp = p.with_name(p.name + ".tmp")
    tmp.write_bytes(blob)
    tmp.replace(p)
    return p
