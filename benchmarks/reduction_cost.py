"""Cost of a reduction over n cells by where it accumulates: into an ndarray element, or into a kernel-scope
variable stored once after the loop.

Taichi 1.7.4 turns an atomic into a reduction (each thread accumulates on its own, then one atomic per warp on
CUDA, per thread on the CPU) only when its destination is a 0-D field or a kernel-scope variable
(``make_thread_local``: GlobalPtrStmt of a place SNode, GlobalTemporaryStmt); an ndarray element is neither, so
``ti.atomic_max(arr[0], v)`` in a parallel loop is one atomic per cell on one address, and a float max is a
compare-and-swap loop (no native float atomic max on CUDA; Taichi's retries until its write lands). The gas step
ran about twenty such reductions over 1e5-4e5 cells a step. This measures both forms, float32, per launch
(synchronised), so the difference is the device's.

    python benchmarks/reduction_cost.py --arch cuda --sizes 118784 366080

Prints a table and appends it to benchmarks/RESULTS.md.
"""

import argparse
import pathlib
import statistics
import sys
import time

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

from app.bench.common import append_results  # noqa: E402


def kernels():
    import taichi as ti

    nd = ti.types.ndarray(ndim=1)

    @ti.kernel
    def max_into_element(x: nd, out: nd, n: ti.i32):
        out[0] = 0.0
        for i in range(n):
            ti.atomic_max(out[0], ti.abs(x[i]))

    @ti.kernel
    def max_into_local(x: nd, out: nd, n: ti.i32):
        m = 0.0
        for i in range(n):
            ti.atomic_max(m, ti.abs(x[i]))
        out[0] = m

    @ti.kernel
    def add_into_element(x: nd, out: nd, n: ti.i32):
        out[0] = 0.0
        for i in range(n):
            out[0] += x[i] * x[i]

    @ti.kernel
    def add_into_local(x: nd, out: nd, n: ti.i32):
        s = 0.0
        for i in range(n):
            s += x[i] * x[i]
        out[0] = s

    return {"max, ndarray element": max_into_element, "max, kernel-scope variable": max_into_local,
            "sum, ndarray element": add_into_element, "sum, kernel-scope variable": add_into_local}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--arch", default="cpu", choices=("cpu", "cuda"))
    ap.add_argument("--threads", type=int, default=None, help="CPU threads (default: all)")
    ap.add_argument("--sizes", type=int, nargs="+", default=[118784, 366080])
    ap.add_argument("--launches", type=int, default=50)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--dry", action="store_true")
    args = ap.parse_args(argv)
    import taichi as ti
    from app.sim import runtime

    arch = runtime.init(args.arch, "float32", threads=args.threads)
    ks = kernels()
    rows = []
    rng = np.random.default_rng(0)
    for n in args.sizes:
        x = ti.ndarray(ti.f32, shape=(n,))
        xv = rng.standard_normal(n).astype(np.float32)
        x.from_numpy(xv)
        out = ti.ndarray(ti.f32, shape=(1,))
        row = {"cells": n}
        for name, k in ks.items():
            k(x, out, n)
            ti.sync()
            got = float(out.to_numpy()[0])
            want = float(np.abs(xv).max()) if name.startswith("max") else float(np.dot(xv.astype(np.float64), xv))
            if not np.isclose(got, want, rtol=1e-3):
                raise SystemExit(f"{name}: {got} against numpy's {want}")
            per = []
            for _ in range(args.repeats):
                t = time.perf_counter()
                for _ in range(args.launches):
                    k(x, out, n)
                    ti.sync()
                per.append((time.perf_counter() - t) / args.launches)
            row[f"{name} (us)"] = f"{1e6 * statistics.median(per):.1f}"
        rows.append(row)
        print(row, flush=True)
    title = (f"Reduction cost by destination ({arch}, float32, threads {args.threads or 'all'}; one launch, "
             f"synchronised, median of {args.repeats} x {args.launches}; includes the launch itself)")
    append_results(title, rows, arch, dry=args.dry)
    return 0


if __name__ == "__main__":
    sys.exit(main())
