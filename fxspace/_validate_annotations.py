"""`checked`: argument checks for every public function, read from its annotations.

One layer for the public API: jaxtyping arrays, ``int``, ``float``, ``bool``, ``str``,
paths, ``Literal[...]``, PRNG keys and fxspace's own classes. The front
`fxspace._validate` re-exports every name here.
"""

from __future__ import annotations

import re
from typing import Any

import jax
import numpy as np

from fxspace._validate_values import (
    _is_tracer,
    check_bool,
    check_choice,
    check_dtype,
    check_int,
    check_key,
    check_scalar,
)
from fxspace.errors import FxspaceError

__all__ = ["checked"]


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
