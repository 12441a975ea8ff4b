"""Issue 43 items 4 and 6: sweeps and searches that never hang, never lose a trial and
never run silently over another study — each case as the issue reported it."""

from __future__ import annotations

import dataclasses
import json
import os
import socket
import subprocess
import sys
import textwrap
import threading
import time
import types
from pathlib import Path

import pytest

from fxspace.cli import main
from fxspace.config import ConfigError
from fxspace.errors import CorruptFileError
from fxspace.pipelines import _REGISTERED, register, sweep_config
from fxspace.pipelines import _sweep as sw

ROOT = Path(__file__).resolve().parents[2]


# ------------------------------------------------------------------ a toy experiment


@dataclasses.dataclass(frozen=True)
class _Cfg:
    n: int = 1
    x: int = 0
    y: str = "a"

    def validate(self):
        pass


def _toy_run(cfg, run_dir, seed):
    print(f"toy run x={cfg.x} y={cfg.y}")
    if os.environ.get("TOY_INTERRUPT") == str(cfg.x):
        raise KeyboardInterrupt
    return {"score": float(cfg.x) + (0.5 if cfg.y == "b" else 0.0), "n": cfg.n}


@pytest.fixture
def toy():
    mod = types.ModuleType("issue43_toy")
    mod.Config, mod.STAGES, mod.run = _Cfg, (), _toy_run
    register(mod, "issue43_toy")
    yield "issue43_toy"
    _REGISTERED.pop("issue43_toy", None)


def _sweep_cfg(tmp_path, toy):
    p = tmp_path / "s.toml"
    p.write_text(f'experiment = "{toy}"\n[sweep]\nn = [1, 3]\n')
    return p


def _search_cfg(tmp_path, toy, name="search", trials=4, metric="score", direction="maximize",
                method="random"):  # fmt: skip
    p = tmp_path / f"{name}.toml"
    p.write_text(textwrap.dedent(f"""\
        experiment = "{toy}"
        [search]
        method = "{method}"
        trials = {trials}
        metric = "{metric}"
        direction = "{direction}"
        [search.space]
        x = {{ low = 0, high = 9 }}
        y = ["a", "b"]
        """))
    return p


def _dead_pid() -> int:
    p = subprocess.Popen([sys.executable, "-c", "pass"])
    p.wait()
    return p.pid


# ------------------------------------------------------------------ item 4: locks


def test_a_run_locked_by_another_host_is_reported_and_skipped_not_waited_for(
    tmp_path, toy, capsys
):
    cfg, out = _sweep_cfg(tmp_path, toy), tmp_path / "o"
    (out / "n=1").mkdir(parents=True)
    lock = out / "n=1" / ".fxspace-lock"
    lock.write_text(json.dumps({"pid": 4242, "host": "node-elsewhere", "at": "2026-01-01"}))
    t0 = time.monotonic()
    rc = main(["sweep", str(cfg), "--out", str(out), "--engine", "serial", "--lock-wait", "0.5"])
    took = time.monotonic() - t0
    got = capsys.readouterr()
    assert rc == 1 and took < 30
    # the other run went first, the locked one was reported with its holder and lock file
    assert "coming back to it after the other runs" in got.out
    assert "node-elsewhere" in got.out and str(lock) in got.out
    assert "still locked after" in got.err and "node-elsewhere" in got.err
    assert "--lock-wait" in got.err
    assert json.loads((out / "n=3" / "metrics.json").read_text())["n"] == 3
    assert not (out / "n=1" / "metrics.json").exists() and lock.is_file()  # not ours to delete
    assert "1 complete, 1 failed" in got.out


def test_a_run_locked_by_a_live_process_waits_bounded_then_runs_when_freed(tmp_path, toy, capsys):
    cfg, out = _sweep_cfg(tmp_path, toy), tmp_path / "o"
    holder = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        (out / "n=1").mkdir(parents=True)
        lock = out / "n=1" / ".fxspace-lock"
        lock.write_text(json.dumps({"pid": holder.pid, "host": socket.gethostname(), "at": "x"}))
        t0 = time.monotonic()
        res = sweep_config(cfg, out, engine="serial", lock_wait=1.0)
        assert time.monotonic() - t0 < 30
        bad = {r["run_dir"]: r for r in res}[str(out / "n=1")]
        assert bad["status"] == "failed" and f"pid {holder.pid}" in bad["error"]
        assert "waiting up to 1 s" in capsys.readouterr().out
        # freed while the sweep waits: the run is taken and completes
        threading.Timer(1.0, lock.unlink).start()
        res = sweep_config(cfg, out, engine="serial", lock_wait=20.0)
        assert [r["status"] for r in res] == ["complete", "complete"]
    finally:
        holder.kill()
        holder.wait()
    with pytest.raises(ConfigError, match="lock_wait"):
        sweep_config(cfg, out, engine="serial", lock_wait=-1)


# ------------------------------------------------------------------ item 4: workers


def test_workers_are_capped_at_the_runs_and_the_cores(tmp_path, toy, monkeypatch, capsys):
    cfg = _sweep_cfg(tmp_path, toy)
    seen = {}

    def fake(args, workers, *a, **k):
        seen["workers"], seen["runs"] = workers, len(args)
        return []

    monkeypatch.setattr(sw, "_run_processes", fake)
    monkeypatch.setattr(sw, "_run_dask", fake)
    monkeypatch.setattr(sw, "_cpu_count", lambda: 16)
    sweep_config(cfg, tmp_path / "o", workers=1000, engine="processes")
    assert seen == {"workers": 2, "runs": 2}
    assert "--workers 1000 capped at 2 (2 runs and 16 CPU cores)" in capsys.readouterr().out
    monkeypatch.setattr(sw, "_cpu_count", lambda: 1)
    sweep_config(cfg, tmp_path / "o", workers=1000, engine="dask")
    assert seen["workers"] == 1
    assert sw.cap_workers(2, 8) == 1 and "1 CPU cores" in capsys.readouterr().out


def test_search_workers_are_capped_at_the_trials_to_run(tmp_path, toy, monkeypatch, capsys):
    cfg = _search_cfg(tmp_path, toy, trials=3)
    seen = {}

    def fake(args, workers, *a, **k):
        seen["workers"] = workers
        return []

    monkeypatch.setattr(sw, "_run_processes", fake)
    monkeypatch.setattr(sw, "_cpu_count", lambda: 64)
    sweep_config(cfg, tmp_path / "o", workers=1000, engine="processes")
    assert seen["workers"] == 3 and "capped at 3 (3 trials to run" in capsys.readouterr().out


# ------------------------------------------------------------------ item 4: --scheduler


def _serve(handler_bytes: bytes | None):
    """A loopback TCP server: sends ``handler_bytes`` on connect (None: an HTTP server
    that waits for a request, as a web server or Dask's dashboard does)."""
    if handler_bytes is None:
        import http.server

        srv = http.server.ThreadingHTTPServer(("127.0.0.1", 0), http.server.BaseHTTPRequestHandler)
    else:
        import socketserver

        class H(socketserver.BaseRequestHandler):
            def handle(self):
                self.request.sendall(handler_bytes)
                time.sleep(0.5)

        srv = socketserver.ThreadingTCPServer(("127.0.0.1", 0), H)
    srv.daemon_threads = True
    threading.Thread(target=srv.serve_forever, daemon=True).start()
    return srv


@pytest.mark.parametrize("greeting, msg", [
    (None, "sent no Dask greeting"),
    (b"HTTP/1.1 400 Bad Request\r\n\r\n", "not a Dask scheduler's greeting"),
])  # fmt: skip
def test_scheduler_that_speaks_another_protocol_fails_fast(tmp_path, toy, monkeypatch, capsys,
                                                           greeting, msg):  # fmt: skip
    pytest.importorskip("dask.distributed")
    monkeypatch.setattr(sw, "SCHEDULER_TIMEOUT_S", 1.0)
    srv = _serve(greeting)
    try:
        addr = f"tcp://127.0.0.1:{srv.server_address[1]}"
        t0 = time.monotonic()
        rc = main(["sweep", str(_sweep_cfg(tmp_path, toy)), "--out", str(tmp_path / "o"),
                   "--scheduler", addr])  # fmt: skip
        assert rc == 2 and time.monotonic() - t0 < 10
        err = capsys.readouterr().err
        assert msg in err and addr in err and err.count("\n") == 1  # one line, no traceback
    finally:
        srv.shutdown()
        srv.server_close()


def test_scheduler_port_closed_is_an_error_naming_it(tmp_path, toy):
    pytest.importorskip("dask.distributed")
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]  # closed once the block ends: nothing listens there
    with pytest.raises(sw.SchedulerError, match="connection refused"):
        sweep_config(_sweep_cfg(tmp_path, toy), tmp_path / "o", scheduler=f"tcp://127.0.0.1:{port}")


@pytest.mark.parametrize("address, msg", [
    ("", "must be an address like tcp://HOST:PORT"),
    ("   ", "must be an address like tcp://HOST:PORT"),
    ("tcp://", "not HOST:PORT"),
    ("tcp://host", "not HOST:PORT"),
    ("tcp:/host:8786", "not HOST:PORT"),
    ("tcp://host:port", "not HOST:PORT"),
    ("tcp://host:0", "not in 1-65535"),
    ("tcp://host:99999", "not in 1-65535"),
    ("http://host:8787", "the Dask dashboard"),
    ("ftp://host:21", "unknown protocol 'ftp'"),
    ("tcp://a b:8786", "not HOST:PORT"),
])  # fmt: skip
def test_malformed_scheduler_addresses_are_one_line_errors(tmp_path, toy, capsys, address, msg):
    with pytest.raises(sw.SchedulerError, match=msg):
        sw.check_scheduler(address)
    rc = main(["sweep", str(_sweep_cfg(tmp_path, toy)), "--scheduler", address])
    err = capsys.readouterr().err
    assert rc == 2 and msg.split("'")[0] in err and "Traceback" not in err
    assert sw.check_scheduler("tcp://10.0.0.5:8786") == ("tcp", "10.0.0.5", 8786)
    assert sw.check_scheduler("[::1]:8786") == ("tcp", "[::1]", 8786)


@pytest.mark.parametrize("engine", ["serial", "processes"])
def test_scheduler_with_a_local_engine_is_refused(tmp_path, toy, engine):
    for cfg in (_sweep_cfg(tmp_path, toy), _search_cfg(tmp_path, toy)):
        with pytest.raises(ConfigError, match=f"--engine {engine} runs them here"):
            sweep_config(cfg, tmp_path / "o", scheduler="tcp://127.0.0.1:8786", engine=engine)
    assert not (tmp_path / "o").exists()  # refused before anything was written


# ------------------------------------------------------------------ item 6: searches


def _outcomes(res):
    return [(r["trial"], r["status"]) for r in res]


def test_ctrl_c_mid_search_is_rerun_and_the_count_completes(tmp_path, toy, monkeypatch, capsys):
    cfg, out = _search_cfg(tmp_path, toy, trials=4), tmp_path / "o"
    first = sweep_config(_search_cfg(tmp_path, toy, name="probe", trials=4), tmp_path / "p",
                         engine="serial")  # fmt: skip
    hit = first[1]["params"]["x"]  # the second configuration the seed draws: interrupt it
    monkeypatch.setenv("TOY_INTERRUPT", str(hit))
    with pytest.raises(KeyboardInterrupt):
        sweep_config(cfg, out, engine="serial")
    assert json.loads((out / "trial_0001" / "status.json").read_text())["status"] == "interrupted"
    import optuna

    study = optuna.load_study(study_name="search", storage=f"sqlite:///{out / 'search.db'}")
    assert [t.state.name for t in study.trials if t.state.name != "WAITING"] == [
        "COMPLETE", "FAIL"]  # never left RUNNING  # fmt: skip
    monkeypatch.delenv("TOY_INTERRUPT")
    capsys.readouterr()
    res = sweep_config(cfg, out, engine="serial")
    assert _outcomes(res) == [(k, "complete") for k in range(4)]
    assert "queued again" in capsys.readouterr().out
    st = json.loads((out / "trial_0001" / "status.json").read_text())
    assert st["status"] == "complete" and res[1]["params"]["x"] == hit


def test_a_trial_whose_process_died_is_failed_and_rerun(tmp_path, toy, capsys):
    import optuna

    from fxspace.pipelines._search import check_search, prepare_search

    cfg, out = _search_cfg(tmp_path, toy, trials=2), tmp_path / "o"
    s = check_search({"method": "random", "trials": 2, "metric": "score",
                      "direction": "maximize",
                      "space": {"x": {"low": 0, "high": 9}, "y": ["a", "b"]}})  # fmt: skip
    prepare_search(cfg, out, s)
    study = optuna.load_study(study_name="search", storage=f"sqlite:///{out / 'search.db'}")
    t = study.ask()  # a worker took trial_0000, then was killed (SIGKILL: nothing told)
    for k, v in {"fxspace_slot": 0, "fxspace_host": socket.gethostname(),
                 "fxspace_pid": _dead_pid()}.items():  # fmt: skip
        t.set_user_attr(k, v)
    capsys.readouterr()
    res = sweep_config(cfg, out, engine="serial")
    assert _outcomes(res) == [(0, "complete"), (1, "complete")]
    assert "is gone); queued again" in capsys.readouterr().out


def test_second_search_into_the_same_out_is_refused_or_starts_fresh(tmp_path, toy, capsys):
    out = tmp_path / "o"
    a = _search_cfg(tmp_path, toy, name="a", trials=3)
    b = _search_cfg(tmp_path, toy, name="b", trials=2)
    sweep_config(a, out, engine="serial")
    before = (out / "trial_0000" / "config.toml").read_text()
    with pytest.raises(ConfigError, match="holds the study of another search \\('a'"):
        sweep_config(b, out, engine="serial")
    assert (out / "trial_0000" / "config.toml").read_text() == before  # untouched
    (out / "trial_0002" / "notes.txt").write_text("mine")
    capsys.readouterr()
    res = sweep_config(b, out, engine="serial", force=True)
    assert _outcomes(res) == [(0, "complete"), (1, "complete")]
    assert "a fresh study; deleted ['a']" in capsys.readouterr().out
    import optuna

    names = [s.study_name for s in optuna.get_all_study_summaries(f"sqlite:///{out / 'search.db'}")]
    assert names == ["b"]  # the old study no longer records folders it does not own
    assert (out / "trial_0002" / "notes.txt").read_text() == "mine"  # a user's file stays
    assert not (out / "trial_0002" / "metrics.json").exists()  # the old study's results went
    # a search.db deleted by hand: its trial folders are not silently overwritten
    (out / "search.db").unlink()
    with pytest.raises(ConfigError, match="no study in .* records"):
        sweep_config(b, out, engine="serial")


def test_changed_direction_is_refused_with_the_fix(tmp_path, toy):
    out = tmp_path / "o"
    sweep_config(_search_cfg(tmp_path, toy, trials=1), out, engine="serial")
    flipped = _search_cfg(tmp_path, toy, trials=1, direction="minimize")
    with pytest.raises(ConfigError, match="started to maximize .* direction = 'maximize' back"):
        sweep_config(flipped, out, engine="serial")
    res = sweep_config(flipped, out, engine="serial", force=True)  # the fix: a fresh study
    assert _outcomes(res) == [(0, "complete")]


def test_misspelt_metric_fixed_reruns_the_failed_trials_honestly(tmp_path, toy, capsys):
    out = tmp_path / "o"
    _search_cfg(tmp_path, toy, trials=2, metric="scor")
    cfg = str(tmp_path / "search.toml")
    assert main(["sweep", cfg, "--out", str(out), "--engine", "serial"]) == 1
    got = capsys.readouterr()
    assert "0 complete, 2 failed" in got.out and "no 'scor'" in got.err
    assert main(["sweep", cfg, "--out", str(out), "--engine", "serial"]) == 1  # still wrong
    assert "0 complete, 2 failed" in capsys.readouterr().out
    _search_cfg(tmp_path, toy, trials=2, metric="score")
    assert main(["sweep", cfg, "--out", str(out), "--engine", "serial"]) == 0
    got = capsys.readouterr().out
    assert "2 complete, 0 failed" in got and "its metric is read again" in got
    # a different metric once trials completed would mix rankings: refused
    _search_cfg(tmp_path, toy, trials=2, metric="n")
    assert main(["sweep", cfg, "--out", str(out), "--engine", "serial"]) == 2
    assert "ranks its 2 completed trials by metric 'score'" in capsys.readouterr().err


@pytest.mark.parametrize("kind", ["garbage", "folder", "other_sqlite", "truncated"])
def test_malformed_search_db_is_a_clear_error(tmp_path, toy, capsys, kind):
    import sqlite3

    cfg, out = _search_cfg(tmp_path, toy, trials=1), tmp_path / "o"
    db = out / "search.db"
    if kind == "truncated":
        sweep_config(cfg, out, engine="serial")
        data = db.read_bytes()
        db.write_bytes(data[: len(data) // 3])
    else:
        out.mkdir()
        if kind == "garbage":
            db.write_text("garbage, not a database")
        elif kind == "folder":
            db.mkdir()
        else:
            con = sqlite3.connect(db)
            con.execute("CREATE TABLE mine (x)")
            con.commit()
            con.close()
    before = db.read_bytes() if db.is_file() else None
    with pytest.raises(CorruptFileError, match="search.db"):
        sweep_config(cfg, out, engine="serial")
    rc = main(["sweep", str(cfg), "--out", str(out), "--engine", "serial"])
    err = capsys.readouterr().err
    assert rc == 2 and "search.db" in err and "Traceback" not in err and err.count("\n") == 1
    if before is not None and kind != "truncated":
        assert db.read_bytes() == before  # never written to


_TWO = """
import dataclasses, json, os, sys, types
sys.path.insert(0, {tests!r})
from test_issue43_sweep import _Cfg, _toy_run
from fxspace.pipelines import register, sweep_config
mod = types.ModuleType("issue43_toy")
mod.Config, mod.STAGES, mod.run = _Cfg, (), _toy_run
register(mod, "issue43_toy")
res = sweep_config({cfg!r}, {out!r}, engine={engine!r}, workers={workers})
print("RESULT", json.dumps([[r["trial"], r["status"], r["params"]] for r in res]))
"""


def _script(tmp_path, cfg, out, engine="serial", workers=1):
    return _TWO.format(tests=str(Path(__file__).parent), cfg=str(cfg), out=str(out),
                       engine=engine, workers=workers)  # fmt: skip


@pytest.mark.slow
@pytest.mark.parametrize("method", ["random", "tpe"])
def test_two_sweep_processes_on_one_search_draw_different_configurations(tmp_path, toy, method):
    cfg, out = _search_cfg(tmp_path, toy, trials=8, method=method), tmp_path / "o"
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    ps = [subprocess.Popen([sys.executable, "-c", _script(tmp_path, cfg, out)], env=env,
                           stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
          for _ in range(2)]  # fmt: skip
    logs = [p.communicate(timeout=600)[0] for p in ps]
    assert [p.returncode for p in ps] == [0, 0], logs
    assert not any("Error" in log for log in logs), logs
    res = sweep_config(cfg, out, engine="serial")  # nothing left to run: the study's tally
    assert _outcomes(res) == [(k, "complete") for k in range(8)]
    params = [tuple(sorted(r["params"].items())) for r in res]
    assert len(set(params)) == 8, params  # no configuration drawn twice
    for k in range(8):
        c = (out / f"trial_{k:04d}" / "config.toml").read_text()
        assert f"x = {res[k]['params']['x']}" in c


def test_a_used_up_space_ends_the_search_saying_so(tmp_path, toy, capsys):
    p = tmp_path / "tiny.toml"
    p.write_text(f'experiment = "{toy}"\n[search]\nmethod = "tpe"\ntrials = 4\n'
                 'metric = "score"\ndirection = "maximize"\n'
                 '[search.space]\ny = ["a", "b"]\n')  # fmt: skip
    res = sweep_config(p, tmp_path / "o", engine="serial")
    got = capsys.readouterr().out
    assert sorted(r["params"]["y"] for r in res) == ["a", "b"]  # each point once, no repeat
    assert "every configuration of [search.space] has been tried" in got
    assert "2 complete, 0 failed, 2 never drawn of 4 trials" in got
