"""Retargeting a skeleton motion onto a skinned character through the mesh IK (Park, Kang
& Kwon's solver; Ha & Han's synthesised motion driving a character).

The source's joints are matched to the character's joints (a correspondence list; the
joint-name map `fxspace.motion.joint_map_for` builds one from CMU, Bandai, Mixamo, VRM,
… and CesiumMan names), the source is scaled to the character's height (the skeleton
path from its highest corresponded joint to its lowest, head to toes, both skeletons'
bone lengths: no rest pose needed) and put on the character's floor (both Y-up; the
source's world trajectory is kept). The character's joint origins are the IK "markers" (skinned
points with weight 1 on their joint); `_track` solves frame by frame, warm-started from
the previous frame (the first frame from the rotation copy), with

- **feet on the floor**: where a source foot/toe joint is in contact (low and slow), the
  character's joint is held at one planted spot (the contact's mean position) and on the
  floor plane at its rest height (`plane_contact`), both per frame;
- **joint limits** (`joint_limits`) and a weak prior towards the rest pose (the twist of
  a bone about its own axis is not seen by joint positions).

The baseline in the same call is plain rotation copying: each character joint takes its
source joint's world rotation through the rest poses (``R_c = R_s Q R_c,rest``, ``Q``
turning the character's rest bones onto the source's), the hips placed on the scaled
source's.

This module takes the motion by its arrays (``names``, ``parents``, ``offsets``,
``root_translation``, ``rotations`` in ``(w, x, y, z)``, ``rate``): `fxspace.mesh` does not
import `fxspace.motion` (the import-linter contracts keep the two independent).
"""

from __future__ import annotations

import re
import time
from collections.abc import Mapping, Sequence
from functools import partial
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from fxspace.errors import FxspaceError
from fxspace.mesh._ik_constraints import (
    IKConstraints,
    PlaneContact,
    joint_limits,
    joint_prior,
)
from fxspace.mesh._ik_model import ik_model
from fxspace.mesh._ik_solvers import LevenbergMarquardt, _pick_solver, _solve
from fxspace.mesh._markers import MarkerSet
from fxspace.mesh._skinning import Pose
from fxspace.results import RESULTS
from fxspace.rigid import fit_rotation
from fxspace.rotations import quat_normalize, quat_to_matrix

__all__ = [
    "Retargeted",
    "RetargetError",
    "retarget",
    "joint_positions",
    "LiveRetarget",
    "live_retarget",
]


class RetargetError(FxspaceError):
    """A motion or joint map that cannot be retargeted (names, shapes, too few pairs)."""


class Retargeted(NamedTuple):
    """A take retargeted onto a character (`fxspace.mesh.retarget`).

    - ``pose``: the character's per-frame `Pose` (``angles (T, J, 3)`` XYZ Euler angles
      relative to the rest rotations, ``translation (T, 3)``: the form `solve_ik`,
      `pose_vertices` and `fxspace.io.write_gltf_animation` take);
    - ``joint_error``: ``(T,)`` mean distance of the corresponded character joints from
      the scaled source joints, in character heights;
    - ``foot_slide``: ``(T,)`` mean horizontal motion of the character's foot joints that
      are in contact, per frame, in character heights (NaN where no foot is in contact);
    - ``source_foot_slide``: the same for the scaled source's own joints;
    - ``result``: a `fxspace.RESULTS` member for the take (``successful``;
      ``nonfinite_input`` when source frames hold NaN; ``poor_fit`` when the median joint
      error exceeds ``max_error``);
    - ``frame_results``: the per-frame IK results;
    - ``ms_per_frame``: solve time per frame (compilation excluded), and ``compile_s``;
    - ``correspondences``: ``(source joint, character joint)`` pairs used;
    - ``targets``: ``(T, M, 3)`` scaled source joints in the character's space (metres);
    - ``joints``: ``(T, M, 3)`` the character's corresponded joints at ``pose``;
    - ``contacts``: ``(T, M)`` the source's contacts (foot/toe joints only);
    - ``height``: the character's height (m); ``scale``: source → character factor;
    - ``rate``: frames per second; ``method``: ``"mesh_ik"`` or ``"rotation_copy"``;
    - ``baseline``: the rotation-copy record of the same take (``None`` inside it).
    """

    pose: Pose
    joint_error: np.ndarray
    foot_slide: np.ndarray
    source_foot_slide: np.ndarray
    result: Any
    frame_results: Any
    ms_per_frame: float
    compile_s: float
    correspondences: tuple[tuple[str, str], ...]
    targets: np.ndarray
    joints: np.ndarray
    contacts: np.ndarray
    height: float
    scale: float
    rate: float
    method: str
    baseline: Retargeted | None = None

    def summary(self) -> dict[str, float]:
        """Take-level figures: median joint error and mean foot slides (character
        heights per frame), ms per frame."""
        fs, ss = self.foot_slide, self.source_foot_slide
        return {
            "joint_error_median": float(np.nanmedian(self.joint_error)),
            "foot_slide_mean": float(np.nanmean(fs)) if np.isfinite(fs).any() else np.nan,
            "source_foot_slide_mean": float(np.nanmean(ss)) if np.isfinite(ss).any() else np.nan,
            "ms_per_frame": float(self.ms_per_frame),
        }


# ------------------------------------------------------------------------------ inputs

_MOTION_FIELDS = ("names", "parents", "offsets", "root_translation", "rotations")
_FOOT = re.compile(r"(foot|toe|ankle|ball)", re.IGNORECASE)


def _norm(name: str) -> str:
    s = re.split(r"[:|]", str(name))[-1]
    return re.sub(r"[^0-9a-z]", "", s.lower())


def _motion_arrays(motion):
    miss = [f for f in _MOTION_FIELDS if not hasattr(motion, f)]
    if miss:
        raise RetargetError(
            f"motion must be a skeletal motion (fx.io.read_bvh / read_amc, a session's "
            f"Motion) with {list(_MOTION_FIELDS)}; got {type(motion).__name__} lacking {miss}"
        )
    names = tuple(str(n) for n in motion.names)
    parents = np.asarray(motion.parents, np.int64)
    off = np.asarray(motion.offsets, np.float64)
    root = np.asarray(motion.root_translation, np.float64)
    rot = np.asarray(motion.rotations, np.float64)
    nj = len(names)
    if (
        parents.shape != (nj,)
        or off.shape != (nj, 3)
        or rot.ndim != 3
        or rot.shape[1:] != (nj, 4)
        or root.shape != (rot.shape[0], 3)
        or rot.shape[0] < 1
    ):
        raise RetargetError(
            f"motion arrays disagree: {nj} names, parents {parents.shape}, offsets "
            f"{off.shape}, root_translation {root.shape}, rotations {rot.shape} (want "
            "(J,), (J, 3), (T, 3), (T, J, 4), T ≥ 1)"
        )
    if np.any(parents >= np.arange(nj)):
        raise RetargetError("motion.parents must list parents first (parents[j] < j)")
    rate = float(getattr(motion, "rate", 30.0) or 30.0)
    return names, parents, off, root, rot, rate


def _pairs(joint_map, src_names, char_names) -> tuple[list[tuple[str, str]], list[str]]:
    """``[(source joint, character joint)]`` and the roles (``""`` when unknown)."""
    if joint_map is None:  # the one joint-name map (CMU, Bandai, Mixamo, VRM, CesiumMan...)
        from fxspace.joints import JointMapError, joint_map_for

        try:
            return _pairs(joint_map_for, src_names, char_names)
        except (JointMapError, RetargetError):
            pass  # names the map does not know: pair the joints of the same name
        cn = {_norm(n): n for n in char_names}
        pairs = [(s, cn[_norm(s)]) for s in src_names if _norm(s) in cn]
        if len(pairs) < 4:
            raise RetargetError(
                f"joint_map: the source's and the character's joint names share only "
                f"{len(pairs)} names; pass joint_map=fx.motion.joint_map_for (CMU, Bandai, "
                "Mixamo, VRM, CesiumMan names) or {source joint: character joint}"
            )
        return pairs, [""] * len(pairs)
    if callable(joint_map) and not hasattr(joint_map, "correspondences"):
        # a resolver such as fx.motion.joint_map_for: names → a map with .correspondences
        try:
            joint_map = joint_map(src_names).correspondences(joint_map(char_names, required=()))
        except (TypeError, AttributeError) as e:
            raise RetargetError(
                "joint_map: a callable must resolve joint names to a joint map with "
                f".correspondences (fx.motion.joint_map_for); it failed: {e}"
            ) from None
    if isinstance(joint_map, tuple) and len(joint_map) == 2 and all(
        hasattr(m, "correspondences") for m in joint_map
    ):
        joint_map = joint_map[0].correspondences(joint_map[1])
    if hasattr(joint_map, "correspondences"):
        raise RetargetError(
            "joint_map: a single JointMap names only one skeleton; pass (source map, "
            "character map) or source_map.correspondences(character_map)"
        )
    if isinstance(joint_map, Mapping):
        items = [(k, v) for k, v in joint_map.items()]
    elif isinstance(joint_map, Sequence) and not isinstance(joint_map, str):
        items = list(joint_map)
    else:
        raise RetargetError(
            "joint_map must be None, {source joint: character joint}, a list of (source, "
            f"character) or (role, source, character) tuples, got {type(joint_map).__name__}"
        )
    pairs, roles = [], []
    for it in items:
        if not isinstance(it, tuple | list) or len(it) not in (2, 3):
            raise RetargetError(f"joint_map entry {it!r} must be (source, character) names")
        role, s, c = ("", *it) if len(it) == 2 else it
        if s not in src_names:
            raise RetargetError(f"joint_map: {s!r} is no joint of the source; joints are "
                                f"{list(src_names)}")  # fmt: skip
        if c not in char_names:
            raise RetargetError(f"joint_map: {c!r} is no joint of the character; joints are "
                                f"{list(char_names)}")  # fmt: skip
        pairs.append((str(s), str(c)))
        roles.append(str(role))
    if len({c for _, c in pairs}) < len(pairs):
        raise RetargetError("joint_map: a character joint is named twice")
    if len(pairs) < 4:
        raise RetargetError(f"joint_map: {len(pairs)} correspondences; at least 4 are needed")
    return pairs, roles


# --------------------------------------------------------------------------- kinematics


def _source_fk(parents, off, root, rot):
    """World positions ``(T, J, 3)`` and rotations ``(T, J, 3, 3)`` (the Motion rules)."""
    r_local = np.asarray(quat_to_matrix(quat_normalize(rot)))
    t, nj = rot.shape[:2]
    rw = np.empty((t, nj, 3, 3))
    x = np.empty((t, nj, 3))
    for j in range(nj):
        p = parents[j]
        if p < 0:
            rw[:, j] = r_local[:, j]
            x[:, j] = root + off[j]
        else:
            rw[:, j] = rw[:, p] @ r_local[:, j]
            x[:, j] = x[:, p] + np.einsum("tab,b->ta", rw[:, p], off[j])
    return x, rw


def _char_rest(mesh):
    """Rest global transforms ``(J, 4, 4)`` of the character (base transforms included)."""
    q = np.asarray(mesh.rest_rotations, np.float64)
    r = np.asarray(quat_to_matrix(quat_normalize(q), order="xyzw"))
    nj = mesh.num_joints
    loc = np.tile(np.eye(4), (nj, 1, 1))
    loc[:, :3, :3] = r * np.asarray(mesh.rest_scales, np.float64)[:, None, :]
    loc[:, :3, 3] = mesh.rest_translations
    g = np.empty_like(loc)
    par = np.asarray(mesh.parents)
    for j in range(nj):
        g[j] = (np.asarray(mesh.base_transforms[j]) @ loc[j]) if par[j] < 0 else g[par[j]] @ loc[j]
    return g, loc


def _global_frames_np(mesh, angles, translation):
    """Character global transforms at IK poses, numpy: ``(T, J, 4, 4)``."""
    _, loc = _char_rest(mesh)
    e = _euler_xyz(angles)  # (T, J, 3, 3)
    t, nj = angles.shape[:2]
    lp = np.broadcast_to(loc, (t, nj, 4, 4)).copy()
    s = np.asarray(mesh.rest_scales, np.float64)
    rr = loc[:, :3, :3] / s[:, None, :]
    lp[..., :3, :3] = rr @ e * s[:, None, :]
    g = np.empty_like(lp)
    par = np.asarray(mesh.parents)
    for j in range(nj):
        g[:, j] = (mesh.base_transforms[j] @ lp[:, j]) if par[j] < 0 else g[:, par[j]] @ lp[:, j]
    g[..., :3, 3] += translation[:, None, :]
    return g


def joint_positions(mesh, pose: Pose) -> np.ndarray:
    """World positions ``(T, J, 3)`` of ``mesh``'s joints at the IK poses ``pose``
    (leading frame axis; numpy, host side)."""
    if not hasattr(mesh, "joint_names") or not hasattr(mesh, "inverse_bind"):
        raise RetargetError(
            f"mesh must be a SkinnedMesh (fx.io.read_gltf), got {type(mesh).__name__}"
        )
    if not isinstance(pose, Pose):
        raise RetargetError(f"pose must be a Pose (fx.mesh.Pose), got {type(pose).__name__}")
    a = np.asarray(pose.angles, np.float64)
    tr = np.asarray(pose.translation, np.float64)
    one = a.ndim == 2
    if one:
        a, tr = a[None], tr[None]
    x = _global_frames_np(mesh, a, tr)[..., :3, 3]
    return x[0] if one else x


def _euler_xyz(a):
    c, s = np.cos(a), np.sin(a)
    cx, cy, cz = c[..., 0], c[..., 1], c[..., 2]
    sx, sy, sz = s[..., 0], s[..., 1], s[..., 2]
    rows = [
        [cy * cz, -cy * sz, sy],
        [cx * sz + sx * sy * cz, cx * cz - sx * sy * sz, -sx * cy],
        [sx * sz - cx * sy * cz, sx * cz + cx * sy * sz, cx * cy],
    ]
    return np.stack([np.stack(r, -1) for r in rows], -2)


def _matrix_to_xyz(r):
    """XYZ Euler angles of ``R = R_x R_y R_z`` (the IK pose's convention)."""
    sy = np.clip(r[..., 0, 2], -1.0, 1.0)
    ay = np.arcsin(sy)
    ax = np.arctan2(-r[..., 1, 2], r[..., 2, 2])
    az = np.arctan2(-r[..., 0, 1], r[..., 0, 0])
    return np.stack([ax, ay, az], -1)


def _joint_model(mesh, joints: np.ndarray, length_scale: float):
    """An `IKModel` whose markers are the origins of ``joints`` (weight 1 on the joint,
    zero bind-local offset): a copy of ``mesh`` with one degenerate triangle per joint at
    its bind position."""
    import dataclasses

    ib = np.asarray(mesh.inverse_bind, np.float64)
    verts = np.linalg.inv(ib)[:, :3, 3]  # bind-pose joint origins: B_j⁻¹ maps them to 0
    nj = mesh.num_joints
    sj = np.zeros((nj, 4), np.int32)
    sj[:, 0] = np.arange(nj)
    sw = np.zeros((nj, 4))
    sw[:, 0] = 1.0
    faces = np.repeat(np.arange(nj, dtype=np.int32)[:, None], 3, axis=1)
    pts = dataclasses.replace(mesh, vertices=verts, faces=faces, skin_joints=sj, skin_weights=sw)
    bary = np.zeros((len(joints), 3))
    bary[:, 0] = 1.0
    ms = MarkerSet(jnp.asarray(np.asarray(joints, np.int32)), jnp.asarray(bary))
    model = ik_model(pts, ms)
    return model._replace(length_scale=jnp.asarray(length_scale, model.length_scale.dtype))


# ----------------------------------------------------------------------------- helpers


def _path_length(parents, x, a: int, b: int) -> float:
    """Length of the skeleton's path between joints ``a`` and ``b`` (rest positions ``x``)."""

    def chain(j):
        out = [int(j)]
        while parents[out[-1]] >= 0:
            out.append(int(parents[out[-1]]))
        return out

    ca, cb = chain(a), chain(b)
    common = next(j for j in ca if j in cb)
    n = 0.0
    for c in (ca, cb):
        for j in c[: c.index(common)]:
            n += float(np.linalg.norm(x[j] - x[parents[j]]))
    return n


def _runs(mask: np.ndarray):
    """``(start, stop)`` of the True runs of a 1-D mask."""
    d = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
    return list(zip(np.flatnonzero(d == 1), np.flatnonzero(d == -1), strict=True))


def _contacts(x: np.ndarray, feet: np.ndarray, height: float, rate: float, min_run: int):
    """Per frame and foot joint: near its lowest height (within 3 % of the height) and
    slower than 0.2 heights per second horizontally; runs shorter than ``min_run``
    dropped. ``x``: ``(T, F, 3)``."""
    t = x.shape[0]
    out = np.zeros((t, len(feet)), bool)
    if t < 2:
        return out
    v = np.zeros((t, len(feet)))
    dx = np.linalg.norm(np.diff(x[..., [0, 2]], axis=0), axis=-1) * rate
    v[1:] = dx
    v[0] = dx[0]
    v = np.minimum(v, np.concatenate([v[1:], v[-1:]]))  # either side of the frame
    low = np.nanpercentile(x[..., 1], 5, axis=0)
    ok = (x[..., 1] < low + 0.03 * height) & (v < 0.2 * height)
    for k in range(len(feet)):
        for a, b in _runs(ok[:, k]):
            if b - a >= min_run:
                out[a:b, k] = True
    return out


def _slide(x: np.ndarray, contact: np.ndarray, height: float) -> np.ndarray:
    """Mean horizontal displacement per frame (character heights) of the joints in contact
    at both ends of the step; NaN where none is."""
    t = x.shape[0]
    out = np.full(t, np.nan)
    if t < 2 or contact.shape[1] == 0:
        return out
    d = np.linalg.norm(np.diff(x[..., [0, 2]], axis=0), axis=-1) / height  # (T-1, F)
    both = contact[1:] & contact[:-1]
    cnt = both.sum(1)
    s = np.where(both, d, 0.0).sum(1)
    out[1:] = np.where(cnt > 0, s / np.maximum(cnt, 1), np.nan)
    return out


@partial(jax.jit, static_argnames=("solver",))
def _track(model, base, weights, contact_w, offsets, targets, init, solver):
    """Per-frame solves in one scan: the marker weights and the floor contacts change per
    frame (``track_ik`` holds one constraint set for the whole take)."""
    nk = targets.shape[1]
    normals = jnp.tile(jnp.asarray([0.0, 1.0, 0.0], targets.dtype), (nk, 1))

    def step(pose, xs):
        tgt, w, cw = xs
        cons = base._replace(marker_weights=w, contact=PlaneContact(cw, normals, offsets))
        res = _solve(model, cons, tgt, pose, None, solver)
        return res.pose, (res.pose, res.result, res.num_steps)

    _, out = jax.lax.scan(step, init, (targets, weights, contact_w))
    return out


# ------------------------------------------------------------------------------ public


def retarget(
    motion,
    mesh,
    joint_map=None,
    *,
    feet: Sequence[str] | None = None,
    solver: Any | None = None,
    contact_weight: float = 100.0,
    foot_weight: float = 100.0,
    limit: float = 0.8 * np.pi,
    prior_weight: float = 1e-4,
    max_error: float = 0.1,
    baseline: bool = True,
) -> Retargeted:
    """Retarget a skeleton motion onto the skinned character ``mesh`` by the mesh IK.

    **Arguments:**

    - ``motion``: a skeletal motion (`fxspace.io.read_bvh`, `fxspace.io.read_amc`, a
      synthesised session's Motion; anything with ``names``, ``parents``, ``offsets``,
      ``root_translation``, ``rotations`` (w, x, y, z) and ``rate``), Y-up.
    - ``mesh``: a `SkinnedMesh` (`fxspace.io.read_gltf`), Y-up, standing on ``y = min``.
    - ``joint_map``: the correspondences, as ``source_map.correspondences(character_map)``
      (``(role, source joint, character joint)`` triples from `fxspace.motion.JointMap`),
      the pair ``(source_map, character_map)``, ``{source joint: character joint}`` or
      ``(source, character)`` pairs, or the resolver itself, ``fx.motion.joint_map_for``
      (applied to both skeletons' names: CMU, Bandai, Mixamo, VRM, CesiumMan, …);
      ``None`` (the default): that resolver (the one joint-name map, `fxspace.joints`),
      and where it knows neither skeleton, the joints of the same (normalised) name.
    - ``feet``: the source joints whose contacts hold the character's feet on the floor
      (default: the ``foot``/``toes`` roles, or joints named foot/toe/ankle/ball).
    - ``solver``: an IK solver object (default ``LevenbergMarquardt(rtol=1e-3,
      xtol=1e-3, max_steps=20)``); ``contact_weight``: the floor plane's weight;
      ``foot_weight``: the marker weight of a planted foot joint (others 1); ``limit``:
      joint limit on every Euler angle (radians); ``prior_weight``: pull towards the rest
      pose; ``max_error``: the median joint error (character heights) above which the
      take is ``poor_fit``; ``baseline``: also compute rotation copying (``.baseline``).

    **Returns:** a `Retargeted` record (``.pose``, ``.joint_error``, ``.foot_slide``,
    ``.result``, ``.ms_per_frame``, …).

    **Example:**

    ```python
    take = fx.io.read_amc("131.asf", "131_09.amc.gz")
    man = fx.io.read_gltf("CesiumMan.glb")
    r = fx.mesh.retarget(take, man, fx.motion.joint_map_for)   # roles by name on both
    r.correspondences      # (source joint, character joint) pairs used
    r.summary()   # joint error, foot slide (ours / source), ms per frame
    ```
    """
    if not hasattr(mesh, "joint_names") or not hasattr(mesh, "inverse_bind"):
        raise RetargetError(
            f"mesh must be a SkinnedMesh (fx.io.read_gltf), got {type(mesh).__name__}"
        )
    names, parents, off, root, rot, rate = _motion_arrays(motion)
    pairs, roles = _pairs(joint_map, names, tuple(mesh.joint_names))
    si = np.array([names.index(s) for s, _ in pairs])
    ci = np.array([mesh.joint_names.index(c) for _, c in pairs])
    is_foot = _foot_mask(feet, pairs, roles)
    g_rest, c_rest, floor, height = _character_at_rest(mesh, ci)
    tgt, finite, scale, x_rest, r_src = _source_targets(
        mesh, g_rest, c_rest, floor, names, parents, off, root, rot, si, ci
    )
    t = len(tgt)
    fi, contact, src_slide, ik_t = _plant_feet(tgt, is_foot, finite, c_rest, height, rate)
    rest_h = c_rest[:, 1]

    # baseline: rotation copying (each joint's world rotation change through the rest poses)
    t0 = time.perf_counter()
    copy_pose = _rotation_copy(mesh, g_rest, r_src, si, ci, x_rest, tgt, finite)
    copy_ms = 1e3 * (time.perf_counter() - t0) / t

    pose, results, ms, compile_s = _solve_take(
        mesh, ci, height, solver, limit, prior_weight, foot_weight, contact_weight, contact,
        finite, copy_pose, rest_h, ik_t,
    )  # fmt: skip

    def record(p, method, results, ms, comp, baseline_rec):
        xj = joint_positions(mesh, p)[:, ci]
        err = np.linalg.norm(xj - tgt, axis=-1).mean(1) / height
        err[~finite] = np.nan
        slide = _slide(xj[:, fi], contact[:, fi], height)
        med = float(np.nanmedian(err)) if finite.any() else np.nan
        if not finite.all():
            res = RESULTS.nonfinite_input
        elif not np.isfinite(med) or med > max_error:
            res = RESULTS.poor_fit
        else:
            res = RESULTS.successful
        return Retargeted(
            p, err, slide, src_slide, res, results, float(ms), float(comp), tuple(pairs),
            tgt, xj, contact, height, scale, rate, method, baseline_rec,
        )  # fmt: skip

    base_rec = record(copy_pose, "rotation_copy", None, copy_ms, 0.0, None) if baseline else None
    return record(pose, "mesh_ik", results, ms, compile_s, base_rec)


def _foot_mask(feet, pairs, roles) -> np.ndarray:
    """Which corresponded pairs hold a foot on the floor: the given source joints
    ``feet`` (each must be corresponded), else the ``foot``/``toes`` roles, or joints
    named foot/toe/ankle/ball."""
    if feet is None:
        is_foot = np.array(
            [r.endswith(("_foot", "_toes")) if r else bool(_FOOT.search(s))
             for r, (s, _) in zip(roles, pairs, strict=True)]
        )  # fmt: skip
    else:
        bad = [f for f in feet if f not in {s for s, _ in pairs}]
        if bad:
            raise RetargetError(f"feet: {bad} are not corresponded source joints")
        is_foot = np.array([s in feet for s, _ in pairs])
    return is_foot


def _character_at_rest(mesh, ci):
    """``(global rest frames, corresponded joints' rest positions, floor height,
    character height)`` of the character at rest."""
    g_rest, _ = _char_rest(mesh)
    c_rest = g_rest[ci, :3, 3]
    verts = np.asarray(mesh.vertices, np.float64)
    floor = float(verts[:, 1].min())
    height = float(np.ptp(verts[:, 1]))
    return g_rest, c_rest, floor, height


def _source_targets(mesh, g_rest, c_rest, floor, names, parents, off, root, rot, si, ci):
    """``(targets, finite, scale, x_rest, r_src)``: the source's corresponded joints per
    frame scaled to the character and put on its floor (``finite``: frames with every
    one seen), with the source's rest positions and posed world rotations."""
    # the source: rest (no rotations) and posed
    ident = np.tile([1.0, 0.0, 0.0, 0.0], (1, len(names), 1))
    x_rest, _ = _source_fk(parents, off, np.zeros((1, 3)), ident)
    x_rest_all = x_rest[0]
    x_rest = x_rest_all[si]
    x_src, r_src = _source_fk(parents, off, root, rot)
    finite = np.all(np.isfinite(x_src[:, si]), axis=(1, 2))
    # scale: the path along the skeleton from the character's highest corresponded joint
    # to its lowest (head to toes), against the source's path between the same joints
    # (pose-free: a rest pose with every bone along one axis, as Bandai's, is fine)
    hi, lo = int(np.argmax(c_rest[:, 1])), int(np.argmin(c_rest[:, 1]))
    span_c = _path_length(np.asarray(mesh.parents), g_rest[:, :3, 3], ci[hi], ci[lo])
    span_s = _path_length(parents, x_rest_all, si[hi], si[lo])
    if not span_s > 0 or not span_c > 0:
        raise RetargetError("the corresponded joints span no height (one joint named twice?)")
    scale = float(span_c / span_s)
    # the source's floor: its lowest corresponded joint (5th percentile over the take)
    lowest = np.where(finite, np.min(np.where(finite[:, None], x_src[:, si, 1], 0.0), 1), np.nan)
    s_floor = float(np.nanpercentile(lowest, 5)) if finite.any() else 0.0
    c_low = float(c_rest[:, 1].min() - floor)  # the character's lowest joint above its floor
    tgt = scale * (x_src[:, si] - [0.0, s_floor, 0.0])  # the source's world, scaled
    tgt[..., 1] += floor + c_low
    return tgt, finite, scale, x_rest, r_src


def _plant_feet(tgt, is_foot, finite, c_rest, height: float, rate: float):
    """``(foot indices, contact, source foot slide, IK targets)``: the contacts of the
    source's feet (in the character's space) and the targets with each planted joint at
    its contact's mean spot, at its rest height (NaN on frames not fully seen)."""
    t, m = tgt.shape[:2]
    # contacts of the source's feet (in the character's space)
    fi = np.flatnonzero(is_foot)
    contact = np.zeros((t, m), bool)
    if fi.size:
        contact[:, fi] = _contacts(tgt[:, fi], fi, height, rate, max(2, int(round(rate / 20))))
        contact &= finite[:, None]
    src_slide = _slide(tgt[:, fi], contact[:, fi], height)

    # the IK targets: a planted joint at its contact's mean spot, at its rest height
    ik_t = tgt.copy()
    rest_h = c_rest[:, 1]
    for k in fi:
        for a, b in _runs(contact[:, k]):
            ik_t[a:b, k, [0, 2]] = tgt[a:b, k][:, [0, 2]].mean(0)
            ik_t[a:b, k, 1] = rest_h[k]
    ik_t[~finite] = np.nan
    return fi, contact, src_slide, ik_t


def _solve_take(mesh, ci, height, solver, limit, prior_weight, foot_weight, contact_weight,
                contact, finite, copy_pose, rest_h, ik_t):
    """``(pose, results, ms per frame, compile seconds)``: the mesh IK tracked through
    the take, warm-started from the rotation copy's first seen frame."""
    # the solve
    model = _joint_model(mesh, ci, height)
    dtype = model.local_rest.dtype
    solver = _pick_solver(solver or LevenbergMarquardt(rtol=1e-3, xtol=1e-3, max_steps=20))
    base = IKConstraints(
        limits=joint_limits(model, float(limit), 1.0),
        prior=joint_prior(model, float(prior_weight), "rest") if prior_weight > 0 else None,
    )
    w = np.where(contact, foot_weight, 1.0)
    cw = np.where(contact, contact_weight, 0.0)
    k0 = int(np.argmax(finite)) if finite.any() else 0
    init = Pose(
        jnp.asarray(copy_pose.angles[k0], dtype), jnp.asarray(copy_pose.translation[k0], dtype)
    )
    args = (
        model,
        base,
        jnp.asarray(w, dtype),
        jnp.asarray(cw, dtype),
        jnp.asarray(rest_h, dtype),
        jnp.asarray(ik_t, dtype),
        init,
    )
    t0 = time.perf_counter()
    compiled = _compiled(args, solver)
    compile_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    poses, results, _steps = jax.block_until_ready(compiled(*args))
    ms = 1e3 * (time.perf_counter() - t0) / len(ik_t)
    pose = Pose(np.asarray(poses.angles, np.float64), np.asarray(poses.translation, np.float64))
    return pose, results, ms, compile_s


_COMPILED: dict = {}


def _compiled(args, solver):
    """`_track` compiled ahead of time for these shapes (cached), so that the solve is
    timed without its compilation."""
    leaves, tree = jax.tree_util.tree_flatten(args)
    key = (tree, tuple((np.shape(x), jnp.result_type(x)) for x in leaves), solver)
    fn = _COMPILED.get(key)
    if fn is None:
        fn = _track.lower(*args, solver=solver).compile()
        if len(_COMPILED) > 16:
            _COMPILED.clear()
        _COMPILED[key] = fn
    return fn


def _align(bc: np.ndarray, bs: np.ndarray) -> np.ndarray:
    """The rotation ``Q`` best taking the character's bone vectors ``bc`` (rows) onto the
    source's ``bs`` (`fxspace.rigid.fit_rotation`; one bone, or bones on one line: the
    shortest arc)."""
    if len(bc) >= 2:
        Q, sv = fit_rotation(np.asarray(bc, np.float64), np.asarray(bs, np.float64))
        # sv of the mean Σ bs bcᵀ / n: the unnormalised test sv₁ > 1e-6 max(sv₀, 1e-12)
        if sv[1] > 1e-6 * max(sv[0], 1e-12 / len(bc)):
            return Q
    a = bc.sum(0)
    b = bs.sum(0)
    a, b = a / (np.linalg.norm(a) or 1.0), b / (np.linalg.norm(b) or 1.0)
    v, c = np.cross(a, b), float(np.dot(a, b))
    if c < -1 + 1e-9:  # opposite: a half turn about any axis orthogonal to a
        ax = np.cross(a, [1.0, 0, 0] if abs(a[0]) < 0.9 else [0, 1.0, 0])
        ax /= np.linalg.norm(ax)
        return 2 * np.outer(ax, ax) - np.eye(3)
    k = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + k + k @ k / (1 + c)


def _rotation_copy(mesh, g_rest, r_src, si, ci, x_rest, tgt, finite) -> Pose:
    """Plain rotation copying through the rest poses: a corresponded character joint
    takes its source joint's world rotation, ``R_c(t) = R_s(t) Q R_c,rest``, where ``Q``
    turns the character's rest bones (to its corresponded children) onto the source's
    rest bones (a Motion's rest has identity rotations); the other joints keep their rest
    local rotation; the hips (the corresponded joint nearest the root) on the scaled
    source."""
    t = r_src.shape[0]
    nj = mesh.num_joints
    par = np.asarray(mesh.parents)
    s = np.asarray(mesh.rest_scales, np.float64)
    lin = g_rest[:, :3, :3]
    rot_rest_g = lin / np.cbrt(np.abs(np.linalg.det(lin)))[:, None, None]
    c_rest = g_rest[:, :3, 3]
    pos = {int(c): k for k, c in enumerate(ci)}

    def corr_parent(j):
        p = par[j]
        while p >= 0 and int(p) not in pos:
            p = par[p]
        return int(p)

    q = {}
    for c in sorted(pos, key=lambda j: len(_chain(par, j))):
        kids = [d for d in pos if corr_parent(d) == c]
        if kids:
            bc = np.array([c_rest[d] - c_rest[c] for d in kids])
            bs = np.array([x_rest[pos[d]] - x_rest[pos[c]] for d in kids])
            q[c] = _align(bc, bs)
        else:
            p = corr_parent(c)
            q[c] = q.get(p, np.eye(3))
    rw = np.empty((t, nj, 3, 3))
    angles = np.zeros((t, nj, 3))
    _, loc = _char_rest(mesh)
    rr = loc[:, :3, :3] / s[:, None, :]
    for j in range(nj):
        if j in pos:
            rw[:, j] = r_src[:, si[pos[j]]] @ q[j] @ rot_rest_g[j]
        elif par[j] < 0:
            rw[:, j] = rot_rest_g[j]
        else:
            rw[:, j] = rw[:, par[j]] @ rr[j]
        if par[j] < 0:
            b = np.asarray(mesh.base_transforms[j])[:3, :3]
            b = b / np.cbrt(abs(np.linalg.det(b)))
            local = b.T @ rw[:, j]
        else:
            local = np.swapaxes(rw[:, par[j]], -1, -2) @ rw[:, j]
        angles[:, j] = _matrix_to_xyz(rr[j].T @ local)
    angles = np.where(finite[:, None, None], angles, 0.0)
    # the world translation putting the corresponded joint nearest the root on its target
    k0 = min(range(len(ci)), key=lambda k: len(_chain(par, ci[k])))
    x0 = _global_frames_np(mesh, angles, np.zeros((t, 3)))[:, ci[k0], :3, 3]
    trans = np.where(finite[:, None], tgt[:, k0] - x0, 0.0)
    return Pose(angles, trans)


def _chain(parents, j):
    out = [int(j)]
    while parents[out[-1]] >= 0:
        out.append(int(parents[out[-1]]))
    return out


class LiveRetarget:
    """Frame-by-frame retargeting for a live source (the walker): `step` takes the
    source's world joint positions of one frame and returns the character's `Pose` and
    skinned vertices, warm-started from the previous frame (no contacts: the live source
    has no future to plan a plant on). Build with `live_retarget`."""

    def __init__(self, skeleton, mesh, joint_map=None, *, solver=None, limit=0.8 * np.pi,
                 prior_weight: float = 1e-4):  # fmt: skip
        from fxspace.mesh._skinning import _pose_vertices, skin_tables

        if not hasattr(mesh, "joint_names") or not hasattr(mesh, "inverse_bind"):
            raise RetargetError(f"mesh must be a SkinnedMesh, got {type(mesh).__name__}")
        for f in ("names", "parents", "offsets"):
            if not hasattr(skeleton, f):
                raise RetargetError(
                    f"skeleton must have names, parents and offsets (a Motion), lacking {f}"
                )
        names = tuple(str(n) for n in skeleton.names)
        parents = np.asarray(skeleton.parents, np.int64)
        off = np.asarray(skeleton.offsets, np.float64)
        pairs, _ = _pairs(joint_map, names, tuple(mesh.joint_names))
        self.mesh, self.pairs = mesh, tuple(pairs)
        self.si = np.array([names.index(s) for s, _ in pairs])
        self.ci = np.array([mesh.joint_names.index(c) for _, c in pairs])
        g_rest, _ = _char_rest(mesh)
        c_rest = g_rest[self.ci, :3, 3]
        ident = np.tile([1.0, 0.0, 0.0, 0.0], (1, len(names), 1))
        x_rest = _source_fk(parents, off, np.zeros((1, 3)), ident)[0][0]
        hi, lo = int(np.argmax(c_rest[:, 1])), int(np.argmin(c_rest[:, 1]))
        cpar = np.asarray(mesh.parents)
        span_c = _path_length(cpar, g_rest[:, :3, 3], self.ci[hi], self.ci[lo])
        span_s = _path_length(parents, x_rest, self.si[hi], self.si[lo])
        if not span_s > 0 or not span_c > 0:
            raise RetargetError("the corresponded joints span no height")
        self.scale = float(span_c / span_s)
        verts = np.asarray(mesh.vertices, np.float64)
        self.height = float(np.ptp(verts[:, 1]))
        self._lift = float(c_rest[:, 1].min())  # the lowest joint's rest height
        self._offset: float | None = None
        self.model = _joint_model(mesh, self.ci, self.height)
        dt = self.model.local_rest.dtype
        self.cons = IKConstraints(
            limits=joint_limits(self.model, float(limit), 1.0),
            prior=joint_prior(self.model, float(prior_weight), "rest")
            if prior_weight > 0
            else None,
        )
        lm = LevenbergMarquardt(rtol=1e-3, xtol=1e-3, max_steps=20)
        self.solver = _pick_solver(solver or lm)
        self.pose = Pose(jnp.zeros((mesh.num_joints, 3), dt), jnp.zeros((3,), dt))
        self._tables = skin_tables(mesh)
        self._skin = _pose_vertices
        self._dtype = dt

    def targets(self, x: np.ndarray) -> np.ndarray:
        """The character-space targets of one frame's source joints ``(J_src, 3)``."""
        t = self.scale * np.asarray(x, np.float64)[self.si]
        if self._offset is None:  # the first frame sets the floor: lowest joint at rest height
            self._offset = self._lift - float(t[:, 1].min())
        t[:, 1] += self._offset
        return t

    def step(self, x) -> tuple[Pose, np.ndarray]:
        """Solve one frame (warm from the last) → ``(pose, vertices (V, 3))``."""
        t = jnp.asarray(self.targets(x), self._dtype)
        res = _solve(self.model, self.cons, t, self.pose, None, self.solver)
        if bool(jnp.all(jnp.isfinite(res.pose.angles))):
            self.pose = res.pose
        v = self._skin(self.mesh, self._tables, self.pose.angles, self.pose.translation)
        return self.pose, np.asarray(v)


def live_retarget(skeleton, mesh, joint_map=None, **kwargs) -> LiveRetarget:
    """A `LiveRetarget` of ``skeleton`` (a Motion's ``names``/``parents``/``offsets``) onto
    ``mesh``: ``lr.step(world_joint_positions)`` → ``(Pose, skinned vertices)`` per frame.
    ``joint_map`` as in `retarget`; keywords ``solver``, ``limit``, ``prior_weight``."""
    return LiveRetarget(skeleton, mesh, joint_map, **kwargs)
