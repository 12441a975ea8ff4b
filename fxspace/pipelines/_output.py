"""A worker's output among other workers' (`named_output`): every line it prints starts
with its name, progress bars reduced to their last state."""

from __future__ import annotations

import io
import sys
from contextlib import contextmanager, redirect_stderr, redirect_stdout
from typing import Any


class _Prefixed(io.TextIOBase):
    """A text stream that writes each whole line to ``stream`` behind ``prefix``; a line
    redrawn with ``\r`` (a progress bar) keeps only its last state, a blank one is
    dropped, so N workers' bars never interleave into garbage."""

    def __init__(self, stream: Any, prefix: str) -> None:
        self._stream, self._prefix, self._buf = stream, prefix, ""

    def writable(self) -> bool:
        return True

    def write(self, s: str) -> int:
        self._buf += s
        *lines, rest = self._buf.split("\n")
        self._buf = rest.rsplit("\r", 1)[-1]
        lines = [ln.rsplit("\r", 1)[-1] for ln in lines]
        for ln in lines:
            if ln.strip():
                self._stream.write(f"{self._prefix}{ln}\n")
        if lines:
            self._stream.flush()
        return len(s)

    def flush(self) -> None:
        self._stream.flush()

    def finish(self) -> None:
        if self._buf.strip():
            self._stream.write(f"{self._prefix}{self._buf}\n")
            self._buf = ""
        self._stream.flush()


@contextmanager
def named_output(name: str | None):
    """Within this block, every line printed to stdout or stderr starts with ``[name]``
    (a worker's lines among other workers'; progress bars reduced to nothing, the
    sweep's own progress lines say how far it is); ``None``: unchanged."""
    if name is None:
        yield
        return
    out = _Prefixed(sys.stdout, f"[{name}] ")
    err = _Prefixed(sys.stderr, f"[{name}] ")
    try:
        with redirect_stdout(out), redirect_stderr(err):
            yield
    finally:
        out.finish()
        err.finish()
