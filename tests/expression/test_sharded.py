"""Multi-device paths (rows of Floyd, thresholds of a sweep) on 2 CPU devices.

XLA's device count is fixed when JAX starts, so this runs in a subprocess.
"""

import json
import os
import subprocess
import sys
import textwrap

SCRIPT = textwrap.dedent(
    """
    import json, jax, numpy as np
    jax.config.update("jax_enable_x64", True)
    import fxspace as fx
    from scipy.sparse.csgraph import shortest_path
    assert jax.device_count() == 2
    rng = np.random.default_rng(0)
    X = rng.standard_normal((301, 3))
    P = np.sqrt(((X[:, None] - X[None]) ** 2).sum(-1))
    t0 = float(fx.connecting_threshold(P))
    W = np.asarray(fx.epsilon_graph(P, 1.1 * t0))
    D = np.asarray(fx.floyd_warshall(W, method="sharded", block=32))
    geo = fx.geodesic_distances(W, method="sharded", block=32)
    assert np.array_equal(np.asarray(geo.distances), D)
    nxt = np.asarray(geo.next_hop)
    i, j = np.nonzero(np.isfinite(D) & ~np.eye(len(D), dtype=bool))
    k = nxt[i, j]
    assert np.allclose(W[i, k] + D[k, j], D[i, j], rtol=1e-12)
    ref = shortest_path(np.where(np.isinf(W), 0, W), directed=False)
    th = np.array([0.8, 1.1, 1.5]) * t0
    sw = fx.threshold_sweep(P, th, shard=True)
    one = [float(fx.threshold_sweep(P, th[k:k + 1]).scores[0]) for k in range(3)]
    print(json.dumps({"fw_err": float(np.max(np.abs(D - ref))),
                      "sweep": np.asarray(sw.scores).tolist(), "loop": one,
                      "connected": np.asarray(sw.connected).tolist()}))
    """
)


def test_sharded_floyd_and_sweep_on_two_devices():
    env = dict(
        os.environ, XLA_FLAGS="--xla_force_host_platform_device_count=2", JAX_PLATFORMS="cpu"
    )
    r = subprocess.run(
        [sys.executable, "-c", SCRIPT],
        capture_output=True,
        text=True,
        env=env,
        check=False,
        timeout=300,
    )
    assert r.returncode == 0, r.stderr[-2000:]
    out = json.loads(r.stdout.strip().splitlines()[-1])
    assert out["fw_err"] < 1e-10
    assert out["connected"] == [False, True, True]
    assert out["sweep"][0] != out["sweep"][0]  # NaN where disconnected
    for a, b in zip(out["sweep"][1:], out["loop"][1:], strict=True):
        assert abs(a - b) < 1e-10
