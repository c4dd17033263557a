"""Kernel launches and host reads per gas step (the flow_throughput scene: cylinder vessel, bed in the
lower 40% re-randomised every step, 0.5 m/s inflow, Model A, MacCormack, dt = 1e-3 s).

    python benchmarks/gas_counts.py --grids 32x32x116 32x32x64

A host read is a kernel launch that returns a value, a to_numpy() or a Python-scope element read
of a field or ndarray (counted by tests/kernel_counter.py around every kernel of app.sim); the
launches count every kernel of app.sim, and so do the ndarray arguments those launches set (each
ndarray member of an argument pack counts: Taichi 1.7.4 sets every one at every launch, ~3 us each on
the host, most of a launch's host cost once app/sim/launch.py cached the rest). Counted over ``--steps`` steps after ``--warmup``; prints
the median per step with the min and max and appends a table to benchmarks/RESULTS.md.

``--tasks`` counts instead the offloaded tasks per step with Taichi's kernel profiler (every top-level loop of a
kernel is a task per launch on the CPU, ~70 us each on one thread even when empty; the serial form of the gas
kernels nests them in one task), in its own process since the profiler times every task.

``--profile`` adds where the device time goes: each kernel's tasks per step and their summed time per step
(Taichi's kernel profiler: device time per task on CUDA), the kernels sorted by time, against the step's wall
time with the profiler on (which times every task, so the wall time there is no throughput figure). A step
whose device time is far below its wall time is bound by the host's launches; one near it, by the device.
"""
from __future__ import annotations

import argparse
import pathlib
import re
import statistics
import sys
import time

from flow_throughput import DT, scene, shuffle_bed  # benchmarks/, this script's folder

from app.bench.common import append_results
from app.sim import runtime

# the kernel counter is a test double of tests/ (it wraps Taichi's kernels, so it cannot live outside app/sim)
sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1] / "tests"))
from kernel_counter import KernelCounter  # noqa: E402


def gas_modules():
    return [m for n, m in sorted(sys.modules.items()) if n.startswith("app.sim") and m is not None]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--arch", default="cpu", choices=("cpu", "cuda"))
    ap.add_argument("--precision", default="float32", choices=("float32", "float64"))
    ap.add_argument("--grids", nargs="+", default=["32x32x116", "32x32x64"])
    ap.add_argument("--steps", type=int, default=5)
    ap.add_argument("--warmup", type=int, default=2)
    ap.add_argument("--label", default="", help="what is counted (e.g. before / after)")
    ap.add_argument("--tasks", action="store_true", help="count offloaded tasks per step (kernel profiler)")
    ap.add_argument("--threads", type=int, default=None,
                    help="CPU threads (default: all; 2 or more runs the parallel form, as CUDA)")
    ap.add_argument("--profile", action="store_true", help="device time per kernel per step (kernel profiler)")
    ap.add_argument("--top", type=int, default=25, help="kernels listed by --profile")
    ap.add_argument("--coarse-block", choices=("on", "off"), default="on",
                    help="off: a launch down and up per multigrid level (app/sim/gas/coarse_cycle.py), for an A/B")
    ap.add_argument("--dry", action="store_true")
    args = ap.parse_args(argv)
    if args.coarse_block == "off":
        from app.sim.gas import coarse_cycle

        coarse_cycle.MAX_CELLS = 0  # no level qualifies: a launch down and up per level
    if args.profile:
        return profile(args)
    if args.tasks:
        return count_tasks(args)
    arch = runtime.init(args.arch, args.precision, threads=args.threads)
    rows = []
    for g in args.grids:
        shape = tuple(int(x) for x in g.lower().split("x"))
        s, bed, eps, rng = scene(shape, 1e-6)
        for _ in range(args.warmup):
            s.step(DT)
        launches, reads, nd_args, iters, sweeps = [], [], [], [], []
        top = None
        with KernelCounter(gas_modules()) as kc:
            for _ in range(args.steps):
                eps = shuffle_bed(s, bed, eps, rng)
                kc.reset()
                info = s.step(DT)
                launches.append(kc.launches)
                reads.append(kc.reads)
                nd_args.append(kc.ndarray_args)
                iters.append(info.pressure_iterations)
                sweeps.append(info.viscous_sweeps)
                top = dict(kc.reads_by)
        med = statistics.median
        rows.append({"label": args.label, "grid": g, "serial form": str(runtime.serial()),
                     "launches/step (median, min-max)":
                     f"{med(launches):g} ({min(launches)}-{max(launches)})",
                     "host reads/step (median, min-max)": f"{med(reads):g} ({min(reads)}-{max(reads)})",
                     "ndarray arguments set/step (median, min-max)":
                     f"{med(nd_args):g} ({min(nd_args)}-{max(nd_args)})",
                     "p-iters (median)": f"{med(iters):g}", "viscous sweeps (median)": f"{med(sweeps):g}"})
        print(rows[-1], "reads by:", top, flush=True)
    title = (f"Gas step: kernel launches and host reads per step ({arch}, {args.precision}; the flow_throughput "
             f"scene; {args.steps} steps after {args.warmup})")
    append_results(title, rows, arch, dry=args.dry)
    return 0


def count_tasks(args) -> int:
    arch = runtime.init(args.arch, args.precision, threads=args.threads, kernel_profiler=True)
    rows = []
    for g in args.grids:
        shape = tuple(int(x) for x in g.lower().split("x"))
        s, bed, eps, rng = scene(shape, 1e-6)
        for _ in range(args.warmup):
            s.step(DT)
        tasks, iters = [], []
        for _ in range(args.steps):
            eps = shuffle_bed(s, bed, eps, rng)
            runtime.clear_profile()
            iters.append(s.step(DT).pressure_iterations)
            tasks.append(runtime.profiled_tasks())
        med = statistics.median
        rows.append({"label": args.label, "grid": g, "serial form": str(s.serial),
                     "tasks/step (median, min-max)": f"{med(tasks):g} ({min(tasks)}-{max(tasks)})",
                     "p-iters (median)": f"{med(iters):g}"})
        print(rows[-1], flush=True)
    title = (f"Gas step: offloaded tasks per step ({arch}, {args.precision}, Taichi's kernel profiler; the "
             f"flow_throughput scene; {args.steps} steps after {args.warmup})")
    append_results(title, rows, arch, dry=args.dry)
    return 0


def kernel_of(task: str) -> str:
    """The kernel a task belongs to: Taichi names a task <kernel>_c<id>_<instance>_<task kind>_<n>."""
    m = re.match(r"(.+?)_c\d+_\d+_", task)
    return m.group(1) if m else task


def profile(args) -> int:
    arch = runtime.init(args.arch, args.precision, threads=args.threads, kernel_profiler=True)
    for g in args.grids:
        shape = tuple(int(x) for x in g.lower().split("x"))
        s, bed, eps, rng = scene(shape, 1e-6)
        for _ in range(args.warmup):
            s.step(DT)
        per_kernel: dict[str, list[float]] = {}
        walls, totals, ntasks, iters = [], [], [], []
        for _ in range(args.steps):
            eps = shuffle_bed(s, bed, eps, rng)
            runtime.clear_profile()
            t = time.perf_counter()
            iters.append(s.step(DT).pressure_iterations)
            runtime.sync()
            walls.append(time.perf_counter() - t)
            rec = runtime.profiled_times()
            totals.append(sum(x for _, x in rec))
            ntasks.append(len(rec))
            for name, x in rec:
                k = per_kernel.setdefault(kernel_of(name), [0.0, 0])
                k[0] += x
                k[1] += 1
        n = args.steps
        med = statistics.median
        rows = [{"kernel": k, "tasks/step": f"{c / n:.1f}", "ms/step": f"{1e3 * x / n:.3f}",
                 "share": f"{100 * x / max(sum(totals), 1e-30):.1f}%"}
                for k, (x, c) in sorted(per_kernel.items(), key=lambda kv: -kv[1][0])[:args.top]]
        head = {"grid": g, "tasks/step (median)": f"{med(ntasks):g}",
                "task time ms/step (median)": f"{1e3 * med(totals):.2f}",
                "wall ms/step, profiler on (median)": f"{1e3 * med(walls):.2f}", "p-iters (median)": f"{med(iters):g}"}
        print(head, flush=True)
        for r in rows:
            print(r, flush=True)
        title = (f"Gas step: time per kernel ({arch}, {args.precision}, Taichi's kernel profiler; the flow_throughput "
                 f"scene, {g}; {n} steps after {args.warmup}; {head})")
        append_results(title, rows, arch, dry=args.dry)
    return 0


if __name__ == "__main__":
    sys.exit(main())
