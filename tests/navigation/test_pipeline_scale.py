"""The navigation pipeline on the k-NN graph (issues 24, 45): ``navigation_scale`` is the
navigation pipeline with scale defaults; down to every frame, the paper's links (no
bridges, ρ by its experiment), every level's FCM at its fixed point; cached stages and
resume."""

import json

import numpy as np
import pytest

import fxspace as fx
import fxspace.pipelines.navigation_scale as nsc
from fxspace.config import ConfigError
from fxspace.pipelines import run_dict

SMALL = {
    "experiment": "navigation_scale",
    "seed": 0,
    "data": {"source": "synthetic", "synthetic_frames": 1500, "synthetic_markers": 24},
    "graph": {"k": 8, "landmarks": 64},
    "hierarchy": {"c0": 6, "levels": 3, "rows_per_task": 500},  # 3 FCM blocks
    "navigation": {"figure": False},
}


@pytest.fixture(autouse=True)
def _fixed_code_digest(monkeypatch):
    import fxspace.runs

    monkeypatch.setattr(fxspace.runs, "code_digest", lambda: "test-code")


def _metrics(d):
    m = json.loads((d / "metrics.json").read_text())
    m.pop("timings"), m.pop("wall_time_s", None)
    return m


def test_route_refined_to_every_frame_is_a_graph_walk(tmp_path):
    (d,) = run_dict(SMALL, tmp_path / "run")
    m = _metrics(d)
    assert m["frames"] == 1500 and m["centres_per_level"] == [6, 12, 24, 1500]
    assert m["graph_kind"] == "knn" and m["path_is_graph_walk"] and m["path_length_frames"] >= 2
    assert m["graph_joins"] is None  # one take: one piece
    # the paper at this size too: no bridges, ρ by the experiment, every level converged
    assert m["links_bridged"] == 0 and m["rho_experiment"]["chosen_scale"] > 0
    assert m["levels_converged"] == "4/4" and m["fcm_not_converged"] == []
    # the pieces the rule leaves each level in are counted (the route keeps to one)
    assert all(lv["link_pieces"] >= 1 and lv["bridges"] == 0 for lv in m["levels"])
    assert 0.5 < m["r"] <= 1.0
    routes = json.loads((d / "routes.json").read_text())
    assert [r["level"] for r in routes] == [0, 1, 2, 3]
    # the finest route's frames are the run's: consecutive frames joined by graph edges
    from fxspace.datasets import FaceData, load_face

    ss = nsc.load_space(nsc.Config(), load_face(FaceData(**SMALL["data"]), 0).positions,
                        d, 0)  # fmt: skip
    W = fx.expression.to_scipy(ss.paths)
    fr = np.asarray(routes[-1]["frames"])
    assert np.all(np.asarray(W[fr[:-1], fr[1:]]).ravel() > 0)


def test_takes_in_pieces_are_joined_and_said(tmp_path, data_dir):
    """The shared AnimFace takes resampled: a k-NN graph in pieces (each take nearer itself
    than the others), joined at their closest frames (graph.join = "closest", the
    default) and said in the metrics and the space's description; "none" refuses it."""
    cfg = {**SMALL, "data": {"source": "animface", "target_frames": 3000},
           "graph": {**SMALL["graph"], "k": 4}}  # two pieces at this k (one at k = 8)
    (d,) = run_dict(cfg, tmp_path / "run")
    m = _metrics(d)
    j = m["graph_joins"]
    assert len(j["pieces"]) >= 2 and sum(j["pieces"]) == m["frames"] == 3000
    assert len(j["frames"]) == len(j["lengths"]) == len(j["pieces"]) - 1
    assert all(x > 0 for x in j["lengths"]) and "pieces joined" in m["threshold_source"]
    assert m["links_bridged"] == 0 and m["path_is_graph_walk"]
    none = {**cfg, "graph": {**cfg["graph"], "join": "none"}}
    with pytest.raises(ConfigError, match='connected components.*graph.join = "closest"'):
        run_dict(none, tmp_path / "none")
    with pytest.raises(ConfigError, match="graph.join must be"):
        run_dict({**cfg, "graph": {**cfg["graph"], "join": "nearest"}}, tmp_path / "bad")


@pytest.mark.slow
def test_interrupted_after_the_space_resumes(tmp_path, monkeypatch):
    """Interrupt after the first stage (the graph and the embedding), rerun: identical
    metrics and the space not recomputed."""
    import fxspace.pipelines.navigation as nav

    assert {"space", "hierarchy"} <= set(nsc.STAGES)
    (ref,) = run_dict(SMALL, tmp_path / "ref")
    calls = []
    real_space = nav._knn_space
    monkeypatch.setattr(nav, "_knn_space", lambda *a: calls.append(1) or real_space(*a))
    real_h = nav.build_hierarchy

    def interrupt(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(nav, "build_hierarchy", interrupt)
    with pytest.raises(KeyboardInterrupt):
        run_dict(SMALL, tmp_path / "a")
    assert (tmp_path / "a" / "cache" / "space.npz").is_file() and len(calls) == 1
    monkeypatch.setattr(nav, "build_hierarchy", real_h)
    (d,) = run_dict(SMALL, tmp_path / "a")
    assert len(calls) == 1  # the space came from the cache
    assert _metrics(d) == _metrics(ref)


def test_config_validate_names_the_key():
    for bad, key in [
        (nsc.GraphConfig(k=1), "graph.k"),
        (nsc.GraphConfig(landmarks=2), "graph.landmarks"),
        (nsc.GraphConfig(landmark_batch=-1), "graph.landmark_batch"),
        (nsc.HierarchyConfig(c0=0), "c0"),
        (nsc.HierarchyConfig(rows_per_task=-1), "hierarchy.rows_per_task"),
        (nsc.GraphConfig(kind="dense"), "graph.kind"),
        (nsc.NavConfig(fps=0.0), "fps"),
        (nsc.NavConfig(num_keys=1), "num_keys"),
    ]:
        with pytest.raises(ConfigError, match=key):
            bad.validate()


def test_unknown_key_centre_names_the_setting(tmp_path):
    bad = {**SMALL, "navigation": {"figure": False, "key_centres": [0, 99]}}
    with pytest.raises(ConfigError, match="navigation.key_centres"):
        run_dict(bad, tmp_path / "bad")


def test_shipped_config_is_valid():
    """``configs/navigation_scale.toml`` (100 000 frames, down to every frame) parses and
    validates; the run itself is measured by ``bench_studio.py`` (README)."""
    from pathlib import Path

    from fxspace.config import config_from_dict, load_toml

    raw = load_toml(Path(__file__).resolve().parents[2] / "configs" / "navigation_scale.toml")
    assert raw["experiment"] == "navigation_scale"
    body = {k: v for k, v in raw.items() if k not in ("experiment", "seed")}
    cfg = config_from_dict(nsc.Config, body)
    cfg.validate()
    assert cfg.data.synthetic_frames == 100_000 and cfg.hierarchy.finest
    assert cfg.graph.kind == "knn" and cfg.hierarchy.levels == 5
    # the same pipeline object serves both names: one Config, one space record
    import fxspace.pipelines.navigation as nav

    assert issubclass(nsc.Config, nav.Config) and nsc.run is nav.run
    assert nsc.load_space is nav.load_space


def test_shipped_archive_config_is_valid():
    """``configs/navigation_archive.toml`` (10⁶ frames) parses, validates and asks for the
    streamed chain: the k-NN graph, landmark rounds, FCM blocks, down to every frame."""
    from pathlib import Path

    from fxspace.config import config_from_dict, load_toml

    raw = load_toml(Path(__file__).resolve().parents[2] / "configs" / "navigation_archive.toml")
    assert raw["experiment"] == "navigation_scale"
    cfg = config_from_dict(nsc.Config, {k: v for k, v in raw.items()
                                        if k not in ("experiment", "seed")})  # fmt: skip
    cfg.validate()
    assert cfg.data.synthetic_frames == 1_000_000 and cfg.hierarchy.finest
    assert cfg.graph.kind == "knn" and cfg.graph.landmark_batch > 0
    assert cfg.hierarchy.rows_per_task > 0


@pytest.mark.slow
def test_a_two_worker_local_cluster_runs_the_same_hierarchy(tmp_path):
    """Issue 45: the scale pipeline with its graph's blocks, its landmarks' rounds and its
    FCM steps' blocks on a 2-worker Dask ``LocalCluster`` (``[graph] scheduler =
    "local"``) gives the hierarchy of one process."""
    pytest.importorskip("dask.distributed")
    (one,) = run_dict(SMALL, tmp_path / "one")
    raw = {**SMALL, "graph": {**SMALL["graph"], "scheduler": "local", "workers": 2}}
    (two,) = run_dict(raw, tmp_path / "two")
    a, b = _metrics(one), _metrics(two)
    for key in ("centres_per_level", "levels", "links_bridged", "levels_converged", "r"):
        assert a[key] == b[key], key
    ha, hb = np.load(one / "hierarchy.npz"), np.load(two / "hierarchy.npz")
    assert sorted(ha.files) == sorted(hb.files)
    for name in ha.files:
        np.testing.assert_array_equal(ha[name], hb[name], err_msg=name)


def test_graph_scheduler_is_checked(tmp_path):
    for bad, msg in (({"scheduler": "http://127.0.0.1:8787"}, "dashboard"),
                     ({"scheduler": "local", "workers": 0}, "workers")):  # fmt: skip
        raw = {**SMALL, "graph": {**SMALL["graph"], **bad}}
        with pytest.raises(ConfigError, match=msg):
            run_dict(raw, tmp_path / "bad")
