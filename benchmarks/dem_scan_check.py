"""The DEM list build with the cell list's scan as one block of threads (CUDA's default, app/sim/dem/scan.py) against
the one-thread scan (``FBED_DEM_SCAN=serial``): the same lists, then what a build costs with each.

On CUDA the block scan's barrier path is checked at start-up on 40,000 counts (``scan.block_scan_works``; a
device that fails it falls back to the one-thread scan); here on the real lists too: run this first in a device call
(``device_run.sh dem_scan``; where the lists differ or the start-up check failed it exits 1, and the script's later
stages run with the one-thread scan). On the CPU both solvers use the CPU's layout unless ``--emulate`` (the block scan's shares on one thread), so
the check there only exercises the script.

1. Lists: both solvers from the same grains (the squeezed lattice of dem_substep.py, or its tri-disperse bed with
   ``--poly``), sorted by cell and built (``prepare``); every grain's neighbours, as a set of grain ids, equal. And the
   step's diagnostics record, whose 95% height bin the block of threads finds where the serial layout has one thread
   run through the bins (``step._record_block``): its counts and bed height equal, and the cost of one record each.
2. Cost: ``--substeps`` substeps with a build forced before each (the device flag set from the host) and as many
   without, interleaved in ``--repeats`` blocks per solver: ms per substep, and the build's share (their difference).
3. ``--profile``: Taichi's kernel profiler over forced-build substeps: each task's device time (the substep's tasks
   in order: the count, the scan, each block's cells, the scatter, the rows, the forces, the integration).

    python benchmarks/dem_scan_check.py --arch cuda --sizes 1000000 --profile
"""
from __future__ import annotations

import argparse
import dataclasses
import os
import pathlib
import statistics
import sys
import time

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

import numpy as np  # noqa: E402


def rows_by_id(dem) -> np.ndarray:
    """Every grain's neighbour ids, sorted, padded with -1, in grain-id order: (n, slots)."""
    ids = dem.fixed.grain_id.to_numpy() if dem.m.sorts else np.arange(dem.m.n)
    partner = dem.nlist.partner.to_numpy().T  # (n, slots) by memory slot
    count = dem.nlist.count.to_numpy()
    used = np.arange(partner.shape[1])[None, :] < count[:, None]
    named = np.where(used, ids[np.clip(partner, 0, None)], np.iinfo(np.int32).max)
    named.sort(axis=1)
    named[named == np.iinfo(np.int32).max] = -1
    out = np.empty_like(named)
    out[ids] = named
    return out


def solver(model, mode: str, emulate: bool):
    """A DemSolver whose scan is ``mode`` (FBED_DEM_SCAN, read when the solver is made); ``emulate`` on the CPU:
    the block scan's layout with one thread taking the shares."""
    from app.sim.dem import DemSolver, scan

    if emulate and mode == "block":
        model = dataclasses.replace(model, scan_block=scan.CUDA_BLOCK, scan_threads=scan.CUDA_THREADS,
                                    scan_emulate=True)
    os.environ["FBED_DEM_SCAN"] = mode
    try:
        return DemSolver(model)
    finally:
        del os.environ["FBED_DEM_SCAN"]


def forced(dem, substeps: int, build: bool) -> float:
    """Seconds per substep over ``substeps``, a build forced before each when ``build``."""
    import taichi as ti

    from app.sim.dem.neighbors import REBUILD

    ti.sync()
    t0 = time.perf_counter()
    for _ in range(substeps):
        if build:
            dem.nlist.counters[REBUILD] = 1
        dem.substep()
    ti.sync()
    return (time.perf_counter() - t0) / substeps


def record_cost(dem, repeats: int, calls: int = 20) -> float:
    """Seconds per ``record_diagnostics`` (the step's diagnostics record, written on the device), median of
    ``repeats`` blocks of ``calls``."""
    import taichi as ti

    ring = ti.ndarray(ti.f64, shape=(calls, len(dem.diag_columns)))
    dem.record_diagnostics(ring, 0)
    times = []
    for _ in range(repeats):
        ti.sync()
        t0 = time.perf_counter()
        for row in range(calls):
            dem.record_diagnostics(ring, row)
        ti.sync()
        times.append((time.perf_counter() - t0) / calls)
    return statistics.median(times)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--arch", default="cpu", choices=("cpu", "cuda"))
    ap.add_argument("--precision", default="float32", choices=("float32", "float64"))
    ap.add_argument("--sizes", type=int, nargs="+", default=[20000])
    ap.add_argument("--poly", action="store_true", help="the tri-disperse bed with rolling friction")
    ap.add_argument("--substeps", type=int, default=40, help="substeps per timed block")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--profile", action="store_true", help="each task's device time (Taichi's kernel profiler)")
    ap.add_argument("--emulate", action="store_true", help="CPU: the block scan emulated on one thread")
    a = ap.parse_args(argv)
    from dem_substep import scene_for

    from app.sim import runtime

    arch = runtime.init(a.arch, a.precision, None, kernel_profiler=a.profile)
    ok = True
    for n in a.sizes:
        scene, pos, r = scene_for(n, a.poly, a.precision, 0, arch)
        model = dataclasses.replace(scene.model, serial=False)
        dems = {mode: solver(model, mode, a.emulate) for mode in ("serial", "block")}
        for dem in dems.values():
            dem.set_grains(pos, radius=r)
            dem.prepare()
        layouts = {m: (d.m.scan_block, d.m.scan_threads) for m, d in dems.items()}
        same = np.array_equal(rows_by_id(dems["serial"]), rows_by_id(dems["block"]))
        ok &= bool(same)
        if arch == "cuda" and dems["block"].m.scan_threads == 0:  # scan.layout fell back: its start-up check failed
            print(f"N={n} the block scan failed its start-up check (app/sim/dem/scan.py: block_scan_works)", flush=True)
            ok = False
        print(f"N={n} lists {'equal' if same else 'DIFFER'}: scan layouts (cells a block, threads) {layouts}",
              flush=True)
        rec = {m: dem.diagnostics() for m, dem in dems.items()}
        keys = ("grains_alive", "contacts", "non_finite", "grains_removed", "bed_height")
        same_record = all(rec["serial"][k] == rec["block"][k] for k in keys)
        ok &= same_record
        print(f"N={n} diagnostics record (the 95% height bin by one thread / by the block) "
              f"{'equal' if same_record else 'DIFFER'}: " + ", ".join(f"{k} {rec['serial'][k]} / {rec['block'][k]}"
                                                                    for k in keys), flush=True)
        cost = {m: record_cost(dem, a.repeats) for m, dem in dems.items()}
        print(f"N={n} diagnostics record, ms per call (median): " + ", ".join(f"{m} {1e3 * c:.4f}"
                                                                          for m, c in cost.items()), flush=True)
        for dem in dems.values():
            forced(dem, 5, True)  # compile and warm both paths
            forced(dem, 5, False)
        t = {(m, b): [] for m in dems for b in (True, False)}
        for _ in range(a.repeats):
            for m, dem in dems.items():
                for b in (True, False):
                    t[(m, b)].append(forced(dem, a.substeps, b))
        for m in dems:
            built, plain = (1e3 * statistics.median(t[(m, b)]) for b in (True, False))
            print(f"N={n} scan={m} {layouts[m]}: ms/substep with a build {built:.4f}, without {plain:.4f}, "
                  f"the build {built - plain:.4f}", flush=True)
        if a.profile:
            for m, dem in dems.items():
                runtime.clear_profile()
                forced(dem, a.substeps, True)
                per: dict[str, float] = {}
                for name, x in runtime.profiled_times():
                    per[name] = per.get(name, 0.0) + x
                print(f"N={n} scan={m}: device time per forced-build substep, by task (us):", flush=True)
                for name, x in per.items():
                    print(f"  {name:55s} {1e6 * x / a.substeps:9.1f}", flush=True)
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
