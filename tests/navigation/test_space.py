"""ε for navigation: a number, a factor of the connecting threshold, a criterion (sweep here,
the seed paper's max_r among them) or a finished sweep run; the source is recorded."""

import json

import jax.numpy as jnp
import numpy as np
import pytest
from helpers import face_like

import fxspace as fx
from fxspace.navigation import navigation_space, resolve_threshold, threshold_from_run


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
    # a finished sweep run
    run = tmp_path / "sweep"
    run.mkdir()
    (run / "metrics.json").write_text(
        json.dumps({"best_threshold": 1.2 * t_conn, "criterion": "elbow"})
    )
    assert threshold_from_run(run) == (pytest.approx(1.2 * t_conn), "elbow")
    ns = navigation_space(pos, f"from:{run}", hierarchy=None)
    assert ns.threshold == pytest.approx(1.2 * t_conn, rel=1e-6)
    assert ns.threshold_source == f"from:{run} (elbow)"
    with pytest.raises(fx.FxspaceError, match="run the sweep first"):
        navigation_space(pos, f"from:{tmp_path / 'missing'}", hierarchy=None)
    with pytest.raises(fx.FxspaceError, match="criterion"):
        resolve_threshold(P, "highest", with_source=True)
    (run / "metrics.json").write_text(json.dumps({"best_threshold": 0.5 * t_conn}))
    with pytest.raises(fx.FxspaceError, match="disconnected"):
        navigation_space(pos, f"from:{run}", hierarchy=None)
    assert np.isfinite(ns.space.embedding).all()
