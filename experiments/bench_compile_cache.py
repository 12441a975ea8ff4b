"""Does the serialised-executable cache earn its keep? (issue 46, item 5)

fxspace turns on JAX's persistent compilation cache (`fxspace._compile_cache`,
``FXSPACE_COMPILE_CACHE``). On top of it, `cached_executable` used to serialise the motion
app's compiled kernels (the locomotion step, its initial state, the turning rates) to disk,
so that a new process would skip tracing and lowering as well as compiling. This script
times what a user waits for, in fresh processes, with the two set-ups:

- ``persistent``: JAX's persistent compilation cache alone (the kernels are plain
  ``jax.jit`` functions; ``fxspace.motion._locomotion.cached_executable`` is replaced by
  the jitted function in the child);
- ``executables``: the library as it is (`cached_executable` as the code defines it).

The workload is the motion app's start (what ``fxspace studio`` does for a
``parametric_synthesis`` run before the first frame): ``load_setup(RUN)``, then
``MotionController(setup)`` (turn table, initial state, the compiled step) and 10 steps.
A sweep's run of ``parametric_synthesis`` calls the same kernels (`session_turn_table`,
`init_locomotion`), so its compile part gains or loses the same way.

Each set-up is timed **cold** (an empty cache folder: the first start after an install or
an upgrade) and **cached** (the folder the cold start filled: every later start), ``--reps``
times (median printed), the set-ups interleaved so machine load hits both alike. The key
of a serialised executable includes fxspace's source digest: run it on a tree nobody edits
meanwhile (a copy: ``git archive HEAD | tar -x -C /tmp/src``), else every start is cold.

Usage: ``python experiments/bench_compile_cache.py [--run runs/parametric_synthesis]
[--reps 3] [--json out.json]``.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
MODES = ("persistent", "executables")

_CHILD = r"""
import json, sys, time
t0 = time.perf_counter()
import fxspace
from fxspace._compile_cache import compile_timer
from fxspace.studio._motion_controller import MotionController, load_setup
mode, run = sys.argv[1], sys.argv[2]
if mode == "persistent":
    import fxspace.motion._locomotion as L

    class _Jit:  # the jitted function itself: compiled through JAX's persistent cache
        source = "jit"

        def __init__(self, fn):
            self.fn = fn

        def __call__(self, *args):
            return self.fn(*args)

    L.cached_executable = lambda fn, *args: _Jit(fn)
t1 = time.perf_counter()
setup = load_setup(run)
t2 = time.perf_counter()
with compile_timer() as timer:
    c = MotionController(setup)
    for _ in range(10):
        c.step()
    c.joints()
t3 = time.perf_counter()
print("RESULT " + json.dumps({
    "import_s": t1 - t0, "load_s": t2 - t1, "controller_s": t3 - t2, "total_s": t3 - t0,
    "controller_compile_s": timer.summary()["compile_s"], "step_source": c._step.source,
    "fxspace": fxspace.__file__,
}))
"""


def _child(mode: str, run: Path, cache: Path, timeout: float) -> dict:
    env = {**os.environ, "FXSPACE_COMPILE_CACHE": str(cache / "jax"), "JAX_PLATFORMS": "cpu",
           "TF_CPP_MIN_LOG_LEVEL": "2", "PYTHONPATH": str(ROOT)}  # fmt: skip
    t = time.perf_counter()
    r = subprocess.run([sys.executable, "-c", _CHILD, mode, str(run)], cwd=ROOT, env=env,
                       capture_output=True, text=True, timeout=timeout)  # fmt: skip
    if r.returncode != 0:
        raise SystemExit(f"{mode}: the child failed:\n{r.stderr[-3000:]}")
    line = [ln for ln in r.stdout.splitlines() if ln.startswith("RESULT ")][-1]
    out = json.loads(line[len("RESULT ") :])
    out["process_s"] = time.perf_counter() - t
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--run", default=str(ROOT / "runs" / "parametric_synthesis"))
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--timeout", type=float, default=600.0)
    ap.add_argument("--json", default=None)
    a = ap.parse_args()
    run = Path(a.run).resolve()
    if not (run / "config.toml").exists():
        raise SystemExit(f"--run {run}: no config.toml; run `fxspace run "
                         "configs/parametric_synthesis.toml` first")  # fmt: skip
    got: dict[str, dict[str, list[dict]]] = {m: {"cold": [], "cached": []} for m in MODES}
    for rep in range(a.reps):
        for mode in MODES if rep % 2 == 0 else MODES[::-1]:
            cache = Path(tempfile.mkdtemp(prefix=f"fx-bench-cc-{mode}-"))
            try:
                for phase in ("cold", "cached"):
                    r = _child(mode, run, cache, a.timeout)
                    got[mode][phase].append(r)
                    print(
                        f"rep {rep} {mode:11s} {phase:6s} controller {r['controller_s']:6.2f} s"
                        f"  total {r['total_s']:6.2f} s  step {r['step_source']}",
                        flush=True,
                    )
            finally:
                shutil.rmtree(cache, ignore_errors=True)
    print(f"\nmedians of {a.reps} fresh processes (seconds), {got[MODES[0]]['cold'][0]['fxspace']}")
    print(
        f"{'set-up':12s} {'phase':7s} {'controller':>10s} {'its compile':>11s} "
        f"{'load_setup':>10s} {'total':>7s}"
    )
    summary = {}
    for mode in MODES:
        for phase in ("cold", "cached"):
            rs = got[mode][phase]
            med = {k: statistics.median(r[k] for r in rs) for k in
                   ("controller_s", "controller_compile_s", "load_s", "total_s")}  # fmt: skip
            summary[f"{mode}/{phase}"] = med
            print(
                f"{mode:12s} {phase:7s} {med['controller_s']:10.2f} "
                f"{med['controller_compile_s']:11.2f} {med['load_s']:10.2f} "
                f"{med['total_s']:7.2f}"
            )
    if a.json:
        Path(a.json).write_text(json.dumps({"summary": summary, "runs": got}, indent=1))


if __name__ == "__main__":
    main()
