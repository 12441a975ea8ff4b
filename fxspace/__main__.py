"""``python -m fxspace`` is the ``fxspace`` command."""

from fxspace.cli import main

raise SystemExit(main())
