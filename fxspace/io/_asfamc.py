"""Acclaim ASF (skeleton) + AMC (motion) reader, as used by the CMU motion-capture database.

Conventions (Acclaim / CMU):

- ``:units length L`` — one file length unit is ``1/L`` inch, so metres = value · 0.0254 / L
  (CMU: ``L = 0.45``). The AMC root translation uses the same unit. Angles are degrees
  unless ``:units angle rad``.
- Each bone has ``direction`` (unit vector, world frame at rest), ``length`` and
  ``axis a b c XYZ`` — its local frame ``C``. An axis order ``XYZ`` means *X first*:
  ``C = R_Z(c) R_Y(b) R_X(a)``; likewise the AMC values of ``dof rx ry rz`` give
  ``M = R_Z(rz) R_Y(ry) R_X(rx)`` (the first-listed DOF is applied first).
- A bone's rotation relative to its parent, in world-aligned rest coordinates, is
  ``L = C M C⁻¹``; its tip is ``start + A · length · direction`` with ``A`` the product of
  the ``L``'s from the root down.

The result is a BVH-style `Motion`: one joint per bone, placed at the bone's
*start* (the root, then the bones in hierarchy order), plus an end site ``<bone>_end`` at
the tip of each leaf bone. ``offsets[b]`` is the parent bone's ``length · direction``.
Channels are recorded as ``Zrotation Yrotation Xrotation`` (and root positions) so that
`write_bvh` produces a standard CMU-style BVH.
"""

from __future__ import annotations

from pathlib import Path

import jax.numpy as jnp
import numpy as np

from fxspace._validate import check_scalar, checked
from fxspace.errors import CorruptFileError
from fxspace.io._bvh import _open_text
from fxspace.motion import Motion
from fxspace.rotations import euler_to_quat, quat_conj, quat_mul

__all__ = ["read_amc", "read_asf", "AsfSkeleton"]

_INCH = 0.0254
_ROOT_CH = ("Xposition", "Yposition", "Zposition", "Zrotation", "Yrotation", "Xrotation")
_BONE_CH = ("Zrotation", "Yrotation", "Xrotation")


class AsfSkeleton:
    """Parsed ASF: bone names, parents, directions, lengths (metres), axes and DOFs."""

    def __init__(self) -> None:
        self.name = ""
        self.length_unit = 1.0
        self.degrees = True
        self.root_order: tuple[str, ...] = ("TX", "TY", "TZ", "RX", "RY", "RZ")
        self.root_axis = "XYZ"
        self.root_position = np.zeros(3)
        self.root_orientation = np.zeros(3)
        self.bones: dict[str, dict] = {}
        self.children: dict[str, list[str]] = {"root": []}

    @property
    def metres_per_unit(self) -> float:
        return _INCH / self.length_unit


def _num(tok: str, path: Path, n: int, what: str) -> float:
    try:
        return float(tok)
    except ValueError:
        raise CorruptFileError(
            f"{path}, line {n}: expected a number for {what}, found {tok!r}"
        ) from None


def _bonedata_line(sk: AsfSkeleton, bone: dict | None, in_limits: bool, key: str, tok, s: str,
                   path: Path, n: int) -> tuple[dict | None, bool]:  # fmt: skip
    """One line of ``:bonedata``: returns the open bone block and whether its limits are
    being read (a finished block is stored in ``sk.bones``)."""
    if key == "begin":
        bone = {"dof": (), "axis": np.zeros(3), "axis_order": "XYZ", "line": n}
        in_limits = False
    elif bone is None:
        raise CorruptFileError(f"{path}, line {n}: {tok[0]!r} outside a begin/end bone block")
    elif key == "end":
        for f in ("name", "direction", "length"):
            if f not in bone:
                raise CorruptFileError(
                    f"{path}, line {n}: bone block starting at line {bone['line']} has no {f!r}"
                )
        sk.bones[bone["name"]] = bone
        bone = None
    elif key == "name":
        bone["name"] = tok[1]
    elif key == "direction":
        if len(tok) < 4:
            raise CorruptFileError(f"{path}, line {n}: direction needs three numbers")
        bone["direction"] = np.asarray([_num(t, path, n, "direction") for t in tok[1:4]])
    elif key == "length":
        bone["length"] = _num(tok[1], path, n, "length")
    elif key == "axis":
        if len(tok) < 5:
            raise CorruptFileError(f"{path}, line {n}: axis needs three angles and an order")
        bone["axis"] = np.asarray([_num(t, path, n, "axis") for t in tok[1:4]])
        bone["axis_order"] = tok[4].upper()
    elif key == "dof":
        dofs = tuple(t.lower() for t in tok[1:])
        for d in dofs:
            if d not in ("rx", "ry", "rz"):
                raise CorruptFileError(
                    f"{path}, line {n}: dof {d!r} is not supported (only rx, ry, rz on bones)"
                )
        bone["dof"] = dofs
    elif key == "limits":
        in_limits = True
    elif in_limits and s.startswith("("):
        pass
    elif key in ("id", "bodymass", "cofmass"):
        pass
    else:
        raise CorruptFileError(f"{path}, line {n}: unexpected {tok[0]!r} in a bone block")
    return bone, in_limits


@checked
def read_asf(path: str | Path) -> AsfSkeleton:
    """Parse an ASF skeleton file (errors name the line)."""
    path = Path(path)
    lines = _open_text(path).splitlines()
    sk = AsfSkeleton()
    section = None
    bone: dict | None = None
    in_limits = False
    saw_hier = False
    for n, raw in enumerate(lines, start=1):
        s = raw.strip()
        if not s or s.startswith("#"):
            continue
        tok = s.split()
        if tok[0].startswith(":"):
            section = tok[0][1:].lower()
            in_limits = False
            if section == "name" and len(tok) > 1:
                sk.name = tok[1]
            if section == "hierarchy":
                saw_hier = True
            continue
        key = tok[0].lower()
        if section == "units":
            if key == "length":
                sk.length_unit = _num(tok[1], path, n, "units length")
                if sk.length_unit <= 0:
                    raise CorruptFileError(f"{path}, line {n}: units length must be positive")
            elif key == "angle":
                sk.degrees = tok[1].lower().startswith("deg")
        elif section == "root":
            if key == "order":
                sk.root_order = tuple(t.upper() for t in tok[1:])
            elif key == "axis":
                sk.root_axis = tok[1].upper()
            elif key == "position":
                sk.root_position = np.asarray([_num(t, path, n, "root position") for t in tok[1:4]])
            elif key == "orientation":
                sk.root_orientation = np.asarray(
                    [_num(t, path, n, "root orientation") for t in tok[1:4]]
                )
        elif section == "bonedata":
            bone, in_limits = _bonedata_line(sk, bone, in_limits, key, tok, s, path, n)
        elif section == "hierarchy":
            if key in ("begin", "end"):
                continue
            parent = tok[0]
            if parent != "root" and parent not in sk.bones:
                raise CorruptFileError(f"{path}, line {n}: hierarchy names unknown bone {parent!r}")
            for c in tok[1:]:
                if c not in sk.bones:
                    raise CorruptFileError(f"{path}, line {n}: hierarchy names unknown bone {c!r}")
                sk.children.setdefault(parent, []).append(c)
    if not sk.bones:
        raise CorruptFileError(f"{path}: no :bonedata (is this an ASF file?)")
    if not saw_hier:
        raise CorruptFileError(f"{path}: no :hierarchy section")
    return sk


def _acclaim_quat(angles: np.ndarray, order: str, degrees: bool) -> np.ndarray:
    """Acclaim order ``"XYZ"`` = X applied first = ``R_Z R_Y R_X``."""
    return euler_to_quat(
        np.asarray(angles, dtype=np.float64)[..., ::-1], order[::-1], degrees=degrees
    )


def _read_amc_frames(sk, asf_path, amc_path) -> list[dict[str, list[float]]]:
    """The AMC frames as ``{bone: values}`` dicts; errors name the line."""
    lines = _open_text(amc_path).splitlines()
    frames: list[dict[str, list[float]]] = []
    cur: dict[str, list[float]] | None = None
    for n, raw in enumerate(lines, start=1):
        s = raw.strip()
        if not s or s.startswith("#") or s.startswith(":"):
            continue
        tok = s.split()
        if len(tok) == 1 and tok[0].isdigit():
            if int(tok[0]) != len(frames) + 1:
                raise CorruptFileError(
                    f"{amc_path}, line {n}: frame {tok[0]} follows frame "
                    f"{len(frames)} (frames must be numbered 1, 2, ...)"
                )
            cur = {}
            frames.append(cur)
            continue
        if cur is None:
            raise CorruptFileError(
                f"{amc_path}, line {n}: {tok[0]!r} before the first frame number"
            )
        bname = tok[0]
        if bname == "root":
            want = len(sk.root_order)
        elif bname in sk.bones:
            want = len(sk.bones[bname]["dof"])
        else:
            raise CorruptFileError(
                f"{amc_path}, line {n}: unknown bone {bname!r} (not in {asf_path})"
            )
        if len(tok) - 1 != want:
            raise CorruptFileError(
                f"{amc_path}, line {n}: bone {bname!r} has {len(tok) - 1} "
                f"values, the skeleton declares {want}"
            )
        try:
            cur[bname] = [float(t) for t in tok[1:]]
        except ValueError:
            raise CorruptFileError(
                f"{amc_path}, line {n}: non-numeric value for bone {bname!r}"
            ) from None
    return frames


@checked
def read_amc(asf_path: str | Path, amc_path: str | Path, rate: float = 120.0) -> Motion:
    """Read a CMU ASF skeleton and an AMC motion (``.amc`` or ``.amc.gz``) into a `Motion`.

    **Arguments:**

    - ``asf_path``: the skeleton (``.asf``).
    - ``amc_path``: the motion (``.amc`` / ``.amc.gz``).
    - ``rate``: frames per second (AMC files do not store it; CMU captures at 120 Hz).

    **Returns:** a ``Motion`` in metres (``length`` units converted), one joint per bone at
    the bone's start plus ``<bone>_end`` tips; see the module docstring for the conventions.
    Malformed files raise ``CorruptFileError`` naming the line; a ``rate`` that is not a
    finite positive number raises `FxspaceError`.
    """
    rate = check_scalar(rate, "rate", low=0.0, low_open=True)
    sk = read_asf(asf_path)
    amc_path = Path(amc_path)
    k = sk.metres_per_unit
    # joint layout: root, bones depth-first in hierarchy order, tips of leaf bones
    names = ["root"]
    parents = [-1]
    offsets = [np.asarray(sk.root_position) * k]
    channels: list[tuple[str, ...]] = [_ROOT_CH]
    bone_joint: dict[str, int] = {}
    local_c: list[np.ndarray] = [
        _acclaim_quat(np.asarray(sk.root_orientation), sk.root_axis, sk.degrees)
    ]

    def visit(bname: str, parent_j: int, parent_vec: np.ndarray) -> None:
        b = sk.bones[bname]
        j = len(names)
        bone_joint[bname] = j
        names.append(bname)
        parents.append(parent_j)
        offsets.append(parent_vec)
        channels.append(_BONE_CH)
        local_c.append(_acclaim_quat(b["axis"], b["axis_order"], sk.degrees))
        vec = b["direction"] * b["length"] * k
        kids = sk.children.get(bname, [])
        for c in kids:
            visit(c, j, vec)
        if not kids:
            names.append(f"{bname}_end")
            parents.append(j)
            offsets.append(vec)
            channels.append(())
            local_c.append(np.asarray([1.0, 0.0, 0.0, 0.0]))

    for c in sk.children.get("root", []):
        visit(c, 0, np.zeros(3))

    frames = _read_amc_frames(sk, asf_path, amc_path)
    if not frames:
        raise CorruptFileError(f"{amc_path}: no frames (is this an AMC file?)")
    T = len(frames)
    J = len(names)
    # per-joint motion rotation M in the bone's local frame
    q_m = np.zeros((T, J, 4))
    q_m[..., 0] = 1.0
    root_t = np.zeros((T, 3))
    ro = sk.root_order
    tcols = [ro.index(a) for a in ("TX", "TY", "TZ")]
    rdofs = [a for a in ro if a.startswith("R")]
    rcols = [ro.index(a) for a in rdofs]
    vals = np.asarray([f.get("root", [0.0] * len(ro)) for f in frames])
    root_t = vals[:, tcols] * k
    q_m[:, 0] = _acclaim_quat(vals[:, rcols], "".join(a[1] for a in rdofs), sk.degrees)
    for bname, j in bone_joint.items():
        dof = sk.bones[bname]["dof"]
        if not dof:
            continue
        v = np.asarray([f.get(bname, [0.0] * len(dof)) for f in frames])
        q_m[:, j] = _acclaim_quat(v, "".join(d[1].upper() for d in dof), sk.degrees)
    c = np.stack(local_c)  # (J, 4)
    q = jnp.asarray(quat_mul(quat_mul(c[None], q_m), quat_conj(c)[None]))  # L = C M C^-1
    return Motion(
        names=tuple(names),
        parents=tuple(parents),
        offsets=jnp.asarray(np.stack(offsets)),
        root_translation=jnp.asarray(root_t),
        rotations=q,
        rate=float(rate),
        channels=tuple(channels),
    )
