"""Threshold sweep on the real AnimFace capture.

Usage: ``python experiments/threshold_sweep.py [--out DIR] [--force]``.
"""

import sys

from fxspace.cli import main

if __name__ == "__main__":
    raise SystemExit(main(["run", "configs/threshold_sweep.toml", *sys.argv[1:]]))
