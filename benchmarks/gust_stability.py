"""Stability of the gas's second-order force splitting (``gas.trace_forces``) with MacCormack convection: the case
that blew up the million-grain Verma bed's freeboard (validation/verma/README.md, runs 3-4), gas only.

Scene: the Verma cross-section (32 x 32 cells of 3.125 mm; ``cyl``: the 0.1 m cylinder with the preset's
min_open_fraction 0.5, ``box``: the square box's side walls), ``--nz`` cells high, a pressure outlet on top; the
inlet 1.02 m/s plus three 8 m/s Gaussian gusts (6 mm wide) whose centres wander (seeded), dt = 1 ms (a gust's CFL
about 2.9). Each run (geometry x seed x trace on/off) is its own process with Taichi on one thread (the serial form:
deterministic); it reports the peak gas speed over ``--steps`` steps and stops at 150 m/s (a blow-up). With trace
off the peak is the gusts' own (~18-24 m/s); ``--tree`` runs another checkout's code (e.g. a worktree of an older
commit) for a before/after table.

    python3 benchmarks/gust_stability.py --seeds 3 4 5 --steps 800 [--tree /tmp/old]
"""
from __future__ import annotations

import argparse
import concurrent.futures
import os
import pathlib
import subprocess
import sys

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

BLOW_UP = 150.0  # m/s

CHILD = r"""
import math, sys
import numpy as np
from app.sim import runtime
runtime.init("cpu", sys.argv[1], threads=1)
from app.sim import gas
from app.sim.geometry import CylinderWall
precision, geom, seed, trace, steps, nz = sys.argv[1], sys.argv[2], int(sys.argv[3]), sys.argv[4] == "1", \
    int(sys.argv[5]), int(sys.argv[6])
H, R = 3.125e-3, 0.05
walls = (CylinderWall(center=(R, R), radius=R),) if geom == "cyl" else ()
cfg = gas.FlowConfig(shape=(32, 32, nz), h=H, rho=1.2, mu=1.8e-5, gravity=(0.0, 0.0, -9.81), walls=walls,
                     pressure_form="shared", convection="maccormack", tol=1e-6, min_open_fraction=0.5,
                     trace_forces=trace,
                     bcs={"bottom": gas.velocity_inlet((0.0, 0.0, 1.02)), "top": gas.pressure_outlet(0.0)})
s = gas.FlowSolver(cfg)
xc = (np.arange(32) + 0.5) * H
X, Y = np.meshgrid(xc, xc, indexing="ij")
rng = np.random.default_rng(seed)
c, vel = rng.uniform(0.03, 0.07, (3, 2)), rng.normal(0, 0.3, (3, 2))
peak, at, dt, total = 0.0, 0, 1e-3, 0.0
for n in range(steps):
    c += vel * dt
    vel = np.where((c < 0.02) | (c > 0.08), -vel, vel) + rng.normal(0, 0.05, vel.shape)
    prof = 1.02 + sum(8.0 * np.exp(-((X - c[k, 0]) ** 2 + (Y - c[k, 1]) ** 2) / (2 * 0.006 ** 2)) for k in range(3))
    if geom == "cyl":
        prof *= (X - R) ** 2 + (Y - R) ** 2 < R ** 2
    s.set_inlet_profile("bottom", prof)
    u = s.step(dt).cfl * H / dt
    total += u
    if u > peak or not math.isfinite(u):
        peak, at = u, n
    if not math.isfinite(u) or u > %(blow)r:
        break
print("RESULT", peak, at, n + 1, total / (n + 1))
""" % {"blow": BLOW_UP}


def one(tree: str, precision: str, geom: str, seed: int, trace: bool, steps: int, nz: int) -> dict:
    env = dict(os.environ, PYTHONPATH=tree)
    out = subprocess.run([sys.executable, "-c", CHILD, precision, geom, str(seed), "1" if trace else "0", str(steps),
                          str(nz)], cwd=tree, env=env, capture_output=True, text=True, timeout=3600)
    line = [x for x in out.stdout.splitlines() if x.startswith("RESULT")]
    if not line:
        raise RuntimeError(out.stderr[-2000:])
    peak, at, ran, mean = line[0].split()[1:]
    return {"peak": float(peak), "at": int(at), "ran": int(ran), "mean": float(mean)}


def main(argv=None) -> int:
    from app.bench.common import append_results, commit

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[3, 4, 5])
    ap.add_argument("--geoms", nargs="+", choices=("cyl", "box"), default=["cyl", "box"])
    ap.add_argument("--steps", type=int, default=800)
    ap.add_argument("--nz", type=int, default=40)
    ap.add_argument("--precision", choices=("float32", "float64"), default="float32")
    ap.add_argument("--tree", default=None, help="another checkout to run as 'before' (its own code, one process each)")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--dry", action="store_true")
    a = ap.parse_args(argv)
    trees = [("this tree", str(ROOT))] + ([("--tree", a.tree)] if a.tree else [])
    cases = [(name, tree, g, s, t) for g in a.geoms for s in a.seeds for name, tree in trees
             for t in ((True, False) if name == "this tree" else (True,))]
    with concurrent.futures.ThreadPoolExecutor(a.jobs) as ex:
        res = list(ex.map(lambda c: one(c[1], a.precision, c[2], c[3], c[4], a.steps, a.nz), cases))
    rows = []
    for (name, tree, g, s, t), r in zip(cases, res):
        label = f"{name} ({commit() if tree == str(ROOT) else pathlib.Path(tree).name})"
        rows.append({"code": label, "geometry": g, "seed": s, "trace_forces": t, "peak gas speed m/s": f"{r['peak']:.1f}",
                     "mean of the steps' peaks m/s": f"{r['mean']:.2f}",
                     "at step": r["at"], "steps run": r["ran"],
                     "outcome": "blow-up" if r["peak"] > BLOW_UP or r["peak"] != r["peak"] else "bounded"})
        print(rows[-1], flush=True)
    append_results(f"Gas force splitting under gusts: peak gas speed (cpu, {a.precision}, one thread; 32x32x{a.nz} "
                   f"cells of 3.125 mm, pressure outlet, 1.02 m/s + three wandering 8 m/s gusts, MacCormack, dt = 1 ms; "
                   f"{a.steps} steps or to {BLOW_UP:g} m/s)", rows, "cpu", dry=a.dry)
    return 0


if __name__ == "__main__":
    sys.exit(main())
