"""Blend-shape rigs as data: a neutral mesh plus named shape deltas (ARKit, Unreal Live
Link, Blender shape keys, glTF morph targets, VRM all animate faces this way).

`read_rig` reads a folder of OBJ files (one neutral mesh, one mesh per named shape, the
ICT Face Model's layout; ``.obj`` or ``.obj.gz``; quads fanned into triangles, UVs kept)
or a glTF file's morph targets. The parsed arrays are kept in a content-keyed cache
(``$XDG_CACHE_HOME/fxspace/rigs``; the key is the SHA-256 of every file's bytes, so an
edited file is read again), so a second read of the ICT folder (~190 MB of OBJ text,
57 MB gzip) takes a fraction of a second.

A shape's delta is its vertices minus the neutral's; the mesh at weights ``w`` is
``neutral + Σ_k w_k deltas[k]``. In the ICT folder ``identity000`` … files are identity
modes (kept apart as ``identity``), ``vertex_indices.json`` gives the 68 Multi-PIE
landmarks as vertex indices (``vertex_sets["landmarks"]``) and the README's part ranges
give ``vertex_sets["face"]`` (the 9 409 face-area vertices), ``"eyes"``, ``"teeth"`` …

Example:

```python
rig = fx.face.read_rig(fx.data.data_path("face", "ict"))
rig.neutral.shape, rig.deltas.shape, rig.names[:3]   # (26719, 3) (53, 26719, 3) ('browDown_L', …)
V = rig.shape_vertices(weights)                       # (..., N, 3) at weights (..., K)
```
"""

from __future__ import annotations

import hashlib
import io
import json
import os
import re
import warnings
import zipfile
from pathlib import Path

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from fxspace._progress import progress
from fxspace.errors import CorruptFileError, FxspaceError
from fxspace.io import read_gltf_blendshapes, read_obj_mesh
from fxspace.runs import save_npz_atomic

__all__ = ["Rig", "read_rig", "rig_from_arrays", "rig_cache_dir", "ICT_PARTS"]

_CACHE_VERSION = "rig-3"  # rig-3: shape files the index does not list are left out

#: vertex ranges (inclusive, 0-indexed) of the ICT Face Model's parts (its README)
ICT_PARTS: dict[str, tuple[int, int]] = {
    "face": (0, 9408),
    "narrow_face": (0, 6705),
    "head_and_neck": (9409, 11247),
    "mouth_socket": (11248, 13293),
    "eye_sockets": (13294, 14061),
    "gums_and_tongue": (14062, 17038),
    "teeth": (17039, 21450),
    "eyes": (21451, 24590),
    "lacrimal_fluid": (24591, 24998),
    "eye_blend": (24999, 25046),
    "eye_occlusion": (25047, 25350),
    "eyelashes": (25351, 26718),
}
_ICT_VERTICES = 26719


class Rig(eqx.Module):
    """A blend-shape rig (a pytree).

    - ``neutral`` ``(N, 3)``: the neutral mesh, in the rig's units (ICT: centimetres);
    - ``deltas`` ``(K, N, 3)``: shape ``k``'s vertices minus the neutral's;
    - ``names`` (``K`` strings, static): the shapes' names (ARKit's for ICT);
    - ``faces`` ``(F, 3)``: triangles; ``uvs`` ``(U, 2)`` and ``face_uvs`` ``(F, 3)``
      texture coordinates where the source has them (else ``None``);
    - ``identity`` ``(I, N, 3)``: identity-mode deltas (``(0, N, 3)`` when none);
    - ``vertex_sets``: named vertex index arrays (``"landmarks"``: the 68 Multi-PIE
      points; ``"face"``: the face area; …).
    """

    neutral: Float[Array, "N 3"]
    deltas: Float[Array, "K N 3"]
    faces: Int[Array, "F 3"]
    identity: Float[Array, "I N 3"]
    vertex_sets: dict
    uvs: Float[Array, "U 2"] | None = None
    face_uvs: Int[Array, "F 3"] | None = None
    names: tuple[str, ...] = eqx.field(static=True, default=())

    @property
    def num_shapes(self) -> int:
        return int(self.deltas.shape[0])

    @property
    def num_vertices(self) -> int:
        return int(self.neutral.shape[0])

    def index(self, names) -> np.ndarray:
        """Indices of the shapes called ``names`` (an unknown name raises, listing some)."""
        pos = {n: i for i, n in enumerate(self.names)}
        missing = [n for n in names if n not in pos]
        if missing:
            raise FxspaceError(
                f"no shape called {missing[:5]} in this rig; its shapes: {list(self.names)[:8]} …"
            )
        return np.asarray([pos[n] for n in names], int)

    def shape_vertices(self, weights: Float[Array, "... K"]) -> Float[Array, "... N 3"]:
        """The mesh at expression weights ``weights`` (any leading axes)."""
        w = jnp.asarray(weights)
        d = jnp.einsum("...k,knc->...nc", w, self.deltas)
        return self.neutral.reshape((1,) * (d.ndim - 2) + self.neutral.shape) + d

    def face_triangles(self, part: str = "face") -> np.ndarray:
        """Indices of the triangles whose three corners are in ``vertex_sets[part]``
        (every triangle when the rig has no such set)."""
        F = np.asarray(self.faces)
        vs = self.vertex_sets.get(part)
        if vs is None:
            return np.arange(len(F))
        keep = np.zeros(self.num_vertices, bool)
        keep[np.asarray(vs)] = True
        return np.flatnonzero(keep[F].all(axis=1))


def rig_cache_dir() -> Path:
    """``$XDG_CACHE_HOME/fxspace/rigs`` (``~/.cache/fxspace/rigs`` without it)."""
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "fxspace" / "rigs"


def rig_from_arrays(
    neutral,
    deltas,
    names,
    faces,
    *,
    identity=None,
    vertex_sets: dict | None = None,
    uvs=None,
    face_uvs=None,
) -> Rig:
    """A `Rig` from arrays, checked: shapes agree, values finite, names unique."""
    V = np.asarray(neutral, np.float64)
    D = np.asarray(deltas, np.float64)
    F = np.asarray(faces, np.int64)
    if V.ndim != 2 or V.shape[1] != 3 or len(V) < 3:
        raise FxspaceError(f"neutral must be (N, 3) with N >= 3; got {V.shape}")
    N = len(V)
    if D.ndim != 3 or D.shape[1:] != (N, 3):
        raise FxspaceError(f"deltas must be (K, {N}, 3) like the neutral; got {D.shape}")
    names = tuple(str(n) for n in names)
    if len(names) != len(D):
        raise FxspaceError(f"names must have one entry per shape ({len(D)}); got {len(names)}")
    if len(set(names)) != len(names):
        dup = sorted({n for n in names if names.count(n) > 1})
        raise FxspaceError(f"shape names must be unique; repeated: {dup}")
    low: dict[str, str] = {}
    for n in names:  # weights travel by name, case-insensitively (transfer_weights)
        if n.lower() in low:
            raise FxspaceError(
                f"shape names {low[n.lower()]!r} and {n!r} differ only in case: both would "
                "take one weight when weights are matched by name; rename one"
            )
        low[n.lower()] = n
    if F.ndim != 2 or F.shape[1] != 3 or (len(F) and (F.min() < 0 or F.max() >= N)):
        raise FxspaceError(f"faces must be (F, 3) indices into the {N} vertices")
    for what, a in (("neutral", V), ("deltas", D)):
        if not np.all(np.isfinite(a)):
            raise FxspaceError(f"{what} contain NaN/inf; repair the mesh files")
    Id = np.zeros((0, N, 3)) if identity is None else np.asarray(identity, np.float64)
    if Id.ndim != 3 or Id.shape[1:] != (N, 3) or not np.all(np.isfinite(Id)):
        raise FxspaceError(f"identity must be finite (I, {N}, 3); got {Id.shape}")
    sets = {k: jnp.asarray(np.asarray(v, np.int64)) for k, v in (vertex_sets or {}).items()}
    return Rig(
        jnp.asarray(V),
        jnp.asarray(D),
        jnp.asarray(F),
        jnp.asarray(Id),
        sets,
        None if uvs is None else jnp.asarray(np.asarray(uvs, np.float64)),
        None if face_uvs is None else jnp.asarray(np.asarray(face_uvs, np.int64)),
        names,
    )


_OBJ = re.compile(r"^(?P<name>.+?)\.obj(\.gz)?$", re.I)
_IDENTITY = re.compile(r"^identity\d+$", re.I)


def _folder_files(folder: Path) -> tuple[Path, list[tuple[str, Path]], list[Path]]:
    objs: dict[str, Path] = {}
    for p in sorted(folder.iterdir()):
        m = _OBJ.match(p.name)
        if m and p.is_file():
            if m["name"] in objs:
                raise FxspaceError(
                    f"{folder}: {objs[m['name']].name} and {p.name} are both shape "
                    f"{m['name']!r}; keep one of them"
                )
            objs[m["name"]] = p
    if not objs:
        raise FxspaceError(
            f"{folder}: no .obj or .obj.gz files; a rig folder holds a neutral mesh "
            "(its name contains 'neutral') and one mesh per named shape"
        )
    neutral = [n for n in objs if "neutral" in n.lower()]
    if len(neutral) != 1:
        raise FxspaceError(
            f"{folder}: need exactly one neutral mesh (a file whose name contains "
            f"'neutral'); found {neutral or 'none'} among {list(objs)[:6]} …"
        )
    npath = objs.pop(neutral[0])
    ident = sorted(p for n, p in objs.items() if _IDENTITY.match(n))
    shapes = [(n, p) for n, p in objs.items() if not _IDENTITY.match(n)]
    return npath, shapes, ident


def _content_key(paths: list[Path], extra: str) -> str:
    h = hashlib.sha256(f"{_CACHE_VERSION}|{extra}".encode())
    for p in paths:
        h.update(p.name.encode() + b"\0")
        h.update(hashlib.sha256(p.read_bytes()).digest())
    return h.hexdigest()[:32]


def _read_folder(folder: Path, npath: Path, shapes, ident) -> dict:

    base = read_obj_mesh(npath)
    V = base.vertices
    _finite(V, npath)
    order = [n for n, _ in shapes]
    meta = folder / "vertex_indices.json"
    info = _vertex_indices(meta, len(V)) if meta.is_file() else {}
    if info.get("expressions"):
        # the rig's own list is the rig (ICT: the 53 ARKit-named shapes, in its order);
        # every listed shape must have its file, and a shape file the list lacks is left
        # out, and said (ICT's folder also holds PupilDilate_L/R, which the list leaves out)
        listed = list(info["expressions"])
        absent = [n for n in listed if n not in dict(shapes)]
        if absent:
            raise FxspaceError(
                f"{meta}: 'expressions' lists {absent[:5]} with no .obj/.obj.gz file in "
                f"{folder}; add the files or remove them from the list"
            )
        unlisted = [n for n in order if n not in set(listed)]
        if unlisted:
            more = ", …" if len(unlisted) > 6 else ""
            print(f"[fxspace] {folder.name}: {len(unlisted)} shape file(s) not in "
                  f"{meta.name}'s 'expressions' left out of the rig "
                  f"({', '.join(unlisted[:6])}{more}); list them there to use them")  # fmt: skip
        order = listed
    paths = dict(shapes)
    D = np.empty((len(order), len(V), 3))
    for k, name in enumerate(progress(order, desc=f"reading {folder.name} shapes")):
        D[k] = _shape(paths[name], base, npath) - V
    Id = np.empty((len(ident), len(V), 3))
    for i, p in enumerate(ident):
        Id[i] = _shape(p, base, npath) - V
    sets = {}
    if "idx_to_landmark_verts" in info:
        sets["landmarks"] = np.asarray(info["idx_to_landmark_verts"], np.int64)
    if "idx_to_rigid_verts" in info:
        sets["rigid"] = np.asarray(info["idx_to_rigid_verts"], np.int64)
    if len(V) == _ICT_VERTICES and info:
        for part, (a, b) in ICT_PARTS.items():
            sets[part] = np.arange(a, b + 1)
    # float32 storage (the files hold 6 digits): the cached and the parsed read agree
    f32 = np.float32
    out = {"neutral": V.astype(f32), "deltas": D.astype(f32), "names": np.asarray(order)}
    out["faces"], out["identity"] = base.faces.astype(np.int32), Id.astype(f32)
    if base.uvs is not None:
        out["uvs"], out["face_uvs"] = base.uvs.astype(f32), base.face_uvs.astype(np.int32)
    out.update({f"set:{k}": v for k, v in sets.items()})
    return out


def _finite(v: np.ndarray, path: Path) -> None:
    bad = np.flatnonzero(~np.all(np.isfinite(v), axis=1))
    if len(bad):
        raise CorruptFileError(
            f"{path}: {len(bad)} vertices hold NaN/inf (first: vertex {int(bad[0]) + 1}); "
            "repair or re-export this mesh"
        )


def _shape(path: Path, base, npath: Path) -> np.ndarray:
    """A shape's (or identity mode's) vertices, checked against the neutral: the same
    vertex count, finite, the same triangles (a file of vertices alone is accepted)."""
    m = read_obj_mesh(path, uvs=False)
    V = base.vertices
    if m.vertices.shape != V.shape:
        raise FxspaceError(
            f"{path}: {len(m.vertices)} vertices, the neutral {npath.name} has {len(V)}: "
            "every shape must share the neutral's topology"
        )
    _finite(m.vertices, path)
    # a shape file with no faces takes the neutral's; one with faces must have its faces
    if len(m.faces) and (m.faces.shape != base.faces.shape
                         or not np.array_equal(m.faces, base.faces)):  # fmt: skip
        raise FxspaceError(
            f"{path}: its triangles differ from the neutral {npath.name}'s (same vertex "
            "count, other faces): every shape must share the neutral's topology; "
            "re-export it from the same mesh"
        )
    return m.vertices


#: vertex_indices.json keys read, and what each must be
_INDEX_KEYS = ("expressions", "idx_to_landmark_verts", "idx_to_rigid_verts")


def _vertex_indices(meta: Path, n: int) -> dict:
    """The rig folder's ``vertex_indices.json``, checked: a JSON object whose
    ``expressions`` is a list of names and whose index lists are integers in ``[0, n)``
    (68 landmarks)."""
    try:
        info = json.loads(meta.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        where = f" at character {e.pos}" if isinstance(e, json.JSONDecodeError) else ""
        raise CorruptFileError(f"{meta}: not JSON ({type(e).__name__}{where})") from None
    if not isinstance(info, dict):
        raise CorruptFileError(
            f"{meta}: must be a JSON object with keys such as {list(_INDEX_KEYS)}; got a "
            f"{type(info).__name__}"
        )
    ex = info.get("expressions")
    if ex is not None and (not isinstance(ex, list) or not all(isinstance(x, str) for x in ex)
                           or len(set(ex)) != len(ex)):  # fmt: skip
        raise CorruptFileError(f"{meta}: 'expressions' must be a list of distinct shape names")
    for key in _INDEX_KEYS[1:]:
        if key not in info:
            continue
        a = info[key]
        ok = isinstance(a, list) and all(isinstance(i, int) and not isinstance(i, bool)
                                         for i in a)  # fmt: skip
        if not ok or not a or min(a) < 0 or max(a) >= n:
            raise CorruptFileError(
                f"{meta}: {key!r} must be a non-empty list of vertex indices in [0, {n})"
            )
    lm = info.get("idx_to_landmark_verts")
    if lm is not None and len(lm) != 68:
        raise CorruptFileError(
            f"{meta}: 'idx_to_landmark_verts' must list the 68 Multi-PIE landmarks; it has "
            f"{len(lm)}"
        )
    return info


def _from_npz(a) -> Rig:
    files = a.files if hasattr(a, "files") else list(a)
    sets = {k[4:]: a[k] for k in files if k.startswith("set:")}
    return rig_from_arrays(
        a["neutral"],
        a["deltas"],
        [str(n) for n in a["names"]],
        a["faces"],
        identity=a["identity"],
        vertex_sets=sets,
        uvs=a["uvs"] if "uvs" in files else None,
        face_uvs=a["face_uvs"] if "face_uvs" in files else None,
    )


def read_rig(path: str | Path, *, cache: bool = True) -> Rig:
    """Read a blend-shape rig: a folder of OBJ files (a neutral mesh, whose file name
    contains ``neutral``, and one mesh per named shape; ``identity<NNN>`` files are
    identity modes; ``.obj`` or ``.obj.gz``) or a ``.glb`` file's morph targets
    (``mesh.extras.targetNames`` name them).

    **Arguments:** `path`: the folder or ``.glb``; `cache`: keep the parsed arrays in
    the content-keyed cache (`rig_cache_dir`; the key hashes every file's bytes).

    **Returns:** a `Rig`. Errors name the file and the fix: an empty folder, no or two
    neutral meshes, a shape whose vertex count differs from the neutral's, NaN.
    """
    p = Path(path)
    if not p.exists():
        raise FxspaceError(
            f"{p}: no such rig folder or file; pass a folder of OBJ shapes or a .glb"
        )
    if p.is_file():
        if p.suffix.lower() not in (".glb",):
            raise FxspaceError(f"{p}: a rig is a folder of OBJ files or a .glb; got {p.suffix!r}")
        b = read_gltf_blendshapes(p)
        if len(b.deltas) == 0:
            raise FxspaceError(f"{p}: the first mesh has no morph targets (blend shapes)")
        return rig_from_arrays(b.neutral, b.deltas, b.names, b.faces)
    npath, shapes, ident = _folder_files(p)
    files = [npath, *[q for _, q in shapes], *ident]
    if (p / "vertex_indices.json").is_file():
        files.append(p / "vertex_indices.json")
    key = _content_key(files, "") if cache else None
    cpath = rig_cache_dir() / f"{key}.npz" if key else None
    if cpath is not None and cpath.is_file():
        try:
            with np.load(io.BytesIO(cpath.read_bytes()), allow_pickle=False) as a:
                return _from_npz(a)  # (from bytes: a torn entry leaves no file open)
        except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile):
            # a torn or damaged cache entry (FxspaceError is a ValueError too): read the
            # files again and rewrite it
            try:
                cpath.unlink(missing_ok=True)
            except OSError:
                pass
    arrays = _read_folder(p, npath, shapes, ident)
    if cpath is not None:
        try:
            cpath.parent.mkdir(parents=True, exist_ok=True)
            save_npz_atomic(cpath, **arrays)
        except OSError as e:  # an unwritable cache: the rig is read, just not kept
            warnings.warn(
                f"rig cache {cpath.parent} not writable ({type(e).__name__}): the rig is "
                "read again next time; set XDG_CACHE_HOME to a writable folder",
                stacklevel=2,
            )
    return _from_npz(arrays)
