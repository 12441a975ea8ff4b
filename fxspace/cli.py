"""The ``fxspace`` command: ``demo``, ``run CONFIG``, ``sweep``, ``docs``, ``studio``
(alias ``view``), ``bench``, ``data``."""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

# no imports of its own (it reads JAX's state lazily): importing it never starts JAX
from fxspace._jax_private import backends_started

__all__ = ["main", "studio_target"]

_DEMO = {
    "experiment": "threshold_sweep",
    "seed": 0,
    "data": {"source": "synthetic"},
}


def _cmd_demo(args: argparse.Namespace) -> int:
    from fxspace.pipelines import run_dict

    raw = dict(_DEMO)
    raw["seed"] = args.seed
    out = args.out
    if args.real:
        raw["data"] = {"source": "animface"}
        out = out or "runs/demo_real"  # never the synthetic demo's folder
    # a finished demo of the same seed is reused; another finished run is never
    # overwritten without --force (and then only the files fxspace wrote are replaced)
    dirs = run_dict(raw, out or "runs/demo", force=args.force)
    for d in dirs:
        print(
            f"demo results in {d}: metrics.json, "
            + ", ".join(p.name for p in sorted(d.glob("*.png")))
        )
    return 0


def _cmd_run(args: argparse.Namespace) -> int:
    from fxspace.pipelines import run_config

    run_config(args.config, args.out, force=args.force)
    return 0


def _cmd_sweep(args: argparse.Namespace) -> int:
    from fxspace.pipelines import sweep_config

    res = sweep_config(
        args.config, args.out, workers=args.workers, scheduler=args.scheduler,
        fail_fast=args.fail_fast, force=args.force, engine=args.engine,
        lock_wait=args.lock_wait,
    )  # fmt: skip
    failed = [r for r in res if r["status"] != "complete"]
    for r in failed:
        print(f"fxspace sweep: {r['status'].upper()} {r['run_dir']}: {r['error']}",
              file=sys.stderr)  # fmt: skip
    print(f"fxspace sweep: {len(res) - len(failed)} complete, {len(failed)} failed")
    return 1 if failed else 0


def _cmd_docs(args: argparse.Namespace) -> int:
    from fxspace.pipelines import write_architecture, write_bench_page, write_docs

    if args.architecture:
        print(f"fxspace docs: wrote {write_architecture(Path(args.architecture))}")
    for p in write_docs(args.runs, args.out, run=args.run, force=args.force):
        print(f"fxspace docs: wrote {p}")
    if (Path(args.runs) / "bench").is_dir():
        page = write_bench_page(args.runs, args.bench_out, force=args.force)
        print(f"fxspace docs: wrote {page}")
    return 0


def _cmd_report(args: argparse.Namespace) -> int:
    from fxspace.report import write_report
    from fxspace.runs import manifest_files

    rows, folder = write_report(args.dir, out=args.out, force=args.force, show_all=args.all)
    figs = len([f for f in manifest_files(folder) if "_vs_" in f and f.endswith(".png")])
    print(f"fxspace report: {len(rows)} runs; every column in {folder / 'runs.csv'} and "
          f"runs.md, {figs} figure{'s' * (figs != 1)} in {folder}")
    return 0


def studio_target(target: str | Path, out: str | Path | None = None) -> Path:
    """What ``fxspace studio`` opens: a run folder, a ``.glb`` mesh, or a config whose app
    builds only what it shows (`fxspace.studio.OPENS_CONFIG`: the IK studio reads one mesh
    and its markers) as they are; for another config file, the stages its app shows are
    computed (`fxspace.pipelines.prepare_config`: the experiment's ``prepare_app``, else
    the whole run; finished stages and a finished run with the same content key are
    reused, so a second launch opens in seconds) and its run folder returned (the first
    run of a ``[sweep]``)."""
    from fxspace.studio import opens_directly

    p = Path(target)
    if opens_directly(p):  # a run folder, a mesh, or an app that builds what it shows
        return p
    from fxspace.pipelines import prepare_config

    print(f"fxspace studio: preparing {target} (cached stages are reused) …", flush=True)
    return prepare_config(p, out)


def _cmd_view(args: argparse.Namespace) -> int:
    """``fxspace studio TARGET`` (alias ``view``): the app of the target's experiment; a
    config is run first where its results are not cached."""
    from fxspace.studio import opens_directly, serve, serve_config

    try:
        env_map = bool(getattr(args, "environment_map", False))
        if opens_directly(args.target):  # a run folder, a mesh, an app reading its config
            serve(args.target, port=args.port, environment_map=env_map)
        else:  # a page with the progress at once, then the app on the same port
            print(f"fxspace studio: preparing {args.target} (cached stages are reused) …")
            serve_config(args.target, port=args.port, out=getattr(args, "out", None),
                         environment_map=env_map)  # fmt: skip
    except ImportError as e:
        print(
            f"fxspace studio needs the optional viewer extra: pip install -e '.[viewer]' ({e})",
            file=sys.stderr,
        )
        return 2
    return 0


def _cmd_bench(args: argparse.Namespace) -> int:
    import runpy

    root = Path(__file__).resolve().parent.parent / "experiments"
    names = sorted(p.stem.removeprefix("bench_") for p in root.glob("bench_*.py"))
    if args.name is None:
        print("benchmarks (fxspace bench NAME [options]):")
        for n in names:
            doc = (root / f"bench_{n}.py").read_text().split('"""')
            first = doc[1].strip().splitlines()[0] if len(doc) > 2 else ""
            print(f"  {n:12s} {first}")
        return 0
    script = root / f"bench_{args.name}.py"
    if not script.is_file():
        print(f"no benchmark {args.name!r}; available: {names}", file=sys.stderr)
        return 2
    from fxspace.runs import check_writable, is_bench_record

    bench = Path(os.environ.get("FXSPACE_RUNS", "runs")) / "bench"
    # refused before minutes of measuring, not after: a NAME.json fxspace did not write
    check_writable(bench, [bench / f"{args.name}.json"], recognise=is_bench_record)
    sys.argv = [str(script), *args.rest]
    runpy.run_path(str(script), run_name="__main__")
    return 0


def _cmd_data(args: argparse.Namespace) -> int:
    from fxspace.data import ENV_VAR, data_root

    root = data_root()
    if root is None:
        print(f"no data root: set {ENV_VAR} (defaults to ../shared/data when present)")
        return 1
    print(root)
    return 0


def _version() -> str:
    from importlib import metadata

    try:
        return metadata.version("fxspace")
    except metadata.PackageNotFoundError:  # pragma: no cover - a bare checkout
        return "0.0.0"


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="fxspace",
        description="fxspace: motion-capture-driven facial and character animation in JAX.",
        epilog="Real data is read from $FXSPACE_DATA (default ../shared/data when present).",
    )
    p.add_argument("--version", action="version", version=f"fxspace {_version()}")
    sub = p.add_subparsers(dest="command", required=True)

    d = sub.add_parser(
        "demo", help="expression space of the embedded synthetic face (no data needed)"
    )
    d.add_argument(
        "--out", default=None, help="run folder (default runs/demo, runs/demo_real with --real)"
    )
    d.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    d.add_argument("--real", action="store_true", help="use the AnimFace capture instead")
    d.add_argument(
        "--force",
        action="store_true",
        help="rerun, replacing a finished run in --out (only the files fxspace wrote)",
    )
    d.set_defaults(func=_cmd_demo)

    r = sub.add_parser("run", help="run the experiment a TOML config describes (serially)")
    r.add_argument("config", help="path to a TOML config (see configs/)")
    r.add_argument("--out", default=None, help="output folder (default runs/<config stem>)")
    r.add_argument("--force", action="store_true", help="rerun runs that are already complete")
    r.set_defaults(func=_cmd_run)

    w = sub.add_parser(
        "sweep", help="run a config's [sweep] in parallel (local Dask cluster or processes)"
    )
    w.add_argument("config", help="path to a TOML config with a [sweep] table")
    w.add_argument("--out", default=None, help="output folder (default runs/<config stem>)")
    w.add_argument("--workers", type=int, default=2, help="local worker processes (default 2)")
    w.add_argument("--scheduler", default=None, help="a running Dask scheduler (tcp://HOST:PORT)")
    w.add_argument("--fail-fast", action="store_true", help="stop at the first failed run")
    w.add_argument("--force", action="store_true", help="rerun runs that are already complete")
    w.add_argument(
        "--engine", default="auto", choices=("auto", "dask", "processes", "serial"),
        help="auto: Dask when installed, else processes",
    )  # fmt: skip
    w.add_argument(
        "--lock-wait", type=float, default=600.0, metavar="SECONDS",
        help="how long to wait for a run folder another process holds, then report it "
        "(default 600)",
    )  # fmt: skip
    w.set_defaults(func=_cmd_sweep)

    dc = sub.add_parser("docs", help="write the reproduction pages from the shipped configs' runs")
    dc.add_argument("--runs", default="runs", help="where the configs' run folders are")
    dc.add_argument("--out", default="docs/reproductions", help="where the pages go")
    dc.add_argument("--bench-out", default="docs/benchmarks",
                    help="where the benchmark page goes (from RUNS/bench/*.json)")  # fmt: skip
    dc.add_argument("--architecture", default="docs/concepts/architecture.md",
                    help="the architecture page (its generated blocks); '' leaves it")
    dc.add_argument("--run", action="store_true", help="run the missing configs first")
    dc.add_argument("--force", action="store_true",
                    help="replace files in --out that fxspace did not write, and pages whose "
                         "runs are missing")  # fmt: skip
    dc.set_defaults(func=_cmd_docs)

    rp = sub.add_parser("report", help="compare the runs under a folder (table + figures)")
    rp.add_argument("dir", help="a folder of runs (e.g. a sweep's --out)")
    rp.add_argument("--out", default=None, help="the report folder (default DIR/report)")
    rp.add_argument(
        "--force", action="store_true",
        help="replace files in the report folder that fxspace did not write",
    )  # fmt: skip
    rp.add_argument(
        "--all", action="store_true",
        help="print every column (default: the swept keys and the metrics that differ)",
    )  # fmt: skip
    rp.set_defaults(func=_cmd_report)

    for name in ("studio", "view"):
        v = sub.add_parser(
            name,
            help="the paper's app for a run in the browser: navigator, editor, …"
            + (" (alias of studio)" if name == "view" else " (needs .[viewer])"),
        )
        v.add_argument("target", help="a run folder, or a config file (run first where not cached)")
        v.add_argument("--port", type=int, default=8080)
        v.add_argument("--out", default=None, help="run folder for a config (default runs/<stem>)")
        v.add_argument(
            "--environment-map",
            action="store_true",
            help="viser's image-based lighting (slow to first frame without a GPU)",
        )
        v.set_defaults(func=_cmd_view)

    b = sub.add_parser("bench", help="run experiments/bench_NAME.py (alone: list them)")
    b.add_argument("name", nargs="?", default=None)
    b.add_argument("rest", nargs=argparse.REMAINDER)
    b.set_defaults(func=_cmd_bench)

    s = sub.add_parser("data", help="print the data root in use")
    s.set_defaults(func=_cmd_data)
    return p


def use_all_cpu_cores() -> None:
    """Expose every CPU core as a JAX device (before JAX starts), so sharded kernels
    (Floyd rows, threshold sweeps) use all cores; a no-op once JAX has initialised or
    when the user set the flag."""
    flags = os.environ.get("XLA_FLAGS", "")
    if "xla_force_host_platform_device_count" in flags:
        return
    if backends_started():
        return  # too late: JAX has already started its backends
    n = os.cpu_count() or 1
    if n > 1:
        os.environ["XLA_FLAGS"] = f"{flags} --xla_force_host_platform_device_count={n}".strip()


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    os.environ.setdefault("TF_CPP_MIN_LOG_LEVEL", "2")
    if os.environ.get("FXSPACE_CPU_DEVICES") == "1":  # opt-in, for method="sharded"/shard=True
        use_all_cpu_cores()
    from fxspace.errors import FxspaceError

    try:
        return int(args.func(args) or 0)
    except FxspaceError as e:
        print(f"fxspace: error: {' '.join(str(e).split())}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("fxspace: interrupted; rerun to resume", file=sys.stderr)
        return 130
    except OSError as e:  # unwritable --out, a full disk, a file that vanished, ...
        where = e.filename or ""
        print(f"fxspace: error: {where}{': ' if where else ''}{e.strerror or e}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    raise SystemExit(main())
