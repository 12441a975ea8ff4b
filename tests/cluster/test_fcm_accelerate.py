"""Issue 45: the block FCM's SQUAREM cycles reach the fixed point of its plain steps in
fewer block passes, never let the objective rise (a bad extrapolation is refused), and
their option is checked by name."""

from __future__ import annotations

import jax
import numpy as np
import pytest

import fxspace as fx
from fxspace.cluster import _fcm_blocks, fuzzy_cmeans


def _blobs(n=3000, seed=0):
    rng = np.random.default_rng(seed)
    centres = rng.uniform(-8, 8, size=(12, 2))
    return centres[rng.integers(0, 12, n)] + rng.normal(scale=0.6, size=(n, 2))


_KW = {"nearest": 4, "key": jax.random.key(0), "tol": 1e-7, "max_steps": 2000,
       "rows_per_task": 1000}  # fmt: skip


def test_squarem_reaches_the_plain_fixed_point_in_fewer_passes():
    X = _blobs()
    plain = fuzzy_cmeans(X, 12, accelerate=False, **_KW)
    fast = fuzzy_cmeans(X, 12, **_KW)  # accelerate is the default with rows_per_task
    assert plain.result == fast.result == fx.RESULTS.successful
    assert int(fast.stats["num_accepted"]) >= 1 and "num_accepted" not in plain.stats
    assert int(fast.num_steps) < 0.6 * int(plain.num_steps)
    np.testing.assert_allclose(float(fast.objective), float(plain.objective), rtol=1e-9)
    np.testing.assert_allclose(np.asarray(fast.centers), np.asarray(plain.centers), atol=1e-4)
    same = np.sort(np.asarray(fast.indices), axis=1) == np.sort(np.asarray(plain.indices), axis=1)
    assert np.mean(np.all(same, axis=1)) > 0.999  # the same nearest centres, but for ties
    # the stop is the plain map's: one more plain step moves no centre tol × spread
    assert float(fast.stats["moved"]) < float(fast.stats["tol_abs"])


def test_a_bad_extrapolation_is_refused_and_the_objective_never_rises(monkeypatch):
    X = _blobs()
    plain = fuzzy_cmeans(X, 12, accelerate=False, **_KW)
    good, seen, bad = _fcm_blocks._extrapolate, [], []
    calls = _fcm_blocks._Map.__call__

    def wild(v0, r, q, a):  # every other extrapolation thrown far off
        out = good(v0, r, q, a)
        if len(bad) % 2 == 0:
            out = out + np.linspace(-30.0, 30.0, out.size).reshape(out.shape)
        bad.append(out)
        return out

    def record(self, v):
        got = calls(self, v)
        seen.append((any(v is b for b in bad), got[1]))
        return got

    monkeypatch.setattr(_fcm_blocks, "_extrapolate", wild)
    monkeypatch.setattr(_fcm_blocks._Map, "__call__", record)
    res = fuzzy_cmeans(X, 12, **_KW)
    assert int(res.stats["num_refused"]) >= 1 and int(res.stats["num_accepted"]) >= 1
    assert len(seen) == int(res.num_steps)  # one pass a map evaluation
    # J over the passes, less the extrapolations above the last J kept (those must be
    # exactly the refused ones), never rises: an accepted cycle is never worse
    kept, dropped = [seen[0][1]], 0
    for ext, j in seen[1:]:
        if ext and j > kept[-1]:
            dropped += 1
        else:
            assert j <= kept[-1] + 1e-12 * abs(kept[0])
            kept.append(j)
    assert dropped == int(res.stats["num_refused"])
    assert res.result == fx.RESULTS.successful
    np.testing.assert_allclose(float(res.objective), float(plain.objective), rtol=1e-9)


def test_squarem_repeats_bit_for_bit_and_stops_on_bad_input():
    X = _blobs(800)
    kw = {"nearest": 3, "key": jax.random.key(2), "rows_per_task": 300, "max_steps": 60}
    a, b = fuzzy_cmeans(X, 10, **kw), fuzzy_cmeans(X, 10, **kw)
    for name in ("centers", "indices", "memberships", "objective", "num_steps"):
        np.testing.assert_array_equal(np.asarray(getattr(a, name)), np.asarray(getattr(b, name)))
    bad = X.copy()
    bad[5, 1] = np.nan
    res = fuzzy_cmeans(bad, 10, nearest=3, init_centers=X[:10], rows_per_task=256)
    assert res.result == fx.RESULTS.nonfinite_input and int(res.num_steps) <= 2


def test_accelerate_is_checked_by_name():
    X = _blobs(200)
    key = jax.random.key(0)
    for bad in ("yes", 1, 0.5):
        with pytest.raises(fx.FxspaceError, match="accelerate must be True or False"):
            fuzzy_cmeans(X, 4, nearest=2, key=key, rows_per_task=64, accelerate=bad)
    with pytest.raises(fx.FxspaceError, match="accelerate applies to the block solver"):
        fuzzy_cmeans(X, 4, nearest=2, key=key, accelerate=True)
    with pytest.raises(fx.FxspaceError, match="accelerate applies to truncated.*nearest=p"):
        fuzzy_cmeans(X, 4, key=key, accelerate=False)
    with pytest.raises(fx.FxspaceError, match="accelerate"):
        fx.navigation.TruncatedFuzzyCMeans(accelerate=False)
