"""The mesh IK experiment's configuration (`fxspace.pipelines.mesh_ik`): the meshes, marker
counts, solvers and regulariser weights, and the mesh specs they name."""

from __future__ import annotations

import dataclasses
from typing import Literal

from fxspace.config import ConfigError

PAPER = {"accelerated_ms": 32.5, "naive_ms": 90.6, "speedup_mean": 3.14, "speedup_human": 2.78}


SOLVERS = (
    "lm",
    "bfgs_factored",
    "bfgs_naive",
)  # the naive run replays frames (see _per_frame_replay)


@dataclasses.dataclass(frozen=True)
class Config:
    """``meshes``: ``"File:animation"`` (file stem under ``mesh/``; empty animation = the
    first); ``"File+N:animation"`` is that mesh subdivided to ``N`` vertices
    (`fxspace.mesh.subdivide_mesh`, e.g. CesiumMan at the paper's 13.8k), ``"chainN:wave"``
    a procedural chain of ``N`` joints (`fxspace.mesh.chain_mesh`).
    ``view_dir``: the camera's viewing direction for marker placement; empty =
    a random viewpoint (seeded) with enough visible triangles. ``reg_*``: the regulariser
    weights of the comparison (``fxspace.mesh.ik_regularization``)."""

    meshes: tuple[str, ...] = (
        "CesiumMan:Anim_0",
        "Fox:Walk",
        "RiggedSimple:",
        "CesiumMan+13800:Anim_0",
        "chain48:wave",
    )
    marker_counts: tuple[int, ...] = (1, 5, 10, 50, 120)
    num_frames: int = 300
    view_dir: tuple[float, ...] = ()
    lm_rtol: float = 1e-3
    lm_steps: int = 50
    bfgs_rtol: float = 1e-3
    bfgs_steps: int = 200
    naive_frames: int = 60  # frames (evenly spaced) the naive-gradient BFGS is timed on
    starts: tuple[str, ...] = ("cold", "warm")
    gradient_repeats: int = 3
    figure_frame: float = 0.5  # which frame (fraction of the animation) the pose figure shows
    reg_mesh: str = "CesiumMan:Anim_0"
    reg_marker_counts: tuple[int, ...] = (1, 5, 10)
    reg_prior: float = 1e-3
    reg_prior_to: Literal["rest", "previous"] = "previous"
    reg_limits: float = 1.0
    reg_limit: float = 1.5707963267948966
    reg_normal: float = 1e-2
    dtype: Literal["float32", "float64"] = "float64"

    def validate(self) -> None:
        if not self.meshes:
            raise ConfigError("meshes must name at least one mesh, e.g. 'CesiumMan:Anim_0'")
        for spec in self.meshes:
            _parse_spec(spec)
        if not self.marker_counts or min(self.marker_counts) < 1:
            raise ConfigError("marker_counts must be positive integers")
        if self.view_dir and (len(self.view_dir) != 3 or not any(self.view_dir)):
            raise ConfigError("view_dir must be empty (random) or a non-zero 3-vector")
        if self.num_frames < 2 or self.gradient_repeats < 1 or self.naive_frames < 1:
            raise ConfigError("num_frames >= 2, naive_frames >= 1, gradient_repeats >= 1 please")
        if not set(self.starts) <= {"cold", "warm"} or not self.starts:
            raise ConfigError("starts must be a non-empty subset of ['cold', 'warm']")
        if not 0.0 <= self.figure_frame <= 1.0:
            raise ConfigError("figure_frame is a fraction of the animation in [0, 1]")
        for name in ("reg_prior", "reg_limits", "reg_normal", "lm_rtol", "bfgs_rtol"):
            if not getattr(self, name) >= 0:
                raise ConfigError(f"{name} must be >= 0")
        if self.reg_prior_to not in ("rest", "previous"):
            raise ConfigError("reg_prior_to must be 'rest' or 'previous'")


def _parse_spec(spec: str) -> tuple[str, int, str]:
    """``(kind, n, animation)`` of a mesh spec: kind ``"chain"`` (n joints) or a file stem
    (n = vertices to subdivide to, 0 = as read)."""
    stem, _, anim = str(spec).partition(":")
    if stem.startswith("chain"):
        n = stem[5:] or "48"
        if not n.isdigit() or int(n) < 2:
            raise ConfigError(f"meshes: {spec!r}: a chain is 'chainN' with N >= 2 joints")
        return "chain", int(n), anim
    base, plus, n = stem.partition("+")
    if not base or (plus and (not n.isdigit() or int(n) < 1)):
        raise ConfigError(f"meshes: {spec!r} is not 'File:anim', 'File+N:anim' or 'chainN:anim'")
    return base, int(n) if plus else 0, anim
