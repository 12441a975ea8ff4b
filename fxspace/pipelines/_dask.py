"""One Dask client for a run's per-block stages: a local cluster of worker processes
(``"local"``) or a running scheduler (``tcp://HOST:PORT``), started and closed around a
stage. The sweep (`fxspace.pipelines._sweep`) starts its own the same way: the address
check, the worker environment and the start method are its."""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from typing import Any

from fxspace.config import ConfigError
from fxspace.pipelines._scheduler import _connect, check_scheduler
from fxspace.pipelines._sweep import SCHEDULER_TIMEOUT_S, _start_method
from fxspace.pipelines._sweep_worker import WORKER_ENV, _worker_env

__all__ = ["check_stage_scheduler", "dask_client"]


def check_stage_scheduler(scheduler: str, workers: int, name: str = "graph") -> None:
    """A config's ``scheduler`` ("" here, "local", or an address) and ``workers``, or a
    `ConfigError` naming the key and the fix."""
    if scheduler not in ("", "local"):
        try:
            check_scheduler(scheduler)
        except Exception as e:  # noqa: BLE001 - re-said as the config key
            raise ConfigError(f"{name}.scheduler: {e}") from None
    if scheduler == "local" and not 1 <= int(workers) <= 256:
        raise ConfigError(f"{name}.workers must be in [1, 256], got {workers}")


@contextlib.contextmanager
def dask_client(scheduler: str, workers: int = 2) -> Iterator[Any]:
    """``None`` for ``scheduler == ""`` (run here), else a ``dask.distributed.Client`` of
    a local cluster of ``workers`` processes (``"local"``) or of the scheduler at the
    address; closed on exit."""
    if not scheduler:
        yield None
        return
    try:
        from dask.distributed import Client, LocalCluster
    except ImportError:
        raise ConfigError(
            "graph.scheduler needs Dask: pip install 'fxspace[cluster]' (or leave "
            "graph.scheduler unset to run here)"
        ) from None
    if scheduler != "local":
        client = _connect(scheduler, SCHEDULER_TIMEOUT_S)
        try:
            yield client
        finally:
            client.close()
        return
    import dask

    with _worker_env(WORKER_ENV), dask.config.set(
        {"distributed.worker.multiprocessing-method": _start_method()}
    ):  # fmt: skip
        cluster = LocalCluster(
            n_workers=int(workers), threads_per_worker=1, processes=True,
            dashboard_address=None, host="127.0.0.1", env=dict(WORKER_ENV),
        )  # fmt: skip
    try:
        with Client(cluster) as client:
            client.wait_for_workers(int(workers))
            yield client
    finally:
        cluster.close()
