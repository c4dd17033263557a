"""The one-launch coarse cycle (app/sim/gas/coarse_cycle.py) against a launch down and up per level, on the arch
given (CUDA: one block with barriers, a path the CPU cannot run): the same pressure systems solved both ways. The
multigrid set-up's coarsenings of the small levels in one launch (``k_coarsen_levels``) come with the cycle: the
hierarchy (every level's transmissibilities and diagonal) is compared too.

For each system: outer iterations both ways (must be equal), the largest difference of the solutions relative to
the largest value (the per-cell arithmetic is the same: 0 on the CPU; on CUDA a few float round-offs at most if
the compiler contracts a multiply-add differently in the two kernels), the scipy residual of the block cycle's
solution (must meet the tolerance), and ms per solve both ways (median of --repeats, after one warm-up solve).
Exits 1 if a check fails, so a device script stops there.

    python3 benchmarks/coarse_cycle_check.py --arch cuda
"""
import argparse
import pathlib
import sys

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))
from app.bench.common import append_results  # noqa: E402
from app.bench.poisson import cell_operator  # noqa: E402
from app.sim import runtime  # noqa: E402

# (shape, periodic axes, singular): the Verma grid (block from 8x8x29), a Neumann box (the coarsest by CG), a
# periodic box (red-black levels with wrapped stencils)
SYSTEMS = [((32, 32, 116), (False, False, False), False), ((16, 16, 20), (False, False, False), True),
           ((16, 16, 20), (True, False, False), False)]


def _residual(shape, ts, periodic, x, b):
    """max |b - A x| with A assembled by scipy (Dirichlet outside value 0)."""
    return float(np.max(np.abs(b.ravel() - cell_operator(shape, ts, periodic) @ x.ravel())))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--arch", choices=("cpu", "cuda"), default="cpu")
    ap.add_argument("--precision", choices=("float32", "float64"), default="float64")
    ap.add_argument("--threads", type=int, default=2, help="CPU threads (2: the parallel form, as CUDA)")
    ap.add_argument("--tol", type=float, default=1e-8)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--dry", action="store_true")
    args = ap.parse_args(argv)
    arch = runtime.init(args.arch, args.precision, threads=args.threads)
    from app.sim.gas.cycle_check import compare, passes, system

    rows, ok = [], True
    for shape, periodic, singular in SYSTEMS:
        r = compare(shape, periodic, singular, args.tol, repeats=args.repeats)
        ts, b = system(shape, periodic, singular)
        res = _residual(shape, ts, periodic, r["x"], b) / max(float(np.max(np.abs(b))), 1e-300)
        # the same solves as the start-up check (app/sim/gas/cycle_check.py, its tolerances), on larger systems,
        # plus the scipy residual of the cycle's solution
        good = passes(r, arch == "cuda", args.precision) and res <= 10 * args.tol
        ok &= good
        (i0, i1), (t0, t1) = r["iterations"], r["seconds"]
        rows.append({"shape": "x".join(map(str, shape)), "periodic": "".join("xyz"[a] for a in range(3) if periodic[a])
                     or "-", "singular": singular, "block from level": r["block_from"], "iterations per level / block":
                     f"{i0} / {i1}", "max |x diff| / max |x|": f"{r['x_diff']:.1e}",
                     "set-up one launch from level": r["coarsen_from"], "hierarchy max diff / max": f"{r['h_diff']:.1e}",
                     "scipy residual / max|b|": f"{res:.1e}", "ms per solve per level / block": f"{1e3 * t0:.2f} / "
                     f"{1e3 * t1:.2f}", "check": "pass" if good else "FAIL"})
        print(rows[-1], flush=True)
    title = (f"The one-launch coarse cycle against a launch per level ({arch}, {args.precision}; tol {args.tol:g}; "
             f"median of {args.repeats} solves)")
    append_results(title, rows, arch, dry=args.dry)
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
