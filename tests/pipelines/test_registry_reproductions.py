"""Issue 46.4: one registry of experiments. The reproduction pages read their experiments
off the pipeline modules (``REPRODUCTION``), as the apps read ``APP``: adding an
experiment is one module (and its config), never a second list of names."""

from __future__ import annotations

import dataclasses
import types

import fxspace.pipelines as pipelines
from fxspace.pipelines._papers import PAPERS
from fxspace.pipelines._registry import experiments_of


def test_every_page_reads_registered_experiments_and_every_claim_has_a_page():
    claimed = {}
    for name in pipelines.available():
        key = getattr(pipelines.load_pipeline(name), "REPRODUCTION", None)
        if key is not None:
            assert key in PAPERS, f"pipeline {name} names an unknown page {key!r}"
            claimed.setdefault(key, []).append(name)
    assert set(claimed) == set(PAPERS)
    for key, paper in PAPERS.items():
        assert paper.key == key
        assert paper.configs == tuple(sorted(claimed[key])) == experiments_of(key)
    assert PAPERS["kim-jung"].configs == ("navigation",)


def test_a_registered_experiment_joins_its_page(monkeypatch):
    """One module, one entry: a pipeline registered with ``REPRODUCTION`` is read by its
    page with nothing else edited."""
    nav = pipelines.load_pipeline("navigation")

    @dataclasses.dataclass(frozen=True)
    class Config:
        def validate(self) -> None:
            pass

    mod = types.ModuleType("my_faces")
    mod.Config, mod.STAGES, mod.REPRODUCTION = Config, (), "kim-jung"
    mod.run = lambda cfg, run_dir, seed: {}
    monkeypatch.setitem(pipelines._REGISTERED, "my_faces", None)
    pipelines.register(mod, "my_faces")
    assert PAPERS["kim-jung"].configs == ("my_faces", "navigation")
    assert nav.REPRODUCTION == "kim-jung"
