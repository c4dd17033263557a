"""CLI tier: bad presets fail clearly; runs stop, checkpoint and resume exactly; presets run.

Runs go through `python -m app` in fresh processes, as a user would run them; the preset smoke runs call the
same entry point (app.cli.main) in-process.
"""
import json
import os
import pathlib
import subprocess
import sys

import h5py
import numpy as np
import pytest

from app.cli import main as cli_main

pytestmark = pytest.mark.smoke

ROOT = pathlib.Path(__file__).resolve().parents[1]
PRESETS = sorted((ROOT / "presets").rglob("*.toml"))


def fbed(*args, cwd=None, timeout=600):
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    return subprocess.run([sys.executable, "-m", "app", *map(str, args)], capture_output=True, text=True,
                          cwd=cwd or ROOT, env=env, timeout=timeout)


GOOD = (ROOT / "presets" / "settle.toml").read_text()

BAD = {
    "unknown_key": (GOOD.replace("density = 2500.0", "densty = 2500.0"), ["particles.densty", "did you mean 'density'"]),
    "wrong_type": (GOOD.replace("count = 2500", 'count = "many"'), ["particles.count", "integer"]),
    "out_of_range": (GOOD.replace("restitution = 0.9", "restitution = 1.5"), ["contact.restitution", "<= 1"]),
    "unphysical_geometry": (GOOD.replace("radius = 0.015", "radius = 0.5"), ["vessel.radius", "does not fit"]),
    "malformed_toml": (GOOD.replace("[vessel]", "[vessel"), ["not valid TOML"]),
    "unknown_section": (GOOD + "\n[partcles]\ncount = 3\n", ["[partcles]", "did you mean [particles]"]),
    "unstable_step": (GOOD + "\n[dem]\ndt = 1e-4\n", ["dem.dt", "stable limit"]),
    "too_many_grains": (GOOD.replace("count = 2500", "count = 900000"), ["particles.count", "fit in the vessel"]),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_preset_clear_message_exit_2(case, tmp_path):
    text, needles = BAD[case]
    preset = tmp_path / "bad.toml"
    preset.write_text(text)
    r = fbed("run", preset, "--out", tmp_path / "out", "--arch", "cpu")
    assert r.returncode == 2, r.stderr
    assert "Traceback" not in r.stderr
    for needle in needles:
        assert needle in r.stderr, r.stderr
    assert str(preset) in r.stderr or "bad.toml" in r.stderr
    assert not (tmp_path / "out" / "run.h5").exists()


@pytest.mark.parametrize("argv, said", [
    (["rcfd", "validate", "p.toml", "--t0", "0.3", "--t1", "0.4", "--t2", "0.5", "--horizon", "5"],
     "--horizon: --horizon is for fbed rcfd run, not validate"),
    (["rcfd", "analyze", "d", "--paths", "3"], "--paths: --paths is for fbed rcfd run and validate, not analyze"),
    (["rcfd", "run", "d", "--t0", "1"], "--t0: --t0 is for fbed rcfd validate, not run"),
    (["rcfd", "run", "d", "--set", "run.duration=1"], "--set: --set is for fbed rcfd validate, not run"),
    (["rcfd", "analyze", "d", "--arch", "cpu"], "--arch: --arch is for fbed rcfd validate, not analyze"),
    (["rcfd", "analyze", "d", "--gas-scheme", "upwind"], "--gas-scheme: --gas-scheme is for fbed rcfd run, not analyze"),
    (["rcfd", "validate", "p.toml", "--t0", "0.3", "--t1", "0.4", "--t2", "0.5", "--workers", "2"],
     "--workers: --workers is for fbed rcfd run, not validate"),
    (["rcfd", "run", "d", "--horizon", "1", "--workers", "0"], "--workers: --workers must be at least 1, got 0"),
    (["bench", "stress", "--cases", "x"], "--cases: --cases is for fbed bench accuracy, not stress"),
    (["bench", "accuracy", "--scenes", "x"], "--scenes: --scenes is for fbed bench stress, not accuracy"),
    (["bench", "stress", "--resume"], "--resume: --resume is for fbed bench accuracy and stiffness, not stress"),
    (["bench", "stiffness", "--limit", "5"], "--limit: --limit is for fbed bench stress, not stiffness"),
    (["bench", "stress", "--limit", "-1"], "--limit: --limit must be a positive time in s, got -1")])
def test_a_flag_the_action_does_not_read_is_refused(argv, said, tmp_path, capsys):
    """`fbed rcfd validate ... --horizon 5` ran its paths over t2 - t1, `rcfd run --set` and `analyze --paths` did
    nothing; `fbed bench stress --cases x` ran every scene and --limit -1 called each one hung: each without a word.
    Now exit 2 naming the flag (and the actions that read it), before any file is written."""
    argv = [str(tmp_path / a) if a in ("d", "p.toml") else a for a in argv]
    assert cli_main([*argv, *(["--out", str(tmp_path / "o")] if argv[0] == "bench" else [])]) == 2
    err = capsys.readouterr().err
    assert said in err and "Traceback" not in err, err
    assert list(tmp_path.iterdir()) == []


@pytest.mark.skipif(__import__("app.sim.runtime", fromlist=["gpu_available"]).gpu_available(),
                    reason="this machine has a CUDA driver: --arch cuda would run there")
def test_cuda_asked_for_without_a_gpu_is_an_error_not_a_cpu_run_labelled_cuda(tmp_path):
    """Taichi falls back to the CPU when CUDA is missing; a run would then step on the CPU while its log and
    summary.json said cuda (and a benchmark would record CPU timings as the GPU's). It stops instead, names the
    flag and the way out, and writes nothing."""
    r = fbed("run", ROOT / "presets" / "settle.toml", "--arch", "cuda", "--set", "run.duration=0.001",
             "--out", tmp_path / "o")
    assert r.returncode == 2, r.stderr
    assert "--arch" in r.stderr and "no usable CUDA device" in r.stderr and "--arch cpu" in r.stderr
    assert "Traceback" not in r.stderr
    assert not (tmp_path / "o").exists()


def test_auto_takes_the_cpu_where_a_cuda_driver_has_no_usable_device():
    """``--arch auto`` tries CUDA where the driver library loads; where Taichi then finds no device it runs on the
    CPU (set up as the CPU, and said so), not an error: the probe is told here that a driver is present."""
    code = ("import app.sim.runtime as r; r.gpu_available = lambda: True; a = r.init('auto'); "
            "import taichi as ti; print(a, ti.lang.impl.current_cfg().arch.name)")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT,
                       env=dict(os.environ, PYTHONPATH=str(ROOT)), timeout=120)
    if "cuda cuda" in r.stdout:
        pytest.skip("this machine has a usable CUDA device")
    assert r.returncode == 0, r.stderr
    assert r.stdout.split()[-2:] == ["cpu", "x64"], r.stdout


def test_missing_preset_and_bad_override(tmp_path):
    r = fbed("run", ROOT / "presets" / "setle.toml")
    assert r.returncode == 2 and "no such preset" in r.stderr and "settle.toml" in r.stderr
    r = fbed("run", ROOT / "presets" / "settle.toml", "--set", "run.duraton=0.1", "--out", tmp_path / "o")
    assert r.returncode == 2 and "run.duraton" in r.stderr and "did you mean 'duration'" in r.stderr
    r = fbed("run", ROOT / "presets" / "settle.toml", "--set", "run.duration=-3", "--out", tmp_path / "o")
    assert r.returncode == 2 and "run.duration" in r.stderr and "Traceback" not in r.stderr


SMALL = ["--set", "particles.count=300", "--set", "run.threads=1", "--set", "run.precision=float64",
         "--set", "run.step=1e-3", "--set", "output.series_interval=1e-3", "--arch", "cpu"]


@pytest.mark.restart
def test_stop_and_resume_matches_a_straight_run(tmp_path):
    """Run 2N steps straight; run N, then resume to 2N in a fresh process: same grains (1e-6 relative)."""
    preset = ROOT / "presets" / "settle.toml"
    straight, split = tmp_path / "straight", tmp_path / "split"
    r = fbed("run", preset, *SMALL, "--set", "run.duration=0.04", "--out", straight)
    assert r.returncode == 0, r.stderr
    r = fbed("run", preset, *SMALL, "--set", "run.duration=0.02", "--out", split)
    assert r.returncode == 0, r.stderr
    # the checkpoint restored in a fresh process equals what was saved, every array included
    probe = (
        "import sys, numpy as np\n"
        "from app.sim import runtime; runtime.init('cpu', 'float64', 1)\n"
        "from app import config; from app.scene import Scene, build_simulation\n"
        "from app.io import store\n"
        f"a, meta = store.read_state(r'{split}/checkpoint.h5')\n"
        f"cfg = config.load(r'{split}/config.toml')\n"
        "dem = build_simulation(Scene(cfg, initial=a)).dem\n"
        "b = dem.state_arrays()\n"
        "assert set(a) == set(b), set(a) ^ set(b)\n"
        "bad = [k for k in a if not np.array_equal(a[k], b[k])]\n"
        "assert not bad, bad\n"
        "assert 'tangential' in a and np.abs(a['tangential']).max() > 0\n"
        "print('restored', len(a))\n")
    r = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, cwd=ROOT,
                       env=dict(os.environ, PYTHONPATH=str(ROOT)))
    assert r.returncode == 0 and "restored" in r.stdout, r.stderr
    r = fbed("run", "--resume", split, "--set", "run.duration=0.04")
    assert r.returncode == 0, r.stderr
    with h5py.File(straight / "checkpoint.h5") as a, h5py.File(split / "checkpoint.h5") as b:
        assert a.attrs["step"] == b.attrs["step"] == 40
        xa, xb = a["grains/position"][...], b["grains/position"][...]
    scale = np.abs(xa).max()
    assert np.abs(xa - xb).max() <= 1e-6 * scale
    sa = json.loads((straight / "summary.json").read_text())
    assert sa["status"] == "finished" and sa["grains_removed"] == 0
    with h5py.File(split / "run.h5") as f:  # series continue without duplicates after resume
        t = f["series/time"][...]
    assert np.all(np.diff(t) > 0) and t[-1] == pytest.approx(0.04)


@pytest.mark.restart
def test_sigterm_stops_cleanly_with_checkpoint(tmp_path):
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    out = tmp_path / "run"
    p = subprocess.Popen([sys.executable, "-m", "app", "run", ROOT / "presets" / "settle.toml", *SMALL,
                          "--set", "run.duration=100", "--out", out], stderr=subprocess.PIPE, text=True, env=env,
                         cwd=ROOT)
    import time

    deadline = time.time() + 120
    while time.time() < deadline and not (out / "run.h5").exists():
        time.sleep(0.5)
    time.sleep(3)
    p.terminate()
    _, err = p.communicate(timeout=120)
    assert p.returncode == 130, err
    assert "resume with: fbed run --resume" in err
    s = json.loads((out / "summary.json").read_text())
    assert s["status"] == "interrupted" and 0 < s["time"] < 100
    with h5py.File(out / "checkpoint.h5") as f:
        assert f.attrs["time"] == pytest.approx(s["time"])


@pytest.mark.parametrize("preset", PRESETS, ids=[p.stem for p in PRESETS])
def test_every_preset_runs_briefly(preset, tmp_path, capsys, session_runtime_after):
    """Smoke tier: each preset starts, steps and writes its outputs (float32, as on a GPU). In-process, through
    the CLI's own entry point (the other tests here run `python -m app` in fresh processes, as a user would):
    one Taichi start-up for all presets of a worker instead of one each. Two fluid steps of 0.05 ms (a twentieth of
    the presets' 1 ms: the million-grain beds' DEM substeps were most of this tier's time on the CPU, mri_poppy's
    39 s at 0.25 ms, 25 s at 0.05; 0.05 ms divides every output interval of the presets)."""
    # run.start_from is emptied: the smoke run starts from the preset's own fill, not a prepared stage
    rc = cli_main(["run", str(preset), "--set", "run.duration=1e-4", "--set", "run.step=5e-5", "--set",
                   'run.start_from=""', "--arch", "cpu", "--out", str(tmp_path / "o")])
    assert rc == 0, capsys.readouterr().err
    s = json.loads((tmp_path / "o" / "summary.json").read_text())
    assert s["status"] == "finished"
    with h5py.File(tmp_path / "o" / "run.h5") as f:
        names = [n for n in f["series"]]
        assert "time" in names
        for name in names:
            assert np.all(np.isfinite(f["series"][name][...])), name
        if "grains" in s:  # grains: their series and snapshots
            assert s["grains_alive"] > 0
            for name in ("kinetic_energy", "max_overlap", "grains_alive", "grains_removed", "bed_height"):
                assert name in names
            assert "0" in f["particles"] and f["particles/0/position"].shape[1] == 3
            assert (tmp_path / "o" / "bed.h5").exists()
        if "gas_cells" in s:  # gas: its series and field snapshots
            assert "pressure_iterations" in names and "gas_cfl" in names
            g = f["fields/0"]
            assert g["gas_velocity"].shape == tuple(s["gas_cells"]) + (3,)
            assert g["pressure"].shape == tuple(s["gas_cells"]) == g["void_fraction"].shape
    assert (tmp_path / "o" / "config.toml").exists()


def test_guard_stops_an_unstable_run_and_keeps_readable_outputs(tmp_path):
    """A DEM step forced to ~0.75 collision times blows up; the guard stops it within its interval."""
    out = tmp_path / "boom"
    r = fbed("run", ROOT / "presets" / "settle.toml", "--set", "dem.dt=8e-5", "--set", "dem.force_dt=true",
             "--set", "output.checkpoint_interval=0.01", "--set", "run.duration=1.0", "--arch", "cpu", "--out", out)
    assert r.returncode == 3, r.stderr
    assert "dem.dt" in r.stderr and "stable limit" in r.stderr and "Traceback" not in r.stderr
    s = json.loads((out / "summary.json").read_text())
    assert s["status"] == "unstable" and s["time"] < 0.2  # stopped early, not after the full second
    with h5py.File(out / "run.h5") as f:
        for name in f["series"]:
            assert np.all(np.isfinite(f["series"][name][...])), name
    # the guard reads its rows a few steps behind the run: the summary says when it went wrong, and the last good row
    assert s["last_good_time"] < s["unstable_at"] <= s["time"]
    assert f"at t = {s['unstable_at']:.6g} s" in s["message"]
    with h5py.File(out / "checkpoint.h5") as f:  # the last good checkpoint is finite and earlier
        t_good = f.attrs["time"]
        assert t_good <= s["last_good_time"]
        assert np.all(np.isfinite(f["grains/position"][...]))
    # the knob the guard names is turned, and the run goes on from that checkpoint (a resume refused dem.dt before:
    # the checkpoint it kept could not be used with the step it advised)
    assert f"fbed run --resume {out} --set KEY=VALUE" in r.stderr
    r = fbed("run", "--resume", out, "--set", "dem.dt=0", "--set", "dem.force_dt=false", "--set", "run.duration=0.06")
    assert r.returncode == 0, r.stderr
    s = json.loads((out / "summary.json").read_text())
    assert s["status"] == "finished" and s["time"] == pytest.approx(0.06)
    with h5py.File(out / "run.h5") as f:  # the series goes on from the checkpoint, the unstable rows cut off
        t = f["series/time"][...]
        assert np.all(np.diff(t) > 0) and np.isfinite(f["series/max_overlap"][...]).all()
        assert f["series/max_overlap"][...][t > t_good].max() < 0.2


INLETS = ("--set", 'boundary.bottom={kind="velocity_inlet",velocity=[0,0,1.1]}', "--set", "particles.count=300")


def test_inlets_that_do_not_balance_without_an_outlet_are_stopped_naming_the_outlet(tmp_path):
    """No pressure outlet, 1.1 m/s in at the bottom and 1.0 out at the top (9% of the flow with nowhere to go):
    the incompressible gas has no solution, yet the run went on ("done"): the divergence residual, a per-cell
    ratio, read 1e-4 for it. (0.5 out: the guard blamed the solver's iterations.) The guard now checks the inlets'
    net flow, from the first row (balanced inlets read 0: test_flow's inflow test)."""
    r = fbed("run", ROOT / "presets" / "fluidize.toml", *INLETS, "--set", "run.duration=0.003", "--set",
             'boundary.top={kind="velocity_inlet",velocity=[0,0,1.0]}', "--set", "guard.interval=0.001",
             "--arch", "cpu", "--out", tmp_path / "o")
    assert r.returncode == 3 and "Traceback" not in r.stderr, r.stderr[-2000:]
    assert "no face is a pressure_outlet" in r.stderr and "(4.76% of their flow)" in r.stderr, r.stderr[-2000:]
    s = json.loads((tmp_path / "o" / "summary.json").read_text())  # stopped before its first row: no traceback
    assert s["status"] == "unstable" and "mean_pressure_drop" not in s


def test_a_run_whose_end_state_fails_the_guard_ends_unstable(tmp_path):
    """With guard.interval 5 ms no guard row is due in a 3 ms run after the start's: the end state failed the guard
    (here a pressure solve starved of iterations, residual 0.1), its files were not written, and yet the run said
    "done" with exit 0 and status "finished". It now ends unstable (exit 3), naming the knob. (No log line either:
    one, due after a slow compile, reads a row that the guard sees.)"""
    r = fbed("run", ROOT / "presets" / "fluidize.toml", *INLETS, "--set", "run.duration=0.003", "--set",
             "gas.max_iterations=1", "--set", "output.log_interval=1000", "--arch", "cpu", "--out", tmp_path / "o")
    assert r.returncode == 3 and "raise gas.max_iterations" in r.stderr, r.stderr[-2000:]
    assert "the final state was not written" in r.stderr and "fbed: done" not in r.stderr, r.stderr[-2000:]
    assert json.loads((tmp_path / "o" / "summary.json").read_text())["status"] == "unstable"
    assert not (tmp_path / "o" / "bed.h5").exists()


def test_energy_growth_stops_a_blow_up_the_other_limits_were_raised_for(tmp_path):
    """With the overlap and speed limits out of the way, the same forced step is stopped by the kinetic energy's
    growth, at the same check (t = 0.042 s with the default limits too), and names the step."""
    out = tmp_path / "boom"
    r = fbed("run", ROOT / "presets" / "settle.toml", "--set", "dem.dt=8e-5", "--set", "dem.force_dt=true",
             "--set", "guard.max_overlap=50", "--set", "guard.max_speed=1e12", "--set", "run.duration=1.0",
             "--arch", "cpu", "--out", out)
    assert r.returncode == 3, r.stderr
    assert "guard.max_energy_growth" in r.stderr and "dem.dt" in r.stderr and "Traceback" not in r.stderr
    s = json.loads((out / "summary.json").read_text())
    assert s["status"] == "unstable" and s["time"] < 0.1
    with h5py.File(out / "run.h5") as f:
        energy = f["series/kinetic_energy"][...]
        # the series ends at the check before the blow-up (4e-4 J; the stopped state held 1.02 J): never written
        assert np.all(np.isfinite(energy)) and energy[-1] < 1e-2


def test_grains_pushed_through_the_floor_stop_the_run(tmp_path):
    """settle at domain.gravity = 1e6 m/s^2 (the DEM step cut to 0.8 us): its 300 grains went through the floor in
    the first 2 ms step, between two guard checks, were removed as if by an outlet, and the run said "done". The
    guard now reads the DEM's count of grains out through a wall: exit 3, its advice, the checkpoint kept."""
    out = tmp_path / "sunk"
    r = fbed("run", ROOT / "presets" / "settle.toml", "--set", "particles.count=300", "--set", "dem.dt=8e-7",
             "--set", "domain.gravity=[0, 0, -1e6]", "--set", "run.duration=0.01", "--arch", "cpu", "--out", out)
    assert r.returncode == 3 and "Traceback" not in r.stderr, r.stderr[-2000:]
    assert "300 grains passed through the vessel's walls" in r.stderr and "contacts are too soft" in r.stderr
    assert json.loads((out / "summary.json").read_text())["status"] == "unstable"


def test_sweep_runs_every_case_and_records_a_failed_one(tmp_path):
    """Two cases of the settle preset, one forced to a DEM step of ~13 stable limits (it blows up on the
    first contacts, t ~ 6 ms): the sweep finishes the
    other, writes both to sweep.csv (the failed one with its status and exit code) and the plot."""
    import csv

    out = tmp_path / "sw"
    r = subprocess.run([sys.executable, "-m", "app", "sweep", ROOT / "presets" / "settle.toml",
                        "--set", "dem.dt=0,2e-4", "--set", "dem.force_dt=true", "--set", "particles.count=300",
                        "--set", "run.duration=0.06", "--out", out, "--jobs", "2", "--plot", "kinetic_energy",
                        "--arch", "cpu"], capture_output=True, text=True, cwd=ROOT,
                       env=dict(os.environ, PYTHONPATH=str(ROOT)), timeout=600)
    assert r.returncode == 1, r.stderr  # one case failed
    rows = list(csv.DictReader(open(out / "sweep.csv")))
    assert [row["dem.dt"] for row in rows] == ["0", "2e-4"]
    assert rows[0]["status"] == "finished" and rows[0]["exit_code"] == "0"
    assert rows[1]["status"] == "unstable" and rows[1]["exit_code"] == "3"
    assert float(rows[0]["grains"]) == 300 and (out / "kinetic_energy.png").stat().st_size > 1000


def test_sweep_records_why_a_case_that_wrote_no_summary_failed(tmp_path):
    """A case refused as it starts (10^12 grains: the memory check needs the built scene, so the sweep's up-front
    load passes it) wrote only its log. Its status in sweep.csv was the log's last line, the error's hint
    ("failed:   hint: fewer grains ..."); it is now the error itself, and a log without one gives its last line."""
    from app.sweep import run_case

    row = run_case(str(ROOT / "presets" / "settle.toml"), ["particles.count"], ["1e12"], tmp_path / "case-000",
                   "cpu", 0)
    assert row["exit_code"] == 2 and not (tmp_path / "case-000" / "summary.json").exists()
    assert row["status"].startswith("failed: ") and "particles.count" in row["status"], row["status"]
    assert "grains need about" in row["status"] and "hint" not in row["status"], row["status"]
    from app.sweep import failure

    assert failure("Traceback (most recent call last):\n  ...\nMemoryError: out of memory\n") == \
        "MemoryError: out of memory"


def test_sweep_refuses_a_bad_value_before_running_anything(tmp_path):
    r = subprocess.run([sys.executable, "-m", "app", "sweep", ROOT / "presets" / "settle.toml",
                        "--set", "contact.restitution=0.5,1.5", "--out", tmp_path / "sw"],
                       capture_output=True, text=True, cwd=ROOT, env=dict(os.environ, PYTHONPATH=str(ROOT)))
    assert r.returncode == 2 and "contact.restitution" in r.stderr and "Traceback" not in r.stderr
    assert not (tmp_path / "sw" / "case-000").exists()


def test_sweep_refuses_fewer_than_one_job(tmp_path):
    """--jobs 0 or below was taken as one job without a word; now it is refused before anything runs."""
    for jobs in ("0", "-3"):
        r = fbed("sweep", ROOT / "presets" / "settle.toml", "--set", "particles.count=100,200", "--jobs", jobs,
                 "--out", tmp_path / "s")
        assert r.returncode == 2 and "--jobs must be at least 1" in r.stderr and "Traceback" not in r.stderr
        assert not (tmp_path / "s").exists()


def test_sweep_refuses_a_key_given_twice_and_a_value_given_twice(tmp_path):
    """`--set k=a,b --set k=c` made the cases (a, c) and (b, c), each applying k=c last: two runs of c, labelled a
    and b in sweep.csv. `--set k=a,a` ran the same run twice. Both are refused before anything runs (the cases are
    deterministic, so a repeat adds nothing; run.seed is the key to sweep for other fills). A key given twice with
    one value each is not a list: the later wins, as in `fbed run` (the device script relies on it)."""
    from app.config import ConfigError
    from app.sweep import cases

    assert cases(["particles.count=100,200", "run.seed=1,2"])[1] == [("100", "1"), ("100", "2"), ("200", "1"),
                                                                     ("200", "2")]
    # a fixed value given again (a script's default, then the user's): the later wins, as in `fbed run`
    assert cases(["run.duration=3.1", "particles.count=100,200", "run.duration=0.6"]) == \
        (["run.duration", "particles.count"], [("0.6", "100"), ("0.6", "200")])
    for sets, said in ((["particles.count=100,200", "particles.count=300"], "the key is given twice, with a list"),
                       (["particles.count=100,200,100"], "100 given twice")):
        with pytest.raises(ConfigError, match=said):
            cases(sets)
        r = fbed("sweep", ROOT / "presets" / "settle.toml", *[a for s in sets for a in ("--set", s)],
                 "--out", tmp_path / "s")
        assert r.returncode == 2 and said in r.stderr and "Traceback" not in r.stderr
        assert not (tmp_path / "s").exists()


def test_sweep_plot_draws_named_values_and_names_a_missing_figure(tmp_path):
    """--plot drew each case at x = float(value): a swept drag law (the MRI study's four laws) gave every point an
    x of NaN and an empty figure without a word; a figure no case has gave an empty figure too; a FIGURE with a
    path in it was written outside the sweep (DIR / '/x.png' is /x.png, with '.png' added) after every case ran,
    or failed with a traceback. Now named values are categories in the order given, a missing figure is an error
    naming the figures there, and a FIGURE that is not a name is refused before anything runs."""
    from app.config import ConfigError
    from app.sweep import plot, plotted

    laws = ["wen_yu", "gidaspow", "beetstra", "tang"]
    rows = [{"case": f"case-{i:03d}", "coupling.drag": law, "status": "finished", "exit_code": 0,
             "mean_pressure_drop": 100.0 + i} for i, law in enumerate(laws)]
    rows[2].update(status="unstable", exit_code=3)
    del rows[2]["mean_pressure_drop"]  # a failed case: left out
    series, categories = plotted(rows, "coupling.drag", "mean_pressure_drop")
    assert categories == laws and series == {None: ([0, 1, 3], [100.0, 101.0, 103.0])}
    plot(rows, "coupling.drag", "mean_pressure_drop", tmp_path / "p.png")
    assert (tmp_path / "p.png").stat().st_size > 1000
    # numbers (a vector by its magnitude) sorted along x, one series per value of the second key
    rows = [{"boundary.bottom.velocity": v, "particles.count": c, "kinetic_energy": e}
            for v, c, e in (("[0,0,0.8]", "1", 3.0), ("[0,0,0.6]", "1", 2.0), ("[0,0,0.6]", "2", 5.0))]
    series, categories = plotted(rows, "boundary.bottom.velocity", "kinetic_energy", group="particles.count")
    assert categories is None and series == {"1": ([0.6, 0.8], [2.0, 3.0]), "2": ([0.6], [5.0])}
    with pytest.raises(ConfigError, match="no case's summary.json has the figure 'kinetc_energy'") as err:
        plotted(rows, "boundary.bottom.velocity", "kinetc_energy")
    assert "kinetic_energy" in err.value.hint
    r = fbed("sweep", ROOT / "presets" / "settle.toml", "--set", "particles.count=100,200", "--plot", "/tmp/x.png",
             "--out", tmp_path / "s")
    assert r.returncode == 2 and "not a summary figure's name" in r.stderr and "Traceback" not in r.stderr
    assert not (tmp_path / "s").exists()


def test_a_sweeps_figure_is_drawn_again_from_its_table(tmp_path, capsys):
    """A misspelt `fbed sweep --plot` was found out after every case had run, and drawing another figure needed the
    cases run again. `fbed analyze SWEEP_DIR --plot FIGURE` draws it from sweep.csv (the swept keys: the columns
    between 'case' and 'status'); a figure no case has names the ones there are; a run folder is refused."""
    d = tmp_path / "sw"
    d.mkdir()
    (d / "sweep.csv").write_text("case,coupling.drag,gas.cell_size,status,exit_code,mean_pressure_drop\n"
                                 "case-000,wen_yu,0.005,finished,0,100.0\ncase-001,koch_hill,0.005,finished,0,110.0\n"
                                 "case-002,wen_yu,0.0025,unstable,3,\n")
    assert cli_main(["analyze", str(d), "--plot", "mean_pressure_drop"]) == 0
    assert (d / "mean_pressure_drop.png").stat().st_size > 1000
    from app.sweep import plotted

    rows = [dict(r) for r in __import__("csv").DictReader(open(d / "sweep.csv"))]
    series, categories = plotted(rows, "coupling.drag", "mean_pressure_drop", "gas.cell_size")
    assert categories == ["wen_yu", "koch_hill"] and series["0.005"] == ([0, 1], [100.0, 110.0])
    capsys.readouterr()
    assert cli_main(["analyze", str(d), "--plot", "mean_presure_drop"]) == 2
    err = capsys.readouterr().err
    assert "figures of these cases: mean_pressure_drop" in err and f"fbed analyze {d} --plot" in err, err
    (tmp_path / "run").mkdir()
    assert cli_main(["analyze", str(tmp_path / "run"), "--plot", "x"]) == 2
    assert "holds no sweep.csv" in capsys.readouterr().err


def test_a_sweep_goes_on_with_resume_keeping_what_finished(tmp_path, capsys):
    """A stopped sweep could only be run again from the start (`--overwrite`) or by hand, case by case. With
    `--resume` (the same --set lists, the same --out) the finished and unstable cases are kept, an interrupted
    case goes on from its checkpoint (its log shows a second start), one without a checkpoint runs anew."""
    import csv

    settle, out = str(ROOT / "presets" / "settle.toml"), tmp_path / "sw"
    sets = ["--set", "particles.count=100,150", "--set", "run.duration=0.004", "--arch", "cpu", "--out", str(out)]
    assert cli_main(["sweep", settle, *sets, "--jobs", "2"]) == 0
    rows = list(csv.DictReader(open(out / "sweep.csv")))
    rows[0].update(status="interrupted", exit_code="130")  # as a Ctrl-C leaves it (its checkpoint kept)
    rows[1].update(status="failed: killed", exit_code="-9")
    (out / "case-001" / "checkpoint.h5").unlink()  # killed before its first checkpoint
    with open(out / "sweep.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    capsys.readouterr()
    assert cli_main(["sweep", settle, *sets, "--resume"]) == 0
    err = capsys.readouterr().err
    assert "(2 left to run)" in err and "2 of 2 cases finished" in err, err
    assert [r["status"] for r in csv.DictReader(open(out / "sweep.csv"))] == ["finished", "finished"]
    log0, log1 = ((out / c / "log.txt").read_text() for c in ("case-000", "case-001"))
    assert log0.count("fbed: settle:") == 2 and log1.count("fbed: settle:") == 1  # went on; ran anew
    assert cli_main(["sweep", settle, *sets, "--resume"]) == 0  # nothing left: nothing runs
    assert "(0 left to run)" in capsys.readouterr().err
    for argv, said in ((["--set", "particles.count=100,200", *sets[2:], "--resume"], "the sweep there ran other cases"),
                       ([*sets, "--resume", "--overwrite"], "--overwrite would remove them")):
        assert cli_main(["sweep", settle, *argv]) == 2
        assert said in capsys.readouterr().err


def test_a_signal_stops_a_sweep_and_starts_no_other_case(tmp_path, monkeypatch, capsys):
    """Ctrl-C (or SIGTERM) on a sweep stopped the running cases, and then the queued ones started and ran to
    their ends. Now the signal is passed to the running cases, no case starts after it ("not started" in the
    table), and the sweep exits 130, saying how to go on."""
    import csv
    import signal
    import threading
    import time

    from app import sweep as sweep_mod

    started = []

    def fake_case(preset, keys, values, out, arch, threads, stop_with_parent=False, resume=False, live=None):
        started.append(out.name)
        if len(started) == 1:  # the signal comes while the first case runs
            threading.Timer(0.2, os.kill, (os.getpid(), signal.SIGTERM)).start()
        time.sleep(0.6)
        row = dict(zip(keys, values))
        row.update(case=out.name, exit_code=130, status="interrupted")
        return row

    monkeypatch.setattr(sweep_mod, "run_case", fake_case)
    before = signal.getsignal(signal.SIGTERM)
    rc = sweep_mod.sweep(str(ROOT / "presets" / "settle.toml"), ["particles.count=100,150,200"], jobs=1,
                         out=str(tmp_path / "sw"), arch="cpu")
    err = capsys.readouterr().err
    assert rc == 130 and started == ["case-000"], (rc, started)
    assert "SIGTERM: the running cases stop with a checkpoint" in err and "--resume" in err, err
    assert [r["status"] for r in csv.DictReader(open(tmp_path / "sw" / "sweep.csv"))] == \
        ["interrupted", "not started (the sweep was stopped)", "not started (the sweep was stopped)"]
    assert signal.getsignal(signal.SIGTERM) == before  # the sweep's handler is gone again


def test_a_signal_as_a_sweep_case_starts_reaches_that_case(tmp_path, monkeypatch, capsys):
    """A signal that came after the sweep had checked that it was not stopped, and before the case it then
    started was listed, reached no process: that case ran to its end. Here the signal comes while the process is
    being started (the handler called from inside Popen); the case must be passed it, and no other start."""
    import csv
    import signal
    import subprocess
    import threading

    from app import sweep as sweep_mod

    class Proc:  # a case process: ends at once when signalled (as a run stopping), else after 5 s (ran to its end)
        def __init__(self):
            self.signalled = threading.Event()

        def send_signal(self, signum):
            self.signalled.set()

        def wait(self):
            return 130 if self.signalled.wait(5.0) else 0

    started = []

    def popen(args, **kw):
        started.append(Proc())
        if len(started) == 1:
            signal.getsignal(signal.SIGTERM)(signal.SIGTERM, None)  # the signal, as the first process starts
        return started[-1]

    monkeypatch.setattr(subprocess, "Popen", popen)
    rc = sweep_mod.sweep(str(ROOT / "presets" / "settle.toml"), ["particles.count=100,150"], jobs=1,
                         out=str(tmp_path / "sw"), arch="cpu")
    assert len(started) == 1 and started[0].signalled.is_set(), "the case that started as the signal came ran on"
    assert rc == 130
    rows = list(csv.DictReader(open(tmp_path / "sw" / "sweep.csv")))
    assert [r["exit_code"] for r in rows] == ["130", "130"]
    # the first wrote nothing (a run signalled as it starts dies before it can): not a failure of its own
    assert [r["status"] for r in rows] == ["not finished (the sweep was stopped)", "not started (the sweep was stopped)"]


def test_a_case_on_a_cluster_stops_when_its_sweep_is_stopped(tmp_path, monkeypatch):
    """On a remote Dask cluster the workers live on after a sweep is stopped, and cancelling a running task does
    not end the `fbed run` it started: those runs ran on to their ends. A case now polls the sweep's stop event
    while its run goes, and passes the run SIGINT (it stops at its next step, with a checkpoint); a case whose
    task starts after the event was set starts nothing."""
    import threading
    import time

    from app import sweep_case

    proc = subprocess.Popen([sys.executable, "-c", "import signal, sys, time; signal.signal(signal.SIGINT, lambda *a: "
                             "sys.exit(130)); print('ready', flush=True); time.sleep(60)"],
                            stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout.readline().strip() == "ready"
        flag = []
        threading.Timer(0.3, flag.append, (1,)).start()  # the sweep stopped while the run goes
        t0 = time.time()
        assert sweep_case.wait(proc, lambda: bool(flag), poll=0.05) == 130
        assert time.time() - t0 < 20  # not the 60 s of its sleep
    finally:
        proc.kill()
        proc.wait()
    monkeypatch.setattr(sweep_case, "cluster_stopped", lambda name: (lambda: name == "stop-1"))
    row = sweep_case.run_case(str(ROOT / "presets" / "settle.toml"), ["particles.count"], ["100"],
                              tmp_path / "case-000", "cpu", 0, True, stop_event="stop-1")
    assert row["status"] == "not started (the sweep was stopped)" and not (tmp_path / "case-000").exists()


def test_a_second_sweep_does_not_write_over_the_first(tmp_path, monkeypatch):
    """Each case runs with --overwrite into case-NNN, so a second sweep into the first's folder (its default one
    included) replaced the first's cases and sweep.csv without a word. Now: the default folder is a new one
    (runs/<preset>-sweep-2 beside -sweep), a given folder holding a sweep is refused unless --overwrite (which
    removes the old cases first), and one holding a run is refused, all before anything runs."""
    import csv

    from app.sweep import sweep_folder

    monkeypatch.chdir(tmp_path)  # the default folders go under ./runs
    first = sweep_folder("presets/settle.toml", None, False)
    (first / "sweep.csv").write_text("case\n")
    assert first == pathlib.Path("runs/settle-sweep") and sweep_folder("presets/settle.toml", None, False) == \
        pathlib.Path("runs/settle-sweep-2")
    out = tmp_path / "sw"
    sw = lambda *a: fbed("sweep", ROOT / "presets" / "settle.toml", "--set", "run.duration=0.002,0.004",  # noqa
                         "--set", "particles.count=100", "--out", out, *a)
    assert sw().returncode == 0
    before = (out / "sweep.csv").read_text()
    r = fbed("sweep", ROOT / "presets" / "settle.toml", "--set", "run.duration=0.006", "--out", out)
    assert r.returncode == 2 and "already holds a sweep (sweep.csv, case-000, case-001)" in r.stderr
    assert "--overwrite" in r.stderr and (out / "sweep.csv").read_text() == before
    r = fbed("sweep", ROOT / "presets" / "settle.toml", "--set", "run.duration=0.006", "--out", out, "--overwrite")
    assert r.returncode == 0 and not (out / "case-001").exists()
    assert [row["run.duration"] for row in csv.DictReader(open(out / "sweep.csv"))] == ["0.006"]
    r = fbed("sweep", ROOT / "presets" / "settle.toml", "--set", "run.duration=0.006", "--out", out / "case-000")
    assert r.returncode == 2 and "holds a run" in r.stderr and "Traceback" not in r.stderr


def test_the_runs_end_reads_the_grains_once_for_its_checkpoint_and_bed(tmp_path, monkeypatch, session_runtime_after):
    """The final checkpoint and bed.h5 hold the same grains at the same step, and each read them from the DEM
    (DemSolver.state_arrays: every field copied to the host and put in id order; a million-grain run's end took
    20.7 s with two reads, 19.3 s with one, RESULTS.md).
    bed.h5 is now written from the checkpoint's arrays: one read, and bed.h5's grains are the checkpoint's."""
    from app.sim.dem.solver import DemSolver

    calls, real = [], DemSolver.state_arrays
    monkeypatch.setattr(DemSolver, "state_arrays", lambda self: calls.append(1) or real(self))
    out = tmp_path / "o"
    rc = cli_main(["run", str(ROOT / "presets" / "settle.toml"), "--set", "particles.count=300", "--set",
                   "run.duration=0.004", "--set", "run.precision=float64", "--arch", "cpu", "--out", str(out)])
    assert rc == 0 and len(calls) == 1, calls
    with h5py.File(out / "bed.h5") as bed, h5py.File(out / "checkpoint.h5") as ck:
        assert sorted(bed["grains"]) == sorted(ck["grains"]) and "position" in bed["grains"]
        for k in bed["grains"]:
            np.testing.assert_array_equal(bed["grains"][k][...], ck["grains"][k][...], err_msg=k)


def test_resume_refuses_out_and_overwrite_and_video_a_non_mp4(tmp_path, capsys):
    """`fbed run --resume A --out B` went on in A without a word (B never made), and `--resume A --overwrite`
    ignored --overwrite; `--video x.gif` was reported as `--set video.file=...`, a flag the user never typed.
    Each is refused before anything runs, naming the flag the user gave."""
    run = tmp_path / "run"
    run.mkdir()
    (run / "notes.txt").write_text("mine")
    for argv, said in ((["--resume", str(run), "--out", str(tmp_path / "branch")], "--out: a resumed run goes on"),
                       (["--resume", str(run), "--overwrite"], "--overwrite: a resumed run goes on"),
                       ([str(ROOT / "presets" / "settle.toml"), "--video", "x.gif", "--out", str(tmp_path / "v")],
                        "--video: 'x.gif' is not an .mp4 file's name")):
        assert cli_main(["run", *argv]) == 2
        err = capsys.readouterr().err
        assert said in err and "Traceback" not in err, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run"] and (run / "notes.txt").read_text() == "mine"
    assert "cp -r" in cli_err(["run", "--resume", str(run), "--out", str(tmp_path / "b")], capsys)


def test_a_video_named_outside_the_run_folder_is_not_written_over(tmp_path, capsys):
    """A video named outside the output folder (`--video ../v.mp4`, an absolute path) that already held a file was
    replaced by a new run without a word (--overwrite guards the folder only). A new folder's '../v.mp4' was also
    no path until the folder was made, so its checks passed whatever lay there. A sweep whose cases all write one
    video outside their folders kept the last case's only. Each is refused before anything runs."""
    settle = str(ROOT / "presets" / "settle.toml")
    old = tmp_path / "v.mp4"
    old.write_bytes(b"an earlier video")
    for video in ("../v.mp4", str(old)):
        assert cli_main(["run", settle, "--video", video, "--out", str(tmp_path / "new")]) == 2
        err = capsys.readouterr().err
        assert "video.file: already exists" in err and "--overwrite" in err and "Traceback" not in err, err
    for sets, said in ((["--set", "particles.count=100,200", "--set", f"video.file={tmp_path / 'w.mp4'}"],
                        "2 cases would write this one video"),
                       (["--set", "particles.count=100", "--set", "video.file=../../v.mp4"], "already exists")):
        assert cli_main(["sweep", settle, *sets, "--set", "video.enabled=true", "--out", str(tmp_path / "sw")]) == 2
        err = capsys.readouterr().err
        assert said in err and "video.file" in err and "Traceback" not in err, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["v.mp4"] and old.read_bytes() == b"an earlier video"


def test_a_record_interval_that_is_no_whole_number_of_steps_is_noted_as_recorded(tmp_path, capsys):
    """Records come every whole number of run.step: boyce's probes.slab_interval = 2.5 ms in 1 ms steps recorded
    the slab every 2 ms while its preset and notes said 2.5. Such an interval is now noted at the start with what
    it is taken as, which is what run.h5 holds; whole multiples give no note (boyce's is now 2 ms)."""
    out = tmp_path / "run"
    assert cli_main(["run", str(ROOT / "presets" / "settle.toml"), *SMALL, "--set", "run.duration=0.012",
                     "--set", "output.series_interval=0.0025", "--out", str(out)]) == 0  # 1 ms steps
    err = capsys.readouterr().err
    assert "output.series_interval = 0.0025 s is taken as 0.002 s (2 steps)" in err, err
    with h5py.File(out / "run.h5") as f:
        assert np.allclose(np.diff(f["series/time"][...]), 0.002)
    from app.callbacks.progress import odd_intervals
    from app.config import load

    assert [k for k, _, _ in odd_intervals(load(ROOT / "presets" / "boyce.toml", ["probes.slab_interval=2.5e-3"]))] \
        == ["probes.slab_interval"]
    assert all(odd_intervals(load(p)) == [] for p in PRESETS)


def cli_err(argv, capsys) -> str:
    cli_main(argv)
    return capsys.readouterr().err


def test_a_saved_bed_is_reused_by_a_later_run(tmp_path):
    """bed.h5 of one run is another run's particles.initial_state: same grains, same places."""
    first, second = tmp_path / "first", tmp_path / "second"
    r = fbed("run", ROOT / "presets" / "settle.toml", *SMALL, "--set", "run.duration=0.01", "--out", first)
    assert r.returncode == 0, r.stderr
    r = fbed("run", ROOT / "presets" / "settle.toml", *SMALL, "--set", "particles.count=0",
             "--set", f'particles.initial_state="{first / "bed.h5"}"', "--set", "run.duration=0.002",
             "--out", second)
    assert r.returncode == 0, r.stderr
    with h5py.File(first / "bed.h5") as a, h5py.File(second / "run.h5") as b:
        np.testing.assert_array_equal(b["particles/0/position"][...], a["grains/position"][...].astype(np.float32))
    r = fbed("run", ROOT / "presets" / "settle.toml", "--set", "particles.count=0",
             "--set", f'particles.initial_state="{first / "summary.json"}"', "--out", tmp_path / "bad")
    assert r.returncode == 2 and "particles.initial_state" in r.stderr and "Traceback" not in r.stderr
