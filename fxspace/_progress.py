"""Progress display for long work (tqdm on stderr; silent when ``FXSPACE_QUIET=1``)."""

from __future__ import annotations

import contextlib
import logging
import os
import sys
import threading
from collections.abc import Callable, Iterable, Iterator
from typing import TypeVar

T = TypeVar("T")

#: the package's logger: `note` records go here too (a NullHandler: no double printing)
_LOG = logging.getLogger("fxspace")
_LOG.addHandler(logging.NullHandler())

#: callables told every stage line and progress step (an app's waiting page shows them)
_LISTENERS: list[Callable[[str], None]] = []


@contextlib.contextmanager
def listening(fn: Callable[[str], None]) -> Iterator[None]:
    """Within the block, ``fn(message)`` is told every `stage` line and `progress` step
    (as well as the terminal)."""
    _LISTENERS.append(fn)
    try:
        yield
    finally:
        _LISTENERS.remove(fn)


_SILENT = threading.local()


@contextlib.contextmanager
def silent() -> Iterator[None]:
    """Within the block, this thread's `stage` lines, `note` records and `progress` bars
    are dropped (work done ahead in a thread, e.g. an app's warm-up, that the main thread
    does, and says, again)."""
    _SILENT.on = True
    try:
        yield
    finally:
        _SILENT.on = False


def _silent() -> bool:
    return getattr(_SILENT, "on", False)


def _tell(msg: str) -> None:
    for fn in list(_LISTENERS):
        try:
            fn(msg)
        except Exception:  # noqa: BLE001 - a listener never stops the work
            pass


def progress(it: Iterable[T], desc: str, total: int | None = None) -> Iterator[T]:
    """Wrap an iterable with a progress bar labelled ``desc``."""
    if _silent():
        yield from it
        return
    if _LISTENERS:
        it = _told(it, desc, total)
    if os.environ.get("FXSPACE_QUIET") == "1":
        yield from it
        return
    from tqdm.auto import tqdm

    yield from tqdm(it, desc=desc, total=total, leave=False, dynamic_ncols=True)


def _told(it: Iterable[T], desc: str, total: int | None) -> Iterator[T]:
    n = total if total is not None else (len(it) if hasattr(it, "__len__") else None)  # type: ignore[arg-type]
    for i, x in enumerate(it):
        _tell(f"{desc}: {i}/{n}" if n else f"{desc}: {i}")
        yield x


def stage(msg: str) -> None:
    """A stage line ``[fxspace] msg`` on stderr (silent when ``FXSPACE_QUIET=1``)."""
    if _silent():
        return
    _tell(msg)
    if os.environ.get("FXSPACE_QUIET") != "1":
        print(f"[fxspace] {msg}", file=sys.stderr, flush=True)


def note(msg: str, *, warning: bool = False) -> None:
    """Something the user must hear of as it happens (a drop, a resample, a unit
    inferred or converted, markers cut to a shared set): a `stage` line on stderr and a
    record on the ``fxspace`` logger (INFO, or WARNING with ``warning=True``; tests read
    it with ``caplog``). A warning is printed even when ``FXSPACE_QUIET=1``."""
    if _silent():
        return
    _LOG.log(logging.WARNING if warning else logging.INFO, msg)
    if warning:
        _tell(f"warning: {msg}")
        print(f"[fxspace] warning: {msg}", file=sys.stderr, flush=True)
    else:
        stage(msg)
