"""`fxspace sweep` (parallel runs of a [sweep]) and `fxspace report` / `fx.report.collect`."""

import csv
import dataclasses
import json
import os
import subprocess
import sys
import types
from pathlib import Path

import pytest

from fxspace.cli import main
from fxspace.config import ConfigError
from fxspace.pipelines import _REGISTERED, register, run_dict, sweep_config
from fxspace.report import collect, write_report

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "configs" / "sweep_example.toml"


@dataclasses.dataclass(frozen=True)
class _Cfg:
    n: int = 2
    k: float = 1.0

    def validate(self):
        pass


def _toy_run(cfg, run_dir, seed):
    if cfg.n == 2:
        raise RuntimeError("n = 2 is broken on purpose")
    return {"err": (cfg.n - 3) ** 2 * cfg.k, "r": 1.0 / cfg.n, "label": "x"}


@pytest.fixture
def toy():
    mod = types.ModuleType("sweep_toy")
    mod.Config, mod.STAGES, mod.run = _Cfg, (), _toy_run
    register(mod, "sweep_toy")
    yield "sweep_toy"
    _REGISTERED.pop("sweep_toy", None)


def _write_cfg(tmp_path, toy, fail=True):
    p = tmp_path / "s.toml"
    ns = "[1, 2, 3, 4]" if fail else "[1, 3, 4]"
    p.write_text(f'experiment = "{toy}"\n[sweep]\nn = {ns}\nk = [1.0, 2.0]\n')
    return p


def test_sweep_reports_a_failed_run_and_goes_on(tmp_path, toy, capsys):
    cfg = _write_cfg(tmp_path, toy)
    rc = main(["sweep", str(cfg), "--engine", "serial", "--out", str(tmp_path / "o")])
    out = capsys.readouterr()
    assert rc == 1 and "n = 2 is broken on purpose" in out.err
    assert "6 complete, 2 failed" in out.out and "failed 2" in out.out
    res = sweep_config(cfg, tmp_path / "o", engine="serial")  # resumes: nothing rerun
    assert [r["status"] for r in res].count("complete") == 6
    with pytest.raises(ConfigError, match="workers must be an integer"):
        sweep_config(cfg, tmp_path / "o", workers=0)


def test_sweep_fail_fast_stops_at_the_first_failure(tmp_path, toy):
    cfg = _write_cfg(tmp_path, toy)
    res = sweep_config(cfg, tmp_path / "o", engine="serial", fail_fast=True)
    assert res[-1]["status"] == "failed" and len(res) < 8


def test_report_table_figures_and_failed_row(tmp_path, toy, capsys):
    cfg = _write_cfg(tmp_path, toy)
    sweep_config(cfg, tmp_path / "o", engine="serial")
    rows, folder = write_report(tmp_path / "o")
    printed = capsys.readouterr().out
    assert len(rows) == 8 and {"run", "k", "n", "err", "r", "status", "error"} <= set(rows[0])
    failed = [r for r in rows if r["status"] == "failed"]
    assert len(failed) == 2 and all("broken on purpose" in r["error"] for r in failed)
    assert all(r["err"] is None for r in failed)  # missing is None, never 0
    ok = {(r["n"], r["k"]): r["err"] for r in rows if r["status"] == "complete"}
    assert ok == {(n, k): (n - 3) ** 2 * k for n in (1, 3, 4) for k in (1.0, 2.0)}
    with open(folder / "runs.csv") as f:
        table = list(csv.DictReader(f))
    assert len(table) == 8 and {t["status"] for t in table} == {"complete", "failed"}
    md = (folder / "runs.md").read_text()
    assert md.count("| failed |") == 2 and "broken on purpose" in printed
    figs = sorted(p.name for p in folder.glob("*.png"))
    assert figs == ["err_vs_n_by_k.png", "r_vs_n_by_k.png"]  # one per differing metric
    frame = collect(tmp_path / "o", as_frame=True)
    assert list(frame.columns) == list(rows[0]) and len(frame) == 8
    with pytest.raises(FileNotFoundError, match="run_dir"):
        collect(tmp_path / "nope")


def test_report_of_a_single_run(tmp_path, toy):
    (d,) = run_dict({"experiment": toy, "n": 3}, tmp_path / "one")
    rows = collect(d)
    assert len(rows) == 1 and rows[0]["err"] == 0 and rows[0]["status"] == "complete"


def _metrics(out):
    return {
        p.parent.name: {k: v for k, v in json.loads(p.read_text()).items()
                        if k not in ("wall_time_s", "timings")}
        for p in sorted(Path(out).glob("*/metrics.json"))
    }  # fmt: skip


def _env():
    return {**os.environ, "PYTHONPATH": str(ROOT)}


def test_workers_match_serial_bit_for_bit(tmp_path):
    """--workers 2 (Dask when installed, else processes) and serial: identical metrics."""
    a, b = tmp_path / "serial", tmp_path / "par"
    cli = [sys.executable, "-m", "fxspace.cli", "sweep", str(EXAMPLE)]
    r1 = subprocess.run([*cli, "--engine", "serial", "--out", str(a)], env=_env(),
                        capture_output=True, text=True, timeout=900)  # fmt: skip
    assert r1.returncode == 0, r1.stderr[-2000:]
    r2 = subprocess.run([*cli, "--workers", "2", "--out", str(b)], env=_env(),
                        capture_output=True, text=True, timeout=900)  # fmt: skip
    assert r2.returncode == 0, r2.stderr[-2000:]
    r3 = subprocess.run([*cli, "--engine", "processes", "--out", str(tmp_path / "proc")],
                        env=_env(), capture_output=True, text=True, timeout=900)  # fmt: skip
    assert r3.returncode == 0, r3.stderr[-2000:]
    ma, mb = _metrics(a), _metrics(b)
    assert len(ma) == 4 and ma == mb == _metrics(tmp_path / "proc")
    # the workers were forked from the CLI (no JAX backend there yet), the runs in blocks
    assert "fork" in r2.stdout and "fork" in r3.stdout


def test_local_workers_take_blocks_and_fork_only_without_a_backend():
    from fxspace.pipelines._sweep import _blocks, _start_method

    assert _blocks(4, 2) == [0, 0, 1, 1]
    assert _blocks(5, 2) == [0, 0, 0, 1, 1]
    assert _blocks(3, 4) == [0, 1, 2]
    import jax.numpy as jnp

    jnp.zeros(1).block_until_ready()  # this process has a JAX backend now
    assert _start_method() == "spawn"


def test_two_concurrent_sweeps_run_every_run_once(tmp_path):
    out = tmp_path / "o"
    cli = [sys.executable, "-m", "fxspace.cli", "sweep", str(EXAMPLE), "--engine", "serial",
           "--out", str(out)]  # fmt: skip
    ps = [subprocess.Popen(cli, env=_env(), stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                           text=True) for _ in range(2)]  # fmt: skip
    logs = [p.communicate(timeout=900)[0] for p in ps]
    assert [p.returncode for p in ps] == [0, 0], logs
    wrote = [ln for log in logs for ln in log.splitlines() if ln.startswith("[fxspace] wrote")]
    assert sorted(wrote) == sorted(set(wrote)) and len(wrote) == 4, logs  # each run once
    assert len(_metrics(out)) == 4


def _free_port():
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_dask_scheduler_survives_a_killed_worker(tmp_path):
    """`dask scheduler` + two `dask worker`s on 127.0.0.1; one worker is killed while a run
    is in progress; every run still completes, with the serial metrics."""
    import signal
    import time

    pytest.importorskip("dask.distributed")
    from fxspace.pipelines._sweep import WORKER_ENV

    port = _free_port()
    addr = f"tcp://127.0.0.1:{port}"
    env = {**_env(), **WORKER_ENV}
    bindir = Path(sys.executable).parent
    procs = [subprocess.Popen([str(bindir / "dask"), "scheduler", "--host", "127.0.0.1",
                               "--port", str(port), "--no-dashboard"], env=env,
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                              start_new_session=True)]  # fmt: skip
    try:
        time.sleep(3)
        for _ in range(2):
            procs.append(subprocess.Popen(
                [str(bindir / "dask"), "worker", addr, "--nthreads", "1", "--no-dashboard",
                 "--host", "127.0.0.1"], env=env, stdout=subprocess.DEVNULL,
                stderr=subprocess.DEVNULL, start_new_session=True))  # fmt: skip
        out = tmp_path / "o"
        sweep = subprocess.Popen(
            [sys.executable, "-m", "fxspace.cli", "sweep", str(EXAMPLE), "--scheduler", addr,
             "--out", str(out)], env=_env(), stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT, text=True)  # fmt: skip
        t0 = time.time()
        while time.time() - t0 < 300 and not list(out.glob("*/.fxspace-lock")):
            time.sleep(0.2)
        time.sleep(1.0)
        os.killpg(procs[1].pid, signal.SIGKILL)  # one worker dies mid-run
        log = sweep.communicate(timeout=900)[0]
        assert sweep.returncode == 0, log[-3000:]
        serial = tmp_path / "serial"
        r = subprocess.run([sys.executable, "-m", "fxspace.cli", "sweep", str(EXAMPLE),
                            "--engine", "serial", "--out", str(serial)], env=_env(),
                           capture_output=True, text=True, timeout=900)  # fmt: skip
        assert r.returncode == 0, r.stdout[-2000:]
        assert len(_metrics(out)) == 4 and _metrics(out) == _metrics(serial)
    finally:
        for p in procs:
            try:
                os.killpg(p.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
            p.wait()
