"""Issue 44: the own-capture guide's steps run as written — every ```python block of
docs/guides/own-capture.md in order, in an empty folder, with every ```toml block that
carries a ``title="FILE"`` written to FILE first — and say what they drop."""

from __future__ import annotations

import logging
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
GUIDE = ROOT / "docs" / "guides" / "own-capture.md"
_BLOCK = re.compile(r'```(python|toml)(?:[ \t]+title="([^"]+)")?\n(.*?)```', re.S)


def _blocks():
    return [(m[1], m[2], m[3]) for m in _BLOCK.finditer(GUIDE.read_text())]


def test_the_guide_has_runnable_blocks_and_every_data_key():
    blocks = _blocks()
    assert sum(k == "python" for k, *_ in blocks) >= 5
    assert [t for k, t, _ in blocks if k == "toml"] == ["my_sweep.toml"]
    import dataclasses

    from fxspace.datasets import FaceData

    text = GUIDE.read_text()
    for f in dataclasses.fields(FaceData):  # documented key by key
        assert f"`{f.name}`" in text, f.name


@pytest.mark.slow
def test_the_guide_runs_in_an_empty_folder(tmp_path, monkeypatch, caplog, capsys):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("FXSPACE_QUIET", "0")
    ns: dict = {}
    with caplog.at_level(logging.INFO, logger="fxspace"):
        for kind, title, code in _blocks():
            if kind == "toml":
                (tmp_path / title).write_text(code)
                continue
            exec(compile(code, str(GUIDE), "exec"), ns)  # noqa: S102 - the guide's own code
    # nothing written outside the folder, and what the guide promises is there
    assert (tmp_path / "runs" / "my_sweep" / "metrics.json").is_file()
    cfg = (tmp_path / "runs" / "my_sweep" / "config.toml").read_text()
    assert "takes = []" in cfg and str(tmp_path / "take_1.csv") in cfg
    assert "animface" not in cfg.split("[data]")[1].split("[")[0].replace('"animface"', "")
    m = ns["m"]
    first = ns["seq"].names[0]
    assert m["reading"]["markers_dropped"] == {"take_1.csv": [first]}
    assert [f["path"] for f in m["reading"]["files"]] == [
        str(tmp_path / "take_1.csv"), str(tmp_path / "take_2.c3d")
    ]
    assert ns["face"].reading["resampled"]["take_120hz.trc"]["to_hz"] == 60.0
    err = capsys.readouterr().err
    said = [r.getMessage() for r in caplog.records if r.name == "fxspace"]
    # each drop / intersection / resample / unit inference said as it happens
    assert any("take_1.csv: 12 markers × 160 frames, separator ';'" in s for s in said)
    assert any("1 non-marker column(s) ignored: 'label'" in s for s in said)
    assert any(f"take_2.c3d: lacks 1 of take_1.csv's markers ({first})" in s for s in said)
    assert any("markers: using the 11 shared by every take" in s for s in said)
    assert any("take_120hz.trc: resampled 120 → 60 Hz" in s for s in said)
    assert any("gaps of at most max_gap = 10 frames filled" in s for s in said)
    assert "[fxspace] markers: using the 11 shared by every take" in err
