"""The inputs of retargeting (`fxspace.mesh.retarget`, `fxspace.mesh.live_retarget`): the
motion taken by its arrays, the joint correspondences (a joint map, a resolver such as
`fxspace.motion.joint_map_for`, or the joints of the same name) and which pairs are feet.
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence

import numpy as np

from fxspace.errors import FxspaceError

__all__ = ["RetargetError"]


class RetargetError(FxspaceError):
    """A motion or joint map that cannot be retargeted (names, shapes, too few pairs)."""


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
