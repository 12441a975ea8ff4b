"""Navigation at scale: 100 000 frames, sparse end to end, down to every frame.

python experiments/navigation_scale.py [--out DIR] [--force]
"""

import sys

from fxspace.cli import main

raise SystemExit(main(["run", "configs/navigation_scale.toml", *sys.argv[1:]]))
