"""Skinned glTF 2.0 meshes (``.glb`` / ``.gltf``) → `SkinnedMesh`.

Reads, with ``pygltflib``, everything linear blend skinning needs: bind-pose vertices,
triangles, the joint hierarchy (in an order where every parent precedes its children),
the joints' rest transforms (translation / rotation quaternion / scale), the inverse
bind matrices, the joint indices and weights per vertex (``JOINTS_n`` / ``WEIGHTS_n``,
4 per set), and the animations (translation / rotation / scale channels, ``LINEAR``,
``STEP`` or ``CUBICSPLINE``), which can be sampled at any time.

Posed vertices of an animation at given times (the stable entry point other code relies
on)::

    mesh = fx.io.read_gltf("CesiumMan.glb")
    V = fx.mesh.animation_vertices(mesh, "Anim_0", np.linspace(0.0, 1.0, 30))  # (30, V, 3)

The skinning follows the glTF specification: a vertex ``v`` is posed as
``Σ_i w_i · G_{j_i} · IBM_{j_i} · v`` where ``G_j`` is joint ``j``'s global (scene)
transform; the transform of the mesh's own node is ignored, as the specification says.
Animation channels on nodes that are not joints of the skin (and morph-target
``weights`` channels) are ignored.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from fxspace._validate import check_readable, checked
from fxspace.errors import CorruptFileError, FxspaceError
from fxspace.mesh import Animation, AnimationChannel, LocalPose, SkinnedMesh
from fxspace.rotations import matrix_to_quat, quat_normalize, quat_to_matrix

__all__ = ["SkinnedMesh", "Animation", "AnimationChannel", "LocalPose", "read_gltf"]

_COMPONENT = {
    5120: np.int8,
    5121: np.uint8,
    5122: np.int16,
    5123: np.uint16,
    5125: np.uint32,
    5126: np.float32,
}
_NCOMP = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}


# ----------------------------------------------------------------------------- reading


def _node_trs(node) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(translation, quaternion, scale, 4x4 matrix) of a node (matrix nodes decomposed)."""
    if node.matrix is not None and len(node.matrix) == 16:
        m = np.asarray(node.matrix, dtype=np.float64).reshape(4, 4).T  # column-major
        t = m[:3, 3].copy()
        lin = m[:3, :3]
        s = np.linalg.norm(lin, axis=0)
        if np.linalg.det(lin) < 0:
            s[0] = -s[0]
        r = lin / np.where(s == 0, 1.0, s)
        q = matrix_to_quat(r, order="xyzw")
        return t, q, s, m
    t = np.asarray(node.translation if node.translation else (0.0, 0.0, 0.0), dtype=np.float64)
    q = np.asarray(node.rotation if node.rotation else (0.0, 0.0, 0.0, 1.0), dtype=np.float64)
    q = quat_normalize(q)
    s = np.asarray(node.scale if node.scale else (1.0, 1.0, 1.0), dtype=np.float64)
    m = np.eye(4)
    m[:3, :3] = quat_to_matrix(q, order="xyzw") * s[None, :]
    m[:3, 3] = t
    return t, q, s, m


class _Reader:
    def __init__(self, path: Path):
        import pygltflib

        self.path = check_readable(path, "glTF file")  # a permission error is not "corrupt"
        try:
            self.g = pygltflib.GLTF2().load(str(path))
        except Exception as e:  # pygltflib raises assorted errors on bad input
            raise CorruptFileError(f"{path}: not a readable glTF 2.0 file ({e})") from e
        if self.g is None:
            raise CorruptFileError(f"{path}: not a readable glTF 2.0 file")
        self._buffers: dict[int, bytes] = {}

    def buffer(self, i: int) -> bytes:
        if i not in self._buffers:
            b = self.g.buffers[i]
            if b.uri is None:
                data = self.g.binary_blob()
            elif b.uri.startswith("data:"):
                import base64

                data = base64.b64decode(b.uri.split(",", 1)[1])
            else:
                p = self.path.parent / b.uri
                if not p.is_file():
                    raise CorruptFileError(f"{self.path}: external buffer {b.uri!r} not found")
                data = p.read_bytes()
            if data is None:
                raise CorruptFileError(f"{self.path}: buffer {i} has no data")
            self._buffers[i] = data
        return self._buffers[i]

    def accessor(self, i: int) -> np.ndarray:
        """Accessor ``i`` as a (count, ncomp) float64 or int array (normalised ints scaled)."""
        g = self.g
        try:
            a = g.accessors[i]
            dtype = np.dtype(_COMPONENT[a.componentType]).newbyteorder("<")
            nc = _NCOMP[a.type]
        except (IndexError, KeyError, TypeError) as e:
            raise CorruptFileError(f"{self.path}: bad accessor {i} ({e})") from e
        if a.bufferView is None:
            arr = np.zeros((a.count, nc), dtype=dtype)
        else:
            bv = g.bufferViews[a.bufferView]
            data = self.buffer(bv.buffer)
            start = (bv.byteOffset or 0) + (a.byteOffset or 0)
            elem = dtype.itemsize * nc
            stride = bv.byteStride or elem
            need = start + stride * (a.count - 1) + elem if a.count else start
            if need > len(data) or (bv.byteOffset or 0) + bv.byteLength > len(data):
                raise CorruptFileError(
                    f"{self.path}: accessor {i} reads past the end of its buffer (truncated file?)"
                )
            raw = np.frombuffer(data, dtype=np.uint8, count=need - start, offset=start)
            if stride == elem:
                arr = raw[: a.count * elem].view(dtype).reshape(a.count, nc)
            else:
                rows = np.lib.stride_tricks.as_strided(
                    raw, shape=(a.count, elem), strides=(stride, 1)
                )
                arr = np.ascontiguousarray(rows).view(dtype).reshape(a.count, nc)
        if a.sparse is not None:
            arr = arr.copy()
            sp = a.sparse
            idx_bv = g.bufferViews[sp.indices.bufferView]
            val_bv = g.bufferViews[sp.values.bufferView]
            idt = np.dtype(_COMPONENT[sp.indices.componentType]).newbyteorder("<")
            idx = np.frombuffer(
                self.buffer(idx_bv.buffer),
                dtype=idt,
                count=sp.count,
                offset=(idx_bv.byteOffset or 0) + (sp.indices.byteOffset or 0),
            )
            vals = np.frombuffer(
                self.buffer(val_bv.buffer),
                dtype=dtype,
                count=sp.count * nc,
                offset=(val_bv.byteOffset or 0) + (sp.values.byteOffset or 0),
            ).reshape(sp.count, nc)
            arr[idx.astype(np.int64)] = vals
        if np.issubdtype(dtype, np.integer):
            if a.normalized:
                info = np.iinfo(dtype)
                out = arr.astype(np.float64) / info.max
                return np.maximum(out, -1.0) if info.min < 0 else out
            return arr.astype(np.int64)
        return arr.astype(np.float64)


def _select_skinned_node(g, path: Path, mesh: str | int | None) -> int:
    cands = [i for i, n in enumerate(g.nodes) if n.mesh is not None and n.skin is not None]
    if not cands:
        raise FxspaceError(f"{path}: no skinned mesh (a node with both 'mesh' and 'skin')")
    if mesh is None:
        if len(cands) > 1:
            names = [g.nodes[i].name or g.meshes[g.nodes[i].mesh].name or str(i) for i in cands]
            raise FxspaceError(
                f"{path}: {len(cands)} skinned mesh nodes {names}; pass mesh=<node name or "
                "index> to read_gltf to choose one"
            )
        return cands[0]
    for i in cands:
        n = g.nodes[i]
        if mesh in (i, n.name, g.meshes[n.mesh].name):
            return i
    raise FxspaceError(f"{path}: no skinned mesh node {mesh!r}; candidates: {cands}")


@checked
def read_gltf(path: str | Path, mesh: str | int | None = None) -> SkinnedMesh:
    """Read a skinned mesh, its skeleton and its animations from a ``.glb``/``.gltf`` file.

    **Arguments:**

    - `path`: the glTF 2.0 file (binary ``.glb`` or JSON ``.gltf`` with its buffers).
    - `mesh`: which skinned mesh node (name or node index) when the file holds several.

    All triangle primitives of the mesh are merged into one vertex/triangle list (each
    needs ``POSITION``, ``JOINTS_0`` and ``WEIGHTS_0``); a primitive that is not made of
    triangles (points, lines, strips, fans) is refused with a clear message, as is a
    skeleton with a non-joint node between two joints.

    **Returns:** a `SkinnedMesh`.
    """
    path = Path(path)
    if path.is_dir():
        raise IsADirectoryError(f"read_gltf: {path} is a directory, not a glTF file")
    if not path.is_file():
        raise FxspaceError(f"read_gltf: {path} does not exist")
    r = _Reader(path)
    g = r.g
    node_i = _select_skinned_node(g, path, mesh)
    node = g.nodes[node_i]
    gmesh = g.meshes[node.mesh]
    skin = g.skins[node.skin]
    skin_nodes = list(skin.joints)
    if not skin_nodes:
        raise CorruptFileError(f"{path}: skin {node.skin} has no joints")

    vertices, tris, skin_joints, skin_weights = _read_primitives(r, gmesh, len(skin_nodes), path)
    sk = _read_skeleton(r, skin, skin_nodes, path)
    skin_joints = sk["new_of_old"][skin_joints].astype(np.int32)
    anims = _read_animations(r, sk["joint_nodes"], path)
    names = tuple(g.nodes[n].name or f"joint{n}" for n in sk["joint_nodes"])
    return SkinnedMesh(
        name=path.stem,
        vertices=vertices,
        faces=tris,
        joint_names=names,
        joint_nodes=sk["joint_nodes"],
        parents=sk["parents"],
        rest_translations=sk["rest_t"],
        rest_rotations=sk["rest_q"],
        rest_scales=sk["rest_s"],
        base_transforms=sk["base"],
        inverse_bind=sk["ibm"],
        skin_joints=skin_joints,
        skin_weights=skin_weights,
        animations=anims,
    )


def _read_primitives(r: _Reader, gmesh, n_joints: int, path: Path):
    """All triangle primitives merged: vertices, faces, joint indices and weights."""
    # -- primitives → one vertex / triangle list
    verts, faces, sj, sw = [], [], [], []
    offset = 0
    for pi, prim in enumerate(gmesh.primitives):
        mode = 4 if prim.mode is None else prim.mode
        if mode != 4:
            kind = {
                0: "POINTS",
                1: "LINES",
                2: "LINE_LOOP",
                3: "LINE_STRIP",
                5: "TRIANGLE_STRIP",
                6: "TRIANGLE_FAN",
            }.get(mode, str(mode))
            raise FxspaceError(
                f"{path}: mesh {gmesh.name!r} primitive {pi} has mode {kind}; only TRIANGLES "
                "primitives are supported (re-export the mesh triangulated)"
            )
        at = prim.attributes
        if at.POSITION is None or at.JOINTS_0 is None or at.WEIGHTS_0 is None:
            raise FxspaceError(
                f"{path}: mesh {gmesh.name!r} primitive {pi} lacks POSITION/JOINTS_0/WEIGHTS_0; "
                "every primitive of a skinned mesh needs all three"
            )
        pos = r.accessor(at.POSITION)
        nv = pos.shape[0]
        js, ws = [], []
        k = 0
        while True:
            ja = getattr(at, f"JOINTS_{k}", None)
            wa = getattr(at, f"WEIGHTS_{k}", None)
            if ja is None or wa is None:
                break
            js.append(r.accessor(ja))
            ws.append(r.accessor(wa))
            k += 1
        jj = np.concatenate(js, axis=1).astype(np.int64)
        ww = np.concatenate(ws, axis=1).astype(np.float64)
        if jj.shape[0] != nv or ww.shape[0] != nv:
            raise CorruptFileError(f"{path}: primitive {pi} attribute counts differ")
        if prim.indices is not None:
            idx = r.accessor(prim.indices).reshape(-1)
        else:
            idx = np.arange(nv)
        if idx.size % 3:
            raise CorruptFileError(
                f"{path}: primitive {pi} index count {idx.size} not a multiple of 3"
            )
        if idx.size and (idx.min() < 0 or idx.max() >= nv):
            raise CorruptFileError(f"{path}: primitive {pi} indices out of range")
        verts.append(pos)
        faces.append(idx.reshape(-1, 3) + offset)
        sj.append(jj)
        sw.append(ww)
        offset += nv
    width = max(a.shape[1] for a in sj)
    sj = [np.pad(a, ((0, 0), (0, width - a.shape[1]))) for a in sj]
    sw = [np.pad(a, ((0, 0), (0, width - a.shape[1]))) for a in sw]
    vertices = np.concatenate(verts, axis=0)
    tris = np.concatenate(faces, axis=0).astype(np.int32)
    skin_joints = np.concatenate(sj, axis=0)
    skin_weights = np.concatenate(sw, axis=0)
    if skin_joints.size and (skin_joints.min() < 0 or skin_joints.max() >= n_joints):
        raise CorruptFileError(f"{path}: JOINTS_n refer to joints outside the skin")
    skin_weights = np.where(skin_weights > 0, skin_weights, 0.0)
    wsum = skin_weights.sum(axis=1, keepdims=True)
    if np.any(wsum <= 0):
        raise CorruptFileError(f"{path}: {int(np.sum(wsum <= 0))} vertices have zero skin weight")
    skin_weights = skin_weights / wsum

    return vertices, tris, skin_joints, skin_weights


def _read_skeleton(r: _Reader, skin, skin_nodes: list, path: Path) -> dict:
    """Parents (parents first), rest transforms, base transforms and inverse binds."""
    g = r.g
    # -- skeleton: parents, topological order, base transforms
    parent_node = {}
    for i, n in enumerate(g.nodes):
        for c in n.children or []:
            parent_node[c] = i
    trs = [_node_trs(n) for n in g.nodes]

    def global_of(i: int) -> np.ndarray:
        m = trs[i][3]
        while i in parent_node:
            i = parent_node[i]
            m = trs[i][3] @ m
        return m

    jset = {n: k for k, n in enumerate(skin_nodes)}
    parent_skin = np.full(len(skin_nodes), -1, dtype=np.int64)
    base = np.tile(np.eye(4), (len(skin_nodes), 1, 1))
    for k, n in enumerate(skin_nodes):
        p = parent_node.get(n)
        if p is None:
            continue
        if p in jset:
            parent_skin[k] = jset[p]
            continue
        # p is not a joint: every node above must also not be a joint
        q = p
        while q in parent_node:
            q = parent_node[q]
            if q in jset:
                raise FxspaceError(
                    f"{path}: node {g.nodes[p].name or p!r} between joints "
                    f"{g.nodes[q].name or q!r} and {g.nodes[n].name or n!r} is not a joint of "
                    "the skin; re-export with it added to the skin's joints"
                )
        base[k] = global_of(p)
    # order: keep the file's order when parents already come first, else sort by depth
    depth = np.zeros(len(skin_nodes), dtype=np.int64)
    for k in range(len(skin_nodes)):
        q = parent_skin[k]
        seen = 0
        while q >= 0:
            depth[k] += 1
            q = parent_skin[q]
            seen += 1
            if seen > len(skin_nodes):
                raise CorruptFileError(f"{path}: the joint hierarchy has a cycle")
    if np.all(parent_skin < np.arange(len(skin_nodes))):
        order = np.arange(len(skin_nodes))
    else:
        order = np.argsort(depth, kind="stable")
    new_of_old = np.empty_like(order)
    new_of_old[order] = np.arange(order.size)
    parents = np.array(
        [new_of_old[parent_skin[o]] if parent_skin[o] >= 0 else -1 for o in order], dtype=np.int32
    )
    joint_nodes = tuple(int(skin_nodes[o]) for o in order)
    rest_t = np.stack([trs[n][0] for n in joint_nodes])
    rest_q = np.stack([trs[n][1] for n in joint_nodes])
    rest_s = np.stack([trs[n][2] for n in joint_nodes])
    base = base[order]
    if skin.inverseBindMatrices is not None:
        ibm = r.accessor(skin.inverseBindMatrices).reshape(-1, 4, 4).transpose(0, 2, 1)
        if ibm.shape[0] != len(skin_nodes):
            raise CorruptFileError(
                f"{path}: {ibm.shape[0]} inverse bind matrices for {len(skin_nodes)} joints"
            )
        ibm = ibm[order]
    else:
        ibm = np.tile(np.eye(4), (len(skin_nodes), 1, 1))

    return dict(
        new_of_old=new_of_old,
        joint_nodes=joint_nodes,
        parents=parents,
        rest_t=rest_t,
        rest_q=rest_q,
        rest_s=rest_s,
        base=base,
        ibm=ibm,
    )


def _read_animations(r: _Reader, joint_nodes: tuple, path: Path) -> dict[str, Animation]:
    """The translation / rotation / scale channels on the skin's joints, per animation."""
    g = r.g
    # -- animations
    node_to_joint = {n: k for k, n in enumerate(joint_nodes)}
    anims: dict[str, Animation] = {}
    for ai, a in enumerate(g.animations or []):
        chans = []
        for c in a.channels:
            tgt = c.target
            if tgt.node not in node_to_joint or tgt.path not in (
                "translation",
                "rotation",
                "scale",
            ):
                continue
            smp = a.samplers[c.sampler]
            interp = smp.interpolation or "LINEAR"
            if interp not in ("LINEAR", "STEP", "CUBICSPLINE"):
                raise CorruptFileError(f"{path}: unknown interpolation {interp!r}")
            times = r.accessor(smp.input).reshape(-1)
            vals = r.accessor(smp.output).astype(np.float64)
            nc = 4 if tgt.path == "rotation" else 3
            if interp == "CUBICSPLINE":
                vals = vals.reshape(times.shape[0], 3, nc)
            else:
                vals = vals.reshape(times.shape[0], nc)
            if times.shape[0] == 0 or np.any(np.diff(times) < 0):
                raise CorruptFileError(
                    f"{path}: animation {a.name or ai!r} has empty or decreasing key times"
                )
            if tgt.path == "rotation" and interp != "CUBICSPLINE":
                vals = quat_normalize(vals)
            chans.append(AnimationChannel(node_to_joint[tgt.node], tgt.path, times, vals, interp))
        name = a.name or f"animation_{ai}"
        if name in anims:
            name = f"{name}_{ai}"
        anims[name] = Animation(name, tuple(chans))

    return anims
