"""Issue 43 (items 1, 4, 5, 7, 8): a run folder's files never leave it, locks and FIFOs
never hang, no user file is overwritten, finished results are kept across versions,
bench records cannot name paths, damaged bookkeeping gives a clear message. Each test is
the reported case's reproduction, in tmp_path only."""

from __future__ import annotations

import contextlib
import dataclasses
import json
import os
import shutil
import signal
import stat
import types
from pathlib import Path

import numpy as np
import pytest

import fxspace._atomic as atomic
import fxspace.runs as runs
from fxspace.cli import main
from fxspace.config import ConfigError
from fxspace.errors import CorruptFileError, FxspaceError
from fxspace.pipelines import _REGISTERED, register, run_dict
from fxspace.report import collect, write_report
from fxspace.runs import (
    LOCK,
    MANIFEST,
    OverwriteRefusedError,
    UnsafePathError,
    cached_arrays,
    read_status,
    reset_cache,
    save_npz_atomic,
    write_bench,
)

ROOT = Path(__file__).resolve().parents[2]
CALLS: list[int] = []


@dataclasses.dataclass(frozen=True)
class _Cfg:
    n: int = 2

    def validate(self):
        pass


def _toy_run(cfg, run_dir, seed):
    st = cached_arrays(run_dir, "space", lambda: CALLS.append(cfg.n) or {"x": np.arange(cfg.n)})
    save_npz_atomic(run_dir / "expression_space.npz", x=st["x"])
    return {"sq": cfg.n**2}


@pytest.fixture
def toy(monkeypatch):
    monkeypatch.setattr(runs, "code_digest", lambda: "code-1")  # others edit the tree
    mod = types.ModuleType("issue43_toy")
    mod.Config, mod.STAGES, mod.run = _Cfg, ("space",), _toy_run
    register(mod, "issue43_toy")
    CALLS.clear()
    yield "issue43_toy"
    _REGISTERED.pop("issue43_toy", None)
    runs._NO_CACHE.clear()


@contextlib.contextmanager
def _within(seconds: int):
    """Fail (instead of hanging the suite) when the block blocks for ``seconds``."""

    def boom(*_):
        raise TimeoutError(f"blocked for more than {seconds} s")

    old = signal.signal(signal.SIGALRM, boom)
    signal.alarm(seconds)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)


def _metrics(d):
    return json.loads((d / "metrics.json").read_text())


# ------------------------------------------------------------- 1: never out of the folder


def test_force_never_deletes_through_a_symlinked_folder_in_the_manifest(tmp_path, toy):
    victim = tmp_path / "victim"
    victim.mkdir()
    (victim / "notes.txt").write_text("precious")
    r = tmp_path / "r"
    run_dict({"experiment": toy}, r)
    (r / "linkdir").symlink_to("../victim")
    with (r / MANIFEST).open("a") as f:
        f.write("linkdir/notes.txt\n")  # a collaborator's line, or a stale one
    (d,) = run_dict({"experiment": toy, "n": 3}, r, force=True)
    assert (victim / "notes.txt").read_text() == "precious"
    assert (r / "linkdir").is_symlink() and _metrics(d)["sq"] == 9


def test_stale_status_key_never_deletes_through_a_symlink(tmp_path, toy, capsys):
    victim = tmp_path / "victim"
    victim.mkdir()
    (victim / "notes.txt").write_text("precious")
    r = tmp_path / "r"
    run_dict({"experiment": toy}, r)
    (r / "metrics.json").unlink()  # an interrupted run …
    st = json.loads((r / "status.json").read_text())
    (r / "status.json").write_text(json.dumps({**st, "key": "stale"}))  # … of another key
    (r / "linkdir").symlink_to(victim)
    with (r / MANIFEST).open("a") as f:
        f.write("linkdir/notes.txt\n")
    run_dict({"experiment": toy}, r)  # no --force: the stale key cleans the folder
    assert (victim / "notes.txt").read_text() == "precious"
    assert "not fxspace's to delete" in capsys.readouterr().out


def test_a_file_replaced_since_fxspace_wrote_it_is_not_deleted(tmp_path, toy):
    r = tmp_path / "r"
    run_dict({"experiment": toy}, r)
    (r / "expression_space.npz").unlink()
    (r / "expression_space.npz").write_bytes(b"the user's own, same name")  # new inode
    runs.clean_run(r)
    assert (r / "expression_space.npz").read_bytes() == b"the user's own, same name"
    assert not (r / "metrics.json").exists()  # fxspace's own files went


def test_symlinked_cache_is_never_written_nor_cleared_and_force_still_works(
    tmp_path, toy, capsys
):
    mine = tmp_path / "scratch"
    mine.mkdir()
    (mine / "KEY").write_text("the user's KEY\n")
    (mine / "space.npz").write_bytes(b"the user's npz")
    r = tmp_path / "r"
    run_dict({"experiment": toy}, r)
    shutil.rmtree(r / "cache")
    (r / "cache").symlink_to(mine)
    for n in (3, 4):  # --force succeeds, again and again ("cache: Not a directory" before)
        (d,) = run_dict({"experiment": toy, "n": n}, r, force=True)
        assert _metrics(d)["sq"] == n * n
    assert (mine / "KEY").read_text() == "the user's KEY\n"
    assert (mine / "space.npz").read_bytes() == b"the user's npz"
    assert sorted(p.name for p in mine.iterdir()) == ["KEY", "space.npz"]
    assert "is a symbolic link" in capsys.readouterr().out


def test_writing_through_a_symlinked_folder_in_the_run_is_refused(tmp_path):
    outside = tmp_path / "outside"
    outside.mkdir()
    r = tmp_path / "r"
    r.mkdir()
    (r / "figs").symlink_to(outside)
    with runs.active_run(r), pytest.raises(UnsafePathError, match=r"figs is a symbolic link"):
        runs.write_text_atomic(r / "figs" / "a.png", "x")
    assert list(outside.iterdir()) == []


def test_force_stopped_part_way_is_never_already_complete(tmp_path, toy, monkeypatch, capsys):
    r = tmp_path / "r"
    run_dict({"experiment": toy}, r)
    real_unlink = Path.unlink
    calls = []

    def unlink(self, *a, **k):
        calls.append(self.name)
        if len(calls) == 2:
            raise KeyboardInterrupt  # Ctrl-C in the middle of --force's clean
        return real_unlink(self, *a, **k)

    monkeypatch.setattr(Path, "unlink", unlink)
    with pytest.raises(KeyboardInterrupt):
        run_dict({"experiment": toy}, r, force=True)
    monkeypatch.setattr(Path, "unlink", real_unlink)
    assert calls[0] == "metrics.json" and not (r / "metrics.json").exists()
    capsys.readouterr()
    (d,) = run_dict({"experiment": toy}, r)  # a plain rerun: runs, never "already complete"
    assert "already complete" not in capsys.readouterr().out
    assert read_status(d)["status"] == "complete" and (d / "config.toml").is_file()
    assert (d / "expression_space.npz").is_file() and (d / "cache" / "space.npz").is_file()


# ------------------------------------------------------------------ 4: locks and FIFOs


@pytest.mark.parametrize("garbage", ["garbage", "{}", "[1, 2]", '{"pid": "x"}', "\xff"])
def test_garbage_lock_is_stale_and_taken_over(tmp_path, toy, garbage, capsys):
    r = tmp_path / "r"
    r.mkdir()
    (r / LOCK).write_bytes(garbage.encode("latin-1"))
    with _within(20):
        (d,) = run_dict({"experiment": toy}, r)
    assert _metrics(d)["sq"] == 4 and not (r / LOCK).exists()
    assert "taking it over" in capsys.readouterr().out


def test_empty_lock_is_awaited_briefly_then_taken_over(tmp_path, toy):
    r = tmp_path / "r"
    r.mkdir()
    (r / LOCK).write_text("")
    old = os.stat(r / LOCK).st_mtime - 60
    os.utime(r / LOCK, (old, old))
    with _within(20):
        run_dict({"experiment": toy}, r)
    assert (r / "metrics.json").is_file()


def test_lock_that_is_a_fifo_is_refused_not_read(tmp_path, toy):
    r = tmp_path / "r"
    r.mkdir()
    os.mkfifo(r / LOCK)
    with _within(20), pytest.raises(UnsafePathError, match=r"FIFO.*remove it"):
        run_dict({"experiment": toy}, r)


def test_waiting_for_a_live_lock_says_whom_and_times_out(tmp_path, capsys):
    r = tmp_path / "r"
    r.mkdir()
    # a live holder on another host (this test's own pid, so it is alive either way)
    (r / LOCK).write_text(json.dumps({"pid": os.getpid(), "host": "elsewhere", "at": "t"}))
    with _within(20), pytest.raises(runs.RunLockedError, match=r"pid \d+ on elsewhere"):
        with runs.run_lock(r, wait=0.5):
            pass
    assert "waiting up to 0.5 s" in capsys.readouterr().out


def test_fifo_named_status_json_never_hangs_run(tmp_path, toy):
    r = tmp_path / "r"
    r.mkdir()
    os.mkfifo(r / "status.json")
    with _within(20), pytest.raises(ConfigError, match="status.json that fxspace did not write"):
        run_dict({"experiment": toy}, r)
    with _within(20), pytest.raises(UnsafePathError, match=r"status\.json is a FIFO"):
        run_dict({"experiment": toy}, r, force=True)
    with _within(20):
        assert runs.read_regular(tmp_path / "absent") is None


def test_fifo_named_metrics_json_never_hangs_report(tmp_path, toy, capsys):
    (d,) = run_dict({"experiment": toy}, tmp_path / "s" / "a")
    run_dict({"experiment": toy, "n": 3}, tmp_path / "s" / "b")
    (d / "metrics.json").unlink()
    os.mkfifo(d / "metrics.json")
    with _within(20):
        assert main(["report", str(tmp_path / "s")]) == 0
    rows = {r["run"]: r for r in collect(tmp_path / "s")}
    assert rows["a"]["status"] == "corrupt" and "FIFO" in rows["a"]["error"]
    assert rows["b"]["status"] == "complete"
    assert "a: " in capsys.readouterr().err


# ----------------------------------------------------- 5: no user file overwritten


def test_report_refuses_the_users_own_runs_md(tmp_path, toy, capsys):
    run_dict({"experiment": toy}, tmp_path / "s" / "a")
    rep = tmp_path / "s" / "report"
    rep.mkdir()
    (rep / "runs.md").write_text("my notes")
    (rep / "runs.csv").write_text("my,table")
    with pytest.raises(OverwriteRefusedError, match=r"runs\.csv.*runs\.md.*--force"):
        write_report(tmp_path / "s")
    assert (rep / "runs.md").read_text() == "my notes"
    assert (rep / "runs.csv").read_text() == "my,table"
    assert main(["report", str(tmp_path / "s")]) == 2
    assert "--force" in capsys.readouterr().err
    _, out = write_report(tmp_path / "s", out=tmp_path / "elsewhere")
    assert (out / "runs.md").is_file() and (rep / "runs.md").read_text() == "my notes"
    write_report(tmp_path / "s", force=True)
    assert (rep / "runs.md").read_text() != "my notes"
    write_report(tmp_path / "s")  # its own now: replaced freely
    assert "runs.md" in runs.manifest_files(rep)


def _repo_pages(tmp_path) -> Path:
    """The committed reproduction pages and snapshots, copied (no figures)."""
    out = tmp_path / "repro"
    (out / "data").mkdir(parents=True)
    src = ROOT / "docs" / "reproductions"
    for p in src.glob("*.md"):
        shutil.copy(p, out / p.name)
    for p in (src / "data").glob("*.json"):
        shutil.copy(p, out / "data" / p.name)
    return out


def _snapshot_bytes(out: Path) -> dict[str, bytes]:
    return {p.relative_to(out).as_posix(): p.read_bytes() for p in out.rglob("*") if p.is_file()}


def test_docs_without_runs_keeps_the_committed_pages(tmp_path, capsys):
    from fxspace.pipelines import write_docs

    out = _repo_pages(tmp_path)
    before = _snapshot_bytes(out)
    with pytest.raises(FxspaceError, match=r"--runs .*nonexistent is not a folder.*kept"):
        write_docs(tmp_path / "nonexistent", out)
    assert main(["docs", "--runs", str(tmp_path / "nonexistent"), "--out", str(out),
                 "--bench-out", str(tmp_path / "b")]) == 2  # fmt: skip
    empty = tmp_path / "runs"
    empty.mkdir()
    assert write_docs(empty, out) == []
    assert _snapshot_bytes(out) == before
    assert capsys.readouterr().out.count("kept ") == 4
    write_docs(empty, out, force=True)  # asked for: the "Not run yet" pages
    assert "Not run yet" in (out / "kim-jung.md").read_text()


def test_docs_refuses_a_users_own_page(tmp_path):
    from fxspace.pipelines import write_docs

    runs_dir = tmp_path / "runs" / "navigation"
    runs_dir.mkdir(parents=True)
    (runs_dir / "metrics.json").write_text(json.dumps({"r": 0.9, "threshold": 200.0}))
    out = tmp_path / "docs" / "reproductions"
    out.mkdir(parents=True)
    (out / "kim-jung.md").write_text("# my own notes on Kim & Jung\n")
    with pytest.raises(OverwriteRefusedError, match=r"kim-jung\.md.*--force"):
        write_docs(tmp_path / "runs", out)
    assert (out / "kim-jung.md").read_text() == "# my own notes on Kim & Jung\n"
    assert not (out / "data").exists()  # nothing written at all
    pages = write_docs(tmp_path / "runs", out, force=True)
    assert out / "kim-jung.md" in pages and "0.9" in (out / "kim-jung.md").read_text()
    write_docs(tmp_path / "runs", out)  # its own now (manifest)


def test_docs_rewrites_its_own_generated_pages_without_a_manifest(tmp_path):
    from fxspace.pipelines import write_docs

    out = _repo_pages(tmp_path)
    r = tmp_path / "runs" / "navigation"
    r.mkdir(parents=True)
    (r / "metrics.json").write_text(json.dumps({"r": 0.5}))
    pages = write_docs(tmp_path / "runs", out)
    assert out / "kim-jung.md" in pages and "| 0.5 |" in (out / "kim-jung.md").read_text()


def test_docs_never_copies_a_symlinked_figure_and_keeps_a_private_ones_mode(tmp_path, capsys):
    from fxspace.pipelines import write_docs

    secret = tmp_path / "secret.png"
    secret.write_bytes(b"\x89PNG secret")
    secret.chmod(0o600)
    r = tmp_path / "runs" / "navigation"
    r.mkdir(parents=True)
    (r / "metrics.json").write_text(json.dumps({"r": 0.9}))
    (r / "r_vs_threshold.png").symlink_to(secret)
    (r / "levels_grid.png").write_bytes(b"\x89PNG private")
    (r / "levels_grid.png").chmod(0o600)
    out = tmp_path / "docs"
    write_docs(tmp_path / "runs", out)
    figs = out / "figures" / "kim-jung"
    assert not (figs / "r_vs_threshold.png").exists()
    assert "skipped" in capsys.readouterr().out
    assert "r_vs_threshold.png" not in (out / "kim-jung.md").read_text()
    assert stat.S_IMODE((figs / "levels_grid.png").stat().st_mode) & 0o077 == 0


def test_docs_names_a_damaged_metrics_json(tmp_path):
    from fxspace.pipelines import write_docs

    r = tmp_path / "runs" / "navigation"
    r.mkdir(parents=True)
    (r / "metrics.json").write_text('{"r": 0.9')  # torn
    match = r"navigation/metrics\.json is not valid JSON.*--force"
    with pytest.raises(CorruptFileError, match=match):
        write_docs(tmp_path / "runs", tmp_path / "docs")


def _rows():
    return [{"case": "c", "size": 1, "ours": "f", "ours_s": 1.0, "peer": "p", "peer_s": 2.0}]


def test_bench_refuses_a_users_file_and_bad_names(tmp_path):
    (tmp_path / "bench").mkdir()
    (tmp_path / "bench" / "dtw.json").write_text('{"mine": true}')
    with pytest.raises(OverwriteRefusedError, match=r"dtw\.json.*FXSPACE_RUNS"):
        write_bench("dtw", _rows(), title="t", command="c", root=tmp_path)
    assert (tmp_path / "bench" / "dtw.json").read_text() == '{"mine": true}'
    p = write_bench("fcm", _rows(), title="t", command="c", root=tmp_path)
    write_bench("fcm", _rows(), title="t2", command="c", root=tmp_path)  # its own: replaced
    assert json.loads(p.read_text())["title"] == "t2"
    for bad in ("../evil", "/tmp/evil", "a/b", "..", ""):
        with pytest.raises(FxspaceError, match="plain file name"):
            write_bench(bad, _rows(), title="t", command="c", root=tmp_path)
    assert not (tmp_path / "evil.json").exists()


def test_bench_record_from_before_manifests_is_replaced(tmp_path):
    p = write_bench("ik", _rows(), title="old", command="c", root=tmp_path)
    (tmp_path / "bench" / MANIFEST).unlink()  # written by an older fxspace
    write_bench("ik", _rows(), title="new", command="c", root=tmp_path)
    assert json.loads(p.read_text())["title"] == "new"


@pytest.mark.parametrize("name", ["../../evil", "/tmp/evil", "other"])
def test_bench_page_refuses_a_record_whose_name_is_a_path(tmp_path, name):
    from fxspace.pipelines import write_bench_page

    p = write_bench("x", _rows(), title="t", command="c", root=tmp_path / "runs")
    rec = json.loads(p.read_text())
    p.write_text(json.dumps({**rec, "name": name}))
    with pytest.raises(CorruptFileError, match=r"x\.json is not a benchmark record.*name"):
        write_bench_page(tmp_path / "runs", tmp_path / "site" / "bench")
    assert not (tmp_path / "evil.png").exists() and not (tmp_path / "site").exists()


@pytest.mark.parametrize("text", ["{", "[]", '{"name": "x"}', "\xff\xfe"])
def test_bench_page_names_a_malformed_record(tmp_path, text):
    from fxspace.pipelines import write_bench_page

    (tmp_path / "bench").mkdir()
    (tmp_path / "bench" / "x.json").write_bytes(text.encode("latin-1"))
    with pytest.raises(CorruptFileError, match=r"x\.json"):
        write_bench_page(tmp_path, tmp_path / "site")


def test_finished_run_kept_after_a_code_change(tmp_path, toy, monkeypatch):
    r = tmp_path / "r"
    run_dict({"experiment": toy}, r)
    before = (r / "metrics.json").read_bytes()
    monkeypatch.setattr(runs, "code_digest", lambda: "code-2")  # an upgrade
    with pytest.raises(ConfigError, match=r"other fxspace code.*kept.*--force.*another --out"):
        run_dict({"experiment": toy}, r)
    assert (r / "metrics.json").read_bytes() == before
    (d,) = run_dict({"experiment": toy}, tmp_path / "beside")  # another --out: both kept
    assert _metrics(d)["sq"] == json.loads(before)["sq"]
    run_dict({"experiment": toy}, r, force=True)  # asked for
    assert read_status(r)["status"] == "complete"


def test_finished_run_kept_after_a_data_change(tmp_path, toy, monkeypatch):
    r = tmp_path / "r"
    run_dict({"experiment": toy}, r)
    monkeypatch.setattr(runs, "run_key", lambda *a, **k: "data-changed")
    import fxspace.pipelines._runner as P

    monkeypatch.setattr(P, "run_key", lambda *a, **k: "data-changed")
    with pytest.raises(ConfigError, match=r"other data"):
        run_dict({"experiment": toy}, r)


# ----------------------------------------- 8: torn caches, unusable cache folders, JSON


def test_truncated_cache_npz_is_recomputed(tmp_path, toy, capsys):
    r = tmp_path / "r"
    run_dict({"experiment": toy}, r)
    p = r / "cache" / "space.npz"
    with p.open("r+b") as f:  # torn in place (same inode, as a crash or a full disk leaves)
        f.truncate(p.stat().st_size // 2)
    (r / "metrics.json").unlink()
    CALLS.clear()
    run_dict({"experiment": toy}, r)
    assert CALLS == [2] and "space.npz is damaged (BadZipFile)" in capsys.readouterr().out


def test_corrupt_member_of_a_cache_npz_is_recomputed(tmp_path):
    reset_cache(tmp_path, "k")
    cached_arrays(tmp_path, "s", lambda: {"x": np.arange(1000.0)})
    p = tmp_path / "cache" / "s.npz"
    data = bytearray(p.read_bytes())
    data[100:140] = b"\0" * 40
    with p.open("r+b") as f:
        f.write(bytes(data))
    got = cached_arrays(tmp_path, "s", lambda: {"x": np.ones(2)})
    assert np.array_equal(got["x"], np.ones(2))


def test_flipped_byte_in_a_stored_cache_array_is_recomputed(tmp_path, capsys):
    """Stage arrays are stored undeflated (fast to write): a flipped byte inside an
    array's data, past its header, is still found (the member's CRC-32)."""
    reset_cache(tmp_path, "k")
    cached_arrays(tmp_path, "s", lambda: {"x": np.arange(4096.0)})
    p = tmp_path / "cache" / "s.npz"
    data = bytearray(p.read_bytes())
    at = data.index(np.arange(4096.0)[2000:2001].tobytes())  # a value inside the array
    data[at] ^= 0xFF
    with p.open("r+b") as f:
        f.write(bytes(data))
    got = cached_arrays(tmp_path, "s", lambda: {"x": np.ones(2)})
    assert np.array_equal(got["x"], np.ones(2))
    assert "s.npz is damaged (BadZipFile)" in capsys.readouterr().out


def test_cache_that_is_a_file_falls_back_with_a_message(tmp_path, toy, capsys):
    r = tmp_path / "r"
    r.mkdir()
    (r / "cache").write_text("the user's file named cache")
    (d,) = run_dict({"experiment": toy}, r)
    assert _metrics(d)["sq"] == 4 and CALLS == [2]
    assert (r / "cache").read_text() == "the user's file named cache"
    out = capsys.readouterr().out
    assert "cache is a regular file, not a folder" in out and "without a cache" in out


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes read-only folders")
def test_read_only_cache_falls_back_with_a_message(tmp_path, toy, capsys):
    r = tmp_path / "r"
    run_dict({"experiment": toy}, r)
    (r / "metrics.json").unlink()
    (r / "cache").chmod(0o500)
    try:
        (d,) = run_dict({"experiment": toy, "n": 2}, r)
    finally:
        (r / "cache").chmod(0o700)
    assert _metrics(d)["sq"] == 4 and "not writable" in capsys.readouterr().out


@pytest.mark.parametrize(
    ("name", "text"),
    [("metrics.json", "[1, 2]"), ("metrics.json", "{torn"), ("status.json", "[]"),
     ("status.json", "\xff"), ("meta.json", '{"timing": "x"}'), ("meta.json", "7")],
)  # fmt: skip
def test_report_names_malformed_bookkeeping(tmp_path, toy, name, text, capsys):
    (d,) = run_dict({"experiment": toy}, tmp_path / "s" / "a")
    (d / name).write_bytes(text.encode("latin-1"))
    assert main(["report", str(tmp_path / "s")]) == 0
    (row,) = collect(tmp_path / "s")
    if name == "meta.json" and text.startswith("{"):
        assert row["status"] == "complete" and row["compile_s"] is None
    else:
        assert row["status"] == "corrupt" and name in row["error"]
        assert name in capsys.readouterr().err


@pytest.mark.parametrize("text", ["[]", "garbage", "\xff", '{"status": 1}'])
def test_malformed_status_json_reruns_cleanly(tmp_path, toy, text):
    r = tmp_path / "r"
    run_dict({"experiment": toy}, r)
    (r / "metrics.json").unlink()
    (r / "status.json").write_bytes(text.encode("latin-1"))
    (d,) = run_dict({"experiment": toy}, r)
    assert read_status(d)["status"] == "complete"


def test_summary_names_a_damaged_metrics_json(tmp_path):
    from fxspace.pipelines import summary

    (tmp_path / "metrics.json").write_text("{")
    with pytest.raises(CorruptFileError, match=r"metrics\.json is not valid JSON"):
        summary(tmp_path)


# ----------------------------------------------------------- 5: the IK app's exports


def test_ik_exports_never_overwrite_a_users_file(data_dir, tmp_path):
    import fxspace as fx
    from fxspace.studio import IKController

    mesh = fx.io.read_gltf(data_dir / "mesh" / "RiggedSimple.glb")
    ctl = IKController(mesh)
    for name in ("ik_pose.bvh", "ik_pose.glb"):
        (tmp_path / name).write_text("the user's")
    b = ctl.export_bvh(tmp_path / "ik_pose.bvh")
    g = ctl.export_gltf(tmp_path / "ik_pose.glb")
    assert (b.name, g.name) == ("ik_pose-2.bvh", "ik_pose-2.glb")
    assert "kept" in ctl.message
    assert all((tmp_path / n).read_text() == "the user's" for n in ("ik_pose.bvh", "ik_pose.glb"))
    assert ctl.export_bvh(tmp_path / "ik_pose.bvh").name == "ik_pose-2.bvh"  # still beside
    assert ctl.export_bvh(tmp_path / "fresh.bvh") == tmp_path / "fresh.bvh"
    assert ctl.export_bvh(tmp_path / "fresh.bvh") == tmp_path / "fresh.bvh"  # its own


def test_cli_bench_refuses_a_users_record_before_measuring(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("FXSPACE_RUNS", str(tmp_path))
    (tmp_path / "bench").mkdir()
    (tmp_path / "bench" / "dtw.json").write_text('{"mine": true}')
    assert main(["bench", "dtw"]) == 2
    assert "dtw.json exist" in capsys.readouterr().err
    assert (tmp_path / "bench" / "dtw.json").read_text() == '{"mine": true}'


def test_cli_run_with_a_fifo_status_is_one_line_exit_2(tmp_path, toy, capsys):
    cfg = tmp_path / "c.toml"
    cfg.write_text(f'experiment = "{toy}"\n')
    r = tmp_path / "r"
    r.mkdir()
    os.mkfifo(r / "status.json")
    with _within(20):
        assert main(["run", str(cfg), "--out", str(r), "--force"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "status.json is a FIFO" in err


def test_bench_page_rewrites_the_committed_page_and_its_own_records(tmp_path):
    from fxspace.pipelines import write_bench_page

    out = tmp_path / "benchmarks"
    shutil.copytree(ROOT / "docs" / "benchmarks", out)
    write_bench("dtw", _rows(), title="DTW again", command="c", root=tmp_path / "runs")
    page = write_bench_page(tmp_path / "runs", out)  # no manifest: recognised as its own
    assert "## DTW again" in page.read_text()
    (out / "data" / "fcm.json").write_text('{"a user": "file"}')  # no longer a record
    write_bench("fcm", _rows(), title="t", command="c", root=tmp_path / "runs")
    with pytest.raises(OverwriteRefusedError, match=r"fcm\.json"):
        write_bench_page(tmp_path / "runs", out)


def test_report_out_pointed_at_a_run_folder_deletes_nothing_of_it(tmp_path, toy):
    run_dict({"experiment": toy}, tmp_path / "s" / "a")
    (other,) = run_dict({"experiment": toy, "n": 3}, tmp_path / "other")
    before = sorted(p.name for p in other.iterdir())
    write_report(tmp_path / "s", out=other)
    write_report(tmp_path / "s", out=other)
    assert set(before) <= {p.name for p in other.iterdir()} and _metrics(other)["sq"] == 9


def test_report_replaces_its_own_old_figures(tmp_path, toy):
    run_dict({"experiment": toy}, tmp_path / "s" / "a")
    run_dict({"experiment": toy, "n": 3}, tmp_path / "s" / "b")
    _, rep = write_report(tmp_path / "s")
    old = rep / "sq_vs_n.png"
    assert old.is_file()
    shutil.rmtree(tmp_path / "s" / "b")
    (rep / "mine_vs_notes.png").write_bytes(b"the user's")
    write_report(tmp_path / "s")  # one run left: no figure to compare, the old one goes
    assert not old.exists() and (rep / "mine_vs_notes.png").read_bytes() == b"the user's"


def test_cache_whose_writes_fail_falls_back_with_a_message(tmp_path, toy, monkeypatch, capsys):
    """A read-only cache as root sees it (root writes anyway): the writes fail."""
    real = atomic.write_bytes_atomic

    def failing(path, data, mode=None):
        if Path(path).parent.name == "cache":
            raise PermissionError(13, "Permission denied", str(path))
        return real(path, data, mode)

    # the home of the writes (fxspace.runs re-exports it): write_text_atomic reads it there
    monkeypatch.setattr(atomic, "write_bytes_atomic", failing)
    (d,) = run_dict({"experiment": toy}, tmp_path / "r")
    assert _metrics(d)["sq"] == 4
    out = capsys.readouterr().out
    assert "KEY cannot be written (Permission denied)" in out and "without a cache" in out


def test_studio_preparation_never_hangs_on_a_garbage_lock(tmp_path, toy):
    from fxspace.pipelines import prepare_config

    cfg = tmp_path / "c.toml"
    cfg.write_text(f'experiment = "{toy}"\n')
    r = tmp_path / "r"
    r.mkdir()
    (r / LOCK).write_text("{}")
    with _within(20):
        assert prepare_config(cfg, r) == r
    assert _metrics(r)["sq"] == 4


def test_studio_opens_a_finished_run_of_older_code_as_it_is(tmp_path, toy, monkeypatch, capsys):
    import fxspace.pipelines as P

    cfg = tmp_path / "c.toml"
    cfg.write_text(f'experiment = "{toy}"\n')
    r = tmp_path / "r"
    P.run_config(cfg, r)
    before = (r / "metrics.json").read_bytes()
    monkeypatch.setattr(runs, "code_digest", lambda: "code-2")
    toy_mod = P.load_pipeline(toy)
    monkeypatch.setattr(toy_mod, "prepare_app", lambda cfg, d, seed: None, raising=False)
    assert P.prepare_config(cfg, r) == r
    assert (r / "metrics.json").read_bytes() == before
    assert "shows it as it is" in capsys.readouterr().out
