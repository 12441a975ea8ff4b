"""Mesh IK experiment (issue 6): ``python experiments/mesh_ik.py [--out DIR]``."""

import sys

from fxspace.cli import main

if __name__ == "__main__":
    raise SystemExit(main(["run", "configs/mesh_ik.toml", *sys.argv[1:]]))
