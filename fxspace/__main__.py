"""``python -m fxspace`` is the ``fxspace`` command."""

from fxspace.cli import main

if __name__ == "__main__":
    raise SystemExit(main())
