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
import statistics
import sys
import time

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))
from app.bench.common import append_results  # noqa: E402
from app.bench.poisson import cell_operator  # noqa: E402
from app.sim import runtime  # noqa: E402

# (shape, periodic axes, singular): the Verma grid (block from 8x8x29), a Neumann box (the coarsest by CG), a
# periodic box (red-black levels with wrapped stencils)
SYSTEMS = [((32, 32, 116), (False, False, False), False), ((16, 16, 20), (False, False, False), True),
           ((16, 16, 20), (True, False, False), False)]


def _system(shape, periodic, singular, rng):
    ts = []
    for a in range(3):
        fs = list(shape)
        fs[a] += 1
        t = 0.1 + rng.random(fs)
        sl0, sl1 = [slice(None)] * 3, [slice(None)] * 3
        sl0[a], sl1[a] = 0, -1
        if periodic[a]:
            t[tuple(sl1)] = t[tuple(sl0)]
        elif singular or a != 2:
            t[tuple(sl0)] = 0.0
            t[tuple(sl1)] = 0.0
        else:
            t[tuple(sl0)] = 0.0  # a Dirichlet top only
        ts.append(t)
    b = rng.standard_normal(shape)
    if singular:
        b -= b.mean()
    return ts, b


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
    from app.sim.gas.linsolve import MGPCG

    rows, ok = [], True
    for shape, periodic, singular in SYSTEMS:
        ts, b = _system(shape, periodic, singular, np.random.default_rng(7))
        out = {}
        for block in (False, True):
            mg = MGPCG(shape, periodic, coarse_block=block)
            times, info = [], None
            for r in range(args.repeats + 1):
                mg.set_system(*ts, b=b, x0=0.0)
                runtime.sync()
                t0 = time.perf_counter()
                info = mg.solve(args.tol, 200, singular=singular)
                runtime.sync()
                if r:
                    times.append(time.perf_counter() - t0)
            hier = np.concatenate([mg.mg.trans.to_numpy(), mg.mg.diag.to_numpy()])
            out[block] = (mg.block_from, info, mg.solution(), statistics.median(times), mg.coarsen_from, hier)
        (_, i0, x0, t0, _, h0), (m, i1, x1, t1, mc, h1) = out[False], out[True]
        diff = float(np.max(np.abs(x1 - x0)) / max(np.max(np.abs(x0)), 1e-300))
        # the hierarchy (every level's transmissibilities and diagonal) built by the set-up's one launch from level
        # coarsen_from (coarse_cycle.k_coarsen_levels) against a launch per level
        hdiff = float(np.max(np.abs(h1 - h0)) / max(np.max(np.abs(h0)), 1e-300))
        res = _residual(shape, ts, periodic, x1, b) / max(float(np.max(np.abs(b))), 1e-300)
        # on the CPU the same code to the bit; on CUDA the two kernels may contract a multiply-add differently
        # (round-off), which can move a stopping test by an iteration: float64 1e-6 leaves 1e10 round-offs of room,
        # float32 (tol 1e-5) 1e-3; a cell updated wrongly or missed by a barrier shows as far more, and in the
        # iterations
        tol_diff = 0.0 if arch == "cpu" else 1e-6 if args.precision == "float64" else 1e-3
        d_it = 0 if arch == "cpu" else 1
        good = m is not None and mc is not None and abs(i0.iterations - i1.iterations) <= d_it and i1.converged \
            and diff <= tol_diff and hdiff <= tol_diff and res <= 10 * args.tol
        ok &= good
        rows.append({"shape": "x".join(map(str, shape)), "periodic": "".join("xyz"[a] for a in range(3) if periodic[a])
                     or "-", "singular": singular, "block from level": m, "iterations per level / block":
                     f"{i0.iterations} / {i1.iterations}", "max |x diff| / max |x|": f"{diff:.1e}",
                     "set-up one launch from level": mc, "hierarchy max diff / max": f"{hdiff:.1e}",
                     "scipy residual / max|b|": f"{res:.1e}", "ms per solve per level / block": f"{1e3 * t0:.2f} / "
                     f"{1e3 * t1:.2f}", "check": "pass" if good else "FAIL"})
        print(rows[-1], flush=True)
    title = (f"The one-launch coarse cycle against a launch per level ({arch}, {args.precision}; tol {args.tol:g}; "
             f"median of {args.repeats} solves)")
    append_results(title, rows, arch, dry=args.dry)
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
