"""Segmentation by the fused lasso: known change points, target count, figure."""

import matplotlib.figure
import numpy as np
import pytest

import fxspace as fx


def _piecewise_linear(rng, knots, T=120, channels=12):
    """Motion whose velocity changes exactly at ``knots``."""
    t = np.arange(T, dtype=float)
    X = np.zeros((T, channels))
    pts = [0, *knots, T - 1]
    vel = rng.standard_normal((len(pts) - 1, channels)) * 2
    for i, (a, b) in enumerate(zip(pts[:-1], pts[1:], strict=True)):
        X[a : b + 1] = X[a] + np.outer(t[a : b + 1] - a, vel[i])
    return X


def test_finds_velocity_change_points(rng):
    knots = [30, 55, 90]
    X = _piecewise_linear(rng, knots)
    seg = fx.segment_motion(X, 4, min_length=5)
    assert seg.boundaries[0] == 0 and seg.boundaries[-1] == len(X) - 1
    np.testing.assert_allclose(seg.boundaries[1:-1], knots, atol=1)


def test_position_mode_on_steps(rng):
    X = np.repeat(rng.standard_normal((4, 6)) * 5, 20, axis=0)
    seg = fx.segment_motion(X, 4, on="position", min_length=5)
    np.testing.assert_array_equal(seg.boundaries, [0, 20, 40, 60, 79])


def test_fixed_lambda_and_segments_helper(rng):
    X = _piecewise_linear(rng, [40, 80])
    seg = fx.segment_motion(X, None, lam=2.0)
    assert seg.lam == 2.0
    segs = fx.segments_from_boundaries(seg.boundaries)
    assert segs[0][0] == 0 and segs[-1][1] == len(X) - 1
    assert all(a < b for a, b in segs)


def test_plot_and_errors(rng):
    X = _piecewise_linear(rng, [40, 80])
    seg = fx.segment_motion(X, 3)
    fig = fx.plot.plot_segmentation(seg)
    assert isinstance(fig, matplotlib.figure.Figure)
    with pytest.raises(fx.FxspaceError, match="n_segments"):
        fx.segment_motion(X, 100)
    with pytest.raises(fx.FxspaceError, match="on must be"):
        fx.segment_motion(X, 3, on="speed")


def test_count_chosen_from_the_data(rng):
    """Three velocity changes: BIC and the elbow on the fused-lasso path both choose the 4
    segments and the table says why; a non-integer count is refused."""
    knots = [30, 55, 90]
    X = _piecewise_linear(rng, knots) + 0.01 * rng.standard_normal((120, 12))
    for crit in ("bic", "elbow"):
        seg = fx.segment_motion(X, "auto", min_length=5, criterion=crit)
        sel = seg.selection
        assert sel["chosen"] == len(seg.boundaries) - 1 == 4, (crit, sel)
        assert sel["criterion"] == crit and sel["why"]
        np.testing.assert_allclose(seg.boundaries[1:-1], knots, atol=1)
    # the BIC table is the refitted least-squares RSS: check one entry by hand
    i = sel["counts"].index(1)
    Z = np.asarray(seg.summary)
    assert sel["rss"][i] == pytest.approx(float(np.sum((Z - Z.mean(0)) ** 2)))
    with pytest.raises(fx.FxspaceError, match="n_segments"):
        fx.segment_motion(X, 2.5)
    with pytest.raises(fx.FxspaceError, match="n_segments"):
        fx.fit_scene(X.reshape(120, 4, 3), 2, n_segments=2.5)
    with pytest.raises(fx.FxspaceError, match="criterion"):
        fx.segment_motion(X, "auto", criterion="aic")


def test_one_segment_default_everywhere():
    """Issue 47.5: one default for the automatic count, the elbow, under one name in
    `segment_motion` (``criterion``), `fit_scene` (``segment_criterion``) and the
    reconstruction config; the count itself defaults to the paper's 8 in both."""
    import inspect

    from fxspace.pipelines.reconstruction import Config

    seg = inspect.signature(fx.segment_motion).parameters
    scene = inspect.signature(fx.fit_scene).parameters
    assert seg["criterion"].default == scene["segment_criterion"].default == "elbow"
    assert Config().segment_criterion == "elbow"
    assert seg["n_segments"].default == scene["n_segments"].default == 8
