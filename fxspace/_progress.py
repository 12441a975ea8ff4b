"""Progress display for long work (tqdm on stderr; silent when ``FXSPACE_QUIET=1``)."""

from __future__ import annotations

import os
import sys
from collections.abc import Iterable, Iterator
from typing import TypeVar

T = TypeVar("T")


def progress(it: Iterable[T], desc: str, total: int | None = None) -> Iterator[T]:
    """Wrap an iterable with a progress bar labelled ``desc``."""
    if os.environ.get("FXSPACE_QUIET") == "1":
        yield from it
        return
    from tqdm.auto import tqdm

    yield from tqdm(it, desc=desc, total=total, leave=False, dynamic_ncols=True)


def stage(msg: str) -> None:
    """A stage line ``[fxspace] msg`` on stderr (silent when ``FXSPACE_QUIET=1``)."""
    if os.environ.get("FXSPACE_QUIET") != "1":
        print(f"[fxspace] {msg}", file=sys.stderr, flush=True)
