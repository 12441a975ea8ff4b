"""Ha & Han Fig. 3 read off the synthesised joints (issue 47.2/47.7): over a 60-s scripted
session of each shipped walk, the upper body's arm swing keeps time with the strides read
off the feet when the clocks are aligned by eqs. 2–3 (cycle lengths equal, no drift, as
in the captured takes), and does not when each half runs on its own clock. Nothing here
reads a clock: an implementation whose alignment did not reach the motion fails."""

from pathlib import Path

import numpy as np
import pytest

from fxspace.config import config_from_dict, load_toml
from fxspace.pipelines import parametric_synthesis as ps

ROOT = Path(__file__).resolve().parents[2]
WALKS = [("mood_walk.toml", "mood_walk"), ("block_walk.toml", "block_walk")]


def _cfg(path):
    raw = load_toml(path)
    body = {k: v for k, v in raw.items() if k not in ("experiment", "seed", "name", "sweep")}
    return config_from_dict(ps.Config, body)


@pytest.mark.slow
@pytest.mark.parametrize(("config", "setup"), WALKS)
def test_arm_swing_keeps_time_with_the_strides_only_when_aligned(data_dir, config, setup):
    path = ROOT / "configs" / config
    st = ps.load_setup(path, setup)
    m = ps.fig3_metrics(st, _cfg(path))
    print(setup, {k: round(v, 4) for k, v in m.items() if isinstance(v, float)})
    # the captured takes: one arm-swing cycle per stride, a steady phase relation
    assert abs(m["fig3_cycle_ratio_examples"] - 1.0) < 0.03
    assert m["fig3_phase_drift_examples"] < 1.0  # cycles per minute (short takes: noisy)
    # (b) aligned, as printed and with the default bound: the same as the captures
    for k in ("aligned", "aligned_as_printed"):
        assert abs(m[f"fig3_cycle_ratio_{k}"] - 1.0) < 0.01, k
        assert m[f"fig3_phase_drift_{k}"] < 0.25, k
    # (a) apart: the lengths differ and the phase slips by whole cycles over the minute
    assert abs(m["fig3_cycle_ratio_unaligned"] - 1.0) > 0.05
    assert m["fig3_phase_drift_unaligned"] > 2.0
    assert np.isfinite(m["fig3_phase_drift_unaligned"])
