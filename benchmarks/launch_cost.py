"""Host cost of the gas step's kernel launches: Taichi's own call against the cached plans (app/sim/launch.py).

The flow_throughput scene (cylinder vessel, bed in the lower 40% re-randomised every step, 0.5 m/s inflow,
Model A, MacCormack, dt = 1e-3 s) on small grids, where a step is mostly launches. In one process, blocks of
``--steps`` steps alternate between the two (``launch.plans(False)`` / ``launch.plans(True)``), ``--blocks``
pairs; per pair the ratio of the median ms/step, and the median of those ratios. The launches per step are
counted once (tests/kernel_counter.py); "us saved a launch" = (ms/step own - ms/step plans) / launches.

On the CPU a launch runs its tasks in the calling thread, so a step's time there is host plus compute; on a
GPU the host's part is what the device waits on between kernels.

    python benchmarks/launch_cost.py --grids 4x4x8 8x8x16 16x16x32
    python benchmarks/launch_cost.py --arch cuda --grids 8x8x16 32x32x116
    python benchmarks/launch_cost.py --per-array     # us a launch against the ndarrays it sets
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
sys.path.insert(0, str(ROOT / "tests"))

from flow_throughput import DT, scene, shuffle_bed  # noqa: E402

from app.bench.common import append_results  # noqa: E402


def block(s, bed, eps, rng, steps: int):
    times = []
    for _ in range(steps):
        eps = shuffle_bed(s, bed, eps, rng)
        t = time.perf_counter()
        s.step(DT)
        times.append(time.perf_counter() - t)
    return statistics.median(times), eps


def run(shape, steps: int, blocks: int, tol: float) -> dict:
    from app.sim import launch
    from kernel_counter import KernelCounter

    s, bed, eps, rng = scene(shape, tol)
    for on in (False, True, False, True):  # compile both paths' kernels, and warm up
        with launch.plans(on):
            _, eps = block(s, bed, eps, rng, 2)
    mods = [m for n, m in sorted(sys.modules.items()) if n.startswith("app.sim") and m is not None]
    with KernelCounter(mods) as kc:
        _, eps = block(s, bed, eps, rng, 3)
    launches = kc.launches / 3
    own, fast, ratio = [], [], []
    for _ in range(blocks):
        with launch.plans(False):
            a, eps = block(s, bed, eps, rng, steps)
        with launch.plans(True):
            b, eps = block(s, bed, eps, rng, steps)
        own.append(a)
        fast.append(b)
        ratio.append(a / b)
    a, b = statistics.median(own), statistics.median(fast)
    return {"grid": "x".join(map(str, shape)), "launches/step": f"{launches:.0f}",
            "ms/step Taichi's own call": f"{1e3 * a:.2f}", "ms/step plans": f"{1e3 * b:.2f}",
            "own / plans (min-max)": f"**{statistics.median(ratio):.2f}** ({min(ratio):.2f}-{max(ratio):.2f})",
            "us saved a launch": f"{1e6 * (a - b) / launches:.0f}"}


def per_array(sizes=(0, 1, 4, 16), launches: int = 2000, repeats: int = 7) -> list:
    """us a launch of a kernel that takes one pack of n ndarrays (and touches one element), plans on: the host
    cost each ndarray argument adds (Taichi 1.7.4 sets every member of a pack at every launch)."""
    import taichi as ti

    from app.sim import launch

    rows = []
    for n in sizes:
        arrays = [ti.ndarray(ti.f32, (4, 4, 4)) for _ in range(max(n, 1))]
        # annotations set by hand: this module's `from __future__ import annotations` makes them strings
        if n == 0:
            def touch(x):
                pass
            touch.__annotations__ = {"x": ti.f32}
            arg = 1.0
        else:
            pt = ti.types.argpack(**{f"a{i}": ti.types.ndarray(ti.f32, ndim=3) for i in range(n)})
            arg = pt(**{f"a{i}": arrays[i] for i in range(n)})

            def touch(p):
                p.a0[0, 0, 0] += 1.0
            touch.__annotations__ = {"p": pt}
        k = launch.kernel(touch)
        for _ in range(50):
            k(arg)
        us = []
        for _ in range(repeats):
            t = time.perf_counter()
            for _ in range(launches):
                k(arg)
            us.append(1e6 * (time.perf_counter() - t) / launches)
        rows.append({"ndarrays in the pack": str(n), "us a launch (median of %d)" % repeats:
                     f"{statistics.median(us):.1f} ({min(us):.1f}-{max(us):.1f})"})
        print(rows[-1], flush=True)
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--arch", default="cpu", choices=("cpu", "cuda"))
    ap.add_argument("--precision", default="float32", choices=("float32", "float64"))
    ap.add_argument("--threads", type=int, default=None, help="CPU threads (default: all)")
    ap.add_argument("--grids", nargs="+", default=["4x4x8", "8x8x16", "16x16x32"])
    ap.add_argument("--steps", type=int, default=10, help="steps a block")
    ap.add_argument("--blocks", type=int, default=7, help="pairs of blocks")
    ap.add_argument("--tol", type=float, default=1e-6)
    ap.add_argument("--per-array", action="store_true",
                    help="instead: us a launch of a kernel taking a pack of 0, 1, 4, 16 ndarrays")
    ap.add_argument("--dry", action="store_true", help="print only, do not append to RESULTS.md")
    args = ap.parse_args(argv)
    from app.sim import runtime

    arch = runtime.init(args.arch, args.precision, threads=args.threads)
    if args.per_array:
        title = (f"Launch host cost by ndarray arguments ({arch}, {args.precision}, threads {args.threads or 'all'}; "
                 f"a kernel taking one pack of n ndarrays, touching one element; launch.kernel's plans; 7 x 2000 "
                 f"launches)")
        append_results(title, per_array(), arch, dry=args.dry)
        return 0
    rows = []
    for g in args.grids:
        rows.append(run(tuple(int(x) for x in g.lower().split("x")), args.steps, args.blocks, args.tol))
        print(rows[-1], flush=True)
    title = (f"Gas step launch cost, Taichi's own call against cached plans ({arch}, {args.precision}, threads "
             f"{args.threads or 'all'}; flow_throughput scene; {args.blocks} interleaved pairs of {args.steps}-step "
             f"blocks in one process, medians)")
    append_results(title, rows, arch, dry=args.dry)
    return 0


if __name__ == "__main__":
    sys.exit(main())
