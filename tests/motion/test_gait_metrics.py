"""Fig. 3's measures read off joints (issue 47.2): `cycle_events`, `cycle_coupling`,
`cadence` and `joint_speeds` on synthetic walkers whose answers are known."""

import numpy as np
import pytest

from fxspace import motion as M


def _walker(rate, seconds, t_lower, t_upper, heading=0.3):
    """Joints: 0/1 hips (left/right), 2/3 feet, 4/5 hands; walking along ``heading``
    with the feet swinging at period ``t_lower`` s and the arms at ``t_upper`` s."""
    t = np.arange(int(seconds * rate)) / rate
    fwd = np.array([np.sin(heading), 0.0, np.cos(heading)])
    left = np.cross(np.array([0.0, 1.0, 0.0]), fwd)
    root = 1.2 * t[:, None] * fwd
    a = 0.3 * np.sin(2 * np.pi * t / t_lower)[:, None]
    b = 0.2 * np.sin(2 * np.pi * t / t_upper + 0.25)[:, None]
    X = np.stack([root + 0.1 * left, root - 0.1 * left,
                  root + 0.1 * left + a * fwd, root - 0.1 * left - a * fwd,
                  root + 0.2 * left + 1.0 * np.array([0, 1, 0]) - b * fwd,
                  root - 0.2 * left + 1.0 * np.array([0, 1, 0]) + b * fwd], 1)  # fmt: skip
    return X


def test_coupling_of_harmonised_and_drifting_halves():
    rate = 30.0
    same = M.cycle_coupling(_walker(rate, 60, 1.1, 1.1), (2, 3), (4, 5), (0, 1), rate)
    assert same.cycle_ratio == pytest.approx(1.0, abs=1e-3)
    assert same.phase_drift < 0.01 and same.lower_period_s == pytest.approx(1.1, rel=1e-3)
    apart = M.cycle_coupling(_walker(rate, 60, 1.1, 1.25), (2, 3), (4, 5), (0, 1), rate)
    assert apart.cycle_ratio == pytest.approx(1.25 / 1.1, rel=2e-3)
    # the arm swing loses (1/1.1 − 1/1.25) cycles per second against the strides
    assert apart.phase_drift == pytest.approx(60 * (1 / 1.1 - 1 / 1.25), rel=0.02)
    assert M.cadence(_walker(rate, 20, 0.9, 0.9), (2, 3), (0, 1), rate) == pytest.approx(
        1 / 0.9, rel=2e-3)  # fmt: skip


def test_short_and_flat_signals():
    t = np.arange(40) / 30.0  # shorter than the 2-s window
    assert M.cycle_events(np.sin(2 * np.pi * t), 30.0).tolist() == pytest.approx([1.0])
    assert M.cycle_events(np.zeros(100), 30.0).size == 0  # no swing, no cycle
    c = M.cycle_coupling(np.zeros((50, 6, 3)), (2, 3), (4, 5), (0, 1), 30.0)
    assert np.isnan(c.cycle_ratio) and np.isnan(c.phase_drift)  # missing: NaN, never 0


def test_joint_speeds_in_heights_per_second():
    X = np.zeros((5, 2, 3))
    X[:, 1, 0] = np.arange(5) * 0.1  # 0.1 m per frame at 30 fps = 3 m/s
    np.testing.assert_allclose(M.joint_speeds(X, 30.0, height=1.5), [0.0, 2.0])
