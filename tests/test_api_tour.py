"""Issue 44.5: the API tour (``docs/guides/api-tour.md``) is code that runs.

Every ```python block of the page is run in order, in one namespace, with the current
folder a temporary one (nothing is written outside it: ``fx.save_edits`` and the writers
write there, never into ``runs/``), on the shipped data. Without the data the blocks that
read it (and those that use what they read) are skipped with the reason; the others still
run. A fast check finds every name a block uses defined by an earlier line of the page,
and the result vocabulary prints readably (``print(res.result)``)."""

from __future__ import annotations

import ast
import builtins
import os
import re
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import fxspace as fx
from fxspace.data import data_root

ROOT = Path(__file__).resolve().parents[1]
PAGE = ROOT / "docs" / "guides" / "api-tour.md"


def _blocks() -> list[str]:
    return re.findall(r"```python\n(.*?)```", PAGE.read_text(), flags=re.S)


class _Names(ast.NodeVisitor):
    """Names a block loads before defining them (``used``) and the names it defines."""

    def __init__(self):
        self.defined: set[str] = set()
        self.used: set[str] = set()

    def visit_Name(self, node):
        if isinstance(node.ctx, ast.Load):
            if node.id not in self.defined:
                self.used.add(node.id)
        else:
            self.defined.add(node.id)

    def visit_Assign(self, node):  # the value is evaluated before the targets are bound
        self.visit(node.value)
        for t in node.targets:
            self.visit(t)

    def visit_alias(self, node):
        self.defined.add((node.asname or node.name).split(".")[0])

    def visit_ExceptHandler(self, node):
        if node.name:
            self.defined.add(node.name)
        self.generic_visit(node)

    def visit_comprehension(self, node):
        self.visit(node.iter)
        self.visit(node.target)
        for c in node.ifs:
            self.visit(c)

    def _comp(self, node):  # the loops bind before the element is evaluated
        for g in node.generators:
            self.visit(g)
        for part in ("key", "value", "elt"):
            if hasattr(node, part):
                self.visit(getattr(node, part))

    visit_ListComp = visit_SetComp = visit_GeneratorExp = visit_DictComp = _comp


def _analyse(blocks: list[str]) -> list[_Names]:
    out = []
    for b in blocks:
        v = _Names()
        v.visit(ast.parse(b))
        out.append(v)
    return out


def _needs_data(blocks: list[str]) -> list[bool]:
    """A block needs the data when it reads a file through ``fx.data`` or uses a name
    that only a block needing the data defines."""
    from_data: set[str] = set()
    needs = []
    for b, v in zip(blocks, _analyse(blocks), strict=True):
        n = "data_path" in b or bool(v.used & from_data)
        needs.append(n)
        if n:
            from_data |= v.defined
        else:
            from_data -= v.defined
    return needs


def test_every_name_the_tour_uses_is_defined_on_the_page():
    blocks = _blocks()
    assert len(blocks) >= 8, "the tour lost blocks"
    known = set(dir(builtins))
    for k, v in enumerate(_analyse(blocks)):
        missing = sorted(v.used - known)
        assert not missing, f"block {k} of api-tour.md uses {missing} before defining them"
        known |= v.defined
    for name in ("threshold", "eps", "X", "Y", "positions", "neutral_markers", "jax", "keys"):
        assert name in known, name
    text = PAGE.read_text()
    assert "runs/reconstruction/edits.json" not in text  # edits go to the current folder
    writes = re.findall(r"(?:save_edits|write_\w+)\(\s*\"([^\"]+)\"", "\n".join(blocks))
    assert writes and all("/" not in w for w in writes), writes  # plain names: the current folder


def test_results_print_readably():
    R = fx.RESULTS
    assert repr(R.successful) == str(R.successful) == "RESULTS.successful"
    assert str(R.max_steps_reached).startswith("RESULTS.max_steps_reached: the iteration limit")
    assert repr(R.max_steps_reached) == "RESULTS.max_steps_reached"
    assert R[R.successful] == "" and R[R.stalled].startswith("the solver could make no")
    batch = fx.results.where_result(jnp.array([True, False, True]), R.successful, R.stalled)
    assert repr(batch) == "RESULTS[successful ×2, stalled ×1]"
    # the same pytree as equinox's item: through jit, vmap, lax.cond and RESULTS.where
    f = jax.jit(lambda x: R.where(x > 0, R.successful, R.nonfinite_input))
    assert repr(f(1.0)) == "RESULTS.successful" and repr(f(-1.0)) == "RESULTS.nonfinite_input"
    c = jax.lax.cond(True, lambda: R.successful, lambda: f(-1.0))
    assert bool(c == R.successful)
    v = jax.vmap(lambda x: R.where(x > 0, R.successful, R.stalled))(jnp.array([1.0, -1.0]))
    assert repr(v) == "RESULTS[successful ×1, stalled ×1]"


def _run(blocks, which, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("FXSPACE_QUIET", "1")
    ns: dict = {}
    for k, b in enumerate(blocks):
        if which[k]:
            exec(compile(b, f"{PAGE.name}, block {k}", "exec"), ns)  # noqa: S102 - the docs' own code
    return ns


def _edits_state():
    """The default run folder's edits (the editor replays them): never touched by the tour."""
    f = ROOT / "runs" / "reconstruction" / "edits.json"
    return f.stat().st_mtime if f.is_file() else None


@pytest.mark.slow
def test_the_blocks_without_data_run(tmp_path, monkeypatch):
    blocks = _blocks()
    needs = _needs_data(blocks)
    assert not all(needs) and any(needs)
    ns = _run(blocks, [not n for n in needs], tmp_path, monkeypatch)
    assert bool(ns["res"].result == fx.RESULTS.successful)
    assert str(ns["res"].result) == "RESULTS.successful"  # print(res.result) reads
    assert list(tmp_path.iterdir()) == []


@pytest.mark.slow
@pytest.mark.timeout(2400)  # every system on real data, compiled from cold
def test_the_whole_tour_runs_on_the_shipped_data(tmp_path, monkeypatch, capsys):
    if data_root() is None:
        pytest.skip("real capture data absent (set FXSPACE_DATA): the data blocks are skipped")
    blocks = _blocks()
    before = _edits_state()
    ns = _run(blocks, [True] * len(blocks), tmp_path, monkeypatch)
    out = capsys.readouterr().out
    assert _edits_state() == before, "the tour wrote runs/reconstruction/edits.json"
    assert not (tmp_path / "runs").exists()  # nothing written to a runs/ folder either
    written = {p.name for p in tmp_path.iterdir()}
    assert {"nav.gif", "edits.json", "out.bvh", "pose.bvh", "ik.glb", "anim.glb"} <= written
    assert 0.9 < ns["best"]["score"] <= 1.0 and ns["threshold"] > 0
    assert "RESULTS.successful" in out and "RESULTS<" not in out
    h, keys = ns["h"], ns["keys"]  # the route's keys: each pair linked at level 0
    assert all(b in h.levels[0].neighbours(a) for a, b in zip(keys, keys[1:], strict=False))
    saved, _ = fx.load_edits(tmp_path / "edits.json")  # the keys, in the temporary folder
    assert len(saved) == len(ns["edit_keys"]) == 2
    assert ns["P"].ndim == 3 and np.isfinite(ns["P"]).all()  # the scripted session's frames
    assert os.getcwd() == str(tmp_path)
