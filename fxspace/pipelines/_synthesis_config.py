"""The ``parametric_synthesis`` experiment's config (`Config`, its ``[synth]`` table
`SynthConfig`), checked by `Config.validate`."""

from __future__ import annotations

import dataclasses
from pathlib import Path

from fxspace import motion as M
from fxspace.config import ConfigError


@dataclasses.dataclass(frozen=True)
class SynthConfig:
    alphas: tuple[float, ...] = (0.0, 0.5, 1.0)
    alpha: float = 0.5  # the one written as BVH
    n_queries: int = 20
    joy_weights: tuple[float, ...] = (0.0, 0.2, 0.4, 0.6, 0.8, 1.0)
    timing_repeats: int = 20
    session_s: float = 60.0  # the scripted continuous session (walks); 0 skips it
    session_every_s: float = 2.0  # controls changed this often


@dataclasses.dataclass(frozen=True)
class Config:
    setups: tuple[str, ...] = ("mood_walk", "block_walk", "block_kick")
    stride: int = 4  # CMU 120 Hz → 30 Hz (the Bandai clips are 30 Hz)
    data: M.SetupData = M.SetupData()
    space: M.SetupSpace = M.SetupSpace()
    synth: SynthConfig = SynthConfig()
    x64: bool = False  # run in float64 (jax.enable_x64 for the run only)
    skeleton: M.SkeletonSpec = M.SkeletonSpec()  # [skeleton] map = {role = "joint name"}

    def validate(self) -> None:
        for s in self.setups:
            if s not in M.SETUPS:
                raise ConfigError(f"setups: unknown set-up {s!r}; choose from {list(M.SETUPS)}")
        self.data.validate()
        self.skeleton.validate()
        if self.data.source == "files":
            if len(self.setups) != 1:
                raise ConfigError(
                    f"data.source = 'files' feeds one set-up; set setups to one of "
                    f"{list(M.SETUPS)}, got {list(self.setups)}"
                )
            n_up = sum(c.part == "upper" for c in self.data.clips)
            if self.setups[0] == "mood_walk" and n_up != 2:
                raise ConfigError(
                    f"data.clips: mood_walk weighs two upper-body walks (w and 1 − w; e.g. "
                    f"labels 'proud' and 'tired'), got {n_up} with part = 'upper'"
                )
            for c in self.data.clips:
                for key, f in (("path", c.path), ("asf", c.asf)):
                    if f and not Path(f).is_file():
                        what = "is a directory" if Path(f).is_dir() else "does not exist"
                        raise ConfigError(
                            f"data.clips: {key} {f} {what} (relative paths resolve against the "
                            "config file's folder)"
                        )
        if self.stride < 1:
            raise ConfigError("stride must be >= 1")
        if not 0.0 <= self.synth.alpha <= 1.0 or any(not 0 <= a <= 1 for a in self.synth.alphas):
            raise ConfigError("synth.alpha and synth.alphas must lie in [0, 1]")
        if not 3 <= self.space.k_replace <= self.space.n_samples:
            raise ConfigError("space.k_replace must be between 3 and space.n_samples")
        if self.space.splice not in ("heck", "heading"):
            raise ConfigError(
                f"space.splice must be 'heck' (spatial alignment + posture transfer, Heck et "
                f"al. 2006) or 'heading' (heading-relative spine copy), got {self.space.splice!r}"
            )
        if self.space.replace not in ("rotation", "rigid"):
            raise ConfigError(
                f"space.replace must be 'rotation' (§3.2 as printed: one rotation about the "
                f"root) or 'rigid' (rotation + translation), got {self.space.replace!r}"
            )
        if not 0.0 <= self.space.posture_transfer <= 1.0:
            raise ConfigError("space.posture_transfer must lie in [0, 1]")
        if self.space.knn_k < 2:
            raise ConfigError("space.knn_k must be at least 2 (k-NN interpolation)")
        if self.synth.n_queries < 2:
            raise ConfigError("synth.n_queries must be at least 2")
        if not self.synth.session_s >= 0 or not self.synth.session_every_s > 0:
            raise ConfigError("synth.session_s must be >= 0 and synth.session_every_s > 0")
        if not self.space.max_clock_rate > 0:
            raise ConfigError("space.max_clock_rate must be > 0 (inf: eqs. 2–3 uncapped)")
        if self.space.n_samples < 1 or self.data.cycles < 1 or self.data.max_reps < 1:
            raise ConfigError("space.n_samples, data.cycles and data.max_reps must be >= 1")
