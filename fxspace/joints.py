"""One joint-name map for humanoid skeletons: canonical joint *roles* (``hips``, ``spine``,
``left_upper_leg``, ``right_hand``, …) resolved from a skeleton's own joint names.

A skeleton's names are matched against naming conventions, each a list of aliases per
role (`CONVENTIONS`):

- ``cmu``: CMU ASF/AMC bones (``root``, ``lowerback``, ``lfemur``, ``ltibia``, ``lfoot``,
  ``ltoes``, ``lclavicle``, ``lhumerus``, ``lradius``, ``lhand``, ``thorax``, …);
- ``cmu_bvh``: the CMU BVH conversion (``LeftHip``, ``LeftKnee``, ``LeftAnkle``,
  ``LeftCollar``, ``LeftShoulder`` = upper arm, ``LeftElbow``, …);
- ``bandai``: Bandai Namco Research Motion (``UpperLeg_L``, ``LowerLeg_L``, ``Foot_L``,
  ``Toes_L``, ``Shoulder_L``, ``UpperArm_L``, ``LowerArm_L``, ``Hand_L``, ``Chest``, …);
- ``mixamo``: Mixamo rigs and the common research BVH (``LeftUpLeg``, ``LeftLeg``,
  ``LeftFoot``, ``LeftToeBase``, ``LeftShoulder``, ``LeftArm``, ``LeftForeArm``,
  ``Spine1``; namespace prefixes such as ``mixamorig:`` are ignored);
- ``vrm``: the VRM / Unity humanoid set (``leftUpperLeg``, ``leftLowerLeg``, ``leftFoot``,
  ``leftToes``, ``leftUpperArm``, ``upperChest``, …);
- ``smpl``: SMPL / SMPL-X joints (``L_Hip``, ``L_Knee``, ``L_Ankle``, ``L_Foot`` = toes,
  ``L_Collar``, ``L_Shoulder`` = upper arm, …);
- ``unreal``: the Unreal mannequin (``thigh_l``, ``calf_l``, ``foot_l``, ``ball_l``, …);
- ``biped``: 3ds Max Biped (``Bip01 L Thigh``, ``Bip01 L Calf``, ``Bip01 L Toe0``, …);
- ``cesium``: the glTF sample CesiumMan (``Skeleton_torso_joint_1``, ``leg_joint_L_1``,
  ``Skeleton_arm_joint_L__4_``, …).

Names are compared without case, separators (``_ - . space``) and namespace prefixes
(``mixamorig:``, ``Armature|``, ``Bip01``). The convention that resolves the most roles
wins (ties: the order above); ``overrides`` (a config's ``[skeleton] map``) name joints
for roles on top of it. `joint_map_for` refuses a skeleton that leaves a required role
unresolved, naming the roles, the best-matching convention and the config key that fixes
it. Pure: no file I/O.
"""

from __future__ import annotations

import dataclasses
import math
import re
from collections.abc import Iterable, Mapping, Sequence
from types import MappingProxyType

import numpy as np

from fxspace.errors import FxspaceError

__all__ = [
    "ROLES",
    "BODY_ROLES",
    "CONVENTIONS",
    "LENGTH_UNITS",
    "JointMap",
    "JointMapError",
    "SkeletonSpec",
    "joint_map_for",
    "infer_length_unit",
]

_SIDES = ("left", "right")
_LIMBS = ("shoulder", "upper_arm", "lower_arm", "hand", "upper_leg", "lower_leg", "foot", "toes")
ROLES: tuple[str, ...] = ("hips", "spine", "chest", "upper_chest", "neck", "head") + tuple(
    f"{s}_{limb}" for s in _SIDES for limb in _LIMBS
)
"""Every canonical role, trunk first, then the left and the right limbs."""

BODY_ROLES: tuple[str, ...] = ("hips", "head") + tuple(
    f"{s}_{limb}"
    for s in _SIDES
    for limb in ("upper_arm", "lower_arm", "hand", "upper_leg", "lower_leg", "foot")
)
"""The roles `joint_map_for` requires by default: a body with arms and legs (no spine,
shoulder, neck or toe joints needed: a set-up derives its split from ``hips`` → ``head``
and falls back from toes to feet)."""

# per convention: role -> aliases, first present wins; "{L}"-style side tokens expand below
_TRUNK: dict[str, dict[str, tuple[str, ...]]] = {
    "cmu": dict(hips=("root",), spine=("lowerback",), chest=("upperback",),
                upper_chest=("thorax",), neck=("lowerneck", "upperneck"), head=("head",)),
    "cmu_bvh": dict(hips=("Hips", "root"), spine=("lowerback", "LowerBack"), chest=("Chest",),
                    upper_chest=("Chest2",), neck=("lowerneck", "Neck"), head=("Head",)),
    "bandai": dict(hips=("Hips",), spine=("Spine",), chest=("Chest",), neck=("Neck",),
                   head=("Head",)),
    "mixamo": dict(hips=("Hips",), spine=("LowerBack", "Spine"), chest=("Spine1",),
                   upper_chest=("Spine2",), neck=("Neck",), head=("Head",)),
    "vrm": dict(hips=("hips",), spine=("spine",), chest=("chest",), upper_chest=("upperChest",),
                neck=("neck",), head=("head",)),
    "smpl": dict(hips=("Pelvis",), spine=("Spine1",), chest=("Spine2",),
                 upper_chest=("Spine3",), neck=("Neck",), head=("Head",)),
    "unreal": dict(hips=("pelvis",), spine=("spine_01",), chest=("spine_02",),
                   upper_chest=("spine_03",), neck=("neck_01",), head=("head",)),
    "biped": dict(hips=("Pelvis",), spine=("Spine",), chest=("Spine1",), upper_chest=("Spine2",),
                  neck=("Neck",), head=("Head",)),
    "cesium": dict(hips=("Skeleton_torso_joint_1",), spine=("Skeleton_torso_joint_2",),
                   chest=("torso_joint_3",), neck=("Skeleton_neck_joint_1",),
                   head=("Skeleton_neck_joint_2",)),
}  # fmt: skip
# limbs: "{s}" is the side's letter (l/r), "{S}" its capital (L/R), "{Side}" Left/Right
_LIMB: dict[str, dict[str, tuple[str, ...]]] = {
    "cmu": dict(shoulder=("{s}clavicle",), upper_arm=("{s}humerus",), lower_arm=("{s}radius",),
                hand=("{s}hand", "{s}wrist"), upper_leg=("{s}femur",), lower_leg=("{s}tibia",),
                foot=("{s}foot",), toes=("{s}toes",)),
    "cmu_bvh": dict(shoulder=("{Side}Collar",), upper_arm=("{Side}Shoulder",),
                    lower_arm=("{Side}Elbow",), hand=("{s}hand", "{Side}Wrist"),
                    upper_leg=("{Side}Hip",), lower_leg=("{Side}Knee",),
                    foot=("{Side}Ankle",), toes=("{Side}Toe",)),
    "bandai": dict(shoulder=("Shoulder_{S}",), upper_arm=("UpperArm_{S}",),
                   lower_arm=("LowerArm_{S}",), hand=("Hand_{S}",), upper_leg=("UpperLeg_{S}",),
                   lower_leg=("LowerLeg_{S}",), foot=("Foot_{S}",), toes=("Toes_{S}",)),
    "mixamo": dict(shoulder=("{Side}Shoulder",), upper_arm=("{Side}Arm",),
                   lower_arm=("{Side}ForeArm",), hand=("{Side}Hand",),
                   upper_leg=("{Side}UpLeg",), lower_leg=("{Side}Leg",), foot=("{Side}Foot",),
                   toes=("{Side}ToeBase", "{Side}Toe")),
    "vrm": dict(shoulder=("{side}Shoulder",), upper_arm=("{side}UpperArm",),
                lower_arm=("{side}LowerArm",), hand=("{side}Hand",),
                upper_leg=("{side}UpperLeg",), lower_leg=("{side}LowerLeg",),
                foot=("{side}Foot",), toes=("{side}Toes",)),
    "smpl": dict(shoulder=("{S}_Collar", "{side}_collar"),
                 upper_arm=("{S}_Shoulder", "{side}_shoulder"),
                 lower_arm=("{S}_Elbow", "{side}_elbow"), hand=("{S}_Wrist", "{side}_wrist"),
                 upper_leg=("{S}_Hip", "{side}_hip"), lower_leg=("{S}_Knee", "{side}_knee"),
                 foot=("{S}_Ankle", "{side}_ankle"), toes=("{S}_Foot", "{side}_foot")),
    "unreal": dict(shoulder=("clavicle_{s}",), upper_arm=("upperarm_{s}",),
                   lower_arm=("lowerarm_{s}",), hand=("hand_{s}",), upper_leg=("thigh_{s}",),
                   lower_leg=("calf_{s}",), foot=("foot_{s}",), toes=("ball_{s}",)),
    "biped": dict(shoulder=("{S} Clavicle",), upper_arm=("{S} UpperArm",),
                  lower_arm=("{S} Forearm",), hand=("{S} Hand",), upper_leg=("{S} Thigh",),
                  lower_leg=("{S} Calf",), foot=("{S} Foot",), toes=("{S} Toe0",)),
    # CesiumMan (glTF sample): the arm joints are numbered differently per side
    "cesium": dict(upper_arm=("Skeleton_arm_joint_{cz_ua}",),
                   lower_arm=("Skeleton_arm_joint_{cz_la}",),
                   hand=("Skeleton_arm_joint_{cz_ha}",), upper_leg=("leg_joint_{S}_1",),
                   lower_leg=("leg_joint_{S}_2",), foot=("leg_joint_{S}_3",),
                   toes=("leg_joint_{S}_5",)),
}  # fmt: skip
# per-side spellings of conventions whose sides are not mirror images of each other
_SIDE_TOKENS = {
    "left": {"cz_ua": "L__4_", "cz_la": "L__3_", "cz_ha": "L__2_"},
    "right": {"cz_ua": "R", "cz_la": "R__2_", "cz_ha": "R__3_"},
}


def _expand() -> dict[str, Mapping[str, tuple[str, ...]]]:
    out = {}
    for conv, trunk in _TRUNK.items():
        roles = dict(trunk)
        for side in _SIDES:
            tok = {"s": side[0], "S": side[0].upper(), "side": side, "Side": side.capitalize()}
            tok |= _SIDE_TOKENS[side]
            for limb, aliases in _LIMB[conv].items():
                roles[f"{side}_{limb}"] = tuple(a.format(**tok) for a in aliases)
        out[conv] = MappingProxyType({r: roles[r] for r in ROLES if r in roles})
    return out


CONVENTIONS: Mapping[str, Mapping[str, tuple[str, ...]]] = MappingProxyType(_expand())
"""Convention name → role → joint-name aliases (first present wins); read-only."""

# role spellings accepted in overrides besides the canonical ones (compared normalised,
# so VRM's camelCase ``leftFoot`` and ``LEFT_FOOT`` name ``left_foot`` too)
_ROLE_ALIASES = {"pelvis": "hips", "root": "hips", "upperchest": "upper_chest"} | {
    f"{s}{a}": f"{s}_{limb}"
    for s in _SIDES
    for a, limb in (("toe", "toes"), ("forearm", "lower_arm"), ("thigh", "upper_leg"),
                    ("shin", "lower_leg"), ("calf", "lower_leg"), ("clavicle", "shoulder"),
                    ("upperleg", "upper_leg"), ("lowerleg", "lower_leg"),
                    ("upperarm", "upper_arm"), ("lowerarm", "lower_arm"))
}  # fmt: skip

_PREFIX = re.compile(r"^(bip0*1|mixamorig\d*)(?=[^a-z0-9]|[A-Z])", re.IGNORECASE)


def _norm(name: str) -> str:
    """``'mixamorig:LeftUpLeg'`` → ``'leftupleg'``, ``'Bip01 L Thigh'`` → ``'lthigh'``."""
    s = re.split(r"[:|]", str(name))[-1].strip()
    s = _PREFIX.sub("", s)
    return re.sub(r"[^0-9a-z]", "", s.lower())


def _role_key(role: str) -> str | None:
    n = _norm(role)
    for r in ROLES:
        if _norm(r) == n:
            return r
    return _ROLE_ALIASES.get(n)


class JointMapError(FxspaceError):
    """A skeleton's joint names leave a required role unresolved, or a joint map is
    malformed; the message names the roles and the config key that fixes it."""


def _example_fix(roles: Iterable[str]) -> str:
    return "[skeleton] map = {" + ", ".join(f'{r} = "…"' for r in list(roles)[:3]) + "}"


@dataclasses.dataclass(frozen=True)
class JointMap:
    """A skeleton's joints by role (`joint_map_for` builds one).

    **Fields:** ``names`` (the skeleton's joint names), ``roles`` (``(role, joint name)``
    pairs in `ROLES` order; only resolved roles), ``convention`` (the matched naming
    convention, one of `CONVENTIONS`, or ``"custom"`` when the overrides resolve more
    roles than any convention), ``overridden`` (the roles named by overrides).
    """

    names: tuple[str, ...]
    roles: tuple[tuple[str, str], ...]
    convention: str
    overridden: tuple[str, ...] = ()

    def as_dict(self) -> dict[str, str]:
        """``{role: joint name}`` of the resolved roles."""
        return dict(self.roles)

    def __contains__(self, role: object) -> bool:
        return any(r == role for r, _ in self.roles)

    def get(self, role: str, default: str | None = None) -> str | None:
        """The joint name of ``role``, or ``default`` when it is not resolved."""
        return self.as_dict().get(role, default)

    def __getitem__(self, role: str) -> str:
        d = self.as_dict()
        if role not in d:
            known = role in ROLES
            raise JointMapError(
                f"joint role {role!r} is "
                + ("not resolved on this skeleton" if known else f"not a role; roles are {ROLES}")
                + (f" (convention {self.convention}); name its joint in the config: "
                   f"{_example_fix([role])}" if known else "")
            )  # fmt: skip
        return d[role]

    def index(self, role: str) -> int:
        """The joint index of ``role`` in ``names``."""
        return self.names.index(self[role])

    def missing(self, roles: Iterable[str] = BODY_ROLES) -> tuple[str, ...]:
        """Those of ``roles`` not resolved."""
        d = self.as_dict()
        return tuple(r for r in roles if r not in d)

    def require(self, roles: Iterable[str] = BODY_ROLES, what: str = "this skeleton") -> JointMap:
        """``self`` when every one of ``roles`` is resolved, else a `JointMapError`."""
        miss = self.missing(roles)
        if miss:
            raise JointMapError(
                f"{what}: no joint found for role(s) {list(miss)} (best naming convention: "
                f"{self.convention}, {len(self.roles)} of {len(ROLES)} roles); name them in "
                f"the config: {_example_fix(miss)}; joints are {list(self.names)}"
            )
        return self

    def correspondences(self, other: JointMap) -> list[tuple[str, str, str]]:
        """``(role, joint here, joint in other)`` for every role both maps resolve (e.g.
        a source skeleton's joints and a character's)."""
        theirs = other.as_dict()
        return [(r, n, theirs[r]) for r, n in self.roles if r in theirs]

    def describe(self) -> str:
        """One line for a console: convention, roles resolved, overrides."""
        s = f"{self.convention} names, {len(self.roles)} of {len(ROLES)} roles"
        return s + (f" ({len(self.overridden)} from the config map)" if self.overridden else "")


def _check_overrides(overrides) -> dict[str, tuple[str, ...]]:
    if overrides is None:
        return {}
    if isinstance(overrides, JointMap):
        overrides = overrides.as_dict()
    if not isinstance(overrides, Mapping):
        raise JointMapError(
            f"the joint map overrides must be a table of role = joint name, e.g. "
            f'{{left_foot = "L_Ankle"}}, got {type(overrides).__name__}'
        )
    out = {}
    for k, v in overrides.items():
        role = _role_key(k) if isinstance(k, str) else None
        if role is None:
            raise JointMapError(
                f"[skeleton] map: {k!r} is not a joint role; roles are {list(ROLES)}"
            )
        vals = (v,) if isinstance(v, str) else v
        if (
            not isinstance(vals, list | tuple)
            or not vals
            or not all(isinstance(x, str) and x for x in vals)
        ):
            raise JointMapError(
                f"[skeleton] map: {k} must be a joint name or a list of joint names (the "
                f"first present is used), got {v!r}"
            )
        out[role] = tuple(vals)
    return out


def _find(names: Sequence[str], norm: Sequence[str], aliases: Iterable[str]) -> str | None:
    for a in aliases:
        if a in names:  # exact spelling first
            return a
        na = _norm(a)
        for n, nn in zip(names, norm, strict=True):
            if nn == na:
                return n
    return None


def joint_map_for(
    names,
    overrides: Mapping | None = None,
    *,
    required: Iterable[str] = BODY_ROLES,
    convention: str | None = None,
    what: str = "this skeleton",
) -> JointMap:
    """Resolve a skeleton's joint names to roles.

    **Arguments:**

    - ``names``: the joint names (a sequence of str, or anything with ``.names``: a
      `Motion`).
    - ``overrides``: ``{role: joint name or [names…]}`` on top of the matched convention
      (a config's ``[skeleton] map``; VRM-style role spellings such as ``leftFoot`` and
      ``pelvis`` are accepted); a listed name the skeleton lacks is an error, for a list
      the first present joint is used.
    - ``required``: roles that must resolve (default `BODY_ROLES`; ``()`` for a partial map).
    - ``convention``: force one of `CONVENTIONS` instead of the best match.
    - ``what``: how errors name the skeleton (e.g. the file).

    **Returns:** a `JointMap`. Raises `JointMapError` naming every unresolved required
    role, the best convention and the ``[skeleton] map`` key to add.

    **Example:**

    ```python
    jm = fx.motion.joint_map_for(["Hips", "mixamorig:LeftUpLeg", ...], required=())
    jm["left_upper_leg"]   # 'mixamorig:LeftUpLeg'
    ```
    """
    raw = getattr(names, "names", names)
    if isinstance(raw, str) or not isinstance(raw, Iterable):
        raise JointMapError(f"names must be a sequence of joint names (str), got {raw!r}")
    names = tuple(raw)
    if not all(isinstance(n, str) for n in names):
        raise JointMapError(f"names must be a sequence of joint names (str), got {names!r}")
    req = (required,) if isinstance(required, str) else tuple(required)
    bad = [r for r in req if r not in ROLES]
    if bad:
        raise JointMapError(f"required: {bad} are not roles; roles are {list(ROLES)}")
    if convention is not None and convention not in CONVENTIONS:
        raise JointMapError(
            f"convention {convention!r} is not known; choose one of {list(CONVENTIONS)} "
            "(or leave it out to match the names)"
        )
    over = _check_overrides(overrides)
    norm = [_norm(n) for n in names]
    best: tuple[int, str, dict] | None = None
    for conv in (convention,) if convention else CONVENTIONS:
        found = {r: _find(names, norm, a) for r, a in CONVENTIONS[conv].items()}
        found = {r: n for r, n in found.items() if n is not None}
        if len(set(found.values())) < len(found):  # one joint, two roles: keep the first
            seen: set[str] = set()
            found = {r: n for r, n in found.items() if not (n in seen or seen.add(n))}
        if best is None or len(found) > best[0]:
            best = (len(found), conv, found)
    assert best is not None
    n_conv, conv, found = best
    for role, vals in over.items():
        hit = next((v for v in vals if v in names), None) or _find(names, norm, vals)
        if hit is None:
            raise JointMapError(
                f"[skeleton] map: {role} = {list(vals) if len(vals) > 1 else vals[0]!r} names "
                f"no joint of {what}; joints are {list(names)}"
            )
        found = {r: n for r, n in found.items() if n != hit or r == role}  # the map wins
        found[role] = hit
    if n_conv == 0 and over:
        conv = "custom"
    elif n_conv == 0:
        conv = "none"
    roles = tuple((r, found[r]) for r in ROLES if r in found)
    jm = JointMap(names, roles, conv, tuple(r for r in ROLES if r in over))
    return jm.require(req, what) if req else jm


@dataclasses.dataclass(frozen=True)
class SkeletonSpec:
    """A config's ``[skeleton]`` table: ``map`` names joints for roles (``{left_foot =
    "L_Ankle", left_toes = ["L_Toe", "L_Foot"]}``) on top of the matched naming
    convention; ``convention`` forces one of `CONVENTIONS` (``"auto"``: the best match)."""

    map: dict = dataclasses.field(default_factory=dict)
    convention: str = "auto"

    def __hash__(self) -> int:  # a dict field: hash its items
        return hash((tuple(sorted((k, str(v)) for k, v in self.map.items())), self.convention))

    def validate(self) -> None:
        from fxspace.config import ConfigError  # the config front (io-free)

        if self.convention != "auto" and self.convention not in CONVENTIONS:
            raise ConfigError(
                f"skeleton.convention must be 'auto' or one of {list(CONVENTIONS)}, "
                f"got {self.convention!r}"
            )
        try:
            _check_overrides(self.map)
        except JointMapError as e:
            raise ConfigError(str(e)) from None

    def joint_map(self, names, *, required: Iterable[str] = BODY_ROLES, what: str = "") -> JointMap:
        """`joint_map_for` with this table's ``map`` and ``convention``."""
        return joint_map_for(
            names,
            self.map,
            required=required,
            convention=None if self.convention == "auto" else self.convention,
            what=what or "this skeleton",
        )


LENGTH_UNITS: Mapping[str, float] = MappingProxyType(
    {"m": 1.0, "cm": 0.01, "mm": 0.001, "in": 0.0254, "ft": 0.3048, "cmu": 0.0254 / 0.45}
)
"""Length units a skeleton file may be in, metres per unit (``cmu``: the CMU ASF unit,
``0.0254 / 0.45`` m, also used by the CMU BVH conversion)."""

_LEG_M = 0.82  # hip-to-ankle length of an adult (CMU subjects: 0.80–0.83 m)


def infer_length_unit(
    offsets, names, joint_map: JointMap | None = None, *, what: str = "this skeleton"
) -> tuple[str, float, float]:
    """The length unit of a skeleton from its leg: ``(unit, metres per unit, leg length in
    file units)``, the unit of `LENGTH_UNITS` that puts the hip-to-ankle length (upper-leg
    and lower-leg bones, averaged over both legs) nearest an adult's 0.82 m. Raises
    `JointMapError` when no unit gives a leg within a factor 1.4 of that (a child, a
    stylised character: declare the unit instead)."""
    if joint_map is not None and not isinstance(joint_map, JointMap):
        raise JointMapError(f"joint_map must be a JointMap, got {type(joint_map).__name__}")
    jm = joint_map if joint_map is not None else joint_map_for(names, required=())
    try:
        off = np.asarray(offsets, np.float64)
    except (TypeError, ValueError):
        off = np.zeros(0)
    if off.shape != (len(jm.names), 3):
        raise JointMapError(
            f"offsets must be ({len(jm.names)}, 3) rest offsets, one per joint name, got "
            f"shape {off.shape}"
        )
    legs = []
    for side in _SIDES:
        if f"{side}_lower_leg" in jm and f"{side}_foot" in jm:
            a, b = jm.index(f"{side}_lower_leg"), jm.index(f"{side}_foot")
            legs.append(np.linalg.norm(off[a]) + np.linalg.norm(off[b]))
    if not legs or not all(np.isfinite(legs)) or min(legs) <= 0:
        raise JointMapError(
            f"{what}: cannot infer its length unit (no lower leg and foot joints found); "
            f"declare it: units = one of {list(LENGTH_UNITS)} or metres per file unit"
        )
    leg = float(np.mean(legs))
    unit = min(LENGTH_UNITS, key=lambda u: abs(math.log(leg * LENGTH_UNITS[u] / _LEG_M)))
    got = leg * LENGTH_UNITS[unit]
    if not _LEG_M / 1.4 <= got <= _LEG_M * 1.4:
        raise JointMapError(
            f"{what}: cannot infer its length unit (leg {leg:.4g} file units: no unit of "
            f"{list(LENGTH_UNITS)} makes it an adult's); declare it: units = \"cm\" (or "
            "metres per file unit)"
        )
    return unit, LENGTH_UNITS[unit], leg
