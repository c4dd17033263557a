"""DEM throughput: particle-substeps per second, ms per substep and bytes per grain.

The scene is a bed in a cylinder: grains of 2 mm start on a touching cubic lattice (about
six contacts each, like a settled bed) and are compressed by gravity; Hertz-Mindlin with
tangential history, e = 0.9, mu = 0.5, E = 5 MPa, dt = 2 us. Timings are medians of
``--repeats`` blocks of ``--substeps`` after a warm-up of 200 substeps.

With ``--liggghts`` (CPU only) the same positions, contact law, step and substep count run
in LIGGGHTS 3.8 (``apt-get install liggghts``) on one core, and the ratio is reported;
fbed then runs on one thread too (``run.threads = 1``).

    python benchmarks/dem_throughput.py --arch cpu --sizes 10000 100000 --liggghts
    python benchmarks/dem_throughput.py --arch cuda --sizes 10000 100000 1000000

Appends a table to benchmarks/RESULTS.md (date, commit, machine, GPU).
"""
from __future__ import annotations

import argparse
import math
import pathlib
import statistics
import sys
import time

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks" / "liggghts"))

import numpy as np  # noqa: E402

from benchmarks_common import append_results, machine_line  # noqa: E402

D, RHO, E, NU, REST, MU, DT = 2e-3, 2500.0, 5e6, 0.3, 0.9, 0.5, 2e-6


def bed(n: int):
    from liggghts_pour import make_lattice

    pos, radius = make_lattice(n, diameter=D, spacing=1.0)
    return pos, radius


def fbed_scene(n: int, pos, radius, precision: str, threads: int, arch: str):
    from app.config import load_text
    from app.scene import Scene

    top = float(pos[:, 2].max()) + 4 * D
    text = f"""
[run]
duration = 1.0
precision = "{precision}"
threads = {threads}
[domain]
lo = [{-radius}, {-radius}, 0.0]
hi = [{radius}, {radius}, {top}]
[vessel]
shape = "cylinder"
radius = {radius}
[particles]
diameter = {D}
density = {RHO}
count = {n}
[contact]
model = "hertz_mindlin"
youngs_modulus = {E}
poisson_ratio = {NU}
restitution = {REST}
friction = {MU}
[dem]
dt = {DT}
"""
    zeros = np.zeros_like(pos)
    return Scene(load_text(text, "bench.toml"), "bench.toml",
                 initial={"position": pos, "velocity": zeros, "radius": np.full(n, D / 2)},
                 serial=arch == "cpu" and threads == 1)


def time_fbed(n, substeps, repeats, arch, precision, threads):
    import taichi as ti

    from app.sim.dem import DemSolver
    from app.sim.fields import bytes_per_grain

    pos, radius = bed(n)
    scene = fbed_scene(n, pos, radius, precision, threads, arch)
    dem = DemSolver(scene.model)
    dem.set_grains(pos, radius=np.full(n, D / 2))
    dem.advance(200)
    ti.sync()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        dem.advance(substeps)
        ti.sync()
        times.append(time.perf_counter() - t0)
    med = statistics.median(times)
    d = dem.diagnostics()
    assert d["grains_removed"] == 0 and d["non_finite"] == 0
    return {"ms_per_substep": 1e3 * med / substeps, "pss": n * substeps / med,
            "bytes": bytes_per_grain(scene.model, 4 if precision == "float32" else 8),
            "slots": scene.model.slots, "rebuilds": dem.nlist.builds, "pos": pos, "radius": radius}


def time_liggghts(pos, radius, substeps, repeats):
    from liggghts_pour import available, run_pour

    if not available():
        return None
    rates = []
    for _ in range(repeats):
        r = run_pour(pos, D, RHO, E, NU, REST, MU, radius, dt=DT, steps=substeps)
        rates.append(r["particle_steps_per_s"])
    return {"pss": statistics.median(rates), "version": r["version"]}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--arch", default="auto", choices=("auto", "cpu", "cuda"))
    ap.add_argument("--sizes", type=int, nargs="+", default=[10000, 100000])
    ap.add_argument("--substeps", type=int, default=1000)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--precision", default="float32", choices=("float32", "float64"))
    ap.add_argument("--threads", type=int, default=0, help="CPU threads (0: all; 1 with --liggghts)")
    ap.add_argument("--liggghts", action="store_true", help="also run LIGGGHTS 3.8 on one core (CPU)")
    ap.add_argument("--no-append", action="store_true", help="print only; do not append to RESULTS.md")
    a = ap.parse_args(argv)
    from app.sim import runtime

    threads = 1 if a.liggghts else a.threads
    arch = runtime.init(a.arch, a.precision, threads or None)
    rows = []
    for n in a.sizes:
        f = time_fbed(n, a.substeps, a.repeats, arch, a.precision, threads)
        row = {"N": n, "ms/substep": f"{f['ms_per_substep']:.3f}", "particle-substeps/s": f"{f['pss']:.3g}",
               "bytes/grain": f"{f['bytes']:.0f}", "slots": f["slots"]}
        if a.liggghts:
            lg = time_liggghts(f["pos"], f["radius"], a.substeps, a.repeats)
            row["LIGGGHTS particle-steps/s"] = f"{lg['pss']:.3g}" if lg else "not installed"
            row["fbed / LIGGGHTS"] = f"{f['pss'] / lg['pss']:.2f}" if lg else "-"
        rows.append(row)
        print(row, flush=True)
    title = (f"DEM throughput ({arch}, {a.precision}, threads {threads or 'all'}; Hertz-Mindlin + tangential "
             f"history, touching-lattice bed in a cylinder, dt = {DT:g} s, median of {a.repeats} x {a.substeps} "
             "substeps after 200 warm-up)")
    append_results(title, rows, arch, dry=a.no_append)


if __name__ == "__main__":
    main()
