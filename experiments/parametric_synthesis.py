"""Decoupled parametric motion synthesis on CMU clips: walk + block, kick + block.

python experiments/parametric_synthesis.py [--out DIR] [--force]
"""

import sys

from fxspace.cli import main

raise SystemExit(main(["run", "configs/parametric_synthesis.toml", *sys.argv[1:]]))
