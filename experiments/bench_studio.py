"""Studio benchmark (issue 24): time from ``fxspace studio CONFIG`` to the first rendered frame.

For every app config (``configs/navigation.toml``, ``reconstruction.toml``,
``parametric_synthesis.toml``, ``mesh_ik.toml``, ``navigation_scale.toml`` — 100 000 frames —
by default) it launches the real command,
``python -m fxspace.cli studio CONFIG --port P --out RUN``, in a new process, opens the page in
headless Chromium (playwright) and waits until the 3-D canvas shows the app's scene: a
canvas screenshot that differs from the one of an empty viser scene. Timed from the launch:

- ``server``: the page answers (the config checked or run, the app built);
- ``frame``: the first rendered frame of the app's scene (an app may open its page with
  the scene and a progress line before its controller is built, as the motion app does);
- ``ready``: the app fully built (its controls and content in place: it prints
  "Ctrl-C to stop") and a frame rendered after that.

Each app is opened twice: **cold** (an empty JAX compilation cache: every kernel compiled, as
on a first install) and **cached** (the same cache again: what every later launch costs).
A config whose run folder is not complete, or not current (other code), is run first (its
time, shown as ``prepare``, is not part of the cold figure), and so are the configs it
reads (``--needs``: the threshold sweep the navigation takes its ε from). Apps are
independent processes, so the figures are the user's; the machine may be shared (times
are noisy). Usage:
``python experiments/bench_studio.py [CONFIG | RUN_DIR ...] [--runs runs] [--timeout 600]
[--json out] [--clean]`` (a finished run folder is opened as it is: ``fxspace studio RUN_DIR``).
With ``--clean`` nothing is prepared: every app starts from an empty run folder and an
empty compilation cache, as from a clean checkout; ``fxspace studio CONFIG`` answers at
once with a page showing the progress of the stages the app needs, then opens the app on
the same port: ``frame`` is that page's first frame, ``ready`` the app built and drawn.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
import urllib.request
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
def _apps() -> list[str]:
    """The experiments with an app (the pipelines' ``APP``), each with a shipped config."""
    from fxspace.studio import APPS

    return [n for n in sorted(APPS) if (ROOT / "configs" / f"{n}.toml").is_file()]


CHROMIUM_ARGS = ["--no-sandbox", "--disable-gpu", "--no-first-run", "--disable-sync"]
VIEWPORT = {"width": 960, "height": 640}


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _chromium() -> str:
    exe = os.environ.get("FXSPACE_CHROMIUM") or shutil.which("chromium") or "/usr/bin/chromium"
    if not Path(exe).exists():
        raise SystemExit("Chromium not found: apt-get install chromium, or set FXSPACE_CHROMIUM")
    return exe


def _pixels(png: bytes) -> np.ndarray:
    from PIL import Image

    return np.asarray(Image.open(io.BytesIO(png)).convert("RGB"), np.int16)


def _differs(a: np.ndarray, b: np.ndarray | None, frac: float = 0.002) -> bool:
    """More than `frac` of the pixels changed by more than 12 levels (any channel)."""
    if b is None or a.shape != b.shape:
        return True
    return float(np.mean(np.abs(a - b).max(axis=-1) > 12)) > frac


def _canvas_png(page) -> bytes | None:
    """The canvas as the page shows it now. Chrome's own capture (DevTools protocol,
    ``optimizeForSpeed``) takes ≈ 0.3 s of a software-rendered page that is playing;
    playwright's element screenshot waits for a stable page and took 2–4 s there, which
    delayed the frame the benchmark saw, not the one the user saw."""
    import base64

    canvas = page.locator("canvas").first
    try:
        canvas.wait_for(timeout=1000)
        box = canvas.bounding_box(timeout=2000)
        if box is None or box["width"] < 1 or box["height"] < 1:
            return None
        cdp = getattr(page, "_fxspace_cdp", None)
        if cdp is None:
            cdp = page._fxspace_cdp = page.context.new_cdp_session(page)
        clip = {k: box[k] for k in ("x", "y", "width", "height")}
        shot = cdp.send(
            "Page.captureScreenshot",
            {"format": "png", "optimizeForSpeed": True, "clip": {**clip, "scale": 1}},
        )
        return base64.b64decode(shot["data"])
    except Exception:  # not attached yet, or mid-reload
        try:
            return canvas.screenshot(timeout=5000)
        except Exception:
            return None


def _wait_http(port: int, proc: subprocess.Popen, deadline: float) -> None:
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise RuntimeError(f"fxspace studio exited with code {proc.returncode}")
        try:
            urllib.request.urlopen(f"http://127.0.0.1:{port}", timeout=1).read(16)
            return
        except OSError:
            time.sleep(0.1)
    raise TimeoutError("the studio server did not answer in time")


def empty_scene(pw, exe: str) -> np.ndarray:
    """A canvas screenshot of an empty viser scene, lit as the apps' (`new_server`): what
    'nothing rendered yet' looks like."""
    from fxspace.studio._server import new_server

    server = new_server(0)
    try:
        browser = pw.chromium.launch(executable_path=exe, args=CHROMIUM_ARGS)
        try:
            page = browser.new_page(viewport=VIEWPORT)
            page.goto(f"http://127.0.0.1:{server.get_port()}")
            png = None
            for _ in range(120):
                png = _canvas_png(page)
                if png is not None:
                    break
                time.sleep(0.25)
            page.wait_for_timeout(1500)  # let the empty scene settle
            png = _canvas_png(page) or png
            if png is None:
                raise RuntimeError("viser's canvas never appeared")
            return _pixels(png)
        finally:
            browser.close()
    finally:
        server.stop()


def browser_floor(pw, exe: str, base: np.ndarray) -> float:
    """Seconds from the browser's launch to the first frame of a bare viser scene holding one
    box: what any app costs on this machine beyond its own work (headless Chromium renders
    in software)."""
    from fxspace.studio._server import new_server

    server = new_server(0)
    server.scene.add_box("/box", dimensions=(1.0, 1.0, 1.0), color=(255, 0, 0))
    try:
        t0 = time.monotonic()
        browser = pw.chromium.launch(executable_path=exe, args=CHROMIUM_ARGS)
        try:
            page = browser.new_page(viewport=VIEWPORT)
            page.goto(f"http://127.0.0.1:{server.get_port()}")
            while time.monotonic() - t0 < 300:
                png = _canvas_png(page)
                if png is not None and _differs(_pixels(png), base):
                    return time.monotonic() - t0
                time.sleep(0.1)
            return float("nan")
        finally:
            browser.close()
    finally:
        server.stop()


def launch(config: Path, run_dir: Path, cache: Path, pw, exe: str, base, timeout: float) -> dict:
    """Launch ``fxspace studio CONFIG`` and time it to the app's first rendered frame."""
    port = _free_port()
    env = {**os.environ, "FXSPACE_COMPILE_CACHE": str(cache), "FXSPACE_QUIET": "1"}
    env["PYTHONUNBUFFERED"] = "1"  # the "Ctrl-C to stop" line reaches the log at once
    cmd = [sys.executable, "-m", "fxspace.cli", "studio", str(config), "--port", str(port)]
    cmd += ["--out", str(run_dir)]
    log = tempfile.TemporaryFile()
    t0 = time.monotonic()
    proc = subprocess.Popen(cmd, cwd=ROOT, env=env, stdout=log, stderr=subprocess.STDOUT,
                            start_new_session=True)  # fmt: skip
    out: dict = {}
    try:
        deadline = t0 + timeout
        _wait_http(port, proc, deadline)
        out["server_s"] = time.monotonic() - t0
        browser = pw.chromium.launch(executable_path=exe, args=CHROMIUM_ARGS)
        try:
            page = browser.new_page(viewport=VIEWPORT)
            page.goto(f"http://127.0.0.1:{port}")
            while time.monotonic() < deadline:
                png = _canvas_png(page)
                if png is not None and _differs(_pixels(png), base):
                    out["frame_s"] = time.monotonic() - t0
                    break
                time.sleep(0.1)
            else:
                raise TimeoutError("no rendered frame before the timeout")
            # ready: the app fully built (it prints its address with "Ctrl-C to stop" once
            # every control and the scene are in place) and a frame rendered after that
            while time.monotonic() < deadline:
                log.seek(0)
                if b"Ctrl-C to stop" in log.read():
                    if _canvas_png(page) is not None:
                        out["ready_s"] = max(time.monotonic() - t0, out["frame_s"])
                        break
                time.sleep(0.1)
            else:
                raise TimeoutError("the app did not finish building before the timeout")
        finally:
            browser.close()
    except Exception as e:  # reported in the table; the other apps still run
        log.seek(0)
        tail = log.read().decode(errors="replace").strip().splitlines()[-3:]
        out["error"] = f"{type(e).__name__}: {e} | {' / '.join(tail)}"
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGTERM)
        try:
            proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
        log.close()
    return out


def _target(config) -> float:
    """Seconds an app may take from a clean checkout: 45 for the navigators (issue 45),
    60 for the others."""
    return 45.0 if Path(config).stem in ("navigation", "navigation_scale") else 60.0


def _status(run_dir: Path) -> tuple:
    import json

    try:
        st = json.loads((run_dir / "status.json").read_text())
        return st.get("status"), st.get("key")
    except (OSError, ValueError):
        return None, None


def _prepare(config: Path, run_dir: Path, cache: Path) -> float | None:
    """``fxspace run CONFIG --out RUN`` so the app opens a complete run folder *of the
    current config, data and code* (a run of older code is rerun: its stored stages would
    not be read); the seconds it took, or None when the folder was already current."""
    env = {**os.environ, "FXSPACE_COMPILE_CACHE": str(cache), "FXSPACE_QUIET": "1"}
    before = _status(run_dir)
    t = time.monotonic()
    subprocess.run(
        [sys.executable, "-m", "fxspace.cli", "run", str(config), "--out", str(run_dir)],
        cwd=ROOT, env=env, check=True, stdout=subprocess.DEVNULL,
    )  # fmt: skip
    return None if _status(run_dir) == before else time.monotonic() - t


def _fmt(r: dict, key: str) -> str:
    return f"{r[key]:>8.1f}" if key in r else f"{'—':>8}"


def _shown(args: list[str]) -> list[str]:
    """The arguments as the page shows the command: without ``--json PATH`` (where a copy
    of the rows went, not what was measured)."""
    out, skip = [], False
    for x in args:
        if skip:
            skip = False
        elif x == "--json":
            skip = True
        elif not x.startswith("--json="):
            out.append(x)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument(
        "configs", nargs="*", help="config files (default: the four apps') or run folders"
    )
    ap.add_argument("--runs", default=str(ROOT / "runs"), help="run folders: RUNS/<stem>")
    ap.add_argument("--timeout", type=float, default=600.0, help="seconds per launch")
    ap.add_argument("--json", default=None)
    ap.add_argument(
        "--needs",
        nargs="*",
        default=[str(ROOT / "configs" / "threshold_sweep.toml")],
        help="configs run first into RUNS/<stem> (the navigation reads runs/threshold_sweep)",
    )
    ap.add_argument(
        "--clean", action="store_true",
        help="as from a clean checkout: empty run folders and compilation cache; the launch "
        "builds what the app shows (its first frame is the progress page, 'ready' the app)",
    )  # fmt: skip
    a = ap.parse_args(argv)
    if a.clean:
        a.needs = []
    configs = [Path(c) for c in a.configs] or [ROOT / "configs" / f"{n}.toml" for n in _apps()]
    from playwright.sync_api import sync_playwright

    exe = _chromium()
    rows = []
    with (
        tempfile.TemporaryDirectory(prefix="fxspace-bench-studio-") as tmp,
        sync_playwright() as pw,
    ):
        base = empty_scene(pw, exe)
        floor = browser_floor(pw, exe, base)
        print(f"floor: browser launch to the first frame of a bare viser scene {floor:.1f} s")
        for need in map(Path, a.needs):
            try:
                t = _prepare(need, Path(a.runs) / need.stem, Path(tmp) / "warm-cache")
                if t is not None:
                    print(f"ran {need.name} first ({t:.0f} s)", flush=True)
            except subprocess.CalledProcessError as e:
                print(f"running {need.name} first failed ({e.returncode})", flush=True)
        print(
            f"time to first rendered frame of `fxspace studio CONFIG` (s from launch); cold = "
            f"empty JAX compilation cache, cached = second launch; {os.cpu_count()} CPUs, "
            "machine may be shared (noisy)",
            flush=True,
        )
        print(f"{'app':<22} {'prepare':>8} {'cold srv':>8} {'cold':>8} {'ready':>8} "
              f"{'cached srv':>10} {'cached':>8} {'ready':>8}")  # fmt: skip
        for config in configs:
            run_dir = config if config.is_dir() else Path(a.runs) / config.stem
            if a.clean and not config.is_dir():
                run_dir = Path(tmp) / f"clean-{config.stem}"  # empty: nothing run before
            warm = Path(tmp) / "warm-cache"  # runs the config if needed, compiles its stages
            row: dict = {"config": str(config), "run_dir": str(run_dir)}
            try:
                if a.clean:
                    pass  # the launch itself builds the app's stages (fxspace studio CONFIG)
                elif not config.is_dir() and (t := _prepare(config, run_dir, warm)) is not None:
                    row["prepare_s"] = t
            except subprocess.CalledProcessError as e:
                row["error"] = f"fxspace run failed ({e.returncode})"
            if "error" not in row:
                cache = Path(tmp) / f"cache-{config.stem}"  # empty: a cold launch
                cold = launch(config, run_dir, cache, pw, exe, base, a.timeout)
                cached = launch(config, run_dir, cache, pw, exe, base, a.timeout)
                row.update({f"cold_{k}": v for k, v in cold.items()})
                row.update({f"cached_{k}": v for k, v in cached.items()})
            rows.append(row)
            print(
                f"{config.stem:<22} {_fmt(row, 'prepare_s')} {_fmt(row, 'cold_server_s')} "
                f"{_fmt(row, 'cold_frame_s')} {_fmt(row, 'cold_ready_s')} "
                f"{_fmt(row, 'cached_server_s'):>10} {_fmt(row, 'cached_frame_s')} "
                f"{_fmt(row, 'cached_ready_s')}",
                flush=True,
            )
            for k in ("error", "cold_error", "cached_error"):
                if k in row:
                    print(f"  {k}: {row[k]}", flush=True)
    sys.path.insert(0, str(ROOT))
    record = [
        {"case": f"{Path(r['config']).stem}: {what}, cold", "ours": "fxspace studio",
         "ours_s": r[key], "peer": f"target: {_target(r['config']):.0f} s",
         "peer_s": _target(r["config"])}
        for r in rows
        for what, key in (("first frame", "cold_frame_s"), ("app ready", "cold_ready_s"))
        if r.get(key) is not None
    ]  # fmt: skip
    if record:
        from fxspace.runs import write_bench

        write_bench(
            "studio",
            record,
            title="Apps: seconds to the first rendered frame",
            command="python experiments/bench_studio.py " + " ".join(_shown(sys.argv[1:])),
        )
    if a.json:
        from fxspace.runs import write_json_atomic

        write_json_atomic(a.json, {"rows": rows, "browser_floor_s": floor})
    bad = [r for r in rows if any(k.endswith("error") for k in r)]
    return 1 if bad else 0


if __name__ == "__main__":
    raise SystemExit(main())
