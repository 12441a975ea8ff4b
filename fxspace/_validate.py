"""The one validation helper of fxspace's public entry points.

Every public function checks its arguments here, outside ``jit``, so a bad input fails at
the boundary with a `FxspaceError` naming the argument and the fix,
never with a traceback from deep inside XLA or a plausible wrong number.

Policy (one place, shared by every subsystem):

- **dtypes**: float32 and float64 are kept; integers and booleans are converted to the
  default float dtype (float32, or float64 under ``jax_enable_x64``); complex, float16,
  bfloat16, object and string arrays are rejected with a message naming the argument.
- **shapes**: an expected rank and axis sizes (``None`` = any); empty arrays and too few
  frames are rejected (``min_frames``).
- **non-finite values**: ``finite="raise"`` rejects NaN/inf and names where they are;
  ``finite="nan"`` accepts NaN (missing data) but rejects ±inf; ``finite="allow"`` skips
  the check. Traced arrays (under ``jit``) skip value checks: report those in the result.
- **scalars**: `check_scalar` rejects NaN/inf/non-numbers and values outside a range;
  `check_int` does the same for integers (seeds, counts: ``2.5`` is refused everywhere,
  ``3.0`` accepted as 3); `check_index`/`check_indices` for frame indices (a float or
  out-of-range index is refused); `check_bool` for flags; `check_key` for PRNG keys (an
  integer is refused with the fix, ``jax.random.PRNGKey(seed)``); `check_choice` for
  ``Literal`` modes.

Example:

```python
from fxspace._validate import as_float_array, check_scalar

x = as_float_array(points, "points", ndim=2, min_frames=2)       # (n, d), finite
gamma = check_scalar(gamma, "gamma", low=0.0, low_open=True)      # gamma > 0
```

The checks live in two private modules, re-exported here (``from fxspace._validate
import …`` keeps working): ``fxspace._validate_values`` (arrays and scalars) and
``fxspace._validate_annotations`` (`checked`, read from the annotations); the checks of
files, gaps, distance matrices, scale and memory are here.
"""

from __future__ import annotations

import weakref
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import jax
import numpy as np

from fxspace._validate_annotations import _ARRAY_ANN as _ARRAY_ANN
from fxspace._validate_annotations import _BOOL_ANN as _BOOL_ANN
from fxspace._validate_annotations import _CLASS_HINTS as _CLASS_HINTS
from fxspace._validate_annotations import _FLOAT_ANN as _FLOAT_ANN
from fxspace._validate_annotations import _FX_TYPES as _FX_TYPES
from fxspace._validate_annotations import _INT_ANN as _INT_ANN
from fxspace._validate_annotations import _LITERAL_ANN as _LITERAL_ANN
from fxspace._validate_annotations import _PATH_ANN as _PATH_ANN
from fxspace._validate_annotations import _STR_ANN as _STR_ANN
from fxspace._validate_annotations import _arg_checker as _arg_checker
from fxspace._validate_annotations import _array_spec as _array_spec
from fxspace._validate_annotations import _check_array_arg as _check_array_arg
from fxspace._validate_annotations import _check_path as _check_path
from fxspace._validate_annotations import _check_str as _check_str
from fxspace._validate_annotations import _class_hints as _class_hints
from fxspace._validate_annotations import _explain as _explain
from fxspace._validate_annotations import _explain_types as _explain_types
from fxspace._validate_annotations import _fxspace_types as _fxspace_types
from fxspace._validate_annotations import _resolved_hints as _resolved_hints
from fxspace._validate_annotations import checked as checked
from fxspace._validate_values import FinitePolicy as FinitePolicy
from fxspace._validate_values import _default_float as _default_float
from fxspace._validate_values import _is_tracer as _is_tracer
from fxspace._validate_values import _where as _where
from fxspace._validate_values import as_float_array as as_float_array
from fxspace._validate_values import check_bool as check_bool
from fxspace._validate_values import check_choice as check_choice
from fxspace._validate_values import check_dtype as check_dtype
from fxspace._validate_values import check_finite as check_finite
from fxspace._validate_values import check_index as check_index
from fxspace._validate_values import check_indices as check_indices
from fxspace._validate_values import check_int as check_int
from fxspace._validate_values import check_key as check_key
from fxspace._validate_values import check_scalar as check_scalar
from fxspace.errors import FxspaceError

__all__ = [
    "as_float_array",
    "check_dtype",
    "check_finite",
    "check_scalar",
    "check_int",
    "check_index",
    "check_indices",
    "check_bool",
    "check_key",
    "check_choice",
    "missing_report",
    "describe_missing",
    "check_readable",
    "check_distance_matrix",
    "check_scale",
    "check_memory",
]


def missing_report(
    positions: Any, marker_names: Sequence[str] | None = None
) -> list[tuple[str, int, int]]:
    """Runs of missing (non-finite) samples per marker: ``[(marker, first, last), ...]``.

    `positions` is ``(T, M)`` or ``(T, M, k)``; a sample is missing when any coordinate is
    non-finite. Frames are 0-based and inclusive; markers are named by `marker_names`
    (default ``"marker <m>"``).
    """
    a = np.asarray(positions)
    bad = ~np.isfinite(a) if a.ndim == 2 else ~np.isfinite(a).all(axis=tuple(range(2, a.ndim)))
    out = []
    for m in range(bad.shape[1]):
        col = bad[:, m].astype(np.int8)
        if not col.any():
            continue
        edges = np.diff(np.concatenate([[0], col, [0]]))
        starts = np.flatnonzero(edges == 1)
        ends = np.flatnonzero(edges == -1) - 1
        label = marker_names[m] if marker_names is not None else f"marker {m}"
        out.extend((label, int(s), int(e)) for s, e in zip(starts, ends, strict=True))
    return out


def describe_missing(runs: Sequence[tuple[str, int, int]], limit: int = 8) -> str:
    """A one-line description of `missing_report` runs, e.g. for an error message."""
    parts = [f"{m} frames {s}–{e}" if e > s else f"{m} frame {s}" for m, s, e in runs[:limit]]
    more = f" and {len(runs) - limit} more gaps" if len(runs) > limit else ""
    return "; ".join(parts) + more


def check_readable(path: Any, what: str = "file") -> Path:
    """``path`` as a `Path` if it is a readable file, else the precise
    ``OSError``: ``FileNotFoundError`` (absent), ``IsADirectoryError`` (a directory, not a
    file) or ``PermissionError`` (not readable) — never a misleading "corrupt"."""
    import errno
    import os
    import stat

    from fxspace.errors import DataNotFoundError

    p = Path(path)
    try:
        st = os.stat(p)
    except OSError as e:
        if e.errno == errno.ELOOP:
            raise FxspaceError(f"{p}: symlink loop (the link points back to itself)") from None
        if e.errno == errno.ENOTDIR:
            raise DataNotFoundError(f"{what} not found: {p} (a parent is not a folder)") from None
        if e.errno == errno.ENOENT:
            if p.is_symlink():
                raise DataNotFoundError(f"{what} not found: {p} (a dangling symlink)") from None
            raise DataNotFoundError(f"{what} not found: {p}") from None
        raise
    if stat.S_ISDIR(st.st_mode):
        from fxspace.errors import NotAFileError

        raise NotAFileError(f"{p} is a directory, not a {what}; pass the {what} inside it")
    if not stat.S_ISREG(st.st_mode):
        kind = "a named pipe (FIFO)" if stat.S_ISFIFO(st.st_mode) else "not a regular file"
        raise FxspaceError(f"{p} is {kind}, not a {what}; pass a regular file (not read)")
    try:
        with p.open("rb"):
            pass
    except PermissionError as e:
        raise PermissionError(f"{p}: permission denied (cannot read the {what})") from e
    return p



def check_distance_matrix(
    D: Any, name: str, *, allow_inf: bool = False, rtol: float = 1e-4
) -> None:
    """A concrete ``(n, n)`` distance matrix must be symmetric and non-negative (NaN is
    left to the caller's finite policy; ``allow_inf`` lets ``inf`` mark "no edge").
    Traced matrices pass. Raises a `FxspaceError` naming ``name``, the worst entry and
    the fix. A JAX array (immutable) that passed is remembered while it lives, so a
    sweep that checks the same matrix once per ε pays once."""
    if _is_tracer(D):
        return
    key = (id(D), bool(allow_inf), float(rtol))
    if isinstance(D, jax.Array) and _DISTANCE_MATRICES.get(key) is D:
        return
    a = np.asarray(D)
    if a.ndim != 2 or a.shape[0] != a.shape[1]:
        raise FxspaceError(f"{name} must be a square (n, n) matrix, got shape {a.shape}")
    with np.errstate(invalid="ignore"):
        neg = a < 0
    if neg.any():
        i, j = np.argwhere(neg)[0]
        raise FxspaceError(
            f"{name} must be non-negative (distances); {name}[{i}, {j}] = {a[i, j]:g}"
        )
    fin = np.isfinite(a) & np.isfinite(a.T)
    both_inf = np.isinf(a) & np.isinf(a.T)
    with np.errstate(invalid="ignore"):  # inf - inf where "no edge": masked out by fin
        diff = np.where(fin, np.abs(a - a.T), 0.0)
    scale = np.where(fin, np.maximum(np.abs(a), np.abs(a.T)), 0.0)
    bad = (diff > rtol * scale + 1e-6 * (np.max(scale) if scale.size else 0.0)) | (
        np.isinf(a) != np.isinf(a.T)
    ) & ~both_inf
    if bad.any():
        i, j = np.argwhere(bad)[0]
        raise FxspaceError(
            f"{name} must be symmetric (distances); {name}[{i}, {j}] = {a[i, j]:g} but "
            f"{name}[{j}, {i}] = {a[j, i]:g}; symmetrise it, e.g. ({name} + {name}.T) / 2"
        )
    if not allow_inf and np.isinf(a).any():
        i, j = np.argwhere(np.isinf(a))[0]
        raise FxspaceError(f"{name} must be finite; {name}[{i}, {j}] = {a[i, j]:g}")
    if isinstance(D, jax.Array):
        _DISTANCE_MATRICES[key] = D


# JAX arrays already found to be distance matrices, by (id, allow_inf, rtol); an entry goes
# with its array, so an id reused by another array is never taken for it
_DISTANCE_MATRICES: weakref.WeakValueDictionary = weakref.WeakValueDictionary()


def check_scale(x: Any, name: str, power: int = 2) -> None:
    """The largest finite magnitude of a concrete ``x`` raised to ``power`` (squared
    distances: 2) must be finite in its dtype; else a `FxspaceError` with the number and the
    fix (rescale), never a result computed from overflowed values."""
    if _is_tracer(x):
        return
    a = np.asarray(x)
    if a.size == 0 or a.dtype.kind != "f":
        return
    fin = a[np.isfinite(a)]
    if fin.size == 0:
        return
    m = float(np.max(np.abs(fin)))
    dt = np.dtype(jax.dtypes.canonicalize_dtype(a.dtype))  # float64 runs as float32 w/o x64
    big = float(np.finfo(dt).max)
    if (
        m > 0
        and power * np.log10(m) + np.log10(max(a.shape[-1] if a.ndim else 1, 1))
        >= np.log10(big) - 1
    ):
        raise FxspaceError(
            f"{name} is too large to compute with in {dt} (max |{name}| = {m:.3g}: its "
            f"squares overflow to inf); rescale {name}, e.g. divide by its standard deviation"
        )


def check_memory(n_bytes: float, what: str, fix: str, limit: float | None = None) -> None:
    """Refuse, before allocating, an array of ``n_bytes`` that cannot fit: more than
    ``limit`` (default: half of the machine's memory) raises a `FxspaceError` naming
    the size in GiB, ``what`` it is for and the ``fix``."""
    if limit is None:
        limit = _total_memory() / 2
    if not np.isfinite(n_bytes) or n_bytes > limit:
        raise FxspaceError(
            f"{what} would need {n_bytes / 2**30:.3g} GiB (more than {limit / 2**30:.3g} GiB "
            f"available); {fix}"
        )


def _total_memory() -> float:
    import os

    try:
        return float(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES"))
    except (ValueError, OSError, AttributeError):
        return 16.0 * 2**30
