"""rCFD end to end on a CPU-sized bubbling bed: record frames, analyze, run paths (through `python -m app`).

rcfd_small (1,500 grains here) bubbles from 0.25 s; frames are recorded from 0.28 s to 0.40 s (24 frames of
5 ms). The recording must be self-consistent (each frame's shift operator carries the grain volume of its
start boundary exactly onto that of its end boundary; nothing is lost), and the commands must produce
their outputs, conserve the tracer and reproduce a path from its seed.
"""
import json
import os
import pathlib
import subprocess
import sys

import h5py
import numpy as np
import pytest

pytestmark = pytest.mark.smoke

ROOT = pathlib.Path(__file__).resolve().parents[1]


def fbed(*args, timeout=900):
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    return subprocess.run([sys.executable, "-m", "app", *map(str, args)], capture_output=True, text=True, cwd=ROOT,
                          env=env, timeout=timeout)


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    out = tmp_path_factory.mktemp("rcfd") / "bed"
    r = fbed("run", ROOT / "presets" / "rcfd_small.toml", "--set", "run.duration=0.40", "--set",
             "probes.rcfd_from=0.28", "--set", "particles.count=1500", "--arch", "cpu", "--out", out)
    assert r.returncode == 0, r.stderr[-3000:]
    return out


def test_recording_is_self_consistent(recorded):
    from app.rcfd.database import load

    db = load(recorded)
    assert db.n_frames == 24 and db.n_states == 25
    assert np.allclose(np.diff(db.time), 5e-3)
    assert np.all(db.b1 == db.b0 + 1)
    with h5py.File(recorded / "rcfd.h5") as f:
        grains = int(f.attrs["grains"])
        assert f.attrs["frame_check"] in ("ok",) or "Taylor" in f.attrs["frame_check"]
        assert 0 < f.attrs["taylor_time"] < np.inf
        for a in "xyz":
            assert np.all(np.isfinite(f[f"frame/flux_{a}"][...]))
    vol = grains * 4 / 3 * np.pi * 1e-3 ** 3
    for k in range(db.n_frames):
        P, a = db.shift(k)
        assert np.allclose(np.asarray(P.sum(0)).ravel(), 1.0, rtol=0, atol=1e-12)
        assert a.sum() == pytest.approx(vol, rel=1e-12)  # every grain counted, none lost
        # the operator carries the start boundary's grain volume onto the end boundary's (stored as float32)
        assert np.abs(P @ a - db.solid[db.b1[k]]).max() <= 1e-6 * a.max()
        assert np.abs(a - db.solid[db.b0[k]]).max() <= 1e-6 * a.max()
    assert np.allclose(db.tagged.sum(1), db.tagged[0].sum(), rtol=1e-6)  # the real tracer is the same grains
    # frames over 4 recorded ones, from each grain's cell at their ends: the same consistency
    lagged = load(recorded, lag=4)
    assert lagged.n_frames == 21 and np.all(lagged.b1 == lagged.b0 + 4)
    assert np.all(lagged.successor()[:17] == np.arange(4, 21))
    for k in range(lagged.n_frames):
        P, a = lagged.shift(k)
        assert np.allclose(np.asarray(P.sum(0)).ravel(), 1.0, rtol=0, atol=1e-12)
        assert np.abs(P @ a - db.solid[lagged.b1[k]]).max() <= 1e-6 * a.max()
    assert np.all((db.eps > 0) & (db.eps <= 1))


def test_analyze_and_reproducible_paths(recorded):
    r = fbed("rcfd", "analyze", recorded)
    assert r.returncode == 0, r.stderr[-3000:]
    res = json.loads((recorded / "rcfd" / "rcfd.json").read_text())
    assert np.isfinite(res["period_mid_bed_eps"]) and res["period_mid_bed_eps"] > 0
    # the frame-mean fluxes (summed on the device with the solver's own face gas fraction) close each bed cell's
    # gas balance with the recorded eps: a gas tracer on them leaves its bounds by at most this (see below)
    assert res["continuity_residual"] <= 1e-4
    for name in ("recurrence.png", "spectrum.png"):
        assert (recorded / "rcfd" / name).stat().st_size > 1000
    runs = []
    for name in ("a", "b"):
        r = fbed("rcfd", "run", recorded, "--horizon", "0.5", "--paths", "3", "--seed", "3", "--name", name, "--gas")
        assert r.returncode == 0, r.stderr[-3000:]
        runs.append(recorded / "rcfd" / name)
    # run b reuses the matched jumps run a stored (RUN_DIR/rcfd/matchings.h5): the same mixing to the last digit
    assert (runs[0] / "path.csv").read_text() == (runs[1] / "path.csv").read_text()
    assert (runs[0] / "mixing.csv").read_text() == (runs[1] / "mixing.csv").read_text()
    s = json.loads((runs[0] / "summary.json").read_text())
    s_b = json.loads((runs[1] / "summary.json").read_text())
    assert s["jump"] == "match" and s["matchings"]["stored"] == s["matchings"]["used"] >= 1
    assert s_b["matchings"]["loaded"] >= s["matchings"]["used"] and s_b["matchings"]["stored"] == 0
    r = fbed("rcfd", "run", recorded, "--horizon", "0.5", "--paths", "3", "--seed", "3", "--name", "st", "--jump",
             "stitch")
    assert r.returncode == 0, r.stderr[-3000:]
    st = json.loads((recorded / "rcfd" / "st" / "summary.json").read_text())
    assert st["jump"] == "stitch" and "matchings" not in st and st["tracer_drift_max"] <= 1e-12
    assert (recorded / "rcfd" / "st" / "path.csv").read_text() == (runs[0] / "path.csv").read_text()  # same paths
    for name in ("fl", "fl2"):  # the flow matching: the same paths, stored beside the dense ones and reused
        r = fbed("rcfd", "run", recorded, "--horizon", "0.5", "--paths", "3", "--seed", "3", "--name", name,
                 "--jump", "flow", *(["--workers", "1"] if name == "fl2" else []))  # fl: one process per core
        assert r.returncode == 0, r.stderr[-3000:]
    fl, fl2 = (json.loads((recorded / "rcfd" / n / "summary.json").read_text()) for n in ("fl", "fl2"))
    assert fl["jump"] == "flow" and fl["matchings"]["stored"] == fl["matchings"]["used"] >= 1
    assert fl2["matchings"]["loaded"] == fl["matchings"]["used"] and fl2["matchings"]["stored"] == 0
    assert fl["tracer_drift_max"] <= 1e-12 and 0.0 <= fl["concentration_min"] <= fl["concentration_max"] <= 1.0
    for f in ("path.csv", "mixing.csv"):  # the paths moved in forked processes as one by one, to the last digit
        assert (recorded / "rcfd" / "fl" / f).read_text() == (recorded / "rcfd" / "fl2" / f).read_text()
    assert (recorded / "rcfd" / "fl" / "path.csv").read_text() == (runs[0] / "path.csv").read_text()
    assert s["tracer_drift_max"] <= 1e-12
    assert 0.0 <= s["concentration_min"] and s["concentration_max"] <= 1.0
    M = np.loadtxt(runs[0] / "mixing.csv", delimiter=",", skiprows=1)
    assert M[0, -2] == pytest.approx(0.0, abs=1e-12)  # x < 0 tagged on a cell boundary: segregated at the tag
    assert 0.0 < M[-1, -2] <= 1.0
    assert s["cost"]["marginal_speedup"] > 0 and s["jumps_per_path"] >= 1
    assert (runs[0] / "recurrence_path.png").exists() and (runs[0] / "mixing.png").exists()
    g = s["gas_tracer"]  # on the recorded fluxes: the balance closes; c exceeds 1 only by the continuity residual
    assert g["balance_error_max"] <= 1e-9 and g["c_min"] >= 0 and g["c_max"] <= 1 + 1e-4
    assert g["scheme"] == "fct"  # the default
    # the distribution over injection times: at frames 0, 12, 24, 36, 48 of each path's 100, windows of 50 frames
    inj = g["injected"]
    assert inj["injections"] == 15 and inj["window"] == pytest.approx(0.25)
    rows = np.loadtxt(runs[0] / "rtd_injected.csv", delimiter=",", skiprows=1)
    assert rows.shape == (51, 3) and rows[0, 1] == 0.0 and rows[:, 1].min() >= 0 and rows[:, 1].max() <= 1 + 1e-4
    # the mean residence time is the region's gas volume over the flow whenever it is injected, as far as that volume
    # holds still (measured: 0.04439 s injected along the paths against 0.04438 s from their starts)
    assert inj["mean_residence_time"] == pytest.approx(g["mean_residence_time"], rel=1e-2)
    r = fbed("rcfd", "run", recorded, "--horizon", "0.005", "--paths", "1", "--name", "one", "--gas")  # one frame
    assert r.returncode == 0, r.stderr[-3000:]  # its injection window was 0 frames: a TypeError
    one = json.loads((recorded / "rcfd" / "one" / "summary.json").read_text())
    assert one["gas_tracer"]["injected"]["injections"] == 1


def test_every_file_of_a_recording_run_is_one_fbed_knows_as_its_own(recorded):
    """rcfd.h5 and the rCFD analyses' folder are a run's outputs (app.outputs.RUN_OUTPUTS): a folder holding them
    holds a run, and --overwrite removes them before the new run writes, so no stale frames or analysis are left
    beside it."""
    from app.outputs import run_outputs

    assert sorted(recorded.iterdir()) == sorted(run_outputs(recorded))


def test_bad_input_exits_2(recorded, tmp_path):
    r = fbed("rcfd", "analyze", tmp_path)
    assert r.returncode == 2 and "no rcfd.h5" in r.stderr and "Traceback" not in r.stderr
    r = fbed("rcfd", "run", recorded, "--tag", "x<<0")
    assert r.returncode == 2 and "--tag" in r.stderr and "Traceback" not in r.stderr
    r = fbed("run", ROOT / "presets" / "rcfd_small.toml", "--set", 'probes.rcfd_tag="q<1"', "--out", tmp_path / "o")
    assert r.returncode == 2 and "probes.rcfd_tag" in r.stderr and "Traceback" not in r.stderr


def test_a_negative_seed_or_lag_and_a_horizon_beyond_memory_are_refused_naming_the_flag(recorded, tmp_path):
    """--seed -5 was refused as an error of the run's rcfd.h5 ("RUN_DIR: expected non-negative integer", numpy's
    words); --lag -3 ran as if 1; --horizon 1e12 (2e14 frames of 5 ms) ended in a numpy traceback allocating the
    path. Each now names its flag (exit 2), before any output folder is made; the horizon with the frames and the
    memory they need against what is available. --lag 30 on 24 recorded frames said numpy's "need at least one array
    to concatenate"; --name ../../x wrote the path's files two folders above RUN_DIR/rcfd; a --tag that tags none
    or all of the grains gave indices of NaN on every path."""
    for args, said in ((["--seed", "-5"], "--seed: --seed must be 0 or more"),
                       (["--lag", "-3"], "--lag: --lag must be at least 1"),
                       (["--lag", "30"], "--lag: --lag 30 leaves 0 frames of 30 recorded frames from the 24"),
                       (["--name", "../../x"], "--name: --name must be one folder name"),
                       (["--tag", "z>100"], "--tag: --tag 'z>100' tags none of the grains at t = 0.4 s"),
                       (["--tag", "x<=1e9"], "--tag: --tag 'x<=1e9' tags all of the grains"),
                       (["--horizon", "1e12"], "--horizon: --horizon 1e+12 s is 200,000,000,000,000 frames of 0.005 s"),
                       (["--gas-scheme", "upwind"], "--gas-scheme: --gas-scheme chooses the gas tracer's scheme, and "
                                                    "--gas is not given")):
        r = fbed("rcfd", "run", recorded, "--horizon", "0.05", "--paths", "1", *args, "--out", tmp_path / "o")
        assert r.returncode == 2 and said in r.stderr and "Traceback" not in r.stderr, r.stderr[-2000:]
        assert not (tmp_path / "o").exists()
    # validate: --paths 0, --continuations 0 and --lag 1000 ran the database and the continuations (minutes on a
    # GPU-sized preset), then stopped in a traceback; t0 < 0 was blamed on --t1
    for args, said in ((["--seed", "-1"], "--seed: --seed must be 0 or more"),
                       (["--paths", "0"], "--paths: --paths must be at least 1"),
                       (["--continuations", "0"], "--continuations: --continuations must be at least 1"),
                       (["--lag", "19"], "--lag: --lag 19 leaves 2 frames of the 20"),
                       (["--t0", "-1"], "--t0: need 0 <= t0 < t1 < t2")):
        r = fbed("rcfd", "validate", ROOT / "presets" / "rcfd_small.toml", "--t0", "0.3", "--t1", "0.4", "--t2", "0.5",
                 *args, "--out", tmp_path / "v")
        assert r.returncode == 2 and said in r.stderr and "Traceback" not in r.stderr, r.stderr[-2000:]
        assert not (tmp_path / "v").exists()


def test_validate_refuses_a_database_window_too_short_before_any_run(tmp_path):
    """rcfd validate records its database over t0..t1: a window of fewer than the 3 frames the analysis needs was
    found only after run A had run (a ValueError traceback); now it is refused first, naming --t1 (exit 2)."""
    r = fbed("rcfd", "validate", ROOT / "presets" / "rcfd_small.toml", "--t0", "0.5", "--t1", "0.51", "--t2", "0.6",
             "--out", tmp_path / "v")
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr[-3000:]
    assert "--t1" in r.stderr and "holds 2 frames" in r.stderr and "at least 3" in r.stderr, r.stderr
    assert not (tmp_path / "v").exists()


def test_a_bad_jump_names_the_option_and_its_choices(tmp_path):
    r = fbed("rcfd", "run", tmp_path, "--jump", "swap")
    assert r.returncode == 2 and "--jump" in r.stderr and "'match'" in r.stderr and "'stitch'" in r.stderr
    assert "'flow'" in r.stderr and "Traceback" not in r.stderr
    assert "--jump {match,flow,stitch}" in fbed("rcfd", "--help").stdout


@pytest.mark.restart
@pytest.mark.parametrize("stop", [0.34, 0.343])
def test_a_resumed_run_records_the_same_frames(recorded, tmp_path, stop):
    """Stopped at 0.34 s (a frame boundary) or 0.343 s (three fluid steps into a frame), with its checkpoint, and
    resumed to 0.40 s, the recording equals the straight run's: the frame open at the checkpoint goes on from the
    checkpoint's part (its start cells, flux sums and the time scale's sums), no gap, same shifts, same fluxes,
    same frame check. (Before the part was saved, the mid-frame resume lost that frame: 23 frames, not 24, and a
    Taylor time from the 12 samples after the resume.)"""
    out = tmp_path / "resumed"
    common = ("--set", "probes.rcfd_from=0.28", "--set", "particles.count=1500", "--arch", "cpu")
    r = fbed("run", ROOT / "presets" / "rcfd_small.toml", "--set", f"run.duration={stop}", *common, "--out", out)
    assert r.returncode == 0, r.stderr[-3000:]
    r = fbed("run", "--resume", out, "--set", "run.duration=0.40", "--arch", "cpu")
    assert r.returncode == 0, r.stderr[-3000:]
    with h5py.File(recorded / "rcfd.h5") as a, h5py.File(out / "rcfd.h5") as b:
        assert np.array_equal(a["frame/b0"][...], b["frame/b0"][...])
        assert np.array_equal(a["frame/b1"][...], b["frame/b1"][...])
        assert np.allclose(a["boundary/time"][...], b["boundary/time"][...])
        for name in ("frame/offset", "shift/c0", "shift/c1", "boundary/cells", "boundary/octant"):
            assert np.array_equal(a[name][...], b[name][...]), name
        assert np.allclose(a["shift/w"][...], b["shift/w"][...], rtol=1e-12)
        assert np.allclose(a["boundary/eps"][...], b["boundary/eps"][...], atol=1e-6)
        for k in "xyz":  # the frame's mean flux [m^3/s] against its largest: a lost step would be 1 part in 5
            fa, fb = a[f"frame/flux_{k}"][...], b[f"frame/flux_{k}"][...]
            assert fa.shape == fb.shape and np.abs(fa - fb).max() <= 1e-5 * np.abs(fa).max(), k
        assert a.attrs["taylor_samples"] == b.attrs["taylor_samples"]
        assert a.attrs["taylor_time"] == pytest.approx(b.attrs["taylor_time"], rel=1e-5)


def test_above_the_dense_matchings_reach_the_grains_are_routed_along_a_flow(recorded, monkeypatch):
    """'auto' pairs a database's grains by the dense assignment up to engine.MATCH_MAX_GRAINS and along a flow
    above (it stitched there before, mixing faster: validation/rcfd/README.md, 0000a), on half cells while they are
    few enough; a database without grain cells has only the stitch."""
    from app.rcfd import engine
    from app.rcfd.database import load

    db = load(recorded, 1)
    first = engine.Engine(db)
    assert first.jump == "match" and first.half and first.matcher.graph is None
    monkeypatch.setattr(engine, "MATCH_MAX_GRAINS", db.cells.shape[1] - 1)
    e = engine.Engine(db, first.st)
    assert e.jump == "flow" and e.half and e.matcher.graph.n == int(np.prod(db.fine_shape))
    monkeypatch.setattr(engine, "FLOW_HALF_MAX_CELLS", db.n_cells)
    assert not engine.Engine(db, first.st).half  # a large grid: on the cells
    assert engine.Engine(db, first.st, solids="cells").jump == "stitch"


def test_the_sensitivity_check_reruns_the_paths_with_frames_doubled_and_sequences_halved(recorded, tmp_path):
    """`fbed rcfd validate --sensitivity`'s part after the full runs: each variant's paths are built as named
    (a frame spanning two recorded frames; half the mean sequence) and checked against the full runs' curves
    on both indices (here two made-up full curves: the plumbing, not rCFD's accuracy, is tested)."""
    from app.rcfd import commands
    from app.rcfd.database import load
    from app.rcfd.validate import sensitivity_checks

    t = np.linspace(0.0, 0.3, 61)
    conts = [{"t": t, "M": 1 - np.exp(-t / tau), "L": 1 - np.exp(-t / tau)} for tau in (0.10, 0.12)]
    eng = commands.Engine(load(recorded, 1))
    checks = sensitivity_checks(recorded, tmp_path, conts, 0.3, 3, 3, 1, eng, "auto", "auto", log=lambda *a: None)
    names = {f"sensitivity_{v}_{c}" for v in ("frames_doubled", "sequences_halved")
             for c in ("mean_mixing_index", "t50", "t90", "mean_lacey_index", "t50_lacey", "t90_lacey")}
    assert set(checks) == names
    assert all(isinstance(c["pass"], bool) for c in checks.values())
    assert "lag 2" in checks["sensitivity_frames_doubled_t50"]["tests"]
    half = f"mean sequence {max(eng.params.l_min + 1, eng.params.l_mean // 2)} frames"
    assert half in checks["sensitivity_sequences_halved_t50"]["tests"]
    doubled = np.loadtxt(tmp_path / "rcfd_paths_frames_doubled" / "mixing.csv", delimiter=",", skiprows=1)
    halved = np.loadtxt(tmp_path / "rcfd_paths_sequences_halved" / "mixing.csv", delimiter=",", skiprows=1)
    assert np.diff(doubled[:, 0])[0] == pytest.approx(2 * np.diff(halved[:, 0])[0])  # 10 ms frames against 5 ms


def test_a_full_disk_while_analyze_writes_is_a_clean_error_that_leaves_no_half_file(recorded, tmp_path, monkeypatch,
                                                                                   capsys):
    """rCFD's JSON outputs are written as every fbed file is (app.io.store.write_text: whole or not at all), and the
    CLI turns the full disk into exit 3 with the file named, no traceback. Injected: the store's write finds ENOSPC."""
    from app.cli import main as cli_main
    from app.io import store

    def full(path, text):
        raise store.DiskFull(path, len(text.encode()), 0)

    monkeypatch.setattr(store, "write_text", full)
    out = tmp_path / "analysis"
    assert cli_main(["rcfd", "analyze", str(recorded), "--out", str(out)]) == 3
    err = capsys.readouterr().err
    assert "the disk is full: writing rcfd.json" in err and "Traceback" not in err
    assert not (out / "rcfd.json").exists()


def test_a_full_disk_in_a_figure_is_a_clean_error_naming_it(recorded, tmp_path, monkeypatch, capsys):
    """A write outside the store's guards (matplotlib's savefig here) that finds the disk full: exit 3 with the file
    named, no traceback (app.cli turns an OSError meaning ENOSPC into that; any other OSError is raised as before)."""
    import errno

    import matplotlib.figure

    from app.cli import main as cli_main

    def full(self, path, *args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device", str(path))

    monkeypatch.setattr(matplotlib.figure.Figure, "savefig", full)
    assert cli_main(["rcfd", "analyze", str(recorded), "--out", str(tmp_path / "a")]) == 3
    err = capsys.readouterr().err
    assert "the disk is full: writing recurrence.png" in err and "Traceback" not in err

    def denied(self, path, *args, **kwargs):
        raise PermissionError(errno.EACCES, "Permission denied", str(path))

    monkeypatch.setattr(matplotlib.figure.Figure, "savefig", denied)
    with pytest.raises(PermissionError):
        cli_main(["rcfd", "analyze", str(recorded), "--out", str(tmp_path / "b")])


@pytest.mark.restart
@pytest.mark.parametrize("key, value", [("rcfd_interval", "0.01"), ("rcfd_tag", "'y<0'"), ("rcfd_fluxes", "false")])
def test_a_resume_that_changes_the_recording_is_refused_and_loses_nothing(recorded, tmp_path, key, value):
    """rcfd.h5 holds frames of one kind (its attributes say which): a resume with another probes.rcfd_interval appended
    10 ms frames to a file of 5 ms ones, silently. It is refused before anything is written, naming the key, the
    file and both values (exit 2, no traceback), with the ways on."""
    import hashlib
    import shutil

    d = tmp_path / "bed"
    shutil.copytree(recorded, d, ignore=shutil.ignore_patterns("rcfd"))
    before = {p.name: hashlib.sha1(p.read_bytes()).hexdigest() for p in d.iterdir() if p.is_file()}
    r = fbed("run", "--resume", d, "--set", "run.duration=0.45", "--set", f"probes.{key}={value}", "--arch", "cpu")
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr[-3000:]
    assert f"rcfd.h5: probes.{key}:" in r.stderr and "in the recording this run appends to" in r.stderr, r.stderr
    assert "move rcfd.h5 aside" in r.stderr and "probes.rcfd_from = -1" in r.stderr, r.stderr
    assert {p.name: hashlib.sha1(p.read_bytes()).hexdigest() for p in d.iterdir() if p.is_file()} == before


@pytest.mark.restart
def test_a_damaged_rcfd_h5_is_refused_at_resume_and_left_as_it_was(recorded, tmp_path):
    """A process killed while it wrote can leave rcfd.h5 unreadable: a resume refuses it before anything is written,
    names it and says what moving it aside costs (exit 2, no traceback), as for run.h5 and checkpoint.h5."""
    import hashlib
    import shutil

    d = tmp_path / "bed"
    shutil.copytree(recorded, d, ignore=shutil.ignore_patterns("rcfd"))
    (d / "rcfd.h5").write_bytes((d / "rcfd.h5").read_bytes()[:4000])  # cut short
    before = {p.name: hashlib.sha1(p.read_bytes()).hexdigest() for p in d.iterdir() if p.is_file()}
    r = fbed("run", "--resume", d, "--set", "run.duration=0.45", "--arch", "cpu")
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr[-3000:]
    assert "rcfd.h5 is damaged" in r.stderr and "--resume" in r.stderr and "start anew" in r.stderr, r.stderr
    assert {p.name: hashlib.sha1(p.read_bytes()).hexdigest() for p in d.iterdir() if p.is_file()} == before

