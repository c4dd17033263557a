"""The DEM's hot loop: the substeps of a fluid step are only queued; the host reads the device once per
``advance``, whatever the number of substeps and rebuilds inside it."""
import dataclasses
import importlib

import numpy as np
import pytest

from app.sim.dem import DemSolver
from dem_helpers import make
from test_dem_sort import scrambled_bed

pytestmark = pytest.mark.verification

FIELD = importlib.import_module("taichi.lang.field")
MATRIX = importlib.import_module("taichi.lang.matrix")
READS = [(cls, name) for cls in (FIELD.ScalarField, MATRIX.MatrixField) for name in ("__getitem__", "to_numpy")]


@pytest.fixture
def host_reads(monkeypatch):
    """A test double on every way a field's values come back to the host: counts the calls."""
    calls = []
    for cls, name in READS:
        original = getattr(cls, name)

        def counted(self, *a, _original=original, _name=name, **k):
            calls.append(_name)
            return _original(self, *a, **k)

        monkeypatch.setattr(cls, name, counted)
    return calls


def falling_bed():
    """300 grains poured into a box: they move more than skin/2 within a few substeps, so the list
    rebuilds inside the loop."""
    rng = np.random.default_rng(3)
    side = 7
    grid = np.stack(np.meshgrid(*[np.arange(side)] * 3, indexing="ij"), -1).reshape(-1, 3)[:300]
    pos = (grid - side / 2) * 2.4e-3 + rng.uniform(-1e-4, 1e-4, (300, 3))
    vel = rng.normal(0.0, 0.5, (300, 3))
    return make(positions=pos, velocities=vel, domain={"gravity": [0.0, 0.0, -9.81]}, particles={"count": 300},
                vessel={"shape": "box"}, contact={"friction": 0.4, "rolling_friction": 0.05,
                                                 "rolling_model": "epsd"})


def test_substep_loop_makes_no_host_read_and_advance_reads_once(host_reads):
    scene, dem = falling_bed()
    builds0 = dem.nlist.builds
    host_reads.clear()
    for _ in range(150):
        dem.substep()
    assert host_reads == []  # 150 substeps queued, not one value read back
    dem.check()  # the once-per-fluid-step read of the counters
    assert len(host_reads) == 1
    host_reads.clear()
    dem.advance(150)
    assert len(host_reads) == 1
    assert dem.nlist.builds - builds0 >= 3  # the rebuilds were decided on the device, inside the loops
    d = dem.diagnostics()
    assert d["non_finite"] == 0 and d["grains_removed"] == 0 and d["contacts"] > 0


def test_device_rebuild_matches_a_rebuild_every_substep():
    """The device flag rebuilds whenever a grain moved skin/2: forcing a rebuild before every substep
    (flag raised from the host) must give the same motion to rounding, springs included."""
    scene, dem = falling_bed()
    scene2, every = falling_bed()
    for _ in range(300):
        dem.substep()
        every.rebuild()
        every.substep()
    dem.check()
    every.check()
    assert every.nlist.builds > 2 * dem.nlist.builds  # the forced one really rebuilt more often
    a, b = dem.state_arrays(), every.state_arrays()
    scale = np.abs(a["velocity"]).max()
    assert np.abs(a["velocity"] - b["velocity"]).max() < 1e-9 * scale
    assert np.abs(a["omega"] - b["omega"]).max() < 1e-9 * np.abs(a["omega"]).max()


def test_contacts_count_every_touching_pair_once():
    scene, dem = falling_bed()
    dem.advance(200)
    a = dem.state_arrays()
    x, r = a["position"][a["alive"] == 1], a["radius"][a["alive"] == 1]
    d = np.linalg.norm(x[:, None] - x[None], axis=-1)
    touching = (d < r[:, None] + r[None]) & np.triu(np.ones_like(d, bool), 1)
    assert touching.sum() > 20 and dem.diagnostics()["contacts"] == touching.sum()



def test_one_thread_advance_in_one_launch_matches_substep_by_substep():
    """On one CPU thread ``advance`` runs all its substeps in one launch (one serial task); the same substeps
    launched one by one (``substep``) must give the same state bit for bit, through rebuilds, sorts by cell,
    springs (tangential and rolling) and wall contacts."""
    scene, pos, vel, radius = scrambled_bed(False)
    model = dataclasses.replace(scene.model, sort_interval=1, sort_min_grains=0)
    one, stepped = (DemSolver(dataclasses.replace(model, serial=True)) for _ in range(2))
    for dem in (one, stepped):
        dem.set_grains(pos, vel, radius)
    for _ in range(30):
        one.advance(10)
        stepped.advance(0)  # the sort when one is due (and a read of the counters)
        for _ in range(10):
            stepped.substep()
        stepped.check()
    assert one.nlist.builds >= 3 and one.nlist.builds == stepped.nlist.builds
    a, b = one.state_arrays(), stepped.state_arrays()
    assert one.substeps_done == stepped.substeps_done == 300
    assert np.abs(a["rolling"]).max() > 0 and np.abs(a["wall_tangential"]).max() > 0
    for key in a:
        assert np.array_equal(a[key], b[key]), key


@pytest.mark.parametrize("serial", [True, False])
def test_prepare_does_the_set_up_ahead_and_changes_nothing(serial):
    """``prepare`` (the sort and the list build a timed ``advance`` would start with, done ahead: the benchmark
    against LIGGGHTS leaves them out of the timing, as LIGGGHTS' own set-up is) must leave the substeps that
    follow as they were, bit for bit, and leave the next ``advance`` no build to do first."""
    scene, pos, vel, radius = scrambled_bed(False)
    model = dataclasses.replace(scene.model, sort_interval=1, sort_min_grains=0, serial=serial)
    ahead, plain = DemSolver(model), DemSolver(model)
    for dem in (ahead, plain):
        dem.set_grains(pos, vel, radius)
    ahead.prepare()
    assert ahead.nlist.builds == plain.nlist.builds + 1 and not ahead._sort_due
    for dem in (ahead, plain):
        dem.advance(40)
    assert ahead.nlist.builds == plain.nlist.builds
    a, b = ahead.state_arrays(), plain.state_arrays()
    assert np.abs(a["tangential"]).max() > 0
    for key in a:
        assert np.array_equal(a[key], b[key]), key


def _packed_bed(poly: bool):
    """scrambled_bed's 300 grains in a box just large enough for them (its cell list 3 cells a grain, so a
    build's counts are zeroed by the substep's loop over grains: ``DemModel.bins_zeroed_after``)."""
    scene, pos, vel, radius = scrambled_bed(poly, half_width=0.0115)
    return scene.model, pos, vel, radius


@pytest.mark.parametrize("poly", [False, True])
def test_bins_zeroed_by_the_force_loop_give_the_same_substeps(poly):
    """Where a build leaves its cell counts for the substep's loop over grains to zero (no zeroing loop before the
    count: one launch a substep fewer on CUDA), every kernel must leave every count zero (else the next build counts
    on top of them; the last entry, the total, the scan overwrites) and the state must be the one the zeroing loop gives, bit for bit on one thread: through
    builds, sorts by cell and ``prepare``. The parallel form leaves the counts zero too (monodisperse)."""
    model, pos, vel, radius = _packed_bed(poly)
    model = dataclasses.replace(model, sort_interval=2, sort_min_grains=0, serial=True)
    assert model.bins_zeroed_after and model.n < model.n_cells  # more than one cell a grain: shares of several
    after, before = DemSolver(model), DemSolver(dataclasses.replace(model, zero_share=0))
    assert not before.m.bins_zeroed_after
    for dem in (after, before):
        dem.set_grains(pos, vel, radius)
        dem.prepare()
    assert not after.nlist.cell_start.to_numpy()[:-1].any() and not after.nlist.block_sum.to_numpy().any()
    for _ in range(20):
        for dem in (after, before):
            dem.advance(15)
        assert not after.nlist.cell_start.to_numpy()[:-1].any() and not after.nlist.block_sum.to_numpy().any()
    assert after.nlist.builds == before.nlist.builds >= 8
    a, b = after.state_arrays(), before.state_arrays()
    for key in a:
        assert np.array_equal(a[key], b[key]), key
    if poly:  # the parallel form's kernels compile once more (~10 s cold): the monodisperse bed checks them
        return
    parallel = DemSolver(dataclasses.replace(model, serial=False))
    parallel.set_grains(pos, vel, radius)
    for _ in range(10):
        parallel.advance(15)
        assert not parallel.nlist.cell_start.to_numpy()[:-1].any()
    assert parallel.nlist.builds >= 4
