"""The rCFD gas tracer's cost and spread by scheme: first-order upwind against flux-corrected transport (FCT), on a
recorded database (app.rcfd.transport.step_response, as `fbed rcfd run --gas` runs it: substeps at Courant number
0.9 on each frame's fluxes).

A step input from ``--start`` s over ``--horizon`` s on frames of ``--factor`` recorded frames (fluxes averaged, as
a recording at that interval holds them); the schemes alternated, ``--repeats`` times each, medians. Per scheme:
wall seconds per simulated second (one path), substeps, the step response's mean residence time and spread. Appends
to benchmarks/RESULTS.md.

    python3 benchmarks/gas_tracer_cost.py runs/gas_rtd --factor 5     # the run of validation/rcfd/README.md, 0000
"""
from __future__ import annotations

import argparse
import pathlib
import statistics
import sys
import time

import h5py
import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from app.bench.common import append_results  # noqa: E402
from app.rcfd.database import load  # noqa: E402
from app.rcfd.transport import GasTracer, recorded_frames, rtd_moments, step_response  # noqa: E402

SCHEMES = GasTracer.SCHEMES  # upwind first: the ratio is to it


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("run", help="run folder with an rcfd.h5 holding gas fluxes")
    ap.add_argument("--start", type=float, default=1.0, help="[s]")
    ap.add_argument("--horizon", type=float, default=1.0, help="[s]")
    ap.add_argument("--factor", type=int, default=5, help="recorded frames a frame spans")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--dry", action="store_true", help="print, do not append to RESULTS.md")
    a = ap.parse_args(argv)
    db = load(pathlib.Path(a.run))
    with h5py.File(db.path, "r") as f:
        fluxes = [f[f"frame/flux_{x}"][: db.n_frames] for x in "xyz"]
    start = int(np.searchsorted(db.time[db.b0], a.start - 1e-9))
    dt = a.factor * db.frame_interval
    n = int(round(a.horizon / dt))
    if start + n * a.factor > db.n_frames:
        raise SystemExit(f"{a.run}: {a.horizon:g} s from {a.start:g} s runs past the recording")
    walls, last = {s: [] for s in SCHEMES}, {}
    for _ in range(a.repeats):
        for s in SCHEMES:
            t = time.perf_counter()
            frames = recorded_frames(db, fluxes, start, n, a.factor)
            last[s] = step_response(db.open_volume, db.h, frames, dt, scheme=s)
            walls[s].append(time.perf_counter() - t)
    rows = []
    for s in SCHEMES:
        m = rtd_moments(last[s]["F"], dt)
        wall = statistics.median(walls[s])
        rows.append({"scheme": s, "cells": int(np.count_nonzero(db.open_volume)), "frame [ms]": f"{dt * 1e3:g}",
                     "wall s per simulated s": f"{wall / (n * dt):.3f}",
                     "min-max": f"{min(walls[s]) / (n * dt):.3f}-{max(walls[s]) / (n * dt):.3f}",
                     "x upwind": f"{wall / statistics.median(walls['upwind']):.2f}",
                     "substeps per frame": f"{last[s]['substeps'] / n:.1f}",
                     "tau [ms] (first step response)": f"{m['tau'] * 1e3:.2f}",
                     "sigma [ms]": f"{m['sigma'] * 1e3:.2f}", "balance error": f"{last[s]['balance_error']:.1e}"})
    append_results(f"rCFD gas tracer by scheme, one path (numpy; {a.run}, step input from {a.start:g} s over "
                   f"{a.horizon:g} s, frames of {a.factor} recorded; {a.repeats} alternated repeats, medians)",
                   rows, "cpu", dry=a.dry)
    return 0


if __name__ == "__main__":
    sys.exit(main())
