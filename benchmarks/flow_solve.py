"""The flow matching's potential solve: its preconditioners against each other, alone and one per core at once.

`fbed rcfd run` builds its jumps in forked workers, one per core (GrainMatcher.prefetch). scipy's cg takes its vector
products from BLAS (numpy's dot), and OpenBLAS runs those on as many threads as there are cores, in every worker: a
core's worth of threads per worker on each core. potential.pcg is the same preconditioned conjugate gradients on
numpy's own loops (one thread), and solves the three size classes' potentials together. Per case: the Laplacian and
right-hand sides of a synthetic jump (benchmarks/flow_matching.py's states), solved by ``--methods`` of: scipy cg
(Jacobi-preconditioned, a class at a time, as before 42e5be4), jacobi (pcg with A's diagonal, as before the
multigrid) and multigrid (pcg with potential.GridMultigrid, its set-up included: what a jump does now); each alone,
then in ``--workers`` forked processes at once (what a prefetch does). Methods alternated ``--rounds`` times, medians
of the wall time of one jump's solves (in the workers: the slowest worker's); the ratio is the first method's time
over the last's, paired. Appends to benchmarks/RESULTS.md.

    python3 benchmarks/flow_solve.py                       # jacobi against multigrid
    python3 benchmarks/flow_solve.py --methods "scipy cg" jacobi
"""
from __future__ import annotations

import argparse
import multiprocessing
import os
import pathlib
import statistics
import sys
import time

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import cg

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from app.bench.common import append_results  # noqa: E402
from app.rcfd.flowmatch import FlowGraph  # noqa: E402
from app.rcfd.potential import GridMultigrid, pcg  # noqa: E402
from app.rcfd.stitch import face_edges  # noqa: E402
from flow_matching import states  # noqa: E402

CASES = ((7000, (32, 8, 32)), (958000, (32, 32, 84)))
METHODS = ("scipy cg", "jacobi", "multigrid")
_PROBLEM = None  # (L, B, shape) the forked workers inherit


def problem(grains: int, shape: tuple):
    cells, vol = states(grains, shape, 1.0, np.random.default_rng(1))
    n = int(np.prod(shape))
    density = 0.5 * (np.bincount(cells[0], minlength=n) + np.bincount(cells[1], minlength=n))
    L, _ = FlowGraph(n, face_edges(shape, np.ones(shape, bool))).laplacian(density)
    B = np.stack([np.bincount(cells[0][vol == v], minlength=n) - np.bincount(cells[1][vol == v], minlength=n)
                  for v in np.unique(vol)], 1).astype(np.float64)
    return L, B, shape


def solve(method: str) -> float:
    L, B, shape = _PROBLEM
    t = time.perf_counter()
    if method == "scipy cg":
        M = sp.diags(1.0 / L.diagonal())
        X = np.stack([cg(L, b, rtol=1e-12, maxiter=20 * L.shape[0], M=M)[0] for b in B.T], 1)
    else:
        mg = GridMultigrid(L, shape) if method == "multigrid" else None
        X = pcg(L, B, 1e-12, 20 * L.shape[0], "bench", precondition=mg)
    wall = time.perf_counter() - t
    assert np.abs(L @ X - B).max() < 1e-6 * np.abs(B).max()
    return wall


def main(argv=None) -> int:
    global _PROBLEM
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--methods", nargs=2, default=["jacobi", "multigrid"], choices=METHODS)
    ap.add_argument("--workers", type=int, default=len(os.sched_getaffinity(0)))
    ap.add_argument("--max-grains", type=int, default=10**7)
    ap.add_argument("--dry", action="store_true", help="print, do not append to RESULTS.md")
    a = ap.parse_args(argv)
    ctx = multiprocessing.get_context("fork")
    rows = []
    for grains, shape in CASES:
        if grains > a.max_grains:
            continue
        _PROBLEM = problem(grains, shape)
        walls = {(m, k): [] for m in a.methods for k in (1, a.workers)}
        with ctx.Pool(a.workers) as pool:
            for _ in range(a.rounds):
                for m in a.methods:
                    walls[(m, 1)].append(solve(m))
                    walls[(m, a.workers)].append(max(pool.map(solve, [m] * a.workers)))
        for k in (1, a.workers):
            old, new = walls[(a.methods[0], k)], walls[(a.methods[1], k)]
            rows.append({"grains": grains, "grid": "x".join(map(str, shape)), "solving at once": k,
                         f"{a.methods[0]}, 3 solves [s]": f"{statistics.median(old):.3g}",
                         f"{a.methods[1]}, 3 solves [s]": f"{statistics.median(new):.3g}",
                         "ratio, paired median": f"{statistics.median(o / n for o, n in zip(old, new)):.2f}",
                         "rounds": a.rounds})
        print(rows[-2:], flush=True)
    append_results(f"The flow matching's potential: {a.methods[0]} against {a.methods[1]}, alone and one per core "
                   "(benchmarks/flow_solve.py)", rows, "cpu", dry=a.dry)
    return 0


if __name__ == "__main__":
    sys.exit(main())
