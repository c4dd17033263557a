"""Restart tier: which code made a state. A bed prepared by other fbed code is prepared again, not reused as this
code's (run.start_from's cache keys on the code's fingerprint); checkpoints and run.h5 name the code that wrote them.
"""
import json
import pathlib
import shutil

import h5py
import numpy as np
import pytest

from app import provenance, resume
from app.io import store

pytestmark = pytest.mark.restart


def _tree(root: pathlib.Path) -> pathlib.Path:
    for rel in ("__init__.py", "sim/dem.py", "config/schema.py", "analysis/mri.py", "rcfd/paths.py", "gui/view.py",
                "bench/common.py"):
        (root / rel).parent.mkdir(parents=True, exist_ok=True)
        (root / rel).write_text(f"# {rel}\n")
    return root


def test_the_fingerprint_follows_the_code_that_computes_not_the_code_that_reads(tmp_path):
    root = _tree(tmp_path / "app")
    base = provenance.fingerprint(root, taichi="1.7.4")
    assert provenance.fingerprint(root, taichi="1.7.4") == base  # the same sources: the same code
    assert provenance.fingerprint(root, taichi="1.7.5") != base  # another Taichi compiles other kernels
    for rel in ("sim/dem.py", "config/schema.py", "__init__.py"):
        text = (root / rel).read_text()
        (root / rel).write_text(text + "x = 1\n")
        assert provenance.fingerprint(root, taichi="1.7.4") != base, rel
        (root / rel).write_text(text)
    (root / "sim" / "dem.py").rename(root / "sim" / "dem2.py")  # a module moved is other code too
    assert provenance.fingerprint(root, taichi="1.7.4") != base
    (root / "sim" / "dem2.py").rename(root / "sim" / "dem.py")
    for rel in ("analysis/mri.py", "rcfd/paths.py", "gui/view.py", "bench/common.py"):
        (root / rel).write_text("changed = True\n")
    (root / "sim" / "__pycache__").mkdir()
    (root / "sim" / "__pycache__" / "dem.py").write_text("stale\n")
    assert provenance.fingerprint(root, taichi="1.7.4") == base  # post-processing and the renderer change no state


def test_the_installed_fingerprint_covers_the_solvers():
    names = {p.relative_to(provenance.PACKAGE).as_posix() for p in provenance.state_sources()}
    assert {"sim/drag.py", "scene.py", "run.py", "config/schema.py"} <= names
    assert not any(n.split("/")[0] in provenance.READ_ONLY for n in names)


def _fake_runner(calls):
    """Stands in for app.run.run: a 'preparation' that writes a finished run folder."""
    def run(preset, overrides, out=None, arch="cpu", overwrite=False, resume=None):
        calls.append(out)
        out = pathlib.Path(out)
        out.mkdir(parents=True, exist_ok=True)
        store.write_checkpoint(out / "checkpoint.h5", {"position": np.zeros((2, 3))}, None, 0.01, 10, "")
        (out / "config.toml").write_text("")
        (out / "summary.json").write_text(json.dumps({"status": "finished"}))
        return 0
    return run


def test_a_bed_prepared_by_other_code_is_prepared_again(tmp_path, monkeypatch, capsys):
    src = pathlib.Path(__file__).resolve().parents[1] / "presets"
    shutil.copy(src / "settle.toml", tmp_path / "prep.toml")
    main = tmp_path / "main.toml"
    main.write_text((tmp_path / "prep.toml").read_text().replace("[run]", '[run]\nstart_from = "prep.toml"', 1))
    monkeypatch.chdir(tmp_path)
    from app import config as cfgmod

    cfg = cfgmod.load(main, [])
    calls = []
    monkeypatch.setattr(resume, "code_id", lambda: "aaaaaaaaaaaa")
    first = resume.prepared_state(cfg, main, "cpu", _fake_runner(calls))
    assert len(calls) == 1
    assert resume.prepared_state(cfg, main, "cpu", _fake_runner(calls)) == first and len(calls) == 1  # reused
    monkeypatch.setattr(resume, "code_id", lambda: "bbbbbbbbbbbb")  # fbed upgraded, or edited
    capsys.readouterr()
    second = resume.prepared_state(cfg, main, "cpu", _fake_runner(calls))
    assert len(calls) == 2 and second != first and first.exists()  # prepared again; the older one kept
    note = capsys.readouterr().err
    assert str(first.parent) in note and "particles.initial_state" in note and "code has changed" in note
    monkeypatch.setattr(resume, "code_id", lambda: "aaaaaaaaaaaa")  # back to the first code: its bed again
    assert resume.prepared_state(cfg, main, "cpu", _fake_runner(calls)) == first and len(calls) == 2


def test_checkpoints_and_run_files_name_the_code_that_wrote_them(tmp_path):
    store.write_checkpoint(tmp_path / "c.h5", {"position": np.zeros((1, 3))}, None, 0.0, 0, "")
    run = store.RunFile(tmp_path / "run.h5", "p.toml")
    run.close()
    for name in ("c.h5", "run.h5"):
        with h5py.File(tmp_path / name) as f:
            assert f.attrs["fbed_code"] == provenance.code_id()
