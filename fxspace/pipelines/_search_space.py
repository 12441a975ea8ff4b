"""A ``[search]`` table checked (`check_search`), its ``[search.space]`` as Optuna
distributions, configurations drawn from it without repeats, and a run's metric read
(`metric_value`)."""

from __future__ import annotations

import math
import random
from typing import Any

from fxspace.config import ConfigError

SEARCH_METHODS = ("tpe", "random")
_KEYS = {"method", "trials", "metric", "direction", "seed", "space"}


def check_search(table: Any) -> dict:
    """The ``[search]`` table checked (every problem named with its key); returns it with
    defaults filled in."""
    if not isinstance(table, dict):
        raise ConfigError("[search] must be a table (method, trials, metric, direction, space)")
    extra = set(table) - _KEYS
    if extra:
        raise ConfigError(f"[search] has unknown keys {sorted(extra)}; allowed: {sorted(_KEYS)}")
    s = {"method": "tpe", "direction": "minimize", "seed": 0, **table}
    if s["method"] not in SEARCH_METHODS:
        raise ConfigError(f"search.method must be one of {SEARCH_METHODS}, got {s['method']!r}")
    if s["direction"] not in ("minimize", "maximize"):
        raise ConfigError(
            f"search.direction must be 'minimize' or 'maximize', got {s['direction']!r}"
        )
    t = s.get("trials")
    if isinstance(t, bool) or not isinstance(t, int) or t < 1:
        raise ConfigError(f"search.trials must be an integer >= 1, got {t!r}")
    sd = s.get("seed")
    if isinstance(sd, bool) or not isinstance(sd, int) or not 0 <= sd < 2**31:
        raise ConfigError(f"search.seed must be an integer in [0, 2**31), got {sd!r}")
    if not isinstance(s.get("metric"), str) or not s["metric"]:
        raise ConfigError('search.metric must name a key of metrics.json (e.g. metric = "r")')
    space = s.get("space")
    if not isinstance(space, dict) or not space:
        raise ConfigError("[search.space] must give at least one key to draw")
    for k, v in space.items():
        _distribution(k, v)
    return s


def _distribution(key: str, spec: Any):
    """The Optuna distribution of one ``[search.space]`` entry (checked)."""
    import optuna.distributions as od

    if isinstance(spec, list):
        if not spec:
            raise ConfigError(f"search.space.{key}: an empty list of choices")
        return od.CategoricalDistribution(spec)
    if not isinstance(spec, dict) or not {"low", "high"} <= set(spec):
        raise ConfigError(
            f"search.space.{key} must be a list of choices or {{low = …, high = …}}, got {spec!r}"
        )
    lo, hi, log = spec["low"], spec["high"], bool(spec.get("log", False))
    if set(spec) - {"low", "high", "log"}:
        raise ConfigError(f"search.space.{key}: only low, high and log are allowed")
    if not all(isinstance(x, int | float) and not isinstance(x, bool) for x in (lo, hi)):
        raise ConfigError(f"search.space.{key}: low and high must be numbers")
    if not lo < hi or (log and lo <= 0):
        raise ConfigError(f"search.space.{key}: need low < high (and low > 0 with log = true)")
    if isinstance(lo, int) and isinstance(hi, int):
        return od.IntDistribution(lo, hi, log=log)
    return od.FloatDistribution(float(lo), float(hi), log=log)


def _set_dotted(raw: dict, key: str, value: Any) -> None:
    node = raw
    *path, last = key.split(".")
    for p in path:
        node = node.setdefault(p, {})
        if not isinstance(node, dict):
            raise ConfigError(f"search.space.{key}: {p!r} is not a table of the config")
    node[last] = value


def metric_value(metrics: dict, name: str) -> float:
    """``metrics[name]`` (a dotted path reaches into tables) as a finite float, or a
    `ConfigError` saying what was found."""
    node: Any = metrics
    for p in name.split("."):
        if not isinstance(node, dict) or p not in node:
            raise ConfigError(f"metrics.json has no {name!r} (search.metric); keys: "
                              f"{sorted(metrics)[:12]} …")  # fmt: skip
        node = node[p]
    if isinstance(node, bool) or not isinstance(node, int | float) or not math.isfinite(node):
        raise ConfigError(f"metric {name!r} is {node!r}, not a finite number")
    return float(node)



def _params_key(params: dict) -> tuple:
    return tuple(sorted((k, repr(v)) for k, v in params.items()))



def _space_size(space: dict) -> float:
    import optuna.distributions as od

    n = 1.0
    for d in space.values():
        if isinstance(d, od.CategoricalDistribution):
            n *= len(d.choices)
        elif isinstance(d, od.IntDistribution):
            n *= (d.high - d.low) // d.step + 1
        else:
            return math.inf
    return n


def _draw(space: dict, rng: random.Random) -> dict:
    import optuna.distributions as od

    p: dict[str, Any] = {}
    for k, d in space.items():
        if isinstance(d, od.CategoricalDistribution):
            p[k] = rng.choice(list(d.choices))
        elif isinstance(d, od.IntDistribution):
            if d.log:
                v = round(math.exp(rng.uniform(math.log(d.low), math.log(d.high))))
                p[k] = int(min(max(v, d.low), d.high))
            else:
                p[k] = rng.randrange(d.low, d.high + 1, d.step)
        elif d.log:
            p[k] = math.exp(rng.uniform(math.log(d.low), math.log(d.high)))
        else:
            p[k] = rng.uniform(d.low, d.high)
    return p


def _untried(space: dict, taken: set, rng: random.Random, n: int = 1) -> list[dict]:
    """Up to ``n`` configurations of ``space`` whose keys are not in ``taken`` (none when
    every point of a finite space is taken)."""
    import itertools

    import optuna.distributions as od

    size = _space_size(space)
    if size <= 20000:  # finite and small: choose among the points left
        axes = []
        for k, d in space.items():
            vals = d.choices if isinstance(d, od.CategoricalDistribution) else range(
                d.low, d.high + 1, d.step)  # fmt: skip
            axes.append([(k, v) for v in vals])
        left = [dict(c) for c in itertools.product(*axes) if _params_key(dict(c)) not in taken]
        rng.shuffle(left)
        return left[:n]
    got = []
    for _ in range(200 * n):
        p = _draw(space, rng)
        key = _params_key(p)
        if key not in taken:
            taken = taken | {key}
            got.append(p)
            if len(got) == n:
                break
    return got
