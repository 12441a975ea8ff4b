"""``fxspace sweep``: the runs of a ``[sweep]`` as tasks on a Dask cluster (or processes).

Each run of the config is one task: a worker resolves the config again, takes the run
folder's lock (`fxspace.runs.run_lock`, waiting while another worker or another
``fxspace sweep`` holds it), and runs it exactly as the serial ``fxspace run`` does, so
the results are the same bit for bit and a finished run is skipped. The embedded
default is a local Dask distributed cluster (``dask.distributed.LocalCluster`` with one
thread per worker process); where Dask is not installed, a
``concurrent.futures.ProcessPoolExecutor``; ``scheduler="tcp://HOST:PORT"`` sends the
tasks to a running cluster (``dask scheduler`` / ``dask worker`` on machines sharing the
run folder, or ``dask-jobqueue``'s SLURM/PBS clusters). Every worker runs XLA with one
intra-op thread (so N workers do not oversubscribe the cores) and keeps the persistent
compilation cache of `fxspace._compile_cache`. Local workers are forked from a process
that has not started JAX (they begin with fxspace imported) and take the runs in
consecutive blocks of the config's order, so each compiles its shapes once.
"""

from __future__ import annotations

import os
import time
import traceback
from contextlib import contextmanager
from pathlib import Path
from typing import Any

__all__ = ["sweep_config", "SweepResult", "WORKER_ENV"]

#: The environment each worker runs with: one XLA/Eigen thread per worker process.
WORKER_ENV = {
    "XLA_FLAGS": "--xla_cpu_multi_thread_eigen=false",
    "OMP_NUM_THREADS": "1",
    "OPENBLAS_NUM_THREADS": "1",
    "MKL_NUM_THREADS": "1",
    "TF_CPP_MIN_LOG_LEVEL": "2",
}


class SweepResult(dict):
    """One run's outcome: ``run_dir``, ``status`` (complete/failed), ``error``, ``metrics``."""


def _task(config: str, out: str, run_dir: str, force: bool) -> dict[str, Any]:
    """Run one run of ``config`` (the one whose folder is ``run_dir``) in this process."""
    import json

    from fxspace.config import load_toml
    from fxspace.pipelines import _plan, _run_one

    try:
        raw = load_toml(config)
        plan = _plan(raw, Path(out), Path(config).resolve().parent)
        (entry,) = [p for p in plan if str(p.run_dir) == run_dir]
        _run_one(entry.pipeline, entry.run_dir, entry.config, entry.seed, entry.text,
                 raw["experiment"], force, wait=None)  # fmt: skip
        metrics = json.loads((entry.run_dir / "metrics.json").read_text())
        return SweepResult(run_dir=run_dir, status="complete", error=None, metrics=metrics)
    except Exception as e:  # noqa: BLE001 - reported per run, the sweep goes on
        tb = traceback.format_exc(limit=3)
        return SweepResult(
            run_dir=run_dir, status="failed", error=f"{type(e).__name__}: {e}", traceback=tb
        )


def _init_worker(env: dict[str, str]) -> None:
    os.environ.update(env)


@contextmanager
def _worker_env(env: dict[str, str]):
    """Set ``env`` in this process while workers start (they inherit it)."""
    old = {k: os.environ.get(k) for k in env}
    os.environ.update(env)
    try:
        yield
    finally:
        for k, v in old.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


def _progress(done: int, running: int, failed: int, total: int, last: dict | None) -> None:
    tail = ""
    if last is not None:
        name = Path(last["run_dir"]).name or last["run_dir"]
        tail = f" — {name}: {last['status']}" + (f" ({last['error']})" if last["error"] else "")
    print(f"[sweep] done {done}/{total}, running {running}, failed {failed}{tail}", flush=True)


def sweep_config(
    path: str | Path,
    out: str | Path | None = None,
    workers: int = 2,
    scheduler: str | None = None,
    fail_fast: bool = False,
    force: bool = False,
    engine: str = "auto",
) -> list[SweepResult]:
    """Run every run of the config at ``path`` as parallel tasks; returns their outcomes
    (in the config's order). A failing run is reported and the others go on (unless
    ``fail_fast``). ``engine``: ``"auto"`` (Dask when installed, else processes),
    ``"dask"``, ``"processes"`` or ``"serial"`` (this process, one after another)."""
    from fxspace.config import ConfigError, load_toml
    from fxspace.pipelines import _clean_tree, _plan, _refuse_overwrite

    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise ConfigError(f"workers must be an integer >= 1, got {workers!r}")
    if engine not in ("auto", "dask", "processes", "serial"):
        raise ConfigError(f"engine must be auto, dask, processes or serial, got {engine!r}")
    path = Path(path)
    raw = load_toml(path)
    out = Path(out) if out is not None else Path("runs") / path.stem
    if "search" in raw:  # configurations drawn by Optuna: `workers` loops share the study
        return _search(path, raw, out, workers, scheduler, fail_fast, force, engine)
    plan = _plan(raw, out, path.resolve().parent)  # every run validated before any starts
    _refuse_overwrite(plan, out, force)
    if force:
        _clean_tree(out, plan)
    args = [(str(path), str(out), str(p.run_dir), force) for p in plan]
    if scheduler is not None:
        engine = "dask"
    elif engine == "auto":
        try:
            import dask.distributed  # noqa: F401

            engine = "dask"
        except ImportError:
            engine = "processes"
    where = f"scheduler {scheduler}" if scheduler else f"{engine}, {workers} workers"
    if engine in ("dask", "processes") and scheduler is None:
        where += f", started by {_start_method()}"
    print(f"[sweep] {len(args)} runs under {out} ({where})", flush=True)
    if engine == "serial":
        results = []
        for i, a in enumerate(args):
            r = _task(*a)
            results.append(r)
            nf = sum(x["status"] == "failed" for x in results)
            _progress(i + 1 - nf, 0, nf, len(args), r)
            if fail_fast and r["status"] == "failed":
                break
        return results
    if engine == "dask":
        return _run_dask(args, workers, scheduler, fail_fast)
    return _run_processes(args, workers, fail_fast)


def _search(path: Path, raw: dict, out: Path, workers: int, scheduler, fail_fast: bool,
            force: bool, engine: str) -> list[SweepResult]:  # fmt: skip
    """A ``[search]``: ``workers`` loops of `search_worker` (asking and telling one
    Optuna study in ``out/search.db``); returns one outcome per trial run."""
    from fxspace.pipelines._search import check_search, search_worker

    s = check_search(raw["search"])
    n = 1 if engine == "serial" else min(workers, s["trials"])
    print(f"[sweep] search ({s['method']}, {s['trials']} trials, {s['direction']} "
          f"{s['metric']}) under {out}, {n} workers", flush=True)  # fmt: skip
    args = [(str(path), str(out), i, force) for i in range(n)]
    if engine == "serial" or n == 1:
        got = [search_worker(*a) for a in args]
    elif scheduler is not None or engine in ("dask", "auto") and _has_dask():
        got = _run_dask(args, n, scheduler, fail_fast, fn=search_worker)
    else:
        got = _run_processes(args, n, fail_fast, fn=search_worker)
    trials = sorted((t for g in got for t in g.get("trials", ())), key=lambda t: t["trial"])
    lost = [g for g in got if g["status"] == "failed" and not g.get("trials")]
    return [SweepResult(t) for t in trials] + [SweepResult(g) for g in lost]


def _has_dask() -> bool:
    try:
        import dask.distributed  # noqa: F401
    except ImportError:
        return False
    return True


def _collect(futures: dict, total: int, fail_fast: bool, as_completed, cancel) -> dict:
    results: dict[str, SweepResult] = {}
    done = failed = 0
    for fut in as_completed(list(futures)):
        try:
            r = fut.result()
        except Exception as e:  # noqa: BLE001 - a worker died: the run is reported
            r = SweepResult(run_dir=futures[fut], status="failed", error=f"{type(e).__name__}: {e}")
        results[r["run_dir"]] = r
        if r["status"] == "failed":
            failed += 1
        else:
            done += 1
        _progress(done, max(min(total - done - failed, len(futures)), 0), failed, total, r)
        if fail_fast and r["status"] == "failed":
            cancel()
            break
    return results


def _run_processes(args: list[tuple], workers: int, fail_fast: bool, fn=_task) -> list[SweepResult]:
    import multiprocessing as mp
    from concurrent.futures import ProcessPoolExecutor, as_completed

    ctx = mp.get_context(_start_method())  # JAX starts in each worker with WORKER_ENV
    with (
        _worker_env(WORKER_ENV),
        ProcessPoolExecutor(
            max_workers=workers, mp_context=ctx, initializer=_init_worker, initargs=(WORKER_ENV,)
        ) as ex,
    ):
        futures = {ex.submit(fn, *a): str(a[2]) for a in args}

        def cancel():
            for f in futures:
                f.cancel()

        got = _collect(futures, len(args), fail_fast, as_completed, cancel)
    return _ordered(got, args, fn)


def _run_dask(
    args: list[tuple], workers: int, scheduler: str | None, fail_fast: bool, fn=_task
) -> list[SweepResult]:
    try:
        from dask.distributed import Client, LocalCluster, as_completed
    except ImportError:
        raise ImportError(
            "fxspace sweep --scheduler needs Dask: pip install 'fxspace[cluster]' "
            "(or drop --scheduler to use local processes)"
        ) from None
    cluster = None
    with _worker_env(WORKER_ENV):
        if scheduler is None:
            import dask

            with dask.config.set({"distributed.worker.multiprocessing-method": _start_method()}):
                cluster = LocalCluster(
                    n_workers=workers, threads_per_worker=1, processes=True,
                    dashboard_address=None, env=dict(WORKER_ENV),
                )  # fmt: skip
            client = Client(cluster)
        else:
            client = Client(scheduler)
    try:
        # pure=False: every run is its own task; retries: a task lost with a killed
        # worker is rerun elsewhere (it resumes from its cached stages)
        where = [None] * len(args)
        if cluster is not None and fn is _task:  # our own workers: a block of runs each
            client.wait_for_workers(workers)
            names = sorted(client.scheduler_info()["workers"])
            where = [[names[b]] for b in _blocks(len(args), len(names))]
        # allow_other_workers: a block is a preference; a lost or idle worker's runs move
        futures = {
            client.submit(fn, *a, key=f"fxspace-run-{i}-{time.time_ns()}", retries=3,
                          workers=w, allow_other_workers=w is not None): str(a[2])
            for i, (a, w) in enumerate(zip(args, where, strict=True))
        }  # fmt: skip

        def cancel():
            client.cancel(list(futures))

        got = _collect(futures, len(args), fail_fast, as_completed, cancel)
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
    return _ordered(got, args, fn)


def _start_method() -> str:
    """How local workers start: ``fork`` while this process has not started a JAX backend
    (a worker then begins with fxspace imported, about 2 s sooner on two cores; its JAX
    starts afresh with `WORKER_ENV`), else ``spawn`` (forking a running XLA runtime is
    unsafe). JAX has no public test for a started backend, so any doubt means spawn."""
    try:
        from jax._src import xla_bridge

        started = xla_bridge.backends_are_initialized()
    except Exception:  # noqa: BLE001 - the private test moved: the safe choice
        return "spawn"
    return "spawn" if started else "fork"


def _blocks(n: int, workers: int) -> list[int]:
    """The worker index of each of ``n`` runs: consecutive blocks of the config's order.
    Neighbouring runs share the slower-varying swept values (often the array shapes), so
    a worker reuses its compiled programs instead of every worker compiling every shape."""
    size = -(-n // workers)
    return [i // size for i in range(n)]


def _ordered(got: dict, args: list[tuple], fn) -> list:
    """The runs' outcomes in the config's order (a search's workers: as they ended)."""
    if fn is not _task:
        return list(got.values())
    return [got[a[2]] for a in args if a[2] in got]
