"""The sweep's worker side: one run of a config in this process (`_task`), under its
folder's lock (waited for, bounded, with the holder named), each output line prefixed with
the run's name; the environment each worker runs with (`WORKER_ENV`)."""

from __future__ import annotations

import json
import os
import traceback
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from fxspace.config import load_toml
from fxspace.pipelines._output import named_output
from fxspace.pipelines._planner import _plan
from fxspace.pipelines._runner import _run_one
from fxspace.runs import RunLockedError

#: The environment each worker runs with: one XLA/Eigen thread per worker process.
WORKER_ENV = {
    "XLA_FLAGS": "--xla_cpu_multi_thread_eigen=false",
    "OMP_NUM_THREADS": "1",
    "OPENBLAS_NUM_THREADS": "1",
    "MKL_NUM_THREADS": "1",
    "TF_CPP_MIN_LOG_LEVEL": "2",
}
#: How long (seconds) a sweep waits for a run folder another process holds, by default.
LOCK_WAIT_S = 600.0


class SweepResult(dict):
    """One run's outcome: ``run_dir``, ``status`` (complete/failed), ``error``, ``metrics``."""



def _run_waiting(entry: Any, experiment: str, force: bool, lock_wait: float | None,
                 defer: bool) -> str:  # fmt: skip
    """Run ``entry`` under its folder's lock; a lock another process holds is reported
    (who holds it: `fxspace.runs.run_lock` says) and waited for at most ``lock_wait`` s
    (``None``: until it is free), then a `RunLockedError` with the fix. Returns
    ``"ran"``, or ``"locked"`` when ``defer`` and it is held now."""
    args = (entry.pipeline, entry.run_dir, entry.config, entry.seed, entry.text, experiment,
            force)  # fmt: skip
    try:
        _run_one(*args, wait=0.0)
        return "ran"
    except RunLockedError as e:
        if defer:
            print(f"[sweep] {entry.run_dir}: {e}; coming back to it after the other runs",
                  flush=True)  # fmt: skip
            return "locked"
        if lock_wait is not None and lock_wait <= 0:
            raise RunLockedError(f"skipped: {e}") from None
    limit = "until it is free" if lock_wait is None else f"up to {lock_wait:g} s (--lock-wait)"
    print(f"[sweep] {entry.run_dir} is held by another process; waiting {limit}", flush=True)
    try:
        _run_one(*args, wait=lock_wait)
    except RunLockedError as e:
        raise RunLockedError(
            f"still locked after {lock_wait:g} s, skipped: {e} (rerun later, or give "
            "--lock-wait SECONDS)"
        ) from None
    return "ran"


def _task(config: str, out: str, run_dir: str, force: bool, lock_wait: float | None = LOCK_WAIT_S,
          named: bool = False, defer: bool = False) -> dict[str, Any]:  # fmt: skip
    """Run one run of ``config`` (the one whose folder is ``run_dir``) in this process."""
    name = Path(run_dir).name or run_dir
    try:
        raw = load_toml(config)
        plan = _plan(raw, Path(out), Path(config).resolve().parent)
        (entry,) = [p for p in plan if str(p.run_dir) == run_dir]
        with named_output(name if named else None):
            how = _run_waiting(entry, raw["experiment"], force, lock_wait, defer)
        if how == "locked":
            return SweepResult(run_dir=run_dir, status="locked", error=None)
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
        name = last.get("name") or Path(last["run_dir"]).name or last["run_dir"]
        tail = f" — {name}: {last['status']}" + (f" ({last['error']})" if last["error"] else "")
    print(f"[sweep] done {done}/{total}, running {running}, failed {failed}{tail}", flush=True)
