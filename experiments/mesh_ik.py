"""Mesh IK experiment (Park, Kang & Kwon §5, Figs. 4-10): every mesh, 300 frames,
1/5/10/50/120 markers from a random viewpoint, cold and warm starts, LM and BFGS on the
factored vs naive gradient, regularisers with few markers.

    python experiments/mesh_ik.py [--out DIR] [--force]

Writes the figures, ``table.md`` and ``metrics.json`` into ``runs/mesh_ik`` (or ``--out``).
"""

import os
import sys

# one BLAS thread: LM's Cholesky solves are small (see experiments/bench_ik.py)
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

from fxspace.cli import main  # noqa: E402

if __name__ == "__main__":
    raise SystemExit(main(["run", "configs/mesh_ik.toml", *sys.argv[1:]]))
