import dataclasses
import json
from typing import Literal

import pytest

from fxspace.config import (
    ConfigError,
    config_from_dict,
    config_to_dict,
    dumps_toml,
    expand_sweep,
    load_toml,
)
from fxspace.runs import cached, write_json_atomic


@dataclasses.dataclass(frozen=True)
class Inner:
    a: int = 1
    b: tuple[float, ...] = ()


@dataclasses.dataclass(frozen=True)
class Outer:
    inner: Inner = Inner()
    mode: Literal["x", "y"] = "x"
    lam: float = 0.5
    note: str | None = None


def test_config_roundtrip_through_toml(tmp_path):
    cfg = config_from_dict(Outer, {"inner": {"a": 3, "b": [1, 2.5]}, "mode": "y"})
    assert cfg.inner.b == (1.0, 2.5) and cfg.mode == "y"
    p = tmp_path / "c.toml"
    p.write_text(dumps_toml(config_to_dict(cfg)))
    assert config_from_dict(Outer, load_toml(p)) == cfg


@pytest.mark.parametrize(
    "bad, match",
    [
        ({"inner": {"c": 1}}, "unknown config key"),
        ({"mode": "z"}, "mode must be one of"),
        ({"lam": "big"}, "lam must be a number"),
        ({"inner": {"a": 1.5}}, "inner.a must be an integer"),
    ],
)
def test_config_errors_name_the_key(bad, match):
    with pytest.raises(ConfigError, match=match):
        config_from_dict(Outer, bad)


def test_bad_toml_file(tmp_path):
    p = tmp_path / "bad.toml"
    p.write_text("a = [1, 2\n")
    with pytest.raises(ConfigError, match="not valid TOML"):
        load_toml(p)
    with pytest.raises(ConfigError, match="does not exist"):
        load_toml(tmp_path / "none.toml")


def test_expand_sweep_product():
    runs = expand_sweep({"x": 1, "sweep": {"inner.a": [1, 2], "lam": [0.1, 0.2, 0.3]}})
    assert len(runs) == 6
    labels = {lab for lab, _ in runs}
    assert "a=1_lam=0.1" in labels
    assert all(r["inner"]["a"] in (1, 2) and "sweep" not in r for _, r in runs)
    with pytest.raises(ConfigError, match="non-empty list"):
        expand_sweep({"sweep": {"lam": 3}})


def test_cached_resumes(tmp_path):
    calls = []

    def compute():
        calls.append(1)
        return {"v": [1, 2]}

    assert cached(tmp_path, "k", compute) == {"v": [1, 2]}
    assert cached(tmp_path, "k", compute) == {"v": [1, 2]}
    assert len(calls) == 1
    (tmp_path / "cache" / "k.json").write_text("{broken")  # damaged entry is recomputed
    assert cached(tmp_path, "k", compute) == {"v": [1, 2]} and len(calls) == 2


def test_atomic_json_leaves_no_temp_on_error(tmp_path):
    p = tmp_path / "m.json"
    write_json_atomic(p, {"a": 1})
    with pytest.raises(TypeError):
        write_json_atomic(p, {"a": object()})
    assert json.loads(p.read_text()) == {"a": 1}
    assert [f.name for f in tmp_path.iterdir()] == ["m.json"]
