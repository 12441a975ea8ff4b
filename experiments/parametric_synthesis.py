"""Decoupled parametric motion synthesis (Ha & Han), the three set-ups of Table 1:
mood walk and block-while-walking (Bandai Namco captures), block + kick (CMU subject 135).

python experiments/parametric_synthesis.py [--out DIR] [--force]
(one set-up: fxspace run configs/mood_walk.toml | block_walk.toml | block_kick.toml)
"""

import sys

from fxspace.cli import main

raise SystemExit(main(["run", "configs/parametric_synthesis.toml", *sys.argv[1:]]))
