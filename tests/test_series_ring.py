"""Restart tier: the series' rows are recorded on the device and read back in blocks (Simulation.record_diagnostics);
what reaches run.h5 is what a read every step gives, and a run checkpointed in the middle of a block and resumed
writes the same series as a straight run."""
import math
import os
import pathlib
import subprocess
import sys

import h5py
import numpy as np
import pytest

from app.callbacks.bed import BedMeasures
from app.callbacks.guard import Guard
from app.callbacks.writers import DEM_SERIES, GAS_SERIES, Series
from app.config import load
from app.scene import Scene, build_simulation

pytestmark = pytest.mark.restart

ROOT = pathlib.Path(__file__).resolve().parents[1]
FLUIDIZE = ROOT / "presets" / "fluidize.toml"
# 300 grains blown from the start (no settling stage), a series row every 1 ms step
SMALL = ["particles.count=300", "run.step=1e-3", "output.series_interval=1e-3", "boundary.bottom.start=0.0",
         "boundary.bottom.ramp=0.0"]


def fbed(*args):
    return subprocess.run([sys.executable, "-m", "app", *map(str, args)], capture_output=True, text=True, cwd=ROOT,
                          env=dict(os.environ, PYTHONPATH=str(ROOT)), timeout=600)


class Rows:
    """A run file that keeps its rows (what Series appends)."""

    def __init__(self):
        self.rows = []

    def append(self, row):
        self.rows.append(dict(row))


def test_buffered_series_rows_equal_the_per_step_values():
    """Rows read back in blocks of 4 steps equal the figures read directly after each step (the DEM's own
    diagnostics, the gas's extremes, the coupler's clipped cells, the bed's pressure drop): counts, maxima and
    time exactly; the sums (kinetic energy, end-layer pressures) to 1e-12, since they are reduced by float64
    atomics whose order may differ between two launches on several threads."""
    scene = Scene(load(FLUIDIZE, SMALL + ["run.duration=0.011"]), str(FLUIDIZE))
    sim = build_simulation(scene)
    sim.diag_rows = 4
    bed = BedMeasures(scene, sim.flow, sim.dem)
    rows, direct = Rows(), []
    Guard(max_overlap=0.5, max_speed=100.0).attach(sim, 5e-3)
    Series(rows, bed).attach(sim, 1e-3)

    def per_step(s):  # what a read after every step gives, through the solvers' own readers
        d = s.dem.diagnostics()
        d.update(time=s.time, gas_max_speed=s.flow.gas_extremes()[0], clipped_cells=s.coupler.clipped_cells,
                 pressure_drop=bed.pressure_drop(), gas_cfl=s.flow_info.cfl if s.flow_info else 0.0)
        direct.append(d)

    sim.add(per_step, 1e-3, at_start=True)
    sim.run()
    sim.flush_diagnostics()
    assert len(direct) == 12 and [r["time"] for r in rows.rows] == [d["time"] for d in direct]
    sums = ("kinetic_energy", "kinetic_energy_rotational", "pressure_drop")
    for r, d in zip(rows.rows, direct):
        for k in DEM_SERIES + GAS_SERIES:
            if k not in d:
                continue
            if k in sums:
                assert r[k] == pytest.approx(d[k], rel=1e-12, abs=1e-300), k
            elif isinstance(d[k], float) and math.isnan(d[k]):
                assert math.isnan(r[k]), k
            else:
                assert r[k] == d[k], (k, r["time"])
    assert max(r["kinetic_energy"] for r in rows.rows) > 0 and max(r["gas_max_speed"] for r in rows.rows) > 0


@pytest.mark.slow
def test_a_resume_from_the_middle_of_a_block_loses_no_row(tmp_path):
    """A run that ends at step 7 (its checkpoint in the middle of a 50-step block: no row read since step 0
    but at the guard's and the writers' steps) and is resumed to step 12 writes the straight run's series: the
    same steps, every column but the wall time equal to the bit (one thread, float64)."""
    args = [a for kv in SMALL + ["run.threads=1", "run.precision=float64"] for a in ("--set", kv)] + ["--arch", "cpu"]
    straight, split = tmp_path / "straight", tmp_path / "split"
    assert fbed("run", FLUIDIZE, *args, "--set", "run.duration=0.012", "--out", straight).returncode == 0
    r = fbed("run", FLUIDIZE, *args, "--set", "run.duration=0.007", "--out", split)
    assert r.returncode == 0, r.stderr
    r = fbed("run", "--resume", split, "--set", "run.duration=0.012")
    assert r.returncode == 0, r.stderr
    with h5py.File(straight / "run.h5") as a, h5py.File(split / "run.h5") as b:
        names = sorted(set(a["series"]) - {"wall_time"})
        assert names == sorted(set(b["series"]) - {"wall_time"}) and "pressure_drop" in names
        assert np.array_equal(a["series/time"][...], b["series/time"][...])
        assert len(a["series/time"]) == 13  # steps 0..12
        for n in names:
            assert np.array_equal(a["series"][n][...], b["series"][n][...], equal_nan=True), n


def test_a_bad_row_still_on_the_device_when_the_run_ends_stops_it():
    """Rows not yet read when the last step is done are read before the run ends, so the guard still stops it
    (3 steps, a block of 50: the speed limit of 1e-9 m/s is passed by the first step's falling grains)."""
    from app.sim.simulation import Unstable

    scene = Scene(load(FLUIDIZE, SMALL + ["run.duration=0.003"]), str(FLUIDIZE))
    sim = build_simulation(scene)
    Guard(max_overlap=0.5, max_speed=1e-9).attach(sim, 1e-3)
    with pytest.raises(Unstable, match=r"a grain moves at .* at t = 0.001 s"):
        sim.run()


def test_the_rows_the_guard_judges_do_not_depend_on_the_log_rate():
    """A headless log line read the current step's diagnostics as a row, and every row read reaches the guard: at a
    fast log rate the guard judged more rows, and a bed started at 20% overlap was stopped at 1 ms on the overlap
    instead of at 2 ms on its energy (the stress scene overlap_20pct, with output.log_interval 0.1 s or 5 s). A log
    line now reads the gas itself: with or without one every step, the guard sees the rows of its own schedule
    and the series', the same steps."""
    from app.callbacks.progress import Progress

    seen = {}
    for logged in (False, True):
        scene = Scene(load(FLUIDIZE, SMALL + ["run.duration=0.006", "output.series_interval=3e-3"]), str(FLUIDIZE))
        sim = build_simulation(scene)
        Guard(max_overlap=0.5, max_speed=100.0).attach(sim, 2e-3)
        Series(Rows(), None).attach(sim, 3e-3)
        steps = seen[logged] = []
        sim.diagnostics_sinks.append(lambda d, steps=steps: steps.append(d["step"]))
        if logged:
            progress = Progress(sim, "log", 0.1)
            progress.tty, progress.bar = False, None
            sim.add(progress, 1e-3)  # a log line after every step
        sim.run()
        sim.flush_diagnostics()
    assert seen[False] == [0, 2, 3, 4, 6]
    assert seen[True] == seen[False]


def test_only_the_guards_own_rows_move_its_energy_reference():
    """A row read off the guard's schedule (a checkpoint on the wall clock's) is checked against the reference but
    does not become it: otherwise where the reference sits, and so the verdict, would depend on the wall clock."""
    from app.sim.simulation import Unstable

    g = Guard(max_overlap=0.2, max_speed=100.0, max_energy_growth=100.0, energy_floor=1e-3, interval=2e-3)
    g._energy_check(1e-3, 0.0, own=True)
    g._energy_check(0.09, 3e-3, own=False)  # 90x: passes, an interval on, but not the guard's row
    with pytest.raises(Unstable, match="grew 500x in 0.004 s"):
        g._energy_check(0.5, 4e-3, own=True)  # 500x the reference at t = 0 (5.6x the wall-timed row's)
