"""The one validation helper of fxspace's public entry points.

Every public function checks its arguments here, outside ``jit``, so a bad input fails at
the boundary with a :class:`~fxspace.errors.FxspaceError` naming the argument and the fix,
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
- **scalars**: :func:`check_scalar` rejects NaN/inf/non-numbers and values outside a range;
  :func:`check_int` does the same for integers (seeds, counts); :func:`check_choice` for
  ``Literal`` modes.

Example:

```python
from fxspace._validate import as_float_array, check_scalar

x = as_float_array(points, "points", ndim=2, min_frames=2)       # (n, d), finite
gamma = check_scalar(gamma, "gamma", low=0.0, low_open=True)      # gamma > 0
```
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any, Literal

import jax
import jax.numpy as jnp
import numpy as np

from fxspace.errors import FxspaceError

__all__ = [
    "as_float_array",
    "check_dtype",
    "check_finite",
    "check_scalar",
    "check_int",
    "check_choice",
    "missing_report",
    "describe_missing",
    "check_readable",
]

FinitePolicy = Literal["raise", "nan", "allow"]


def _is_tracer(x: Any) -> bool:
    return isinstance(x, jax.core.Tracer)


def _default_float() -> np.dtype:
    return np.dtype(np.float64) if jax.config.jax_enable_x64 else np.dtype(np.float32)


def check_dtype(x: Any, name: str) -> np.dtype:
    """The float dtype ``x`` will be computed in, or a :class:`FxspaceError`.

    float32/float64 are kept, integers/booleans map to the default float dtype; complex,
    float16, bfloat16, object and string dtypes raise naming `name`.
    """
    dt = np.dtype(getattr(x, "dtype", None) or np.asarray(x).dtype)
    if dt in (np.float32, np.float64):
        return dt
    if dt.kind in "iub":
        return _default_float()
    if dt.kind == "c":
        raise FxspaceError(
            f"{name} is complex ({dt}); fxspace works on real numbers: pass the real part "
            f"(np.real({name})) or the magnitude explicitly"
        )
    if dt.kind == "f":  # float16 / bfloat16 / float128
        raise FxspaceError(
            f"{name} has dtype {dt}, which fxspace does not compute in (too few bits: "
            f"distances and solvers overflow to inf); convert it with {name}.astype('float32')"
        )
    raise FxspaceError(f"{name} must be a numeric array, got dtype {dt}")


def _where(mask: np.ndarray, limit: int = 5) -> str:
    idx = np.argwhere(mask)
    shown = ", ".join(str(tuple(int(v) for v in row)) for row in idx[:limit])
    more = f" and {len(idx) - limit} more" if len(idx) > limit else ""
    return f"{len(idx)} entries, at {shown}{more}"


def check_finite(x: Any, name: str, finite: FinitePolicy = "raise") -> None:
    """Raise a :class:`FxspaceError` naming where `x` holds non-finite values.

    **Arguments:**
    - `x`: a concrete array (traced arrays are not checked).
    - `name`: the argument name used in the message.
    - `finite`: ``"raise"`` rejects NaN and ±inf; ``"nan"`` accepts NaN (missing data) but
      rejects ±inf; ``"allow"`` checks nothing.
    """
    if finite == "allow" or _is_tracer(x):
        return
    a = np.asarray(x)
    if a.dtype.kind not in "fc":
        return
    if finite == "nan":
        bad = np.isinf(a)
        if bad.any():
            raise FxspaceError(
                f"{name} holds ±inf ({_where(bad)}); mark a missing value with NaN instead"
            )
        return
    bad = ~np.isfinite(a)
    if bad.any():
        raise FxspaceError(
            f"{name} holds NaN/inf ({_where(bad)}); fill or drop the missing values first "
            "(fxspace.fill_gaps for marker positions)"
        )


def as_float_array(
    x: Any,
    name: str,
    *,
    ndim: int | None = None,
    shape: Sequence[int | None] | None = None,
    min_frames: int = 1,
    finite: FinitePolicy = "raise",
    dtype: Any = None,
    xp: Literal["jax", "numpy"] = "jax",
    axes: Sequence[str] | None = None,
):
    """Validate and convert a float array argument.

    **Arguments:**
    - `x`: array-like.
    - `name`: the argument name used in every message.
    - `ndim`: required rank (``None``: any).
    - `shape`: required sizes per axis, ``None`` for any (implies `ndim`).
    - `min_frames`: least length of the first axis (1 rejects empty inputs).
    - `finite`: see :func:`check_finite`.
    - `dtype`: force this float dtype (else keep float32/64, ints → default float).
    - `xp`: return a ``jax.Array`` (``"jax"``) or a ``numpy.ndarray`` (``"numpy"``).
    - `axes`: axis names for the shape message, e.g. ``("n_points", "n_features")``.

    **Returns:** the array in a float32/float64 dtype.
    """
    if isinstance(x, str | bytes) or x is None:
        raise FxspaceError(f"{name} must be a numeric array, got {type(x).__name__}")
    if not hasattr(x, "dtype"):
        try:
            x = np.asarray(x)
        except (TypeError, ValueError) as e:
            raise FxspaceError(f"{name} must be a numeric array ({e})") from None
    dt = check_dtype(x, name) if dtype is None else np.dtype(dtype)
    if dtype is not None:
        check_dtype(x, name)
    if shape is not None:
        ndim = len(shape)
    if axes is not None:
        ndim = len(axes) if ndim is None else ndim
    if ndim is not None and x.ndim != ndim and axes is not None:
        raise FxspaceError(f"{name} must be ({', '.join(axes)}); got shape {tuple(x.shape)}")
    if ndim is not None and x.ndim != ndim:
        want = "(" + ", ".join("*" if s is None else str(s) for s in shape) + ")" if shape else ""
        raise FxspaceError(
            f"{name} must have {ndim} dimensions {want}".rstrip() + f", got shape {tuple(x.shape)}"
        )
    if shape is not None:
        for ax, (got, want) in enumerate(zip(x.shape, shape, strict=True)):
            if want is not None and got != want:
                raise FxspaceError(
                    f"{name} must have size {want} on axis {ax}, got shape {tuple(x.shape)}"
                )
    if x.ndim == 0 and min_frames > 0 and ndim not in (None, 0):
        raise FxspaceError(f"{name} must be an array, got a scalar")
    if x.ndim >= 1:
        if x.shape[0] < min_frames:
            what = "is empty" if x.shape[0] == 0 else f"has {x.shape[0]} frame(s)"
            raise FxspaceError(f"{name} {what}; at least {min_frames} frame(s) are needed")
        if x.size == 0:
            raise FxspaceError(f"{name} is empty (shape {tuple(x.shape)})")
    if xp == "numpy":
        if _is_tracer(x):
            raise FxspaceError(f"{name} must be a concrete array here, not a traced value")
        out = np.asarray(x, dtype=dt)
    else:
        # float64 without jax_enable_x64 computes in float32 (jax's rule), without a warning
        out = jnp.asarray(x, dtype=jax.dtypes.canonicalize_dtype(dt))
    check_finite(out, name, finite)
    return out


def check_scalar(
    value: Any,
    name: str,
    *,
    low: float | None = None,
    high: float | None = None,
    low_open: bool = False,
    high_open: bool = False,
) -> float:
    """A finite real scalar within ``[low, high]`` (or open ends), as a Python float."""
    if _is_tracer(value):
        return value  # type: ignore[return-value]
    if isinstance(value, bool) or isinstance(value, str | bytes):
        raise FxspaceError(f"{name} must be a real number, got {value!r}")
    a = np.asarray(value)
    if a.ndim != 0:
        raise FxspaceError(f"{name} must be a scalar, got shape {a.shape}")
    if a.dtype.kind == "c":
        raise FxspaceError(f"{name} must be a real number, got complex {value!r}")
    if a.dtype.kind not in "iuf":
        raise FxspaceError(f"{name} must be a real number, got {value!r}")
    v = float(a)
    if not np.isfinite(v):
        raise FxspaceError(f"{name} must be a finite number, got {v}")
    lo_bad = low is not None and (v <= low if low_open else v < low)
    hi_bad = high is not None and (v >= high if high_open else v > high)
    if lo_bad or hi_bad:
        if high is None:
            want = f"be {'>' if low_open else '>='} {low:g}"
        elif low is None:
            want = f"be {'<' if high_open else '<='} {high:g}"
        else:
            left, right = "(" if low_open else "[", ")" if high_open else "]"
            want = f"lie in {left}{low:g}, {high:g}{right}"
        raise FxspaceError(f"{name} must {want}, got {v:g}")
    return v


def check_int(value: Any, name: str, *, low: int | None = None, high: int | None = None) -> int:
    """An integer (Python or NumPy, not bool/float) within ``[low, high]``, as a Python int."""
    if isinstance(value, bool) or not isinstance(value, int | np.integer):
        if isinstance(value, float | np.floating) and float(value).is_integer():
            value = int(value)
        else:
            raise FxspaceError(f"{name} must be an integer, got {value!r}")
    v = int(value)
    if (low is not None and v < low) or (high is not None and v > high):
        if high is None:
            raise FxspaceError(f"{name} must be >= {low}, got {v}")
        if low is None:
            raise FxspaceError(f"{name} must be <= {high}, got {v}")
        raise FxspaceError(f"{name} must lie in [{low}, {high}], got {v}")
    return v


def check_choice(value: Any, name: str, choices: Iterable[Any]) -> Any:
    """`value` if it is one of `choices`, else a :class:`FxspaceError` listing them."""
    choices = tuple(choices)
    if value not in choices:
        raise FxspaceError(
            f"{name} must be one of {', '.join(repr(c) for c in choices)}; got {value!r}"
        )
    return value


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
    """A one-line description of :func:`missing_report` runs, e.g. for an error message."""
    parts = [f"{m} frames {s}–{e}" if e > s else f"{m} frame {s}" for m, s, e in runs[:limit]]
    more = f" and {len(runs) - limit} more gaps" if len(runs) > limit else ""
    return "; ".join(parts) + more


def check_readable(path: Any, what: str = "file") -> Path:
    """``path`` as a :class:`~pathlib.Path` if it is a readable file, else the precise
    ``OSError``: ``FileNotFoundError`` (absent), ``IsADirectoryError`` (a directory, not a
    file) or ``PermissionError`` (not readable) — never a misleading "corrupt"."""
    p = Path(path)
    if p.is_dir():
        raise IsADirectoryError(f"{p} is a directory, not a {what}")
    if not p.exists():
        raise FileNotFoundError(f"{what} not found: {p}")
    try:
        with p.open("rb"):
            pass
    except PermissionError as e:
        raise PermissionError(f"{p}: permission denied (cannot read the {what})") from e
    return p
