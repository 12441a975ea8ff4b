"""Hierarchical navigation on the AnimFace capture.

python experiments/navigation.py [--out DIR] [--force]
"""

import sys

from fxspace.cli import main

raise SystemExit(main(["run", "configs/navigation.toml", *sys.argv[1:]]))
