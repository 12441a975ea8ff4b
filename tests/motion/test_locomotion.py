"""Continuous locomotion (issue 22) and honest answers for bad input (issue 19): the walker
reproduces an example's root path exactly, walks on across cycle wraps without a jump,
and NaN / out-of-range controls never give a plausible pose."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import TOY_NAMES as NAMES
from helpers import TOY_OFFSETS as OFFSETS
from helpers import TOY_PARENTS as PARENTS
from helpers import toy_clips as _clips

import fxspace as fx
from fxspace import motion as M


def _spaces(upper_joint=-1):
    rng = np.random.default_rng(3)
    qL, rL = _clips(rng, 4, 20, 0.3)
    qU, rU = _clips(rng, 2 if upper_joint < 0 else 5, 16, 0.4)
    wl = np.stack([np.linspace(0, 19, 20) * s for s in (1.0, 0.9, 0.8, 0.95)])
    wu = np.stack([np.linspace(0, 15, 16) * s for s in (1.0, 0.8, 0.9, 0.85, 1.0)[: len(qU)]])
    return M.build_spaces(
        M.stack_examples(list(qL), list(rL), wl), M.stack_examples(list(qU), list(rU), wu),
        np.linspace(0, 15, 20), PARENTS, OFFSETS, mask=M.upper_body_mask(PARENTS, NAMES),
        spine=4, lower_joint=3, lower_dims=(0, 2), lower_time=19.0, upper_joint=upper_joint,
        upper_time=8.0, key=jax.random.PRNGKey(0), n_samples=60, knn_k=4, k_replace=5,
    )  # fmt: skip


@pytest.fixture(scope="module")
def sp():
    return _spaces()


def _run(sp, F, lower, alpha=1.0):
    up = jnp.tile(jnp.asarray([1.0, 0.0]), (F, 1))
    low = jnp.tile(jnp.asarray(lower), (F, 1))
    st = M.init_locomotion(sp, lower)
    return M.locomotion(sp, st, up, low, jnp.full((F,), alpha))


def test_one_example_walks_its_own_root_path(sp):
    """Known answer: lower parameter = example 0's own sample (k-NN exact, one-hot) and
    α = 1: the lower clock advances one frame per frame and the integrated ground path is
    the example's root path, turned so that the walker starts facing +Z."""
    _, poses = _run(sp, 19, sp.lower_params[0])
    r = np.asarray(sp.lower.root[0, :19])
    yaw0 = float(M.heading_angle(sp.lower.rotations[0, 0, 0]))
    c, s = np.cos(-yaw0), np.sin(-yaw0)
    d = r - r[0]
    ref = np.stack([c * d[:, 0] + s * d[:, 2], r[:, 1], -s * d[:, 0] + c * d[:, 2]], 1)
    got = np.asarray(poses.root)
    np.testing.assert_allclose(got[:, [0, 2]], ref[:, [0, 2]], atol=1e-5)
    np.testing.assert_allclose(got[:, 1], ref[:, 1], atol=1e-6)


def test_walks_on_across_wraps_without_a_jump(sp):
    final, poses = _run(sp, 120, sp.lower_params[1], alpha=0.5)
    assert int(final.cycles) >= 4  # the clocks wrapped, the walker did not stop
    root = np.asarray(poses.root)
    step = np.linalg.norm(np.diff(root, axis=0), axis=1)
    assert step.max() <= 2.0 * np.median(step)  # no jump back at a wrap
    travelled = np.linalg.norm(root[-1, [0, 2]] - root[0, [0, 2]])
    assert travelled > 3 * 0.5 * float(np.linalg.norm(sp.lower.root[1, 19] - sp.lower.root[1, 0]))
    X = M.world_positions(PARENTS, OFFSETS, poses)
    assert np.isfinite(X).all() and X.shape == (120, len(NAMES), 3)


def test_nan_parameter_gives_nan_pose_never_a_plausible_one(sp):
    st = M.init_state(sp, sp.lower_params[0])
    _, pose = M.synthesize_step(sp, st, jnp.asarray([jnp.nan, 0.5]), sp.lower_params[0])
    assert np.isnan(np.asarray(pose.rotations)).all()
    _, pose = M.synthesize_step(sp, st, jnp.asarray([0.5, 0.5]), jnp.asarray([jnp.nan, 0.0]))
    assert np.isnan(np.asarray(pose.rotations)).all()
    ls = M.init_locomotion(sp, sp.lower_params[0])
    _, pose = M.locomotion_step(sp, ls, jnp.asarray([0.5, 0.5]), jnp.asarray([0.0, jnp.nan]))
    assert np.isnan(np.asarray(pose.root)).all()
    # the upper parameterised space (k-NN over re-placed samples) as well
    sp7 = _spaces(7)
    st7 = M.init_state(sp7, sp7.lower_params[0])
    bad = jnp.asarray([jnp.nan, 0.0, 0.0])
    _, pose = M.synthesize_step(sp7, st7, bad, sp7.lower_params[0])
    assert np.isnan(np.asarray(pose.rotations)).all()


@pytest.mark.parametrize(("alpha", "dt"), [(5.0, 1.0), (-0.1, 1.0), (0.5, -1.0), (0.5, np.nan)])
def test_out_of_range_controls_are_refused(sp, alpha, dt):
    st = M.init_state(sp, sp.lower_params[0])
    up = jnp.asarray([0.5, 0.5])
    with pytest.raises(fx.FxspaceError, match="alpha|dt"):
        M.synthesize_step(sp, st, up, sp.lower_params[0], alpha, dt)
    with pytest.raises(fx.FxspaceError, match="alpha|dt"):
        M.locomotion_step(sp, M.init_locomotion(sp, sp.lower_params[0]), up,
                          sp.lower_params[0], alpha, dt)  # fmt: skip
    F = 3
    with pytest.raises(fx.FxspaceError, match="alpha|dt"):
        M.synthesize(sp, jnp.tile(up, (F, 1)), jnp.tile(sp.lower_params[0], (F, 1)), alpha, dt)


def test_knn_nan_query_gives_nan_weights(sp):
    ok = M.knn_blend_weights(sp.lower_params[3], sp.lower_params, sp.lower_weights, 4)
    assert np.isfinite(np.asarray(ok.weights)).all()
    bad = M.knn_blend_weights(jnp.asarray([jnp.nan, 0.0]), sp.lower_params, sp.lower_weights, 4)
    assert np.isnan(np.asarray(bad.weights)).all()
    # vmapped: only the NaN query is NaN
    Q = jnp.stack([sp.lower_params[3], jnp.asarray([0.0, jnp.inf])])
    W = jax.vmap(lambda q: M.knn_blend_weights(q, sp.lower_params, sp.lower_weights, 4).weights)(Q)
    assert np.isfinite(np.asarray(W[0])).all() and np.isnan(np.asarray(W[1])).all()


def test_dtw_nan_frame_flags_the_result_and_gives_no_path():
    rng = np.random.default_rng(0)
    a, b = rng.standard_normal((12, 3)), rng.standard_normal((9, 3))
    ok = M.dtw(a, b)
    assert ok.result == fx.RESULTS.successful and ok.converged
    assert int(ok.num_steps) == 12 + 9 - 1 and int(ok.stats["max_steps"]) == 20
    cost, path = ok  # still unpacks as (cost, path)
    assert path.shape[0] == int(ok.stats["path_length"]) > 0
    a[4, 1] = np.nan
    bad = M.dtw(a, b)
    assert np.isnan(float(bad.cost)) and bad.path.shape == (0, 2)
    assert bad.result == fx.RESULTS.nonfinite_input
    with pytest.raises(fx.FxspaceError, match="dtw"):
        M.dtw(a, b, throw=True)
    # batched: the NaN pair is flagged, its neighbour is not
    res = M.dtw_batch(np.stack([a, np.nan_to_num(a)]), b)
    assert np.asarray(fx.results.result_code(res.result)).tolist() == [
        int(fx.results.result_code(fx.RESULTS.nonfinite_input)),
        int(fx.results.result_code(fx.RESULTS.successful)),
    ]
    assert np.all(np.asarray(res.path[0]) == -1) and np.isfinite(float(res.cost[1]))


def test_fk_normalises_quaternions_and_refuses_zero():
    rng = np.random.default_rng(2)
    q = rng.standard_normal((3, len(NAMES), 4))
    unit = q / np.linalg.norm(q, axis=-1, keepdims=True)
    mot = M.Motion(NAMES, PARENTS, np.asarray(OFFSETS), np.zeros((3, 3)), unit, 30.0,
                   ((),) * len(NAMES))  # fmt: skip
    ref = M.forward_kinematics(mot)
    scaled = M.forward_kinematics(mot.__class__(**{**mot.__dict__, "rotations": 3.0 * q}))
    np.testing.assert_allclose(scaled, ref, atol=1e-9)
    zero = unit.copy()
    zero[1, 2] = 0.0
    zmot = mot.__class__(**{**mot.__dict__, "rotations": zero})
    with pytest.raises(fx.FxspaceError, match="zero quaternion"):
        M.forward_kinematics(zmot)
    X = jax.jit(M.forward_kinematics)(jax.tree.map(jnp.asarray, zmot))
    assert np.isnan(np.asarray(X[1])).any()  # under jit: NaN, never a plausible pose


def test_registration_result_flags_nan_features():
    rng = np.random.default_rng(1)
    f = [rng.standard_normal((15, 3)) for _ in range(3)]
    ok = M.register_examples(f)
    assert ok.result == fx.RESULTS.successful and ok.warps.shape == (3, 15)
    assert int(ok.stats["max_steps"][0]) == 15 + 15 - 1
    np.testing.assert_allclose(M.register_dtw(f), ok.warps)
    f[2][5, 1] = np.nan
    bad = M.register_examples(f)
    assert bad.result == fx.RESULTS.nonfinite_input
    assert np.isnan(bad.warps[2]).all() and np.isfinite(bad.warps[:2]).all()
    with pytest.raises(fx.FxspaceError, match="register_dtw"):
        M.register_dtw(f, throw=True)


_STEPPER_CHILD = """
import json, sys
sys.path[:0] = [sys.argv[1], sys.argv[1] + "/.."]
import jax
jax.config.update("jax_enable_x64", True)  # as the test suite runs
import jax.numpy as jnp, numpy as np
from fxspace import motion as M
from test_locomotion import _spaces
uj = int(sys.argv[2])
sp = _spaces(uj)
low = jnp.asarray(sp.lower_params[1])
up = jnp.asarray(sp.upper_params[0]) if uj >= 0 else jnp.asarray([0.7, 0.3])
st = M.init_locomotion(sp, low)
step = M.locomotion_stepper(sp, st, up, low)
roots = []
for k in range(30):
    st, pose = step(st, up, low + 0.01 * k, 0.5, 1.0)
    roots.append(np.asarray(pose.root).tolist())
print("RESULT", json.dumps({"source": step.source, "roots": roots,
                            "cycles": float(st.cycles)}))
"""


@pytest.mark.slow
@pytest.mark.parametrize("upper_joint", [7, -1])
def test_stepper_is_locomotion_step_compiled_and_read_back(tmp_path, upper_joint):
    """`locomotion_stepper` (what the live controller calls each frame): the first process
    compiles the step and writes it, the next reads it back (no tracing) and walks the same
    30 frames (across a wrap of the 20-frame cycle) as `locomotion_step` does here: a
    parametric upper space (Horn re-placement, a LAPACK eigh inside) and a style one."""
    import json
    import os
    import subprocess
    import sys
    from pathlib import Path

    env = {**os.environ, "FXSPACE_COMPILE_CACHE": str(tmp_path / "jax"), "JAX_PLATFORMS": "cpu"}
    here = str(Path(__file__).resolve().parent)
    got = []
    for _ in range(2):
        r = subprocess.run([sys.executable, "-c", _STEPPER_CHILD, here, str(upper_joint)],
                           env=env, capture_output=True, text=True, timeout=600)  # fmt: skip
        assert r.returncode == 0, r.stderr[-2000:]
        line = [ln for ln in r.stdout.splitlines() if ln.startswith("RESULT ")][-1]
        got.append(json.loads(line[len("RESULT ") :]))
    assert [g["source"] for g in got] == ["compiled", "disk"]
    assert got[1]["roots"] == got[0]["roots"]  # the same executable
    sp = _spaces(upper_joint)
    low = jnp.asarray(sp.lower_params[1])
    up = jnp.asarray(sp.upper_params[0]) if upper_joint >= 0 else jnp.asarray([0.7, 0.3])
    st = M.init_locomotion(sp, low)
    for k in range(30):
        st, pose = M.locomotion_step(sp, st, up, low + 0.01 * k, 0.5, 1.0)
        np.testing.assert_allclose(got[1]["roots"][k], np.asarray(pose.root), atol=1e-9)
    assert got[1]["cycles"] == float(st.cycles) >= 1
    with pytest.raises(fx.errors.FxspaceError):  # the stepper checks its controls
        M.locomotion_stepper(sp, st, up, low)(st, up, low, 1.5, 1.0)
