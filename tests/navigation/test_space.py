"""ε for navigation: a number, a factor of the connecting threshold, a criterion (sweep here,
the seed paper's max_r among them) or a finished sweep run; the source is recorded."""

import json

import jax.numpy as jnp
import numpy as np
import pytest
from helpers import face_like

import fxspace as fx
from fxspace.navigation import navigation_space, resolve_threshold
from fxspace.pipelines.navigation import threshold_from_run


@pytest.fixture(scope="module")
def pos():
    return face_like(n=60, m=8)[1]


def test_threshold_sources(pos, tmp_path):
    P = fx.pairwise_distances(fx.distance_features(jnp.asarray(pos)))
    t_conn = float(fx.connecting_threshold(P))
    eps, tc, src = resolve_threshold(P, None, 1.5, with_source=True)
    assert eps == pytest.approx(1.5 * t_conn) and tc == pytest.approx(t_conn)
    assert src.startswith("factor 1.5")
    # a criterion runs the sweep here — over the whole range, connecting ε to the largest
    # distance — and picks as choose_threshold does
    eps_r, _, src_r = resolve_threshold(P, "max_r", with_source=True, num_thresholds=8)
    sw = fx.threshold_sweep(P, fx.threshold_grid(P, 8))
    assert float(sw.thresholds[-1]) == pytest.approx(float(np.max(np.asarray(P))))
    assert eps_r == pytest.approx(fx.choose_threshold(sw, "max_r")["threshold"])
    assert src_r.startswith("criterion max_r") and "largest distance" in src_r
    # bad values: a clear FxspaceError
    for bad in ("230", -1.0, float("nan")):
        with pytest.raises(fx.FxspaceError, match="threshold"):
            resolve_threshold(P, bad)
    with pytest.raises(fx.FxspaceError, match="num_thresholds"):
        resolve_threshold(P, "max_r", num_thresholds=2.5)
    # a finished sweep run: read in the pipeline layer, passed to the library as a number
    run = tmp_path / "sweep"
    run.mkdir()
    (run / "metrics.json").write_text(
        json.dumps({"best_threshold": 1.2 * t_conn, "criterion": "elbow"})
    )
    eps_run, crit = threshold_from_run(run)
    assert (eps_run, crit) == (pytest.approx(1.2 * t_conn), "elbow")
    ns = navigation_space(pos, eps_run, hierarchy=None)
    assert ns.threshold == pytest.approx(1.2 * t_conn, rel=1e-6)
    assert ns.threshold_source == "value"
    with pytest.raises(fx.FxspaceError, match="run the sweep first"):
        threshold_from_run(tmp_path / "missing")
    # the library reads no run folder: "from:RUN_DIR" is refused, naming the fix
    with pytest.raises(fx.FxspaceError, match="pipelines.navigation.threshold_from_run"):
        navigation_space(pos, f"from:{run}", hierarchy=None)
    with pytest.raises(fx.FxspaceError, match="criterion"):
        resolve_threshold(P, "highest", with_source=True)
    (run / "metrics.json").write_text(json.dumps({"best_threshold": 0.5 * t_conn}))
    with pytest.raises(fx.FxspaceError, match="disconnected"):
        navigation_space(pos, threshold_from_run(run)[0], hierarchy=None)
    assert np.isfinite(ns.space.embedding).all()


def test_library_threshold_from_run_is_deprecated(tmp_path):
    """`fxspace.navigation.threshold_from_run` still answers (a stable name), warning that
    its home is the pipeline layer now."""
    (tmp_path / "metrics.json").write_text(json.dumps({"best_threshold": 2.5}))
    with pytest.warns(DeprecationWarning, match="pipelines.navigation.threshold_from_run"):
        assert fx.navigation.threshold_from_run(tmp_path) == (2.5, "?")


def test_a_criterion_sweep_can_be_supplied(pos):
    """`sweep=`: the library's rule over a sweep run elsewhere (the pipeline's cached stage)."""
    P = fx.pairwise_distances(fx.distance_features(jnp.asarray(pos)))
    calls = []

    def sweep(pairwise, grid):
        calls.append(len(grid))
        return fx.threshold_sweep(pairwise, grid)

    a = resolve_threshold(P, "max_r", with_source=True, num_thresholds=6, sweep=sweep)
    b = resolve_threshold(P, "max_r", with_source=True, num_thresholds=6)
    assert calls == [6] and a == b


def test_the_pipeline_resolves_a_runs_threshold_once(pos, tmp_path):
    """The navigation pipeline's ε: ``from:RUN_DIR`` read there (no distances computed), a
    number as it is, 0 and a criterion by the library's rule over these frames."""
    import fxspace.pipelines.navigation as nav
    from fxspace.config import ConfigError

    P = fx.pairwise_distances(fx.distance_features(jnp.asarray(pos)))
    t_conn = float(fx.connecting_threshold(P))

    def no_distances():
        raise AssertionError("the distances were computed")

    run = tmp_path / "sweep"
    run.mkdir()
    (run / "metrics.json").write_text(
        json.dumps({"best_threshold": 1.2 * t_conn, "criterion": "elbow"})
    )
    g = nav.GraphConfig(threshold=f"from:{run}")
    assert nav._threshold(g, no_distances, None) == (
        pytest.approx(1.2 * t_conn), f"from:{run} (elbow)", None, None)  # fmt: skip
    with pytest.raises(ConfigError, match="graph.threshold.*run the sweep first"):
        nav._threshold(nav.GraphConfig(threshold=f"from:{tmp_path}"), no_distances, None)
    assert nav._threshold(nav.GraphConfig(threshold=2.0), no_distances, None)[:2] == (
        2.0, "value")  # fmt: skip
    eps, src, sw, ch = nav._threshold(nav.GraphConfig(threshold=0.0), lambda: P, None)
    assert eps == pytest.approx(1.25 * t_conn) and src.startswith("factor 1.25")
    assert sw is None and ch is None
    g = nav.GraphConfig(threshold="max_r", num_thresholds=6)
    eps, src, sw, ch = nav._threshold(g, lambda: P, None)
    assert (eps, src) == resolve_threshold(P, "max_r", with_source=True, num_thresholds=6)[::2]
    assert len(sw.thresholds) == 6 and ch["criterion"] == "max_r" and ch["threshold"] == eps
