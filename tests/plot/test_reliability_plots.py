"""Issue 10 figure fixes: criteria that pick the same ε stay visible; "disconnected" marks
do not sit at an r height; levels_grid.png has a legend."""

import jax
import numpy as np

import fxspace as fx
from fxspace.plot import plot_levels_grid, plot_sweep


def test_sweep_same_threshold_criteria_share_one_labelled_line():
    th = np.geomspace(10, 100, 6)
    r = np.array([np.nan, np.nan, 0.91, 0.95, 0.97, 0.96])
    conn = np.isfinite(r)
    fig = plot_sweep(th, r, conn, {"max_r": th[4], "elbow": th[4], "bounded_degree": th[3]})
    labels = [t.get_text() for t in fig.axes[0].get_legend().get_texts()]
    assert any("max_r = elbow" in s for s in labels)
    assert any(s.startswith("bounded_degree") for s in labels)
    ax = fig.axes[0]
    crosses = [ln for ln in ax.get_lines() if ln.get_label().startswith("disconnected")]
    assert len(crosses) == 1
    # drawn in axes coordinates at the bottom edge, not at an r value in data coordinates
    assert crosses[0].get_transform() == ax.get_xaxis_transform()
    assert np.all(np.asarray(crosses[0].get_ydata()) < 0.1)
    assert fig.axes[0].get_ylim()[0] > 0.5  # the r axis is not stretched down to fake r values


def test_levels_grid_has_a_legend(rng):
    Y = rng.standard_normal((120, 2))
    h = fx.build_hierarchy(Y, c0=4, key=jax.random.PRNGKey(0))
    fig = plot_levels_grid(h)
    assert fig.legends, "levels_grid.png needs a legend"
    texts = [t.get_text() for t in fig.legends[0].get_texts()]
    assert "cluster centre" in texts and "frame" in texts
