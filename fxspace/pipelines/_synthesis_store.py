"""A built set-up as arrays and back (the ``setup`` stage's ``cache/<setup>_setup.npz``)."""

from __future__ import annotations

import json
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from fxspace import motion as M
from fxspace.io import Motion
from fxspace.pipelines._synthesis_clips import _build_setup
from fxspace.pipelines._synthesis_config import Config
from fxspace.runs import cached_arrays

_SP_ARRAYS = (
    "lam",
    "offsets",
    "lower_weights",
    "lower_params",
    "upper_weights",
    "upper_params",
    "lower_w0",
    "lower_time",
    "upper_time",
    "posture_transfer",
    "joint_steps",
)
_SP_META = (
    "parents",
    "mask",
    "spine",
    "lower_joint",
    "lower_dims",
    "upper_joint",
    "k_replace",
    "knn_k",
    "min_slope",
    "max_clock_rate",
    "splice",
    "torso",
    "replace",
)


def _setup_to_arrays(st: M.Setup) -> dict:
    sp, sk = st.spaces, st.skeleton
    arr = {f"lower_{k}": v for k, v in sp.lower._asdict().items()}
    arr |= {f"upper_{k}": v for k, v in sp.upper._asdict().items()}
    arr |= {k: getattr(sp, k) for k in _SP_ARRAYS}
    arr |= {"skel_offsets": sk.offsets, "skel_root": sk.root_translation, "skel_rot": sk.rotations}
    meta = {k: getattr(sp, k) for k in _SP_META}
    meta |= dict(
        name=st.name,
        names=sk.names,
        skel_parents=sk.parents,
        channels=sk.channels,
        rate=sk.rate,
        scale=st.scale,
        feet=st.feet,
        lower_names=st.lower_names,
        upper_names=st.upper_names,
        info=st.info,
    )
    arr["meta"] = np.asarray(json.dumps(meta))
    return arr


def _setup_from_arrays(a: dict) -> M.Setup:
    meta = json.loads(str(a["meta"]))
    ex = {
        s: M.ExampleSet(**{k: jnp.asarray(a[f"{s}_{k}"]) for k in M.ExampleSet._fields})
        for s in ("lower", "upper")
    }
    tup = {k: tuple(v) if isinstance(v, list) else v for k, v in meta.items() if k in _SP_META}
    if "joint_steps" not in a:  # a set-up stored before the joint-speed bound: derived
        a = {
            **a,
            "joint_steps": M.example_joint_steps(
                ex["lower"], ex["upper"], tuple(meta["parents"]), np.asarray(a["offsets"])
            ),
        }
    sp = M.SynthesisSpaces(**ex, **{k: jnp.asarray(a[k]) for k in _SP_ARRAYS}, **tup)
    skel = Motion(
        tuple(meta["names"]),
        tuple(meta["skel_parents"]),
        np.asarray(a["skel_offsets"]),
        np.asarray(a["skel_root"]),
        np.asarray(a["skel_rot"]),
        float(meta["rate"]),
        tuple(tuple(c) for c in meta["channels"]),
    )
    return M.Setup(
        meta["name"],
        sp,
        skel,
        float(meta["scale"]),
        tuple(meta["feet"]),
        meta["lower_names"],
        meta["upper_names"],
        meta["info"],
    )



def _stage_setup(name: str, cfg: Config, run_dir: Path, key) -> M.Setup:
    def compute() -> dict:
        return _setup_to_arrays(_build_setup(name, cfg, jax.random.fold_in(key, 0)))

    return _setup_from_arrays(cached_arrays(run_dir, f"{name}_setup", compute))
