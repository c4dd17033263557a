"""The rCFD recording probe's host work per frame (app/rcfd_probe.py) for a million grains: each grain's cell and
octant, and the frame's volume shifts, as the probe did them before 2026-12-06 (two floors; np.unique over every
grain's (start cell, end cell) pair) against now (one floor on the half-cells; ``shift_sums``, which sorts only
the grains that changed cell). Numpy only; the same arrays are checked equal.

The grains: ``--n`` at random in the poppy-seed column's recorded region (32 x 32 x 84 cells of 3 mm), a fraction
``--moved`` of them one to three cells from where they started the frame. Medians of ``--repeats``, alternated.

    python3 benchmarks/rcfd_frame_cost.py --n 1000000 --moved 0.1
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

from app.bench.common import append_results  # noqa: E402
from app.rcfd_probe import RcfdRecorder, shift_sums  # noqa: E402


def before(rec, x, c_start, vol):
    q = np.floor((x - rec.origin) / rec.h).astype(np.int64)
    for a in range(3):
        np.clip(q[:, a], 0, rec.shape[a] - 1, out=q[:, a])
    cells = (q[:, 0] * rec.shape[1] + q[:, 1]) * rec.shape[2] + q[:, 2]
    q = np.floor((x - rec.origin) / (0.5 * rec.h)).astype(np.int64)
    for a in range(3):
        np.clip(q[:, a], 0, 2 * rec.shape[a] - 1, out=q[:, a])
    octant = (((q[:, 0] & 1) << 2) | ((q[:, 1] & 1) << 1) | (q[:, 2] & 1)).astype(np.uint8)
    keys, inv = np.unique(c_start * rec.n + cells, return_inverse=True)
    return cells, octant, keys, np.bincount(inv, weights=vol)


def after(rec, x, c_start, vol):
    cells, octant = rec.cells_and_octants(x)
    keys, w = shift_sums(c_start, cells, vol, rec.n)
    return cells, octant, keys, w


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=1000000)
    ap.add_argument("--moved", type=float, default=0.1, help="fraction of the grains that change cell in the frame")
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--no-append", action="store_true")
    a = ap.parse_args(argv)
    rec = RcfdRecorder.__new__(RcfdRecorder)
    rec.origin, rec.h, rec.shape = np.array([-0.048, -0.048, 0.0]), 0.003, (32, 32, 84)
    rec.n = int(np.prod(rec.shape))
    rng = np.random.default_rng(2)
    hi = np.array([0.048, 0.048, 0.252])
    x0 = (rec.origin + rng.uniform(0.0, 1.0, (a.n, 3)) * (hi - rec.origin)).astype(np.float32)
    step = rng.choice([-1, 1], (a.n, 3)) * rng.integers(1, 4, (a.n, 3)) * rec.h * (rng.uniform(size=(a.n, 1)) < a.moved)
    x = (x0 + step).astype(np.float32)
    vol = rng.choice([4.07e-10, 6.06e-10, 1.07e-9], a.n)
    c_start = rec.cells_and_octants(x0)[0]
    same = all(np.array_equal(u, v) for u, v in zip(before(rec, x, c_start, vol), after(rec, x, c_start, vol)))
    t = {"before": [], "after": []}
    for _ in range(a.repeats):
        for name, f in (("before", before), ("after", after)):
            t0 = time.perf_counter()
            f(rec, x, c_start, vol)
            t[name].append(time.perf_counter() - t0)
    b, c = (1e3 * statistics.median(t[k]) for k in ("before", "after"))
    moved = float(np.mean(c_start != rec.cells_and_octants(x)[0]))
    row = {"N": a.n, "grains that changed cell": f"{moved:.2f}", "before ms/frame": f"{b:.1f}",
           "after ms/frame": f"{c:.1f}", "before / after": f"{b / c:.2f}", "same arrays": "yes" if same else "NO"}
    print(row, flush=True)
    append_results(f"rCFD recording probe, host work per frame: cells, octants and volume shifts (numpy; random "
                   f"grains in the poppy column's 32 x 32 x 84 recorded cells; median of {a.repeats})", [row], "cpu",
                   dry=a.no_append)
    return 0 if same else 1


if __name__ == "__main__":
    sys.exit(main())
