"""Configs are data: frozen dataclasses loaded from TOML.

A config file names its ``experiment`` (a module of `fxspace.pipelines`), a
``seed``, and tables that fill that experiment's frozen ``Config`` dataclass. An
optional ``[sweep]`` table maps dotted keys to lists of values; the runs are the
Cartesian product, each in its own sub-folder, and a finished run is skipped when the
sweep is run again (resume).

```toml
experiment = "threshold_sweep"
seed = 0
[data]
source = "animface"
[sweep]
"graph.num_thresholds" = [16, 32]
```
"""

from __future__ import annotations

import dataclasses
import hashlib
import itertools
import math
import tomllib
import types
import typing
from pathlib import Path
from typing import Any, TypeVar

from fxspace.errors import FxspaceError

__all__ = [
    "ConfigError",
    "load_toml",
    "config_from_dict",
    "config_to_dict",
    "expand_sweep",
    "dumps_toml",
    "set_dotted",
]

C = TypeVar("C")


class ConfigError(FxspaceError):
    """A config file or value is invalid; the message names the key and the fix."""


def load_toml(path: str | Path) -> dict[str, Any]:
    """Read a TOML config, with a clear error for a missing or malformed file."""
    p = Path(path)
    if not p.is_file():
        raise ConfigError(f"config file {p} does not exist")
    try:
        with p.open("rb") as f:
            return tomllib.load(f)
    except tomllib.TOMLDecodeError as e:
        raise ConfigError(f"config file {p} is not valid TOML: {e}") from e


def _check_type(value: Any, tp: Any, where: str) -> Any:
    origin = typing.get_origin(tp)
    if tp is Any:
        return value
    if origin in (typing.Union, types.UnionType):
        args = typing.get_args(tp)
        if value is None and type(None) in args:
            return None
        errors = []
        for a in args:
            if a is type(None):
                continue
            try:
                return _check_type(value, a, where)
            except ConfigError as e:
                errors.append(str(e))
        raise ConfigError(errors[0] if errors else f"{where}: bad value {value!r}")
    if origin is typing.Literal:
        if value not in typing.get_args(tp):
            raise ConfigError(f"{where} must be one of {typing.get_args(tp)}, got {value!r}")
        return value
    if origin in (tuple, list):
        if not isinstance(value, list | tuple):
            raise ConfigError(f"{where} must be a list, got {value!r}")
        args = typing.get_args(tp)
        inner = args[0] if args else Any
        return tuple(_check_type(v, inner, f"{where}[{i}]") for i, v in enumerate(value))
    if dataclasses.is_dataclass(tp):
        if not isinstance(value, dict):
            raise ConfigError(f"{where} must be a table, got {value!r}")
        return config_from_dict(tp, value, prefix=where + ".")
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise ConfigError(f"{where} must be a number, got {value!r}")
        return float(value)
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{where} must be an integer, got {value!r}")
        return value
    if tp is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{where} must be true or false, got {value!r}")
        return value
    if tp is str:
        if not isinstance(value, str):
            raise ConfigError(f"{where} must be a string, got {value!r}")
        return value
    return value


def config_from_dict(cls: type[C], data: dict[str, Any], prefix: str = "") -> C:
    """Build the frozen dataclass ``cls`` from ``data``; unknown keys are an error."""
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls)}  # type: ignore[arg-type]
    unknown = set(data) - set(fields)
    if unknown:
        raise ConfigError(
            f"unknown config key(s) {sorted(prefix + k for k in unknown)}; "
            f"valid keys here: {sorted(prefix + k for k in fields)}"
        )
    kwargs = {k: _check_type(v, hints[k], prefix + k) for k, v in data.items()}
    try:
        obj = cls(**kwargs)
    except TypeError as e:
        raise ConfigError(f"config {prefix or cls.__name__}: {e}") from e
    validate = getattr(obj, "validate", None)
    if callable(validate):
        validate()
    return obj


def config_to_dict(cfg: Any) -> dict[str, Any]:
    """A dataclass config as a plain dict (tuples become lists), for ``dumps_toml``."""

    def conv(v: Any) -> Any:
        if dataclasses.is_dataclass(v) and not isinstance(v, type):
            return {f.name: conv(getattr(v, f.name)) for f in dataclasses.fields(v)}
        if isinstance(v, tuple | list):
            return [conv(x) for x in v]
        return v

    return conv(cfg)


def set_dotted(d: dict[str, Any], key: str, value: Any) -> dict[str, Any]:
    """Return a copy of ``d`` with ``a.b.c = value`` set."""
    out = dict(d)
    head, _, rest = key.partition(".")
    if rest:
        sub = out.get(head, {})
        if not isinstance(sub, dict):
            raise ConfigError(f"sweep key {key!r}: {head!r} is not a table")
        out[head] = set_dotted(sub, rest, value)
    else:
        out[head] = value
    return out


def expand_sweep(raw: dict[str, Any]) -> list[tuple[str, dict[str, Any]]]:
    """Expand a ``[sweep]`` table into ``(label, config)`` pairs (Cartesian product)."""
    sweep = raw.get("sweep")
    base = {k: v for k, v in raw.items() if k != "sweep"}
    if not sweep:
        return [("", base)]
    if not isinstance(sweep, dict):
        raise ConfigError("[sweep] must be a table of dotted keys → lists of values")
    keys = sorted(sweep)
    for k in keys:
        if not isinstance(sweep[k], list) or not sweep[k]:
            raise ConfigError(f"sweep key {k!r} must be a non-empty list of values")
    runs = []
    for values in itertools.product(*(sweep[k] for k in keys)):
        cfg = base
        parts = []
        for k, v in zip(keys, values, strict=True):
            cfg = set_dotted(cfg, k, v)
            parts.append(f"{k.split('.')[-1]}={v}")
        runs.append(("_".join(parts).replace("/", "-"), cfg, values))
    # labels unique by construction: colliding ones get a short hash of the swept values
    counts: dict[str, int] = {}
    for label, _, _ in runs:
        counts[label] = counts.get(label, 0) + 1
    out = []
    for label, cfg, values in runs:
        if counts[label] > 1:
            h = hashlib.sha256(repr(list(values)).encode()).hexdigest()[:8]
            label = f"{label}-{h}"
        out.append((label, cfg))
    if len({lab for lab, _ in out}) != len(out):
        raise ConfigError("[sweep] holds the same combination of values twice; drop the repeat")
    return out


def _fmt(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if math.isnan(v):
            return "nan"
        if math.isinf(v):
            return "inf" if v > 0 else "-inf"
        return repr(v)
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"').replace("\n", "\\n") + '"'
    if isinstance(v, list | tuple):
        return "[" + ", ".join(_fmt(x) for x in v) + "]"
    if isinstance(v, dict):  # an inline table (e.g. one entry of a list of tables)
        items = (
            f"{k if k.replace('_', '').isalnum() else _fmt(k)} = {_fmt(x)}"
            for k, x in v.items()
            if x is not None
        )
        return "{" + ", ".join(items) + "}"
    raise ConfigError(f"cannot write {v!r} ({type(v).__name__}) to TOML")


def dumps_toml(d: dict[str, Any], _prefix: str = "") -> str:
    """Serialise a nested dict of scalars/lists to TOML (``None`` values are omitted)."""
    lines = []
    tables = []
    for k, v in d.items():
        key = k if k.replace("_", "").isalnum() else _fmt(k)
        if v is None:
            continue
        if isinstance(v, dict):
            tables.append((key, v))
        else:
            lines.append(f"{key} = {_fmt(v)}")
    out = "\n".join(lines) + ("\n" if lines else "")
    for key, v in tables:
        name = f"{_prefix}{key}"
        out += f"\n[{name}]\n" + dumps_toml(v, name + ".")
    return out
