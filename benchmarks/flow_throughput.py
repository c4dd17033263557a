"""Gas-solver throughput: milliseconds per fluid step and pressure iterations per step.

The scene is a fluidized-bed-like gas step: 6 mm cells, a cylindrical vessel (cut cells)
filling the box, a dense bed in the lower 40% (eps 0.45-0.50, beta 1.5e4-1.95e4
kg m^-3 s^-1, random per cell and drawn anew before every timed step with the matching
d(eps)/dt, as moving grains would give; ``--frozen`` keeps it fixed), 0.5 m/s superficial
inflow through the bottom, pressure
outlet on top, gravity, Model A ("shared") pressure, MacCormack convection, dt = 1e-3 s,
tolerance 1e-6. Timings are medians over ``--steps`` steps after ``--warmup`` steps (the
first of which compiles the kernels); every step ends in a host read, so it is timed whole.

    python benchmarks/flow_throughput.py --arch cpu --grids 32x32x64 32x32x116
    python benchmarks/flow_throughput.py --arch cuda --grids 32x32x64 32x32x116 64x64x128

Prints a table and appends it to benchmarks/RESULTS.md (date, commit, machine, arch, GPU).
"""
from __future__ import annotations

import argparse
import pathlib
import statistics
import sys
import time

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

import numpy as np  # noqa: E402

from app.bench.common import append_results  # noqa: E402

H, DT, U_IN = 0.006, 1e-3, 0.5


def scene(shape, precision_tol: float):
    from app.sim import gas
    from app.sim.geometry import CylinderWall

    nx, ny, nz = shape
    radius = (min(nx, ny) / 2 - 1) * H
    cyl = CylinderWall(center=(nx * H / 2, ny * H / 2), radius=radius)
    cfg = gas.FlowConfig(shape=shape, h=H, rho=1.2, mu=1.8e-5, gravity=(0.0, 0.0, -9.81), walls=(cyl,),
                          pressure_form="shared", convection="maccormack", tol=precision_tol,
                          min_open_fraction=0.0,  # the cut cells of every row before 2026-12-01 (then its default)
                          bcs={"bottom": gas.velocity_inlet((0.0, 0.0, U_IN)), "top": gas.pressure_outlet(0.0)})
    s = gas.FlowSolver(cfg)
    rng = np.random.default_rng(1)
    bed = np.zeros(shape, bool)
    bed[:, :, : int(0.4 * nz)] = True
    eps = np.ones(shape)
    beta = np.zeros(shape)
    eps[bed] = 0.45 + 0.05 * rng.random(bed.sum())
    beta[bed] = 1.5e4 * (1.0 + 0.3 * rng.random(bed.sum()))
    s.set_eps(eps)
    s.set_beta(beta)
    return s, bed, eps, rng


def shuffle_bed(s, bed, eps_old, rng):
    """New random eps/beta in the bed with the matching d(eps)/dt, as moving grains would give
    (set outside the timed region)."""
    eps = np.ones(bed.shape)
    beta = np.zeros(bed.shape)
    eps[bed] = 0.45 + 0.05 * rng.random(bed.sum())
    beta[bed] = 1.5e4 * (1.0 + 0.3 * rng.random(bed.sum()))
    s.set_eps(eps)
    s.set_beta(beta)
    s.set_deps_dt((eps - eps_old) / DT)
    return eps


def run(shape, steps: int, warmup: int, tol: float, moving: bool) -> dict:
    s, bed, eps, rng = scene(shape, tol)
    t0 = time.perf_counter()
    for _ in range(warmup):
        s.step(DT)
    warm = time.perf_counter() - t0
    times, iters, sweeps, cfl, conv = [], [], [], [], 0
    for _ in range(steps):
        if moving:
            eps = shuffle_bed(s, bed, eps, rng)
        t = time.perf_counter()
        info = s.step(DT)
        times.append(time.perf_counter() - t)
        iters.append(info.pressure_iterations)
        sweeps.append(info.viscous_sweeps)
        cfl.append(info.cfl)
        conv += int(info.converged)
    return {"grid": "x".join(map(str, shape)), "cells": int(np.prod(shape)),
            "ms/step": f"{1e3 * statistics.median(times):.1f}",
            "p-iters (median/max)": f"{statistics.median(iters):g}/{max(iters)}",
            "viscous sweeps": f"{statistics.median(sweeps):g}", "CFL": f"{max(cfl):.2f}",
            "converged": f"{conv}/{steps}", "MG levels": f"{s.mg.nlevels} (coarsest {'x'.join(map(str, s.mg.level_shapes[-1]))})",
            "warm-up s": f"{warm:.1f}"}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--arch", default="cpu", choices=("cpu", "cuda"))
    ap.add_argument("--precision", default="float32", choices=("float32", "float64"))
    ap.add_argument("--threads", type=int, default=None, help="CPU threads (default: all)")
    ap.add_argument("--grids", nargs="+", default=["32x32x64"], help="NXxNYxNZ, e.g. 32x32x64 32x32x116 64x64x128")
    ap.add_argument("--steps", type=int, default=10)
    ap.add_argument("--warmup", type=int, default=3)
    ap.add_argument("--tol", type=float, default=1e-6)
    ap.add_argument("--frozen", action="store_true", help="keep the bed fixed (default: new eps/beta every step)")
    ap.add_argument("--coarse-block", choices=("on", "off"), default="on",
                    help="off: a launch down and up per multigrid level, not the coarse levels in one launch "
                         "(app/sim/gas/coarse_cycle.py; the parallel form only), for an A/B")
    ap.add_argument("--dry", action="store_true", help="print only, do not append to RESULTS.md")
    args = ap.parse_args(argv)
    from app.sim import runtime
    from app.sim.gas import coarse_cycle

    if args.coarse_block == "off":
        coarse_cycle.MAX_CELLS = 0  # no level qualifies

    arch = runtime.init(args.arch, args.precision, threads=args.threads)
    rows = []
    for g in args.grids:
        shape = tuple(int(x) for x in g.lower().split("x"))
        rows.append(run(shape, args.steps, args.warmup, args.tol, not args.frozen))
        print(rows[-1], flush=True)
    bed = "frozen bed" if args.frozen else "bed re-randomised every step (eps, beta, deps/dt)"
    title = (f"Gas solver throughput ({arch}, {args.precision}, threads {args.threads or 'all'}, coarse block "
             f"{args.coarse_block}; 6 mm cells, "
             f"cylinder vessel, {bed} in the lower 40%, 0.5 m/s inflow, Model A, MacCormack, dt = 1e-3 s, "
             f"tol {args.tol:g}; median of {args.steps} steps after {args.warmup} warm-up)")
    append_results(title, rows, arch, dry=args.dry)
    return 0


if __name__ == "__main__":
    sys.exit(main())
