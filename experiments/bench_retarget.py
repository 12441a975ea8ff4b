"""Benchmark: retargeting captured walks onto CesiumMan by the mesh IK (`fx.mesh.retarget`)
against plain rotation copying, and the source's own foot slide.

Takes: CMU 131_09 (ASF/AMC, 120 Hz, a walk to the left) and Bandai
``dataset-1_walk_normal_001`` (BVH in cm, 30 Hz), onto ``mesh/CesiumMan.glb``, the
correspondences from the joint-name map (`fx.motion.joint_map_for`, CMU / Bandai names →
CesiumMan's). Printed per take:

* joint error: median over frames of the mean distance of the character's corresponded
  joints from the scaled source's, in character heights (mesh IK vs rotation copy);
* foot slide: mean horizontal motion per frame of the foot/toe joints in contact (the
  source's contacts), in character heights and in mm per frame on the character: the
  mesh IK, the scaled source itself, rotation copy (goal: ours ≤ the source's);
* ms per frame: the IK solve along the take, warm (compiled), median of ``--repeats``
  calls (goal ≤ 2 ms), and rotation copying's.

    python experiments/bench_retarget.py            # both takes, 5 repeats
    python experiments/bench_retarget.py --quick    # 2 repeats, CMU take cut to 600 frames
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import numpy as np  # noqa: E402

TAKES = (
    ("CMU 131_09 walk", "cmu"),
    ("Bandai walk_normal_001", "bandai"),
)


def _read(fx, root, kind):
    body = root / "body"
    if kind == "cmu":
        cmu = body / "cmu" / "131"
        return fx.io.read_amc(cmu / "131.asf", cmu / "131_09.amc.gz")
    return fx.io.read_bvh(body / "bandai" / "dataset-1_walk_normal_001.bvh.gz", units="cm")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="2 repeats, the CMU take cut short")
    ap.add_argument("--repeats", type=int, default=None)
    args = ap.parse_args(argv)
    os.environ.setdefault("FXSPACE_QUIET", "1")
    import jax

    import fxspace as fx
    from fxspace.data import data_root

    root = data_root()
    if root is None:
        print("bench_retarget: real data absent (set FXSPACE_DATA); nothing measured")
        return 1
    repeats = args.repeats or (2 if args.quick else 5)
    man = fx.io.read_gltf(root / "mesh" / "CesiumMan.glb")
    cmap = fx.motion.joint_map_for(man.joint_names, required=())
    print(f"CesiumMan: {man.num_joints} joints ({cmap.describe()}); {jax.devices()[0]}, "
          f"{np.dtype(jax.numpy.result_type(float)).name}")  # fmt: skip
    hdr = (f"{'take':24s} {'frames':>6s} {'pairs':>5s} {'err ik':>7s} {'err copy':>8s} "
           f"{'slide ik':>9s} {'slide src':>9s} {'slide copy':>10s} {'mm/f ik':>7s} "
           f"{'mm/f src':>8s} {'ik ms/f':>7s} {'copy ms/f':>9s} {'compile s':>9s}")  # fmt: skip
    print(hdr)
    record = []
    for label, kind in TAKES:
        m = _read(fx, root, kind)
        if args.quick and m.num_frames > 600:
            m = m.frames(slice(0, 600))
        jm = fx.motion.joint_map_for(m).correspondences(cmap)
        r = fx.mesh.retarget(m, man, jm)  # compiles
        ms, cms = [], []
        for _ in range(repeats):
            t0 = time.perf_counter()
            rr = fx.mesh.retarget(m, man, jm)
            _ = time.perf_counter() - t0
            ms.append(rr.ms_per_frame)
            cms.append(rr.baseline.ms_per_frame)
        s, c = r.summary(), r.baseline.summary()
        ik_ms, copy_ms = statistics.median(ms), statistics.median(cms)
        mm = 1e3 * r.height
        print(f"{label:24s} {m.num_frames:6d} {len(jm):5d} {s['joint_error_median']:7.4f} "
              f"{c['joint_error_median']:8.4f} {s['foot_slide_mean']:9.2e} "
              f"{s['source_foot_slide_mean']:9.2e} {c['foot_slide_mean']:10.2e} "
              f"{s['foot_slide_mean'] * mm:7.3f} {s['source_foot_slide_mean'] * mm:8.3f} "
              f"{ik_ms:7.3f} {copy_ms:9.3f} {r.compile_s:9.2f}")  # fmt: skip
        ok_slide = s["foot_slide_mean"] <= s["source_foot_slide_mean"]
        print(f"  {r.result!s}; scale {r.scale:.3f}; contact frames per foot joint "
              f"{r.contacts.sum(0)[r.contacts.any(0)].tolist()}; foot slide "
              f"{'no worse than' if ok_slide else 'WORSE than'} the source's; "
              f"{'≤' if ik_ms <= 2.0 else '>'} 2 ms per frame warm")  # fmt: skip
        record.append({"case": f"{label} onto CesiumMan ({m.num_frames} frames), per frame",
                       "size": m.num_frames, "ours": "fx.mesh.retarget (mesh IK, warm)",
                       "ours_s": ik_ms / 1e3, "peer": "rotation copying",
                       "peer_s": copy_ms / 1e3})  # fmt: skip
    print("err: median joint error (character heights); slide: mean foot slide in contact "
          "(character heights per frame); mm/f: the same in mm per frame on the character")
    from fxspace.runs import write_bench

    cmd = "python experiments/bench_retarget.py " + " ".join(argv or sys.argv[1:])
    write_bench("retarget", record, title="Retargeting walks onto CesiumMan", command=cmd)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
