"""The same user calls timed at two revisions of fxspace: did a change slow anything down?

    python experiments/bench_revisions.py [--before REV] [--after REV] [--repeats 5]

Each revision is exported (``git archive``) to a temporary folder and timed in its own
subprocess (``PYTHONPATH`` and the working directory set to that folder), so the two
runs share the installed libraries and nothing else. The calls are public, stable names
(`fx.expression_space`, `fx.navigation.build_hierarchy`, `fx.fuzzy_cmeans`,
`fx.solve_ik` per frame, `fx.track_ik`), with the same inputs at both revisions; each is
called once to compile, then timed ``--repeats`` times; ``--rounds`` processes per
revision, alternating, and the median over all. With ``REV`` ``.``
(the default for ``--after``) the working tree is timed as it is.

The default ``--before`` is the last commit before issue 29's interface work (one
hierarchy interface for dense and sparse, one IK solver loop, one result record, one
config reader, apps as controller + view). Writes ``runs/bench/revisions.json`` (the
docs' benchmark page draws it): "ours" is ``--after``, "peer" is ``--before``.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
BEFORE_29 = "7b90cc0"  # the parent of 68bcb7b, issue 29's first commit

# runs inside the revision's folder: only names both revisions export
_CHILD = r"""
import json, statistics, sys, time
import jax, jax.numpy as jnp, numpy as np
import fxspace as fx

R = int(sys.argv[1])
out = {}

def med(name, fn):
    jax.block_until_ready(fn())  # compile and warm
    ts = []
    for _ in range(R):
        t = time.perf_counter()
        jax.block_until_ready(fn())
        ts.append(time.perf_counter() - t)
    out[name] = statistics.median(ts)
    print(f"  {name}: {out[name]:.4f} s", file=sys.stderr, flush=True)

face = fx.synthetic.synthetic_face(n_frames=600, seed=0)
X = jnp.asarray(face.sequence.positions)
eps = 1.05 * float(fx.connecting_threshold(fx.expression_space(X, 1e9, paths=False).pairwise))
med("expression_space", lambda: fx.expression_space(X, eps).mds.embedding)
sp = fx.expression_space(X, eps)
key = jax.random.PRNGKey(0)
# rho_scale=0.5: the ρ both revisions know (the later default runs the ρ experiment too)
med("build_hierarchy", lambda: fx.navigation.build_hierarchy(
    sp.mds.embedding, sp.geodesics, key=key, rho_scale=0.5).levels[-1].centers)
pts = np.random.default_rng(0).normal(size=(2400, 2)).astype(np.float32)
med("fuzzy_cmeans", lambda: fx.fuzzy_cmeans(jnp.asarray(pts), 40, key=key).centers)

from fxspace.data import data_path
try:
    mesh = fx.io.read_gltf(data_path("mesh", "CesiumMan.glb"))
except Exception as e:  # no shared data: the IK rows are left out
    print(f"  IK skipped: {e}", file=sys.stderr)
else:
    ms = fx.place_markers(mesh.vertices, mesh.faces, 120, seed=0)
    model = fx.ik_model(mesh, ms)
    anim = mesh.animation_names[0]
    t0, t1 = mesh.animation_range(anim)
    V = fx.mesh.animation_vertices(mesh, anim, np.linspace(t0, t1, 60))
    T = np.stack([np.asarray(fx.mesh.marker_positions(v, mesh.faces, ms)) for v in V])
    T32 = jnp.asarray(T, jnp.float32)

    def per_frame():
        pose = None
        for t in range(len(T32)):
            pose = fx.solve_ik(model, T32[t], pose).pose
        return pose.angles

    med("solve_ik_per_frame", lambda: per_frame())
    out["solve_ik_per_frame"] /= len(T32)
    med("track_ik", lambda: fx.track_ik(model, T32).pose.angles)
print(json.dumps(out))
"""

CASES = {
    "expression_space": "fx.expression_space: 600 synthetic frames, geodesics + MDS",
    "build_hierarchy": "fx.navigation.build_hierarchy: FCM levels + links (ρ scale 0.5)",
    "fuzzy_cmeans": "fx.fuzzy_cmeans: 2 400 points, c = 40",
    "solve_ik_per_frame": "fx.solve_ik per frame (CesiumMan, 120 markers, float32, warm)",
    "track_ik": "fx.track_ik: the same 60 frames",
}


def _export(rev: str, into: Path) -> Path:
    if rev == ".":
        return ROOT
    into.mkdir(parents=True)
    archive = subprocess.run(["git", "-C", str(ROOT), "archive", rev], check=True,
                             capture_output=True).stdout  # fmt: skip
    subprocess.run(["tar", "-x", "-C", str(into)], input=archive, check=True)
    return into


def _label(rev: str) -> str:
    """``rev`` as a commit (``.``: HEAD, ``-dirty`` when the working tree differs)."""
    args = ["describe", "--always", "--dirty"] if rev == "." else ["rev-parse", "--short", rev]
    return subprocess.run(["git", "-C", str(ROOT), *args], check=True, capture_output=True,
                          text=True).stdout.strip()  # fmt: skip


def _time(tree: Path, repeats: int) -> dict[str, float]:
    env = {**os.environ, "PYTHONPATH": str(tree)}
    env.setdefault("FXSPACE_DATA", str(ROOT.parent / "shared" / "data"))
    p = subprocess.run([sys.executable, "-c", _CHILD, str(repeats)], cwd=tree, env=env,
                       check=True, stdout=subprocess.PIPE, text=True)  # fmt: skip
    return json.loads(p.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--before", default=BEFORE_29)
    ap.add_argument("--after", default=".")
    ap.add_argument("--repeats", type=int, default=5, help="timed calls per process")
    ap.add_argument("--rounds", type=int, default=3,
                    help="processes per revision, alternating before / after")  # fmt: skip
    a = ap.parse_args()
    with tempfile.TemporaryDirectory() as d:
        trees = {n: _export(r, Path(d) / n) for n, r in (("before", a.before), ("after", a.after))}
        runs: dict[str, list[dict[str, float]]] = {"before": [], "after": []}
        for i in range(a.rounds):  # alternating: a slow spell of the machine hits both
            for name, tree in trees.items():
                print(f"round {i + 1}, {name}:", file=sys.stderr, flush=True)
                runs[name].append(_time(tree, a.repeats))
    res = {n: {k: statistics.median(r[k] for r in rs) for k in rs[0]} for n, rs in runs.items()}
    rows = []
    print(
        f"\nmedians of {a.rounds} processes × {a.repeats} calls; ratio = before / after "
        "(above 1: faster now)"
    )
    print(f"{'call':<66} {'before':>9} {'after':>9} {'ratio':>6}")
    for k, label in CASES.items():
        if k not in res["before"] or k not in res["after"]:
            continue
        b, f = res["before"][k], res["after"][k]
        unit, s = ("ms", 1e3) if max(b, f) < 1 else ("s", 1.0)
        print(f"{label:<66} {b * s:>7.2f}{unit:>2} {f * s:>7.2f}{unit:>2} {b / f:>5.2f}x")
        rows.append({"case": label, "ours": f"after ({_label(a.after)})", "ours_s": f,
                     "peer": f"before ({_label(a.before)})", "peer_s": b})  # fmt: skip
    from fxspace.runs import write_bench

    cmd = "python experiments/bench_revisions.py " + " ".join(sys.argv[1:])
    write_bench("revisions", rows, title="The same calls at two revisions", command=cmd.strip())


if __name__ == "__main__":
    main()
