"""What one neighbour-list build costs, two source trees side by side (``--a`` / ``--b``, one process each, in turn).

The squeezed lattice of dem_substep.py (``--poly``: its tri-disperse bed) on one CPU thread (the serial form, as a
run on 2 cores uses) or in the parallel form (``--threads N``): ``--substeps`` substeps with a build forced before
each (the device flag set from the host) and as many without, in ``--repeats`` blocks; the build's cost is their
difference. A bubbling bed builds every few tens of substeps (verma_small: 316 builds in 10,400 substeps), a settled
one almost never: the substep benches (dem_substep.py, dem_throughput.py) do not see this cost.

    python3 benchmarks/dem_build_cost.py --a /tmp/base --b . --sizes 20000 125000
"""
from __future__ import annotations

import argparse
import json
import pathlib
import statistics
import subprocess
import sys

HERE = pathlib.Path(__file__).resolve()


def measure(a) -> dict:
    """In this process (the tree on sys.path first): ms per substep with and without a forced build."""
    import dataclasses

    from app.sim import runtime  # the tree's own app, imported before dem_substep puts this tree first on the path
    from app.sim.dem import DemSolver

    sys.path.insert(1, str(HERE.parent))
    from dem_scan_check import forced
    from dem_substep import scene_for

    arch = runtime.init("cpu", a.precision, a.threads)
    scene, pos, r = scene_for(a.n, a.poly, a.precision, a.threads, arch)
    dem = DemSolver(dataclasses.replace(scene.model, serial=a.threads == 1))
    dem.set_grains(pos, radius=r)
    dem.prepare()
    dem.advance(100)
    forced(dem, a.substeps, True), forced(dem, a.substeps, False)
    built, plain = [], []
    for _ in range(a.repeats):
        built.append(1e3 * forced(dem, a.substeps, True))
        plain.append(1e3 * forced(dem, a.substeps, False))
    return {"built": statistics.median(built), "plain": statistics.median(plain), "slots": dem.m.slots}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--a", default=None, help="tree A (default: this one)")
    ap.add_argument("--b", default=".", help="tree B")
    ap.add_argument("--sizes", type=int, nargs="+", default=[20000])
    ap.add_argument("--poly", action="store_true")
    ap.add_argument("--precision", default="float32", choices=("float32", "float64"))
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--substeps", type=int, default=20)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--pairs", type=int, default=2, help="A, B processes in turn, this many times")
    ap.add_argument("--dry", action="store_true")
    ap.add_argument("--child", default=None, help=argparse.SUPPRESS)
    ap.add_argument("--n", type=int, default=0, help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.child:
        sys.path.insert(0, a.child)
        print(json.dumps(measure(a)))
        return 0
    trees = {"A": pathlib.Path(a.a or HERE.parents[1]).resolve(), "B": pathlib.Path(a.b).resolve()}
    rows = []
    for n in a.sizes:
        got = {k: [] for k in trees}
        for _ in range(a.pairs):
            for k, tree in trees.items():
                cmd = [sys.executable, str(HERE), "--child", str(tree), "--n", str(n), "--precision", a.precision,
                       "--threads", str(a.threads), "--substeps", str(a.substeps), "--repeats", str(a.repeats)]
                out = subprocess.run(cmd + (["--poly"] if a.poly else []), capture_output=True, text=True, check=True,
                                     cwd=tree)
                got[k].append(json.loads(out.stdout.strip().splitlines()[-1]))
        med = {k: {q: statistics.median(x[q] for x in v) for q in ("built", "plain")} for k, v in got.items()}
        cost = {k: m["built"] - m["plain"] for k, m in med.items()}
        rows.append({"N": n, "bed": "tri-disperse" if a.poly else "monodisperse", "precision": a.precision,
                     "A ms/substep, build / none": f"{med['A']['built']:.3f} / {med['A']['plain']:.3f}",
                     "B ms/substep, build / none": f"{med['B']['built']:.3f} / {med['B']['plain']:.3f}",
                     "a build A -> B (ms)": f"{cost['A']:.3f} -> {cost['B']:.3f}",
                     "in substeps A -> B": f"{cost['A'] / med['A']['plain']:.2f} -> {cost['B'] / med['B']['plain']:.2f}",
                     "A / B": f"**{cost['A'] / cost['B']:.2f}**"})
        print(rows[-1], flush=True)
    sys.path.insert(0, str(HERE.parents[1]))
    from app.bench.common import append_results

    title = (f"DEM list build cost, two trees (cpu, {a.precision}, threads {a.threads}; A = {a.a}, B = {a.b}; the "
             f"squeezed lattice of dem_substep.py; {a.substeps} substeps with a forced build and as many without, "
             f"median of {a.repeats} blocks, {a.pairs} processes each in turn)")
    append_results(title, rows, "cpu", dry=a.dry)
    return 0


if __name__ == "__main__":
    sys.exit(main())
