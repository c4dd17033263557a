"""Coupled-step cost: ms per fluid step (coupling + gas + its DEM substeps) and the split.

The scene is a fluidized bed of 1 mm glass grains (2526 kg/m^3, E = 5 MPa, e = 0.86,
mu = 0.1) in a square column 32 gas cells across (cells of 3.125 mm, as Verma's grid),
blown at 1 m/s with Beetstra drag; the grain count sets the bed depth and the column
height. Grains start on a loose lattice and the timing starts after a warm-up of 20 fluid
steps of 0.4 ms; medians over --repeats steps.

    python benchmarks/coupled_step.py --arch cpu --sizes 20000
    python benchmarks/coupled_step.py --arch cuda --sizes 250000 1000000

Appends to benchmarks/RESULTS.md.
"""
from __future__ import annotations

import argparse
import statistics

from app.bench.common import append_results
from app.config import load_text
from app.scene import Scene, build_simulation
from app.sim import runtime

H, CELLS_ACROSS, D = 3.125e-3, 32, 1e-3


def scene_for(n: int, precision: str, threads: int):
    width = CELLS_ACROSS * H
    bed = n * (3.14159 / 6 * D ** 3) / 0.45 / (width * width)  # loose-lattice depth
    nz = int(max(32, 2 * round(1.6 * bed / H / 2)))
    text = f"""
[run]
duration = 1.0
step = 4.0e-4
precision = "{precision}"
threads = {threads}
[domain]
lo = [{-width / 2}, {-width / 2}, 0.0]
hi = [{width / 2}, {width / 2}, {nz * H}]
[vessel]
shape = "box"
[particles]
diameter = {D}
density = 2526.0
count = {n}
fill_spacing = 1.1
[contact]
youngs_modulus = 5.0e6
restitution = 0.86
friction = 0.1
[gas]
cell_size = {H}
pressure_form = "shared"
[coupling]
drag = "beetstra"
[boundary]
bottom = {{ kind = "velocity_inlet", velocity = [0.0, 0.0, 1.0] }}
top = "pressure_outlet"
"""
    # serial as `fbed run` decides it (app/run.py): on one CPU thread each solver's loops run as few tasks
    return Scene(load_text(text, "coupled_bench.toml"), "coupled_bench.toml", serial=runtime.serial())


def measure(n, repeats, precision, threads):
    sc = scene_for(n, precision, threads)
    sim = build_simulation(sc)
    for _ in range(20):
        sim.step()
    # each timed step through Simulation.step (the one coupling order), every phase synchronised at its end
    sim.timing, sim.timing_every = True, 1
    parts = {"coupling": [], "gas": [], "dem": []}
    for _ in range(repeats):
        sim.phase_seconds = {}
        sim.step()
        for name in parts:
            parts[name].append(sim.phase_seconds[name])
    med = {k: 1e3 * statistics.median(v) for k, v in parts.items()}
    total = sum(med.values())
    return {"N": n, "gas cells": "x".join(map(str, sc.flow.shape)), "substeps": sc.derived.substeps,
            "ms/step": f"{total:.1f}", "coupling ms": f"{med['coupling']:.2f}", "gas ms": f"{med['gas']:.1f}",
            "DEM ms": f"{med['dem']:.1f}", "coupling / DEM": f"{med['coupling'] / med['dem']:.3f}"}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--arch", default="auto", choices=("auto", "cpu", "cuda"))
    ap.add_argument("--sizes", type=int, nargs="+", default=[20000])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--precision", default="float32", choices=("float32", "float64"))
    ap.add_argument("--threads", type=int, default=0)
    ap.add_argument("--no-append", action="store_true")
    a = ap.parse_args(argv)
    arch = runtime.init(a.arch, a.precision, a.threads or None)
    rows = []
    for n in a.sizes:
        rows.append(measure(n, a.repeats, a.precision, a.threads))
        print(rows[-1], flush=True)
    append_results(f"Coupled step ({arch}, {a.precision}; Beetstra drag, 1 mm glass at 1 m/s, fluid step 0.4 ms, "
                   f"median of {a.repeats} steps after 20 warm-up)", rows, arch, dry=a.no_append)


if __name__ == "__main__":
    main()
