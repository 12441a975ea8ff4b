"""``fxspace sweep``: the runs of a ``[sweep]`` as tasks on a Dask cluster (or processes).

Each run of the config is one task: a worker resolves the config again, takes the run
folder's lock (`fxspace.runs.run_lock`) and runs it exactly as the serial ``fxspace run``
does, so the results are the same bit for bit and a finished run is skipped. A run folder
locked by another process (another worker, another ``fxspace sweep``, another host) is
reported at once, naming the holder and the lock file, and waited for at most
``lock_wait`` seconds (the serial engine first runs every other run); then it is
reported as failed with the fix, never waited for without a word. The embedded default
is a local Dask distributed cluster (``dask.distributed.LocalCluster`` with one thread
per worker process); where Dask is not installed, a
``concurrent.futures.ProcessPoolExecutor``; ``scheduler="tcp://HOST:PORT"`` sends the
tasks to a running cluster (``dask scheduler`` / ``dask worker`` on machines sharing the
run folder, or ``dask-jobqueue``'s SLURM/PBS clusters). The address is checked first: a
malformed one, a closed port, or a port that does not greet like a Dask scheduler (an
HTTP server) is an error within `SCHEDULER_TIMEOUT_S` seconds. Local workers are capped
at the number of runs and of CPU cores (with a message). Every worker runs XLA with one
intra-op thread (so N workers do not oversubscribe the cores), prefixes its output lines
with its run's name (progress bars left out) and keeps the persistent compilation cache
of `fxspace._compile_cache`. Local workers are forked from a process that has not
started JAX (they begin with fxspace imported) and take the runs in consecutive blocks
of the config's order, so each compiles its shapes once.
"""

from __future__ import annotations

import os
import time
from pathlib import Path

from fxspace._jax_private import backends_started
from fxspace.config import ConfigError, load_toml
from fxspace.pipelines._planner import _clean_tree, _plan, _refuse_overwrite
from fxspace.pipelines._scheduler import SchedulerError, _connect, check_scheduler
from fxspace.pipelines._search import prepare_search, search_outcomes, search_worker
from fxspace.pipelines._search_space import check_search
from fxspace.pipelines._sweep_worker import (
    LOCK_WAIT_S,
    WORKER_ENV,
    SweepResult,
    _init_worker,
    _progress,
    _task,
    _worker_env,
)

__all__ = [
    "sweep_config",
    "SweepResult",
    "WORKER_ENV",
    "SchedulerError",
    "check_scheduler",
    "cap_workers",
    "LOCK_WAIT_S",
    "SCHEDULER_TIMEOUT_S",
]

#: How long (seconds) ``--scheduler`` may take to connect and greet like a Dask scheduler.
SCHEDULER_TIMEOUT_S = 10.0
_ENGINES = ("auto", "dask", "processes", "serial")


# ------------------------------------------------------------------ checks


def _cpu_count() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


def cap_workers(workers: int, jobs: int, what: str = "runs") -> int:
    """The local worker count: ``workers`` capped at ``jobs`` (the runs or trials to do)
    and at the CPU cores this process may use, with a message when capped (each worker is
    a process with its own JAX: more workers than either only costs memory)."""
    cpus = _cpu_count()
    n = max(1, min(workers, jobs, cpus))
    if n < workers:
        why = [f"{jobs} {what}"] if jobs < workers else []
        why += [f"{cpus} CPU cores"] if cpus < workers else []
        print(f"[sweep] --workers {workers} capped at {n} ({' and '.join(why)}): more local "
              "workers would only cost memory", flush=True)  # fmt: skip
    return n


# ------------------------------------------------------------------ the sweep


def sweep_config(
    path: str | Path,
    out: str | Path | None = None,
    workers: int = 2,
    scheduler: str | None = None,
    fail_fast: bool = False,
    force: bool = False,
    engine: str = "auto",
    lock_wait: float | None = LOCK_WAIT_S,
) -> list[SweepResult]:
    """Run every run of the config at ``path`` as parallel tasks; returns their outcomes
    (in the config's order). A failing run is reported and the others go on (unless
    ``fail_fast``). ``engine``: ``"auto"`` (Dask when installed, else processes),
    ``"dask"``, ``"processes"`` or ``"serial"`` (this process, one after another);
    ``scheduler`` (a running Dask scheduler) goes with ``"auto"`` or ``"dask"`` only.
    ``workers`` is capped at the runs and the CPU cores (with a message). A run folder
    another process holds is waited for at most ``lock_wait`` seconds (``None``: until
    it is free), then reported as failed naming the holder."""
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise ConfigError(f"workers must be an integer >= 1, got {workers!r}")
    if engine not in _ENGINES:
        raise ConfigError(f"engine must be auto, dask, processes or serial, got {engine!r}")
    if lock_wait is not None and (
        isinstance(lock_wait, bool) or not isinstance(lock_wait, int | float)
        or not 0 <= lock_wait < float("inf")
    ):  # fmt: skip
        raise ConfigError(f"lock_wait (--lock-wait) must be seconds >= 0, got {lock_wait!r}")
    if scheduler is not None:
        check_scheduler(scheduler)
        if engine in ("serial", "processes"):
            raise ConfigError(
                f"--scheduler sends the runs to a Dask cluster, --engine {engine} runs them "
                f"here: drop --scheduler, or drop --engine {engine} (or give --engine dask)"
            )
    path = Path(path)
    raw = load_toml(path)
    out = Path(out) if out is not None else Path("runs") / path.stem
    if "search" in raw:  # configurations drawn by Optuna: `workers` loops share the study
        return _search(path, raw, out, workers, scheduler, fail_fast, force, engine)
    plan = _plan(raw, out, path.resolve().parent)  # every run validated before any starts
    _refuse_overwrite(plan, out, force)
    if force:
        _clean_tree(out, plan)
    if scheduler is not None:
        engine = "dask"
    elif engine == "auto":
        engine = "dask" if _has_dask() else "processes"
    if engine != "serial" and scheduler is None:
        workers = cap_workers(workers, len(plan))
    named = engine != "serial"
    args = [(str(path), str(out), str(p.run_dir), force, lock_wait, named) for p in plan]
    where = f"scheduler {scheduler}" if scheduler else f"{engine}, {workers} workers"
    if engine in ("dask", "processes") and scheduler is None:
        where += f", started by {_start_method()}"
    print(f"[sweep] {len(args)} runs under {out} ({where})", flush=True)
    if engine == "serial":
        return _run_serial(args, fail_fast)
    if engine == "dask":
        return _run_dask(args, workers, scheduler, fail_fast)
    return _run_processes(args, workers, fail_fast)


def _run_serial(args: list[tuple], fail_fast: bool) -> list[SweepResult]:
    """One run after another in this process; a run another process holds is put off to
    the end (the other runs go first), then waited for (bounded)."""
    got: dict[str, SweepResult] = {}
    later = []
    done = failed = 0
    for pass_ in (0, 1):
        for a in args if pass_ == 0 else later:
            r = _task(*a, defer=pass_ == 0)
            if r["status"] == "locked":
                later.append(a)
                continue
            got[a[2]] = r
            failed += r["status"] == "failed"
            done += r["status"] != "failed"
            _progress(done, 0, failed, len(args), r)
            if fail_fast and r["status"] == "failed":
                return [got[a[2]] for a in args if a[2] in got]
    return [got[a[2]] for a in args if a[2] in got]


def _search(path: Path, raw: dict, out: Path, workers: int, scheduler, fail_fast: bool,
            force: bool, engine: str) -> list[SweepResult]:  # fmt: skip
    """A ``[search]``: its study prepared once here (`prepare_search`: created, stale
    trials failed, failed ones queued again), then ``workers`` loops of `search_worker`
    (asking and telling one Optuna study in ``out/search.db``); returns one outcome per
    trial of the study (`search_outcomes`)."""
    s = check_search(raw["search"])
    todo = prepare_search(path, out, s, force)
    if engine == "serial" or todo <= 1:
        n = 1
    elif scheduler is not None:
        n = min(workers, todo)
    else:
        n = cap_workers(workers, todo, "trials to run")
    print(f"[sweep] search ({s['method']}, {s['trials']} trials, {s['direction']} "
          f"{s['metric']}) under {out}: {todo} to run, {n} worker{'s' * (n > 1)}",
          flush=True)  # fmt: skip
    got: list[dict] = []
    if todo:
        named = n > 1
        args = [(str(path), str(out), i, False, named) for i in range(n)]
        if n == 1 and scheduler is None:
            got = [search_worker(*a) for a in args]
        elif scheduler is not None or engine in ("dask", "auto") and _has_dask():
            got = _run_dask(args, n, scheduler, fail_fast, fn=search_worker)
        else:
            got = _run_processes(args, n, fail_fast, fn=search_worker)
    return [SweepResult(r) for r in search_outcomes(path, out, s, got)]


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
        futures = {ex.submit(fn, *a): _key(a, fn) for a in args}

        def cancel():
            for f in futures:
                f.cancel()

        got = _collect(futures, len(args), fail_fast, as_completed, cancel)
    return _ordered(got, args, fn)


def _key(a: tuple, fn) -> str:
    """The ``run_dir`` a task's outcome carries (a search worker: ``OUT#workerN``)."""
    return str(a[2]) if fn is _task else f"{a[1]}#worker{a[2]}"


def _run_dask(
    args: list[tuple], workers: int, scheduler: str | None, fail_fast: bool, fn=_task
) -> list[SweepResult]:
    try:
        from dask.distributed import LocalCluster, as_completed
    except ImportError:
        raise ImportError(
            "fxspace sweep --scheduler needs Dask: pip install 'fxspace[cluster]' "
            "(or drop --scheduler to use local processes)"
        ) from None
    cluster = None
    if scheduler is None:
        from dask.distributed import Client

        with _worker_env(WORKER_ENV):
            import dask

            with dask.config.set({"distributed.worker.multiprocessing-method": _start_method()}):
                cluster = LocalCluster(
                    n_workers=workers, threads_per_worker=1, processes=True,
                    dashboard_address=None, env=dict(WORKER_ENV),
                )  # fmt: skip
            client = Client(cluster)
    else:
        client = _connect(scheduler, SCHEDULER_TIMEOUT_S)
        if not client.scheduler_info().get("workers"):
            print(f"[sweep] the scheduler at {scheduler} has no workers yet: the runs wait for "
                  f"one (start `dask worker {scheduler} --nthreads 1`)", flush=True)  # fmt: skip
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
                          workers=w, allow_other_workers=w is not None): _key(a, fn)
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
    unsafe). JAX has no public test for a started backend (`fxspace._jax_private`), so
    any doubt means spawn."""
    return "fork" if backends_started() is False else "spawn"


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
