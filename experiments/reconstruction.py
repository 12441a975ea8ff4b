"""Control-point reconstruction (issue 4): ``python experiments/reconstruction.py [--out DIR]``."""

import sys

from fxspace.cli import main

if __name__ == "__main__":
    raise SystemExit(main(["run", "configs/reconstruction.toml", *sys.argv[1:]]))
