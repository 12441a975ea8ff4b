"""Shortest-path rows of a large graph on every core of this machine.

scipy's Dijkstra holds the GIL for the whole search, so two rows at once need two
processes (checked: two threads take as long as one). Where a graph has at least
`MIN_FRAMES` frames, its many-source searches — the landmark rows, the shortest-path
trees into the centres that the links walk — are split between worker processes, each
holding the graph's CSR (sent once, kept while the graph lives). Every row is the same
scipy call on the same CSR as in this process, so the answers are the same, bit for bit.

The workers run this file alone (``python -c`` loading it by path: numpy and scipy, not
the package, not the user's script — unlike ``multiprocessing``'s spawn, which runs the
``__main__`` script again in each worker unless it is guarded). They exit when this
process closes their input (it exits, is killed, or the graph is collected).

``FXSPACE_PROCESSES``: how many processes share the rows, this one included (default:
the cores this process may use, at most 8); ``0`` or ``1`` keeps every row here. This
file imports nothing of ``fxspace`` at the top: it is also the workers' whole program.
"""

from __future__ import annotations

import atexit
import os
import pickle
import subprocess
import sys
import threading
import weakref

import numpy as np

__all__: list[str] = []

MIN_FRAMES = 50_000  # graphs below this run their rows here (a row costs under ~15 ms)
_MAX_WORKERS = 8
_BOOT = (
    "import sys, importlib.util as u; s = u.spec_from_file_location('_fxspace_rows', "
    "sys.argv[1]); m = u.module_from_spec(s); s.loader.exec_module(m); m._serve()"
)


def processes() -> int:
    """Processes sharing the rows, this one included (``FXSPACE_PROCESSES``, default the
    usable cores, at most 8); below 2, the rows run in this process alone."""
    raw = os.environ.get("FXSPACE_PROCESSES", "").strip()
    if raw:
        try:
            n = int(raw)
        except ValueError:
            from fxspace.errors import FxspaceError

            raise FxspaceError(
                f"FXSPACE_PROCESSES must be a whole number of worker processes (0 or 1: "
                f"none), got {raw!r}"
            ) from None
        return max(n, 0)
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        cores = os.cpu_count() or 1
    return min(cores, _MAX_WORKERS)


class RowWorkers:
    """``n`` worker processes holding one CSR; `rows` splits sources between them and
    this process."""

    def __init__(self, csr, directed: bool, n: int):
        self._csr, self._directed = csr, bool(directed)
        self.pid = os.getpid()  # a forked child does not share these pipes
        self._lock = threading.Lock()
        self._procs: list[subprocess.Popen] = []
        try:
            for _ in range(int(n)):
                self._procs.append(subprocess.Popen(
                    [sys.executable, "-c", _BOOT, os.path.abspath(__file__)],
                    stdin=subprocess.PIPE, stdout=subprocess.PIPE, start_new_session=True,
                ))  # fmt: skip
            msg = ("graph", csr.data, csr.indices, csr.indptr, bool(directed))
            for p in self._procs:
                self._send(p, msg)
            for p in self._procs:
                self._recv(p)
        except BaseException:
            self.close()
            raise
        self._finalizer = weakref.finalize(self, _stop, list(self._procs), self.pid)

    @property
    def size(self) -> int:
        return len(self._procs)

    def rows(self, sources, predecessors: bool = False, limit: float = np.inf):
        """``dist`` ``(k, T)`` float64 (and ``pred`` ``(k, T)`` int32 with
        ``predecessors``): scipy's ``dijkstra(csr, directed, indices=sources, …)``, the
        sources split in order between this process (the first part) and the workers."""
        from scipy.sparse.csgraph import dijkstra

        src = np.asarray(sources, np.int64).reshape(-1)
        parts = np.array_split(src, min(self.size + 1, max(len(src), 1)))
        with self._lock:
            used = self._procs[: len(parts) - 1]
            try:
                for p, part in zip(used, parts[1:], strict=True):
                    self._send(p, ("rows", part, bool(predecessors), float(limit)))
                here = _rows(self._csr, self._directed, parts[0], predecessors, limit, dijkstra)
                got = [here] + [self._recv(p) for p in used]
            except BaseException:  # interrupted mid-request: replies would be out of step
                self.close()
                raise
        if predecessors:
            return np.concatenate([d for d, _ in got]), np.concatenate([q for _, q in got])
        return np.concatenate(got)

    def close(self) -> None:
        _stop(self._procs, self.pid)
        self._procs = []

    def _send(self, p, msg) -> None:
        try:
            pickle.dump(msg, p.stdin, protocol=5)
            p.stdin.flush()
        except (BrokenPipeError, OSError) as e:
            raise self._died(p) from e

    def _recv(self, p):
        try:
            status, value = pickle.load(p.stdout)
        except (EOFError, OSError, pickle.UnpicklingError) as e:
            raise self._died(p) from e
        if status != "ok":
            from fxspace.errors import FxspaceError

            raise FxspaceError(f"a shortest-path worker failed:\n{value}")
        return value

    def _died(self, p):
        from fxspace.errors import FxspaceError

        code = p.poll()
        self.close()
        return FxspaceError(
            f"a shortest-path worker process stopped (exit code {code}; its error, if any, "
            "is on stderr above); set FXSPACE_PROCESSES=1 to run the rows in this process"
        )


def _stop(procs, pid: int) -> None:
    if os.getpid() != pid:  # a forked child: the workers are its parent's
        return
    for p in procs:
        try:
            p.stdin.close()  # the worker reads EOF and exits
        except OSError:
            pass
    for p in procs:
        try:
            p.wait(timeout=5)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()
        try:
            p.stdout.close()
        except OSError:
            pass


# one set of workers at a time, for the graph whose rows were asked last
_CURRENT: dict = {}
_CURRENT_LOCK = threading.Lock()


def for_graph(graph, csr_of) -> RowWorkers | None:
    """The workers holding ``graph``'s CSR (``csr_of(graph)`` -> ``(csr, directed)``),
    started on first use; None where the graph is small or one process is asked for.
    Kept while the graph's arrays live; a new graph's workers replace them."""
    n = processes()
    if n < 2 or graph.num_frames < MIN_FRAMES:
        return None
    key = (id(graph.indices), id(graph.weights))
    with _CURRENT_LOCK:
        hit = _CURRENT.get("entry")
        if hit is not None and hit[3].pid != os.getpid():  # inherited by a fork: not ours
            _CURRENT.clear()
            hit = None
        if hit is not None and hit[0] == key and hit[1]() is graph.indices \
                and hit[2]() is graph.weights and hit[3].size == n - 1:  # fmt: skip
            return hit[3]
        _drop()
        csr, directed = csr_of(graph)
        try:
            refs = tuple(weakref.ref(a, lambda _: _forget(key))
                         for a in (graph.indices, graph.weights))  # fmt: skip
        except TypeError:  # arrays without weak references: no workers kept
            return None
        workers = RowWorkers(csr, directed, n - 1)  # and this process
        _CURRENT["entry"] = (key, *refs, workers)
        return workers


def _forget(key) -> None:
    with _CURRENT_LOCK:
        hit = _CURRENT.get("entry")
        if hit is not None and hit[0] == key:
            _drop()


def _drop() -> None:
    hit = _CURRENT.pop("entry", None)
    if hit is not None and hit[3].pid == os.getpid():
        hit[3].close()


atexit.register(lambda: _drop())


def _rows(csr, directed, src, preds, limit, dijkstra):
    """One part of a request: scipy's Dijkstra from the sources ``src``."""
    if not len(src):
        n = csr.shape[0]
        return (np.zeros((0, n)), np.zeros((0, n), np.int32)) if preds else np.zeros((0, n))
    got = dijkstra(csr, directed=directed, indices=src, return_predecessors=preds, limit=limit)
    return (got[0], got[1].astype(np.int32)) if preds else got


def _serve() -> None:  # pragma: no cover - runs in the worker processes
    """The worker: read requests from stdin, answer on stdout (pickle), until EOF."""
    from scipy.sparse import csr_matrix
    from scipy.sparse.csgraph import dijkstra

    inp = sys.stdin.buffer
    out = os.fdopen(os.dup(1), "wb")
    os.dup2(2, 1)  # anything printed goes to stderr, never into the replies
    csr, directed = None, True
    while True:
        try:
            msg = pickle.load(inp)
        except EOFError:
            return
        try:
            if msg[0] == "graph":
                data, indices, indptr, directed = msg[1:]
                n = len(indptr) - 1
                csr = csr_matrix((data, indices, indptr), shape=(n, n))
                reply = ("ok", None)
            else:
                reply = ("ok", _rows(csr, directed, *msg[1:], dijkstra))
        except Exception:  # the parent raises it with the traceback
            import traceback

            reply = ("error", traceback.format_exc())
        pickle.dump(reply, out, protocol=5)
        out.flush()
