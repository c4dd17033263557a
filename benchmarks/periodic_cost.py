"""What periodic faces cost when they are on: the same DEM bed in a box with side walls and in a box periodic in x
and y, substeps interleaved in ONE process (their ratio is robust on a loaded CPU; a scene without periodic faces
compiles none of the periodic code, which benchmarks/dem_ab.py checks against an older tree).

Bed: grains of 2 mm on a cubic lattice squeezed to a pitch of 0.997 d (jittered by 0.1% d) filling a square box
(side a whole number of pitches, so the lattice continues across a periodic face: every grain has the same
neighbours in both boxes, and the walled box's outer grains touch its walls instead), a floor below, gravity,
Hertz-Mindlin with friction 0.5, E = 5 MPa, dt = 2 us. Prints and appends the medians of ``--blocks`` alternated
blocks of ``--substeps`` substeps (CPU time per substep, one thread) and their ratio, with the touching pairs.

    python3 benchmarks/periodic_cost.py --n 50000 --precision float32
"""
from __future__ import annotations

import argparse
import pathlib
import statistics
import sys
import time

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

D, PITCH = 2e-3, 0.997


def bed(n: int):
    """Lattice positions [m], the box's half side [m] and its height [m]."""
    side = max(3, int(round((n / 2) ** (1 / 3))))  # a box twice as tall as wide
    layers = int(np.ceil(n / side ** 2))
    g = np.stack(np.meshgrid(np.arange(side), np.arange(side), np.arange(layers), indexing="ij"), -1).reshape(-1, 3)[:n]
    s = PITCH * D
    pos = (g + 0.5) * s
    half = 0.5 * side * s
    pos[:, :2] -= half
    pos += np.random.default_rng(0).uniform(-1e-3, 1e-3, pos.shape) * D
    return pos, half, layers * s + 4 * D


def solver(n: int, periodic: bool, precision: str):
    from app.config import load_text
    from app.scene import Scene, place_grains
    from app.sim.dem import DemSolver

    pos, half, top = bed(n)
    faces = "".join(f'"{a}{s}" = {{ kind = "periodic" }}\n' for a in "xy" for s in "-+") if periodic else ""
    text = f"""
[run]
duration = 1.0
precision = "{precision}"
[domain]
lo = [{-half}, {-half}, 0.0]
hi = [{half}, {half}, {top}]
[vessel]
shape = "box"
[particles]
diameter = {D}
density = 2500.0
count = {n}
[contact]
model = "hertz_mindlin"
youngs_modulus = 5.0e6
restitution = 0.9
friction = 0.5
[dem]
dt = 2.0e-6
""" + (f"[boundary]\n{faces}" if periodic else "")
    scene = Scene(load_text(text, "periodic_cost.toml"), "periodic_cost.toml", serial=True,
                  initial={"position": pos, "radius": np.full(n, D / 2)})
    dem = DemSolver(scene.model)
    place_grains(dem, scene.initial)
    return dem


def main(argv=None) -> int:
    from app.bench.common import append_results
    from app.sim import runtime

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, nargs="+", default=[50000])
    ap.add_argument("--precision", default="float32", choices=("float32", "float64"))
    ap.add_argument("--blocks", type=int, default=9)
    ap.add_argument("--substeps", type=int, default=100)
    ap.add_argument("--warmup", type=int, default=200)
    ap.add_argument("--no-append", action="store_true")
    a = ap.parse_args(argv)
    arch = runtime.init("cpu", a.precision, 1)
    rows = []
    for n in a.n:
        walled, wrapped = solver(n, False, a.precision), solver(n, True, a.precision)
        assert wrapped.m.periodic == (True, True, False) and not walled.m.wraps
        for dem in (walled, wrapped):
            dem.advance(a.warmup)
        times = {"walled": [], "periodic": []}
        for b in range(a.blocks):
            order = (("walled", walled), ("periodic", wrapped)) if b % 2 == 0 else (("periodic", wrapped),
                                                                                     ("walled", walled))
            for name, dem in order:
                t = time.process_time()
                dem.advance(a.substeps)
                times[name].append((time.process_time() - t) / a.substeps * 1e3)
        ratios = [w / p for w, p in zip(times["walled"], times["periodic"])]
        med = statistics.median
        rows.append({"N": n, "walled cpu ms/substep": f"{med(times['walled']):.3f}",
                     "periodic cpu ms/substep": f"{med(times['periodic']):.3f}",
                     "walled / periodic (median of pairs, min-max)":
                     f"{med(ratios):.3f} ({min(ratios):.2f}-{max(ratios):.2f})",
                     "touching pairs walled / periodic": f"{walled.diagnostics()['contacts']} / "
                                                          f"{wrapped.diagnostics()['contacts']}"})
        print(rows[-1], flush=True)
    title = (f"Periodic faces on: the same lattice bed walled and periodic in x, y (cpu, {a.precision}, one thread; "
             f"{a.blocks} alternated blocks of {a.substeps} substeps after {a.warmup})")
    append_results(title, rows, arch, dry=a.no_append)
    return 0


if __name__ == "__main__":
    sys.exit(main())
