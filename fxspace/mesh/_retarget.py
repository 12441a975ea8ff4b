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

import time
from collections.abc import Sequence
from functools import partial
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from fxspace.mesh._ik_constraints import (
    IKConstraints,
    PlaneContact,
    joint_limits,
    joint_prior,
)
from fxspace.mesh._ik_solvers import LevenbergMarquardt, _pick_solver, _solve
from fxspace.mesh._retarget_inputs import RetargetError, _foot_mask, _motion_arrays, _pairs
from fxspace.mesh._retarget_kinematics import (
    _char_rest,
    _joint_model,
    _path_length,
    _rotation_copy,
    _source_fk,
    joint_positions,
)
from fxspace.mesh._skinning import Pose
from fxspace.results import RESULTS

__all__ = [
    "Retargeted",
    "RetargetError",
    "retarget",
]


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
