"""Argument checks of values: arrays and scalars.

Arrays (dtype, shape, non-finite values) and scalars (numbers, integers, indices, flags,
PRNG keys, choices), each raising a `FxspaceError` that names the argument and the fix.
The policy is described in `fxspace._validate`, the front that re-exports every name here.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
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
        want = jax.dtypes.canonicalize_dtype(dt)
        if isinstance(x, jax.Array) and x.dtype == want and not getattr(x, "weak_type", False):
            out = x  # already what is asked: no conversion dispatched (~0.1 ms a call)
        else:
            out = jnp.asarray(x, dtype=want)
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
