"""Serial vs ``--workers 2`` wall time of ``configs/sweep_example.toml`` (medians).

    python experiments/bench_sweep.py [--repeats 3] [--workers 2]

Each repeat runs the sweep into a fresh folder with ``fxspace sweep --engine serial``
and with ``fxspace sweep --workers N`` (Dask when installed, else processes), in
subprocesses (fresh JAX, persistent compile cache as configured), and prints the median
wall times and the ratio serial / parallel.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CONFIG = ROOT / "configs" / "sweep_example.toml"


def _time(args: list[str]) -> float:
    with tempfile.TemporaryDirectory() as d:
        cmd = [sys.executable, "-m", "fxspace.cli", "sweep", str(CONFIG), "--out", d, *args]
        env = {**os.environ, "PYTHONPATH": str(ROOT)}
        t0 = time.perf_counter()
        subprocess.run(cmd, env=env, check=True, capture_output=True)
        return time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--workers", type=int, default=2)
    a = ap.parse_args()
    serial, par = [], []
    for i in range(a.repeats):
        serial.append(_time(["--engine", "serial"]))
        par.append(_time(["--workers", str(a.workers)]))
        print(f"repeat {i + 1}: serial {serial[-1]:.1f} s, workers={a.workers} {par[-1]:.1f} s")
    s, p = statistics.median(serial), statistics.median(par)
    print(f"sweep_example ({a.repeats} repeats, medians): serial {s:.1f} s, "
          f"--workers {a.workers} {p:.1f} s, ratio serial/parallel {s / p:.2f}x")  # fmt: skip
    from fxspace.runs import write_bench

    write_bench("sweep", [{"case": "configs/sweep_example.toml, whole sweep",
                           "ours": f"--workers {a.workers} (Dask)", "ours_s": p,
                           "peer": "serial engine", "peer_s": s}],
                title="A sweep's wall time: parallel against serial",
                command="python experiments/bench_sweep.py " + " ".join(sys.argv[1:]))  # fmt: skip


if __name__ == "__main__":
    main()
