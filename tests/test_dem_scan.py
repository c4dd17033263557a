"""The cell list's scan (app/sim/dem/scan.py): the block scan CUDA runs (one block of threads at barriers), emulated on
the CPU (one thread taking the threads' shares in turn, what the barriers guarantee), gives the exact running sums,
and the DEM built on it the same substeps, bit for bit, as the one-thread scan."""
import dataclasses

import numpy as np
import pytest
import taichi as ti

from app.sim.dem import DemSolver
from app.sim.dem import scan
from test_dem_sort import scrambled_bed

pytestmark = pytest.mark.verification


@pytest.mark.parametrize("n", [1, 7, 64, 65, 1000])
@pytest.mark.parametrize("threads", [1, 3, 8, 512])
def test_block_scan_gives_the_exclusive_running_sums(n, threads):
    """Every split of the items into threads' chunks (fewer items than threads, a ragged last chunk, a thread
    count that is no power of two) against numpy's cumsum; the total returned."""
    values, tmp, total = ti.field(ti.i32, n), ti.field(ti.i32, 2 * threads), ti.field(ti.i32, ())

    @ti.kernel
    def k():
        ti.loop_config(serialize=True)
        for _ in range(1):
            total[None] = scan.exclusive_scan(0, values, n, tmp, threads, True, False)

    a = np.random.default_rng(n + 1000 * threads).integers(0, 40, n).astype(np.int32)
    values.from_numpy(a)
    tmp.fill(-7)  # whatever the buffers held before
    k()
    assert np.array_equal(values.to_numpy(), np.concatenate([[0], np.cumsum(a)[:-1]]))
    assert total[None] == a.sum()


def _rows_by_id(dem):
    """Each grain's neighbours as a set of grain ids, by grain id (memory order aside)."""
    ids = dem.fixed.grain_id.to_numpy() if dem.m.sorts else np.arange(dem.m.n)
    partner, count = dem.nlist.partner.to_numpy(), dem.nlist.count.to_numpy()
    rows = {}
    for p in range(dem.m.n):
        rows[int(ids[p])] = frozenset(int(ids[partner[k, p]]) for k in range(count[p]))
    return rows


@pytest.mark.parametrize("serial", [True, False])
def test_the_block_scan_builds_the_same_lists(serial):
    """The tri-disperse scrambled bed in a box it fills (512 cells, grains in most of them), rebuilding every few
    substeps and sorted by cell every other build, with its cells in blocks of 4 (128 blocks) scanned by 8 emulated
    threads (chunks of 16 blocks, every one holding grains) against the one-thread scan of 64-cell blocks (8): on one
    thread (``serial``) the state bit for bit through 300 substeps; in the parallel form (its own kernels, the scan's
    loops among the substep's) every row the same set of neighbours after each of 10 fluid steps (the order within
    a cell there follows the threads' atomics). And the diagnostics record, whose height bin the same block finds
    (:func:`_same_record`), every third step."""
    scene, pos, vel, radius = scrambled_bed(True, half_width=0.0115)
    plain = dataclasses.replace(scene.model, sort_interval=2, sort_min_grains=0, serial=serial, scan_block=64)
    block = dataclasses.replace(plain, scan_block=4, scan_threads=8, scan_emulate=True)
    assert block.scan_blocks == 128 and plain.scan_blocks == 8
    a, b = DemSolver(plain), DemSolver(block)
    assert a.m.scan_threads == 0 and b.m.scan_threads == 8  # (on the CPU the solver keeps the layout it is given)
    for dem in (a, b):
        dem.set_grains(pos, vel, radius)
    for step in range(10):
        for dem in (a, b):
            dem.advance(30)
        if not serial:
            assert _rows_by_id(a) == _rows_by_id(b)
        if step % 3 == 0:
            _same_record(a, b, serial)
    assert a.nlist.builds == b.nlist.builds >= 5
    if serial:
        sa, sb = a.state_arrays(), b.state_arrays()
        assert np.abs(sa["rolling"]).max() > 0
        for key in sa:
            assert np.array_equal(sa[key], sb[key]), key


def _same_record(a, b, serial):
    """The step's diagnostics record (``DemSolver.diagnostics``) of the one-thread scan's solver ``a`` and the block
    scan's ``b``. Its bed height comes from the first bin of a 1,024-bin height histogram where the running count
    reaches 95% of the grains: where the list's scan is a block of threads (CUDA; emulated in ``b``) the bins are
    scanned by that block and each thread tests its own bins, else one thread runs through them. In this bed (300
    grains, about one a bin in its top layers) the 95% target, 285 grains exactly, is met in the bin of the 285th grain
    from below, and a search that stopped a bin late would differ. On one thread every figure the same; in the
    parallel form the integer counts and the bed height (from integer bins; the float sums follow the threads)."""
    da, db = a.diagnostics(), b.diagnostics()
    z = np.sort(a.read("position")[:, 2])
    assert da["grains_alive"] == 300 and abs(da["bed_height"] - z[284]) <= (a.m.hi[2] - a.m.lo[2]) / 1024
    for key in da if serial else ("grains_alive", "grains_removed", "non_finite", "contacts", "bed_height"):
        assert da[key] == db[key], key


def test_the_scan_layout_follows_the_device(monkeypatch):
    """CUDA's layout (small blocks, a block of threads) only on CUDA and in the parallel form, once the block scan
    has passed its start-up check there; where the check fails, the one-thread scan with a warning;
    FBED_DEM_SCAN=serial keeps the one-thread scan; a wrong value is named."""
    scene, *_ = scrambled_bed(False)
    model = dataclasses.replace(scene.model, serial=False)
    monkeypatch.setattr(scan, "block_scan_works", lambda threads: True)  # (the barrier path needs CUDA)
    assert scan.layout(model, cuda=False) is model
    assert scan.layout(dataclasses.replace(model, serial=True), cuda=True).scan_threads == 0
    on = scan.layout(model, cuda=True)
    assert (on.scan_block, on.scan_threads, on.scan_emulate) == (scan.CUDA_BLOCK, scan.CUDA_THREADS, False)
    monkeypatch.setattr(scan, "block_scan_works", lambda threads: False)
    with pytest.warns(RuntimeWarning, match="start-up check"):
        failed = scan.layout(model, cuda=True)
    assert (failed.scan_block, failed.scan_threads) == (scan.CPU_BLOCK, 0)
    monkeypatch.setenv("FBED_DEM_SCAN", "serial")
    off = scan.layout(model, cuda=True)
    assert (off.scan_block, off.scan_threads) == (scan.CPU_BLOCK, 0)
    monkeypatch.setenv("FBED_DEM_SCAN", "blocks")
    with pytest.raises(Exception, match="FBED_DEM_SCAN"):
        scan.layout(model, cuda=True)


def test_the_start_up_check_passes_a_right_scan_and_fails_a_wrong_one(monkeypatch):
    """``block_scan_works`` (run once per process on CUDA before a DEM takes the block scan), here on the emulated
    shares: true for the scan as it is; false for one whose first entry is off by one."""
    assert scan.block_scan_works(512, emulate=True)
    right = scan.exclusive_scan

    @ti.func
    def off_by_one(t, values: ti.template(), n: ti.template(), tmp: ti.template(), nt: ti.template(),
                   emulate: ti.template(), barrier: ti.template()):
        total = right(t, values, n, tmp, nt, emulate, barrier)
        values[0] += 1
        return total

    monkeypatch.setattr(scan, "exclusive_scan", off_by_one)  # (a new item count: the check's kernel compiles anew)
    assert not scan.block_scan_works(512, emulate=True, n=4321)
