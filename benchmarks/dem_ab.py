"""Two commits' DEM substep side by side in ONE process, interleaved: robust ratios on a loaded CPU.

Each tree's ``app`` package is copied into a temporary folder under its own name (``app_a``, ``app_b``:
fbed imports itself relatively), Taichi is started once, and both solvers are built on the same bed
(benchmarks/dem_substep.py's squeezed lattice in a cylinder, Hertz-Mindlin with friction; ``--poly``:
tri-disperse with epsd rolling). Blocks of ``--substeps`` alternate A B, B A, ...; each block's process
CPU time (not counting time spent descheduled) and wall time per substep are kept. Prints and appends the
medians and the median of the per-pair ratios A/B (> 1: B is faster).

``--build``: what one neighbour-list build costs instead. Each tree's block is ``--substeps`` substeps with a build
forced before each (the device flag set from the host) and then as many without; a build's cost is their
difference, and the ratio is taken pair by pair. A bubbling bed builds every few tens of substeps (verma_small: 316
builds in 10,400 substeps), a settled one almost never: the substep timings do not see this cost.

    git worktree add /tmp/old e7a1a90   # or: git archive e7a1a90 | tar -x -C /tmp/old
    python benchmarks/dem_ab.py --a /tmp/old --b . --n 10000 50000 --precision float32
    python benchmarks/dem_ab.py --a /tmp/old --b . --n 20000 --build --substeps 20 --blocks 11
"""
from __future__ import annotations

import argparse
import importlib
import pathlib
import shutil
import statistics
import sys
import tempfile
import time

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
sys.path.insert(0, str(ROOT / "benchmarks" / "liggghts"))

import numpy as np  # noqa: E402

import dem_substep as bench  # noqa: E402
from app.bench.common import append_results  # noqa: E402


def settled(beds: pathlib.Path, n: int, shuffle: bool) -> dict:
    """The LIGGGHTS-poured settled bed of ``n`` grains (benchmarks/dem_throughput.py's cache), its grain ids
    shuffled when asked (the same permutation for both trees): memory order then has nothing to do with space."""
    hits = sorted(beds.glob(f"bed_n{n}_*.npz"))
    if not hits:
        raise SystemExit(f"no settled bed of {n} grains in {beds}: run benchmarks/dem_throughput.py --liggghts first")
    z = np.load(hits[-1])
    bed = {k: np.asarray(z[k]) for k in ("position", "velocity", "omega")}
    bed["cylinder_radius"] = float(z["cylinder_radius"])
    if shuffle:
        perm = np.random.default_rng(12).permutation(n)
        bed.update({k: bed[k][perm] for k in ("position", "velocity", "omega")})
    return bed


def settled_solver(pkg: str, n: int, precision: str, bed: dict, serial: bool = True):
    """dem_throughput.py's fair scene (2 mm grains, skin 0.1 d, Hertz-Mindlin + friction) on the settled bed."""
    cfgmod = importlib.import_module(pkg + ".config")
    scenemod = importlib.import_module(pkg + ".scene")
    demmod = importlib.import_module(pkg + ".sim.dem")
    pos, radius = bed["position"], bed["cylinder_radius"]
    top = float(pos[:, 2].max()) + 4 * bench.D
    text = (f"[run]\nduration = 1.0\nprecision = \"{precision}\"\nthreads = 1\n[domain]\nlo = [{-radius}, {-radius}, 0.0]\n"
            f"hi = [{radius}, {radius}, {top}]\n[vessel]\nshape = \"cylinder\"\nradius = {radius}\n[particles]\n"
            f"diameter = {bench.D}\ndensity = {bench.RHO}\ncount = {n}\n[contact]\nmodel = \"hertz_mindlin\"\n"
            f"youngs_modulus = {bench.E}\npoisson_ratio = {bench.NU}\nrestitution = {bench.REST}\nfriction = {bench.MU}\n"
            f"[dem]\ndt = {bench.DT}\nskin = {0.1 * bench.D}\n")
    r = np.full(n, bench.D / 2)
    scene = scenemod.Scene(cfgmod.load_text(text, "bench.toml"), "bench.toml",
                           initial={"position": pos, "velocity": bed["velocity"], "radius": r}, serial=serial)
    dem = demmod.DemSolver(scene.model)
    dem.set_grains(pos, bed["velocity"], r, bed["omega"])
    return dem


def solver(pkg: str, n: int, poly: bool, precision: str, rolling: bool = False, serial: bool = True):
    cfgmod = importlib.import_module(pkg + ".config")
    scenemod = importlib.import_module(pkg + ".scene")
    demmod = importlib.import_module(pkg + ".sim.dem")
    from liggghts_pour import make_lattice

    sizes = bench.POPPY
    dmax = sizes[-1] if poly else bench.D
    pos, radius = make_lattice(n, diameter=dmax, spacing=1.0)
    pos = pos * 0.997 + np.random.default_rng(0).uniform(-1e-3, 1e-3, pos.shape) * dmax
    top = float(pos[:, 2].max()) + 4 * dmax
    grains = (f"diameter = 0.0\ndiameters = [{sizes[0]}, {sizes[1]}, {sizes[2]}]\nfractions = [0.3333, 0.3333, "
              f"0.3334]\nfractions_by = \"number\"" if poly else f"diameter = {bench.D}")
    rolling = "rolling_friction = 0.1\nrolling_model = \"epsd\"\n" if (poly or rolling) else ""
    text = (f"[run]\nduration = 1.0\nprecision = \"{precision}\"\nthreads = 1\n[domain]\nlo = [{-radius}, {-radius}, 0.0]\n"
            f"hi = [{radius}, {radius}, {top}]\n[vessel]\nshape = \"cylinder\"\nradius = {radius}\n[particles]\n{grains}\n"
            f"density = {bench.RHO}\ncount = {n}\n[contact]\nmodel = \"hertz_mindlin\"\nyoungs_modulus = {bench.E}\n"
            f"poisson_ratio = {bench.NU}\nrestitution = {bench.REST}\nfriction = {bench.MU}\n{rolling}[dem]\n"
            f"dt = {bench.DT}\n")
    r = np.random.default_rng(1).choice(np.asarray(sizes) / 2, n) if poly else np.full(n, bench.D / 2)
    scene = scenemod.Scene(cfgmod.load_text(text, "bench.toml"), "bench.toml",
                           initial={"position": pos, "velocity": np.zeros_like(pos), "radius": r}, serial=serial)
    dem = demmod.DemSolver(scene.model)
    dem.set_grains(pos, radius=r)
    return dem


def timed(dem, substeps: int, build: bool, rebuild: int) -> tuple[float, float]:
    """Process CPU and wall ms per substep over ``substeps`` single substeps, a build forced before each when
    ``build`` (``rebuild``: the tree's index of the flag in ``nlist.counters``)."""
    import taichi as ti

    ti.sync()
    c0, w0 = time.process_time(), time.perf_counter()
    for _ in range(substeps):
        if build:
            dem.nlist.counters[rebuild] = 1
        dem.substep()
    ti.sync()
    return 1e3 * (time.process_time() - c0) / substeps, 1e3 * (time.perf_counter() - w0) / substeps


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--a", required=True, help="tree A (a checkout holding app/)")
    ap.add_argument("--b", default=str(ROOT), help="tree B (default: this one)")
    ap.add_argument("--n", type=int, nargs="+", default=[10000])
    ap.add_argument("--precision", default="float32", choices=("float32", "float64"))
    ap.add_argument("--poly", action="store_true")
    ap.add_argument("--rolling", action="store_true", help="monodisperse bed with epsd rolling (mu_r = 0.1)")
    ap.add_argument("--bed", default="lattice", choices=("lattice", "settled"),
                    help="settled: the LIGGGHTS-poured bed of dem_throughput.py (monodisperse, skin 0.1 d)")
    ap.add_argument("--beds", default=str(ROOT / "runs" / "liggghts_beds"), help="where the settled beds are cached")
    ap.add_argument("--shuffle", action="store_true", help="shuffle the grain ids of the settled bed (both trees)")
    ap.add_argument("--blocks", type=int, default=9)
    ap.add_argument("--substeps", type=int, default=100)
    ap.add_argument("--build", action="store_true", help="time a forced neighbour-list build, not the substep")
    ap.add_argument("--threads", type=int, default=1, help="CPU threads: 1, the serial form a run on 2 cores uses; "
                                                           "more, the parallel form (CUDA's kernels)")
    ap.add_argument("--no-append", action="store_true")
    a = ap.parse_args(argv)
    tmp = pathlib.Path(tempfile.mkdtemp(prefix="dem_ab_"))
    for name, tree in (("app_a", a.a), ("app_b", a.b)):
        shutil.copytree(pathlib.Path(tree) / "app", tmp / name, ignore=shutil.ignore_patterns("__pycache__"))
    sys.path.insert(0, str(tmp))
    import taichi as ti

    run_a = importlib.import_module("app_a.sim.runtime")
    run_b = importlib.import_module("app_b.sim.runtime")
    run_b.init("cpu", a.precision, a.threads)
    serial = a.threads == 1
    run_a._current = run_b._current  # one Taichi for both: a second ti.init would drop the first's fields
    rows = []
    for n in a.n:
        if a.bed == "settled":
            bed = settled(pathlib.Path(a.beds), n, a.shuffle)
            dems = {k: settled_solver(k, n, a.precision, bed, serial) for k in ("app_a", "app_b")}
        else:
            dems = {k: solver(k, n, a.poly, a.precision, a.rolling, serial) for k in ("app_a", "app_b")}
        for dem in dems.values():
            dem.advance(200)
        ti.sync()
        rebuild = {k: importlib.import_module(k + ".sim.dem.neighbors").REBUILD for k in dems}
        if a.build:
            for k, dem in dems.items():  # compile the substep on its own, with and without a build
                timed(dem, 2, True, rebuild[k]), timed(dem, 2, False, rebuild[k])
        cpu = {k: [] for k in dems}
        wall = {k: [] for k in dems}
        plain = {k: [] for k in dems}
        for b in range(a.blocks):
            order = list(dems) if b % 2 == 0 else list(dems)[::-1]
            for k in order:
                if a.build:
                    (c1, w1), (c0, w0) = (timed(dems[k], a.substeps, f, rebuild[k]) for f in (True, False))
                    cpu[k].append(c1 - c0)
                    wall[k].append(w1 - w0)
                    plain[k].append(c0)
                else:
                    c0, w0 = time.process_time(), time.perf_counter()
                    dems[k].advance(a.substeps)
                    ti.sync()
                    cpu[k].append(1e3 * (time.process_time() - c0) / a.substeps)
                    wall[k].append(1e3 * (time.perf_counter() - w0) / a.substeps)
        rc = [x / y for x, y in zip(cpu["app_a"], cpu["app_b"])]
        rw = [x / y for x, y in zip(wall["app_a"], wall["app_b"])]
        kind = "tri-disperse epsd" if a.poly else ("monodisperse epsd" if a.rolling else "monodisperse")
        if a.bed == "settled":
            kind = "settled (LIGGGHTS), ids shuffled" if a.shuffle else "settled (LIGGGHTS)"
        what = "build" if a.build else "substep"
        row = {"N": n, "bed": kind,
               f"A cpu ms/{what}": f"{statistics.median(cpu['app_a']):.3f}",
               f"B cpu ms/{what}": f"{statistics.median(cpu['app_b']):.3f}",
               "A/B cpu (median of pairs, min-max)": f"{statistics.median(rc):.3f} ({min(rc):.2f}-{max(rc):.2f})",
               "A/B wall": f"{statistics.median(rw):.3f}"}
        if a.build:
            rp = [x / y for x, y in zip(plain["app_a"], plain["app_b"])]
            row.update({"A / B cpu ms/substep without": f"{statistics.median(plain['app_a']):.3f} / "
                                                         f"{statistics.median(plain['app_b']):.3f}",
                        "A/B without": f"{statistics.median(rp):.3f}"})
        row["B contacts"] = dems["app_b"].diagnostics().get("contacts", "-")
        rows.append(row)
        print(rows[-1], flush=True)
    shutil.rmtree(tmp, ignore_errors=True)
    bed_text = "squeezed-lattice bed"
    if a.bed == "settled":
        bed_text = "settled LIGGGHTS bed (skin 0.1 d" + (", ids shuffled)" if a.shuffle else ")")
    title = (f"DEM substep, two commits in one process (cpu, {a.precision}, threads {a.threads}; A = {a.a}, B = {a.b}; "
             f"{bed_text} in a cylinder, Hertz-Mindlin + friction, dt = 2e-06 s; {a.blocks} interleaved "
             f"blocks of {a.substeps} substeps after 200 warm-up)")
    if a.build:
        title = (f"DEM list build, two commits in one process (cpu, {a.precision}, threads {a.threads}; A = {a.a}, B = {a.b}; "
                 f"{bed_text} in a cylinder; {a.blocks} interleaved blocks, each {a.substeps} substeps with a build "
                 f"forced before each and {a.substeps} without, after 200 warm-up; a build = their difference)")
    append_results(title, rows, "cpu", dry=a.no_append)


if __name__ == "__main__":
    main()
