"""DEM substep cost on one CPU thread (or any arch), through the public DemSolver API only, so the same
script times two commits side by side (copy it into the other tree).

Bed: grains of 2 mm on a cubic lattice squeezed to a pitch of 0.997 d (jittered by 0.1% d) in a cylinder, compressed by gravity
(Hertz-Mindlin, friction 0.5, E = 5 MPa, dt = 2 us), as benchmarks/dem_throughput.py's; ``--poly`` uses
the tri-disperse 0.919/1.050/1.269 mm sizes (equal numbers) with elastic-plastic rolling friction.
Prints one line: N, precision, median ms per substep over ``--repeats`` blocks after a warm-up,
particle-substeps/s, bytes per grain, touching pairs.

    python benchmarks/dem_substep.py --sizes 10000 --precision float32 --threads 1
    python benchmarks/dem_substep.py --sizes 100000 --shuffle --sort-interval 0   # the grains left unsorted
"""
from __future__ import annotations

import argparse
import pathlib
import statistics
import sys
import time

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks" / "liggghts"))

import numpy as np  # noqa: E402

D, RHO, E, NU, REST, MU, DT = 2e-3, 2500.0, 5e6, 0.3, 0.9, 0.5, 2e-6
POPPY = (0.919e-3, 1.050e-3, 1.269e-3)


def scene_for(n, poly, precision, threads, arch):
    from liggghts_pour import make_lattice

    from app.config import load_text
    from app.scene import Scene

    dmax = POPPY[-1] if poly else D
    pos, radius = make_lattice(n, diameter=dmax, spacing=1.0)
    # squeezed 0.3% with a jitter of 0.1% d: every lattice neighbour touches, as in a settled bed, and no
    # contact hangs on float32 rounding
    pos = pos * 0.997 + np.random.default_rng(0).uniform(-1e-3, 1e-3, pos.shape) * dmax
    top = float(pos[:, 2].max()) + 4 * dmax
    sizes = (f"diameter = 0.0\ndiameters = [{POPPY[0]}, {POPPY[1]}, {POPPY[2]}]\nfractions = [0.3333, 0.3333, "
             f"0.3334]\nfractions_by = \"number\"" if poly else f"diameter = {D}")
    rolling = "rolling_friction = 0.1\nrolling_model = \"epsd\"\n" if poly else ""
    text = f"""
[run]
duration = 1.0
precision = "{precision}"
threads = {threads}
[domain]
lo = [{-radius}, {-radius}, 0.0]
hi = [{radius}, {radius}, {top}]
[vessel]
shape = "cylinder"
radius = {radius}
[particles]
{sizes}
density = {RHO}
count = {n}
[contact]
model = "hertz_mindlin"
youngs_modulus = {E}
poisson_ratio = {NU}
restitution = {REST}
friction = {MU}
{rolling}[dem]
dt = {DT}
"""
    rng = np.random.default_rng(1)
    r = rng.choice(np.asarray(POPPY) / 2, n) if poly else np.full(n, D / 2)
    zeros = np.zeros_like(pos)
    scene = Scene(load_text(text, "bench.toml"), "bench.toml",
                  initial={"position": pos, "velocity": zeros, "radius": r},
                  serial=arch == "cpu" and threads == 1)
    return scene, pos, r


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--arch", default="cpu", choices=("cpu", "cuda"))
    ap.add_argument("--sizes", type=int, nargs="+", default=[10000])
    ap.add_argument("--substeps", type=int, default=300)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--warmup", type=int, default=200)
    ap.add_argument("--precision", default="float32", choices=("float32", "float64"))
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--poly", action="store_true", help="tri-disperse bed with epsd rolling friction")
    ap.add_argument("--settle", type=int, default=0,
                    help="substeps run before the warm-up (the tri-disperse lattice is spaced for its largest grains: "
                         "it needs ~10000 to compact into touching contacts; cheap on a GPU)")
    ap.add_argument("--shuffle", action="store_true",
                    help="shuffle the grain ids (memory order then has nothing to do with space)")
    ap.add_argument("--sort-interval", type=int, default=None,
                    help="the DEM's sort_interval (list builds between re-orderings by cell; 0: never); default: "
                         "the model's")
    ap.add_argument("--diag-calls", type=int, default=0,
                    help="also time this many diagnostics records (a run's series and guard take one a fluid step): "
                         "ms a call, read back included")
    a = ap.parse_args(argv)
    import dataclasses

    import taichi as ti

    from app.sim import runtime
    from app.sim.dem import DemSolver
    try:
        from app.sim.dem import bytes_per_grain
    except ImportError:  # before the dem package
        from app.sim.fields import bytes_per_grain

    arch = runtime.init(a.arch, a.precision, a.threads or None)
    for n in a.sizes:
        scene, pos, r = scene_for(n, a.poly, a.precision, a.threads, arch)
        if a.shuffle:
            perm = np.random.default_rng(12).permutation(n)
            pos, r = pos[perm], r[perm]
        model = scene.model
        if a.sort_interval is not None and hasattr(model, "sort_interval"):
            model = dataclasses.replace(model, sort_interval=a.sort_interval)
        dem = DemSolver(model)
        dem.set_grains(pos, radius=r)
        for _ in range(a.settle // 1000):
            dem.advance(1000)
        dem.advance(a.warmup)
        ti.sync()
        times = []
        for _ in range(a.repeats):
            t0 = time.perf_counter()
            dem.advance(a.substeps)
            ti.sync()
            times.append(time.perf_counter() - t0)
        med = statistics.median(times)
        d = dem.diagnostics()
        assert d["grains_removed"] == 0 and d["non_finite"] == 0
        diag_ms = "-"
        if a.diag_calls:
            per = []
            for _ in range(3):
                t0 = time.perf_counter()
                for _ in range(a.diag_calls):
                    dem.diagnostics()
                per.append((time.perf_counter() - t0) / a.diag_calls)
            diag_ms = f"{1e3 * statistics.median(per):.3f}"
        print(f"N={n} {a.precision} {'poly' if a.poly else 'mono'} ms/substep={1e3 * med / a.substeps:.4f} "
              f"pss={n * a.substeps / med:.4g} bytes/grain={bytes_per_grain(scene.model, 4 if a.precision == 'float32' else 8):.0f} "
              f"slots={scene.model.slots} builds={dem.nlist.builds} contacts={d.get('contacts', '-')} "
              f"shuffled={a.shuffle} sort_interval={getattr(model, 'sort_interval', '-')} ms/diagnostics={diag_ms}", flush=True)


if __name__ == "__main__":
    main()
