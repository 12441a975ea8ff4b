"""Many processes (``jax.distributed``) and many devices, on this machine.

Two local CPU processes join one JAX runtime (a coordinator on 127.0.0.1, gloo
collectives); each computes its share of the landmark geodesics and of a threshold
sweep, and both must return exactly the one-process result. XLA's device count and the
distributed runtime are fixed when JAX starts, so everything runs in subprocesses.
"""

import json
import os
import socket
import subprocess
import sys
import textwrap

import numpy as np
import pytest

COMMON = """
import json, sys, jax, numpy as np
jax.config.update("jax_enable_x64", True)
import fxspace as fx

def work():
    rng = np.random.default_rng(0)
    X = rng.standard_normal((120, 3))
    g = fx.neighbourhood_graph(X, k=6, reduce_dim=None)
    lm = np.array([0, 11, 57, 90, 119, 42, 77])
    geo = fx.landmark_geodesics(g, lm, method="dijkstra")
    mds = fx.landmark_mds(geo, dim=2)
    P = np.asarray(fx.pairwise_distances(X))
    t0 = float(fx.connecting_threshold(P))
    sw = fx.threshold_sweep(P[:40, :40], np.array([0.5, 1.1, 2.0]) * t0, mds_method="eigh")
    return {"geo": np.asarray(geo.distances).tolist(),
            "emb": np.asarray(mds.embedding).tolist(),
            "scores": np.asarray(sw.scores).tolist(),
            "connected": np.asarray(sw.connected).tolist(),
            "n_components": np.asarray(sw.n_components).tolist()}
"""

WORKER = COMMON + textwrap.dedent(
    """
    pid, port = int(sys.argv[1]), sys.argv[2]
    jax.config.update("jax_cpu_collectives_implementation", "gloo")
    jax.distributed.initialize(
        coordinator_address=f"127.0.0.1:{port}", num_processes=2, process_id=pid,
        initialization_timeout=60,
    )
    assert jax.process_count() == 2
    out = work()
    out["process_count"] = jax.process_count()
    print("RESULT" + json.dumps(out), flush=True)
    jax.distributed.shutdown()
    """
)

SINGLE = COMMON + 'print("RESULT" + json.dumps(work()), flush=True)\n'

SHARDED = textwrap.dedent(
    """
    import json, jax, numpy as np
    import fxspace as fx
    from scipy.sparse.csgraph import shortest_path
    from fxspace.expression import _geodesic
    assert jax.local_device_count() == 2
    _geodesic._SHARDED_FROM = 256  # "auto" shards from 1024 vertices; smaller here, faster
    rng = np.random.default_rng(1)
    X = rng.standard_normal((300, 3)).astype(np.float32)
    P = np.asarray(fx.pairwise_distances(X))
    eps = 1.2 * float(fx.connecting_threshold(P))
    W = fx.epsilon_graph(P, eps)
    D = fx.floyd_warshall(W)  # auto: sharded over the 2 devices, then gathered
    es = fx.expression_space(None, eps, pairwise=P, paths=False, mds_method="eigh")
    ref = shortest_path(np.where(np.isinf(np.asarray(W)), 0, np.asarray(W)), directed=False)
    print("RESULT" + json.dumps({
        "sharded": len(D.sharding.device_set),
        "err": float(np.max(np.abs(np.asarray(D) - ref) / np.maximum(ref, 1e-6))),
        "es_err": float(np.max(np.abs(np.asarray(es.geodesics.distances) - ref)
                               / np.maximum(ref, 1e-6))),
        "score": float(es.score)}))
    """
)


def _env(**extra):
    env = dict(os.environ, JAX_PLATFORMS="cpu", **extra)
    env.pop("XLA_FLAGS", None)
    env.update(extra)
    return env


def _result(stdout: str) -> dict:
    lines = [ln for ln in stdout.splitlines() if ln.startswith("RESULT")]
    assert lines, stdout
    return json.loads(lines[-1][len("RESULT") :])


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_two_processes_equal_one_process():
    try:
        import jax

        if not hasattr(jax, "distributed"):
            pytest.skip("this JAX has no jax.distributed runtime")
    except ImportError:  # pragma: no cover
        pytest.skip("jax missing")
    port = _free_port()
    procs = [
        subprocess.Popen(
            [sys.executable, "-c", WORKER, str(pid), str(port)],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            env=_env(),
        )
        for pid in (0, 1)
    ]
    outs = []
    for p in procs:
        try:
            out, err = p.communicate(timeout=240)
        except subprocess.TimeoutExpired:
            for q in procs:
                q.kill()
            pytest.fail("jax.distributed workers timed out")
        if p.returncode != 0 and ("gloo" in err.lower() and "not" in err.lower()):
            pytest.skip(f"CPU collectives (gloo) unavailable: {err[-300:]}")
        assert p.returncode == 0, err[-3000:]
        outs.append(_result(out))
    single = subprocess.run(
        [sys.executable, "-c", SINGLE], capture_output=True, text=True, env=_env(), timeout=240
    )
    assert single.returncode == 0, single.stderr[-3000:]
    ref = _result(single.stdout)
    for out in outs:
        assert out.pop("process_count") == 2
        for key in ref:  # identical, not merely close
            np.testing.assert_array_equal(np.asarray(out[key]), np.asarray(ref[key]), err_msg=key)
    assert np.isnan(ref["scores"][0]) and not ref["connected"][0]


def test_sharding_on_by_default_and_gathered_before_downstream_ops():
    r = subprocess.run(
        [sys.executable, "-c", SHARDED],
        capture_output=True,
        text=True,
        env=_env(XLA_FLAGS="--xla_force_host_platform_device_count=2"),
        timeout=400,
    )
    assert r.returncode == 0, r.stderr[-3000:]
    out = _result(r.stdout)
    assert out["sharded"] == 1  # gathered to one device: what follows is not partitioned
    assert out["err"] < 1e-5 and out["es_err"] < 1e-5
    assert 0.0 < out["score"] <= 1.0
