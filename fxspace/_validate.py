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
"""

from __future__ import annotations

import re
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

FinitePolicy = Literal["raise", "nan", "allow"]


def _is_tracer(x: Any) -> bool:
    return isinstance(x, jax.core.Tracer)


def _default_float() -> np.dtype:
    return np.dtype(np.float64) if jax.config.jax_enable_x64 else np.dtype(np.float32)


def check_dtype(x: Any, name: str) -> np.dtype:
    """The float dtype ``x`` will be computed in, or a `FxspaceError`.

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
    """Raise a `FxspaceError` naming where `x` holds non-finite values.

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
    - `finite`: see `check_finite`.
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
    """An integer within ``[low, high]``, as a Python int.

    Python/NumPy integers and 0-d integer arrays are accepted, and so is an
    integer-valued float (``3.0``); ``2.5``, NaN, inf, booleans, strings and ``None`` raise
    a `FxspaceError` naming `name` (the same message everywhere)."""
    if isinstance(value, np.ndarray | jax.Array) and value.ndim == 0 and not _is_tracer(value):
        if value.dtype.kind in "iu":
            value = int(value)
        elif value.dtype.kind == "f":
            value = float(value)
    if isinstance(value, bool | np.bool_) or not isinstance(value, int | np.integer):
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


def check_index(value: Any, name: str, size: int) -> int:
    """A position in ``range(size)`` (a frame, a marker…), as a Python int: a float
    (``2.5``, ``2.0`` too: an index is never a float), a negative or an out-of-range
    value raises a `FxspaceError` naming `name` and the valid range."""
    if isinstance(value, float | np.floating) or (
        isinstance(value, np.ndarray | jax.Array) and value.dtype.kind == "f"
    ):
        raise FxspaceError(f"{name} must be an integer index, got the float {value!r}")
    return check_int(value, name, low=0, high=size - 1)


def check_indices(values: Any, name: str, size: int, *, min_len: int = 0) -> np.ndarray:
    """A 1-D sequence of positions in ``range(size)`` as an int64 array (see `check_index`)."""
    if isinstance(values, str | bytes) or values is None:
        raise FxspaceError(f"{name} must be a sequence of integer indices, got {values!r}")
    try:
        a = np.asarray(values)
    except (TypeError, ValueError) as e:
        raise FxspaceError(f"{name} must be a sequence of integer indices ({e})") from None
    if a.ndim != 1:
        raise FxspaceError(f"{name} must be a 1-D sequence of indices, got shape {a.shape}")
    if a.size and a.dtype.kind not in "iu":
        raise FxspaceError(f"{name} must hold integer indices, got dtype {a.dtype}")
    if a.size < min_len:
        raise FxspaceError(f"{name} needs at least {min_len} indices, got {a.size}")
    bad = (a < 0) | (a >= size)
    if bad.any():
        raise FxspaceError(
            f"{name} holds {a[bad][:5].tolist()}, outside [0, {size - 1}] (valid indices)"
        )
    return a.astype(np.int64)


def check_bool(value: Any, name: str) -> bool:
    """``True``/``False`` (Python or NumPy), else a `FxspaceError` naming `name`."""
    if not isinstance(value, bool | np.bool_):
        raise FxspaceError(f"{name} must be True or False, got {value!r}")
    return bool(value)


def check_key(key: Any, name: str = "key") -> Any:
    """A JAX PRNG key: a typed key (``jax.random.key``) or a raw ``uint32[2]`` key
    (``jax.random.PRNGKey``); an integer seed, a float or a wrongly shaped array raises a
    `FxspaceError` with the fix."""
    fix = f"pass {name}=jax.random.PRNGKey(seed)"
    if _is_tracer(key):
        return key
    if isinstance(key, int | np.integer | float | np.floating | str | bytes) or key is None:
        raise FxspaceError(f"{name} must be a JAX PRNG key, got {key!r}; {fix}")
    dt = getattr(key, "dtype", None)
    if dt is not None and jax.dtypes.issubdtype(dt, jax.dtypes.prng_key):
        if key.shape != ():
            raise FxspaceError(
                f"{name} must be one PRNG key, got a batch of shape {tuple(key.shape)}; "
                f"pass one key (e.g. {name}[0]) or jax.vmap over the batch"
            )
        return key
    a = np.asarray(key) if dt is None else key
    if a.dtype == np.uint32 and a.ndim > 1 and a.shape[-1:] == (2,):
        raise FxspaceError(
            f"{name} must be one PRNG key of shape (2,), got a batch of shape "
            f"{tuple(a.shape)}; pass one key (e.g. {name}[0]) or jax.vmap over the batch"
        )
    if a.dtype != np.uint32 or a.shape[-1:] != (2,):
        raise FxspaceError(
            f"{name} must be a JAX PRNG key (uint32[2]), got {a.dtype} of shape "
            f"{tuple(a.shape)}; {fix}"
        )
    return key


def check_choice(value: Any, name: str, choices: Iterable[Any]) -> Any:
    """`value` if it is one of `choices`, else a `FxspaceError` listing them."""
    choices = tuple(choices)
    try:
        known = value in choices
    except (TypeError, ValueError):  # an array compared with strings
        known = False
    if not known:
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


# -- one layer for every public function: checks read from the annotations ---------------
_ARRAY_ANN = re.compile(
    r"(?:\b\w+\.)*\b(Float|Int|Bool|Shaped|Real|Num)\[\s*[\w.]+\s*,\s*['\"]([^'\"]*)['\"]\]"
)
_INT_ANN = re.compile(r"^int(\s*\|\s*None)?$")
_FLOAT_ANN = re.compile(r"^float(\s*\|\s*None)?$")
_STR_ANN = re.compile(r"^str(\s*\|\s*None)?$")
_BOOL_ANN = re.compile(r"^bool(\s*\|\s*None)?$")
_LITERAL_ANN = re.compile(r"^Literal\[([^\]]*)\](\s*\|\s*None)?$")


def _array_spec(ann: str) -> tuple[str, tuple[str, ...]] | None:
    """``(kind, dims)`` of a jaxtyping annotation such as ``Float[Array, 'n 3']``; ``None``
    when the annotation is a union with a non-array type (then nothing is checked)."""
    m = _ARRAY_ANN.search(ann)
    if m is None:
        return None
    rest = (ann[: m.start()] + ann[m.end() :]).replace("|", " ").split()
    if any(r != "None" for r in rest):
        return None  # e.g. `float | Float[Array, '']`: a scalar is fine too
    return m.group(1), tuple(m.group(2).split())


def _check_array_arg(
    value: Any, name: str, kind: str, dims: tuple[str, ...], shape: bool = False
) -> Any:
    """Type and dtype of an array argument (and, with ``shape``, its rank and fixed sizes)."""
    if isinstance(value, list | tuple):
        try:
            value = np.asarray(value)
        except (TypeError, ValueError) as e:
            raise FxspaceError(f"{name} must be a numeric array ({e})") from None
    if isinstance(value, str | bytes | dict | set) or not hasattr(value, "shape"):
        if isinstance(value, int | float | np.number) and not isinstance(value, bool):
            value = np.asarray(value)
        else:
            raise FxspaceError(f"{name} must be a numeric array, got {type(value).__name__}")
    dt = (
        np.dtype(value.dtype)
        if not jax.dtypes.issubdtype(value.dtype, jax.dtypes.prng_key)
        else None
    )
    if dt is not None:
        if kind == "Int" and dt.kind == "f":
            raise FxspaceError(f"{name} must hold integers (indices), got dtype {dt}")
        if kind in ("Float", "Real", "Num") and dt.kind not in "biuf":
            check_dtype(value, name)  # names the dtype and the fix
        if dt.kind in "cOSUV" or (dt.kind == "f" and dt.itemsize < 4):
            check_dtype(value, name)
    if not shape:
        return value
    if value.size == 0:
        raise FxspaceError(f"{name} is empty (shape {tuple(value.shape)})")
    variadic = any(d.startswith(("*", "#*")) or d == "..." for d in dims)
    fixed = [d for d in dims if not (d.startswith(("*", "#*")) or d == "...")]
    if (not variadic and value.ndim != len(fixed)) or (variadic and value.ndim < len(fixed)):
        want = "(" + ", ".join(dims) + ")" if dims else "a scalar"
        raise FxspaceError(f"{name} must have shape {want}, got shape {tuple(value.shape)}")
    # fixed sizes (the 3 of xyz, the 4 of a quaternion): axes before a variadic axis
    # count from the left, axes after it from the right
    cut = next((i for i, d in enumerate(dims) if d.startswith(("*", "#*")) or d == "..."), None)
    head = dims if cut is None else dims[:cut]
    tail = () if cut is None else dims[cut + 1 :]
    pairs = list(zip(head, value.shape, strict=False))
    if tail:
        pairs += list(zip(tail, value.shape[-len(tail) :], strict=False))
    for d, got in pairs:
        d = d.lstrip("#")
        if d.isdigit() and got != int(d):
            raise FxspaceError(
                f"{name} must have shape ({', '.join(dims)}), got shape {tuple(value.shape)}"
            )
    return value


def _check_str(value: Any, name: str) -> str:
    if not isinstance(value, str):
        raise FxspaceError(f"{name} must be a string, got {value!r}")
    return value


_PATH_ANN = re.compile(r"^(str \| (Path|os\.PathLike)|(Path|os\.PathLike) \| str|Path)( \| None)?$")


def _check_path(v: Any, name: str) -> Any:
    """A file-system path: a ``str`` or an ``os.PathLike`` (a `pathlib.Path`)."""
    import os

    if isinstance(v, str | os.PathLike):
        return v
    raise FxspaceError(f"{name} must be a path (str or pathlib.Path), got {type(v).__name__}")


def _arg_checker(name: str, ann: str, optional_default: bool):
    """A function checking one argument, derived from its annotation (or ``None``)."""
    ann = ann.strip()
    if name == "key" and not ann:
        return lambda v: v if v is None else check_key(v, name)
    spec = _array_spec(ann)
    allows_none = "None" in ann.replace("NoneType", "None") or optional_default
    if spec is not None:
        kind, dims = spec
        fn = lambda v: v if v is None and allows_none else _check_array_arg(v, name, kind, dims)  # noqa: E731
        fn.spec = spec  # type: ignore[attr-defined]
        return fn
    if name == "key" or "PRNGKey" in ann:
        return lambda v: v if v is None and allows_none else check_key(v, name)
    if _INT_ANN.match(ann):
        return lambda v: v if v is None and allows_none else check_int(v, name)
    if _FLOAT_ANN.match(ann):
        return lambda v: v if v is None and allows_none else check_scalar(v, name)
    if _STR_ANN.match(ann):
        return lambda v: v if v is None and allows_none else _check_str(v, name)
    if _BOOL_ANN.match(ann):
        return lambda v: v if v is None and allows_none else check_bool(v, name)
    if _PATH_ANN.match(ann):
        return lambda v: v if v is None and allows_none else _check_path(v, name)
    m = _LITERAL_ANN.match(ann)
    if m:
        import ast

        try:
            choices = tuple(ast.literal_eval("(" + m.group(1) + ",)"))
        except (ValueError, SyntaxError):
            return None
        return lambda v: v if v is None and allows_none else check_choice(v, name, choices)
    return None


def _explain(arguments: dict[str, Any], checks: dict[str, Any], error: Exception) -> None:
    """After a raw error, check every array argument's rank, fixed sizes and emptiness, and
    the named axes shared between arguments (``x (n, d)`` and ``centers (c, d)`` agree on
    ``d``); raise the first problem as a `FxspaceError` (else return: the raw error stands)."""
    sizes: dict[str, tuple[str, int]] = {}
    for k, v in arguments.items():
        c = checks.get(k)
        spec = getattr(c[0], "spec", None) if c is not None else None
        if spec is None or v is None or _is_tracer(v):
            continue
        kind, dims = spec
        v = _check_array_arg(v, k, kind, dims, shape=True)
        if any(d.startswith(("*", "#")) or d == "..." for d in dims):
            continue
        for d, got in zip(dims, v.shape, strict=False):
            if d.isidentifier() and d in sizes and sizes[d][1] != got:
                other, n = sizes[d]
                raise FxspaceError(
                    f"{other} and {k} disagree on the axis {d!r} ({n} vs {got}): "
                    f"{k} must have shape ({', '.join(dims)})"
                ) from error
            sizes.setdefault(d, (k, got))


_CLASS_HINTS: dict[Any, dict[str, tuple[type, bool]]] = {}
_FX_TYPES: dict[str, type] = {}


def _fxspace_types() -> dict[str, type]:
    """The public classes of fxspace's subpackages by name, to resolve annotations that
    name a class imported only for type checking (``mesh: "SkinnedMesh"``)."""
    if not _FX_TYPES:
        import importlib

        for sub in ("cluster", "controlpoints", "expression", "face", "io", "mesh", "motion",
                    "navigation", "results"):  # fmt: skip
            mod = importlib.import_module(f"fxspace.{sub}")
            for n in getattr(mod, "__all__", ()):
                v = getattr(mod, n, None)
                if isinstance(v, type) and v.__module__.startswith("fxspace"):
                    _FX_TYPES.setdefault(n, v)
    return _FX_TYPES


def _resolved_hints(fn: Any) -> dict[str, Any]:
    """``fn``'s parameter annotations resolved one by one (an unresolvable one is left out),
    names not in its module looked up among fxspace's public classes."""
    import typing

    try:
        return typing.get_type_hints(fn)
    except Exception:  # noqa: BLE001 - resolve one by one below
        pass
    import inspect

    inner = inspect.unwrap(fn)
    raw = getattr(inner, "__annotations__", {})
    ns = {**_fxspace_types(), **getattr(inner, "__globals__", {})}
    out = {}
    for k, a in raw.items():
        try:
            out[k] = eval(a, ns) if isinstance(a, str) else a  # noqa: S307 - annotations
        except Exception:  # noqa: BLE001 - unresolvable: unchecked
            continue
    return out


def _class_hints(fn: Any) -> dict[str, tuple[type, bool]]:
    """The arguments of ``fn`` annotated with one class (``mesh: SkinnedMesh``), resolved
    once (``X | None`` counts as ``X``)."""
    if fn not in _CLASS_HINTS:
        import types
        import typing

        out: dict[str, tuple[type, bool]] = {}
        for k, h in _resolved_hints(fn).items():
            none_ok = False
            if typing.get_origin(h) in (typing.Union, types.UnionType):
                args = [a for a in typing.get_args(h) if a is not type(None)]
                none_ok = len(args) < len(typing.get_args(h))
                h = args[0] if len(args) == 1 else None
            if (
                isinstance(h, type)
                and h.__module__.startswith("fxspace")
                and not getattr(h, "_is_protocol", False)
            ):
                out[k] = (h, none_ok)
        _CLASS_HINTS[fn] = out
    return _CLASS_HINTS[fn]


def _explain_types(
    fn: Any, arguments: dict[str, Any], error: Exception | None = None, skip: Any = ()
) -> None:
    """An argument that is not of its annotated fxspace type (a mesh, a model, a
    hierarchy …) is named, with the type it must be (``skip``: names left unchecked)."""
    for k, (cls, none_ok) in _class_hints(fn).items():
        v = arguments.get(k)
        if k not in arguments or k in skip or (v is None and none_ok) or isinstance(v, cls):
            continue
        raise FxspaceError(
            f"{k} must be a {cls.__name__} (fxspace.{cls.__module__.split('.')[1]}), "
            f"got {type(v).__name__}"
        ) from error


def checked(fn: Any) -> Any:
    """Check ``fn``'s arguments from its annotations before it runs — the one validation
    layer of the public API (issue 19).

    Per annotation, before the call: jaxtyping arrays (``Float[Array, 'n 3']``) must be
    numeric arrays (lists are converted; strings, ``None``, complex, string, object and
    float16 arrays are refused; ``Int[...]`` refuses float indices); ``int`` →
    `check_int` (``2.5`` refused), ``float`` → `check_scalar` (NaN/inf/strings refused),
    ``bool`` → `check_bool`, ``Literal[...]`` → `check_choice`, a ``key`` → `check_key`
    (an integer seed is refused). Array ranks, fixed sizes (the 3 of xyz), emptiness and
    the named axes shared between arguments are checked only when the function fails with
    a raw error, so its own messages come first and a valid call pays nothing for them.
    Traced values (under ``jit``/``vmap``) are left to the function; an argument left at
    its default is not checked. Every failure is a one-line `FxspaceError` naming the
    argument. Value checks that need the meaning of an argument (ranges, NaN as missing
    data) stay in the function.
    """
    import functools
    import inspect

    sig = inspect.signature(fn)
    checks = {}
    for p in sig.parameters.values():
        if p.kind in (p.VAR_POSITIONAL, p.VAR_KEYWORD):
            continue
        ann = p.annotation
        if ann is inspect.Parameter.empty:
            ann = ""
        elif not isinstance(ann, str):
            ann = inspect.formatannotation(ann)
        c = _arg_checker(p.name, ann, p.default is None)
        if c is not None:
            checks[p.name] = (c, p.default)
    if not sig.parameters:
        return fn
    defaults = {p.name: p.default for p in sig.parameters.values()}

    @functools.wraps(fn)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        try:
            bound = sig.bind(*args, **kwargs)
        except TypeError as e:
            raise FxspaceError(f"{fn.__name__}: {e}") from None
        # an argument of an fxspace type (a mesh, a model …) must be one, unless left at
        # its default; traced stand-ins are never of another type, so this is jit-safe
        if _class_hints(fn):
            _explain_types(fn, bound.arguments, skip={
                k for k, v in bound.arguments.items() if v is defaults.get(k)})  # fmt: skip
        for k, v in bound.arguments.items():
            c = checks.get(k)
            # the author's default is never second-guessed; traced values are checked
            # by the function itself (shapes are static there)
            if c is not None and v is not c[1] and not _is_tracer(v):
                bound.arguments[k] = c[0](v)
        try:
            return fn(*bound.args, **bound.kwargs)
        except FxspaceError:
            raise
        except Exception as e:  # a raw error: say which argument is malformed, if one is
            _explain(bound.arguments, checks, e)
            _explain_types(fn, bound.arguments, e)
            raise

    wrapper.__fxspace_checked__ = True  # type: ignore[attr-defined]
    return wrapper


def check_distance_matrix(
    D: Any, name: str, *, allow_inf: bool = False, rtol: float = 1e-4
) -> None:
    """A concrete ``(n, n)`` distance matrix must be symmetric and non-negative (NaN is
    left to the caller's finite policy; ``allow_inf`` lets ``inf`` mark "no edge").
    Traced matrices pass. Raises a `FxspaceError` naming ``name``, the worst entry and
    the fix."""
    if _is_tracer(D):
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
