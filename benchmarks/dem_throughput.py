"""DEM throughput: particle-substeps per second, ms per substep and bytes per grain.

Grains of 2 mm in a cylinder, Hertz-Mindlin with tangential history, e = 0.9, mu = 0.5, E = 5 MPa,
dt = 2 us, gravity. Two beds:

* ``settled`` (the default with ``--liggghts``): a random bed poured and settled by LIGGGHTS 3.8
  (``benchmarks/liggghts/liggghts_pour.py``, ``pour_bed``: loose random grains fall into a cylinder
  about as wide as the settled bed is tall, then settle; cached under ``runs/liggghts_beds/`` keyed by
  size and parameters, so each bed is poured once). Its overlaps (about 1e-6 to 1e-5 m) are far above
  float32 rounding, so both codes see the same contacts.
* ``lattice`` (the default otherwise, e.g. on a GPU where there is no LIGGGHTS): a touching cubic
  lattice compressed by gravity. Its contacts have overlaps near zero, which float32 rounding halves:
  use it for fbed alone, never against LIGGGHTS.

With ``--liggghts`` (CPU) the comparison is like for like: fbed (``run.threads = 1``) and LIGGGHTS (one
process, ``OMP_NUM_THREADS=1``) start each block from the same settled state (positions, velocities,
angular velocities; tangential history zero in both), with the same contact law, step, skin (0.1 d)
and number of steps (``--substeps``, 1000), and run in turn: fbed, LIGGGHTS, fbed, LIGGGHTS, ... for
``--repeats`` pairs (after one untimed fbed warm-up that compiles its kernels). fbed's time is the
wall time of ``advance(substeps)``, its set-up (the sort by cell and the first list build,
``DemSolver.prepare``) done before the clock starts; LIGGGHTS's is its ``Loop time`` (its set-up, which
builds the list and computes the first forces, excluded). Before 2026-12-02 fbed's first sort and build
were timed (a slight overstatement of fbed's cost in the earlier tables). The ratio
fbed / LIGGGHTS in particle-substeps per second is the median of the pair-by-pair ratios. Contacts
(grain pairs + floor + cylinder, overlap > 0) are counted from each code's positions by one numpy
helper (``benchmarks_common.count_contacts``), at the start and after the timed block; LIGGGHTS's own
pair count (``compute contact/atom``) is printed as a check of the helper. The 1-minute load average
is recorded before every block, and each code's CPU time over the timed block (fbed: the process's;
LIGGGHTS: from /proc/PID/stat around its timed run): the core share (CPU / wall) is below 1 when the
load took the core away, and the ratio in CPU seconds is given beside the wall-time one.

    python3 benchmarks/dem_throughput.py --arch cpu --liggghts --sizes 10000 50000 125000 --precision float32 float64
    python3 benchmarks/dem_throughput.py --arch cuda --sizes 10000 100000 1000000

Appends a table to benchmarks/RESULTS.md (date, commit, machine, GPU).
"""
from __future__ import annotations

import argparse
import inspect
import os
import pathlib
import statistics
import sys
import time

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))
sys.path.insert(0, str(ROOT / "benchmarks" / "liggghts"))

import numpy as np  # noqa: E402

from app.bench.common import append_results, count_contacts, interleaved, median_ratio  # noqa: E402

D, RHO, E, NU, REST, MU, DT = 2e-3, 2500.0, 5e6, 0.3, 0.9, 0.5, 2e-6
POUR_REST, POUR_DT = 0.5, 2e-5  # the pour only: a damped, longer-step fall (the result is just a start)
CACHE = ROOT / "runs" / "liggghts_beds"


def bed(n: int):
    """Touching cubic lattice in a cylinder: (positions, cylinder radius)."""
    from liggghts_pour import make_lattice

    pos, radius = make_lattice(n, diameter=D, spacing=1.0)
    return pos, radius


def settled_bed(n: int, seed: int = 0) -> dict:
    """The LIGGGHTS-poured settled bed of ``n`` grains (from the cache when it was made before)."""
    from liggghts_pour import available, pour_bed

    res = pour_bed(n, D, RHO, E, NU, POUR_REST, MU, dt=POUR_DT, seed=seed, cache_dir=str(CACHE)) \
        if available() else None
    if res is None:
        from liggghts_pour import settled_radius  # the cache still serves a machine without LIGGGHTS
        hits = sorted(CACHE.glob(f"bed_n{n}_*.npz")) if CACHE.exists() else []
        if not hits:
            raise SystemExit(f"no settled bed of {n} grains in {CACHE} and no LIGGGHTS to pour one: "
                             "apt-get install -y liggghts, or use --bed lattice")
        z = np.load(hits[-1])
        res = {"position": z["position"], "velocity": z["velocity"], "omega": z["omega"],
               "cylinder_radius": float(z["cylinder_radius"]), "cached": True, "path": str(hits[-1]),
               "simulated_time": float(z["simulated_time"]), "pour_wall_s": float(z["pour_wall_s"])}
        assert abs(res["cylinder_radius"] - settled_radius(n, D)) < 1e-12
    return res


def fbed_scene(n: int, pos, radius, precision: str, threads: int, arch: str, skin: float = 0.0):
    """A grains-only fbed scene around ``pos`` in a cylinder of ``radius`` [m]; ``skin`` [m] (0: fbed's)."""
    from app.config import load_text
    from app.scene import Scene

    top = float(pos[:, 2].max()) + 4 * D
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
diameter = {D}
density = {RHO}
count = {n}
[contact]
model = "hertz_mindlin"
youngs_modulus = {E}
poisson_ratio = {NU}
restitution = {REST}
friction = {MU}
[dem]
dt = {DT}
skin = {skin}
"""
    zeros = np.zeros_like(pos)
    return Scene(load_text(text, "bench.toml"), "bench.toml",
                 initial={"position": pos, "velocity": zeros, "radius": np.full(n, D / 2)},
                 serial=arch == "cpu" and threads == 1)


def _bytes_per_grain(model, precision: str) -> float:
    try:
        from app.sim.fields import bytes_per_grain
    except ImportError:  # the DEM may move it into its own package
        from app.sim.dem import bytes_per_grain
    return bytes_per_grain(model, 4 if precision == "float32" else 8)


class FbedRun:
    """One size's fbed solver, compiled once; every block starts again from the same state."""

    def __init__(self, n, start, cyl_radius, precision, threads, arch, skin):
        from app.scene import build_simulation

        self.n, self.start, self.arch = n, start, arch
        self.scene = fbed_scene(n, start["position"], cyl_radius, precision, threads, arch, skin)
        self.dem = build_simulation(self.scene).dem
        self.bytes = _bytes_per_grain(self.scene.model, precision)
        self.with_omega = "omega" in inspect.signature(self.dem.set_grains).parameters

    def reset(self):
        kw = {"velocity": self.start["velocity"], "radius": np.full(self.n, D / 2)}
        if self.with_omega and self.start.get("omega") is not None:
            kw["omega"] = self.start["omega"]
        self.dem.set_grains(self.start["position"], **kw)

    def positions(self) -> np.ndarray:
        return np.asarray(self.dem.state_arrays()["position"])

    def block(self, substeps: int) -> float:
        """Reset, then the wall time [s] of ``substeps`` substeps."""
        import taichi as ti

        self.reset()
        if hasattr(self.dem, "prepare"):  # set-up outside the timing, as LIGGGHTS' is
            self.dem.prepare()
        ti.sync()
        b0 = self.builds()
        c0 = time.process_time()
        t0 = time.perf_counter()
        self.dem.advance(substeps)
        ti.sync()
        dt = time.perf_counter() - t0
        self.cpu = time.process_time() - c0
        self.last_builds = None if b0 is None else self.builds() - b0
        d = self.dem.diagnostics()
        if d["grains_removed"] or d["non_finite"]:
            raise RuntimeError(f"fbed lost grains or went non-finite at N = {self.n}: {d}")
        return dt

    def builds(self):
        """Neighbour-list builds so far (None where the solver does not say)."""
        nl = getattr(self.dem, "nlist", None)
        return getattr(nl, "builds", None)


def _contacts(pos, cyl_radius) -> dict:
    return count_contacts(pos, D / 2, cylinder_radius=cyl_radius, floor_z=0.0)


def _pct(a: int, b: int) -> str:
    return f"{100.0 * (a - b) / b:+.2f}%" if b else "-"


def fair_size(n, precision, threads, arch, substeps, repeats, skin_d, log=print) -> dict:
    """Interleaved fbed / LIGGGHTS blocks from the settled bed of ``n`` grains (see the module doc)."""
    from liggghts_pour import run_pour

    b = settled_bed(n)
    R = b["cylinder_radius"]
    log(f"N = {n}: settled bed {'from the cache' if b['cached'] else 'poured'} ({b.get('path')}; "
        f"{b['simulated_time']:.3f} s simulated, poured in {b['pour_wall_s']:.0f} s)")
    skin = skin_d * D
    f = FbedRun(n, b, R, precision, threads, arch, skin)
    if not f.with_omega:
        log("  note: this fbed's set_grains takes no omega: fbed starts without the bed's angular velocities")
    t0 = time.perf_counter()
    f.block(min(substeps, 20))  # compiles the kernels; not timed
    log(f"  fbed compiled and warmed up in {time.perf_counter() - t0:.1f} s")
    f.reset()
    c0_f = _contacts(f.positions(), R)           # fbed's own (rounded) start
    c0_l = _contacts(b["position"], R)            # LIGGGHTS reads it at full precision
    top_z = float(b["position"][:, 2].max()) + 4 * D
    t_f, t_l, loads, ends, cpu_f, cpu_l = [], [], [], {}, [], []
    for k, code in interleaved("fbed", "liggghts", repeats):
        loads.append(os.getloadavg()[0])
        if code == "fbed":
            t = f.block(substeps)
            t_f.append(t)
            cpu_f.append(f.cpu)
            if k == 0:
                ends["fbed"] = _contacts(f.positions(), R)
                ends["fbed_builds"] = f.last_builds
            log(f"  [{k}] fbed      {t:8.3f} s  {n * substeps / t:.3g} p-substeps/s  load {loads[-1]:.2f}  "
                f"core share {cpu_f[-1] / t:.2f}")
        else:
            r = run_pour(b["position"], D, RHO, E, NU, REST, MU, R, top_z=top_z, dt=DT, steps=substeps,
                         skin=skin, velocities=b["velocity"], omegas=b["omega"], check_overlap=False)
            if r["atoms_final"] != n:
                raise RuntimeError(f"LIGGGHTS lost {n - r['atoms_final']} grains at N = {n}")
            t_l.append(r["loop_time_s"])
            cpu_l.append(r["loop_cpu_s"])
            if k == 0:
                ends["liggghts"] = _contacts(r["final_positions"], R)
                ends["liggghts_own_pairs"] = r["contacts_final"]
                ends["liggghts_builds"] = r["neighbor_builds"]
                ends["version"] = r["version"]
            log(f"  [{k}] LIGGGHTS  {t_l[-1]:8.3f} s  {n * substeps / t_l[-1]:.3g} p-steps/s     "
                f"load {loads[-1]:.2f}  core share {cpu_l[-1] / t_l[-1]:.2f}")
    # pss ratio fbed / LIGGGHTS = t_LIGGGHTS / t_fbed, pair by pair
    q, qmin, qmax = median_ratio(t_l, t_f)
    qc = median_ratio(cpu_l, cpu_f)[0]  # the same in CPU seconds: what the load's preemption leaves out
    mf, ml = statistics.median(t_f), statistics.median(t_l)
    cf, cl = ends["fbed"], ends["liggghts"]
    log(f"  contacts (pairs + walls) at the start: fbed {c0_f['pairs']} + {c0_f['walls']}, LIGGGHTS "
        f"{c0_l['pairs']} + {c0_l['walls']} ({_pct(c0_f['total'], c0_l['total'])}); after {substeps} steps: "
        f"fbed {cf['pairs']} + {cf['walls']}, LIGGGHTS {cl['pairs']} + {cl['walls']} "
        f"({_pct(cf['total'], cl['total'])}; LIGGGHTS's own pair count {ends['liggghts_own_pairs']})")
    log(f"  fbed / LIGGGHTS = {q:.2f} (pairs {qmin:.2f}-{qmax:.2f}); in CPU time {qc:.2f}")
    return {"N": n, "precision": precision,
            "fbed ms/substep": f"{1e3 * mf / substeps:.3f}",
            "fbed p-substeps/s": f"{n * substeps / mf:.3g}",
            "LIGGGHTS p-steps/s": f"{n * substeps / ml:.3g}",
            "fbed / LIGGGHTS (min-max)": f"**{q:.2f}** ({qmin:.2f}-{qmax:.2f})",
            "contacts at start fbed / LIGGGHTS": f"{c0_f['total']} / {c0_l['total']} ({_pct(c0_f['total'], c0_l['total'])})",
            "contacts at end fbed / LIGGGHTS": f"{cf['total']} / {cl['total']} ({_pct(cf['total'], cl['total'])})",
            "of which walls (end)": f"{cf['walls']} / {cl['walls']}",
            "LIGGGHTS own pairs (end)": ends["liggghts_own_pairs"],
            "list builds fbed / LIGGGHTS": f"{ends['fbed_builds']} / {ends['liggghts_builds']}",
            "bytes/grain": f"{f.bytes:.0f}",
            "in CPU time": f"{qc:.2f}",
            "core share fbed / LIGGGHTS": f"{median_ratio(cpu_f, t_f)[0]:.2f} / {median_ratio(cpu_l, t_l)[0]:.2f}",
            "load (median, min-max)": f"{statistics.median(loads):.2f} ({min(loads):.2f}-{max(loads):.2f})",
            "_version": ends["version"]}


def fbed_only(n, precision, threads, arch, substeps, repeats, bed_kind, skin_d, log=print) -> dict:
    """fbed alone (e.g. on a GPU): median of ``repeats`` blocks, each from the same start."""
    if bed_kind == "settled":
        b = settled_bed(n)
        R = b["cylinder_radius"]
    else:
        pos, R = bed(n)
        b = {"position": pos, "velocity": np.zeros_like(pos), "omega": None}
    f = FbedRun(n, b, R, precision, threads, arch, skin_d * D if skin_d else 0.0)
    f.block(200)  # compiles; not timed
    times = [f.block(substeps) for _ in range(repeats)]
    med = statistics.median(times)
    c = _contacts(f.positions(), R)
    row = {"N": n, "precision": precision, "ms/substep": f"{1e3 * med / substeps:.3f}",
           "particle-substeps/s": f"{n * substeps / med:.3g}", "bytes/grain": f"{f.bytes:.0f}",
           "slots": f.scene.model.slots, "contacts at end (pairs + walls)": f"{c['pairs']} + {c['walls']}"}
    log(row)
    return row


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--arch", default="auto", choices=("auto", "cpu", "cuda"))
    ap.add_argument("--sizes", type=int, nargs="+", default=[10000, 100000])
    ap.add_argument("--substeps", type=int, default=1000)
    ap.add_argument("--repeats", type=int, default=3, help="timed blocks (with --liggghts: fbed/LIGGGHTS pairs)")
    ap.add_argument("--precision", nargs="+", default=["float32"], choices=("float32", "float64"))
    ap.add_argument("--threads", type=int, default=0, help="CPU threads (0: all; 1 with --liggghts)")
    ap.add_argument("--liggghts", action="store_true",
                    help="interleave with LIGGGHTS 3.8 on one core from the same settled bed (CPU)")
    ap.add_argument("--bed", default="auto", choices=("auto", "settled", "lattice"),
                    help="auto: settled with --liggghts, lattice otherwise")
    ap.add_argument("--skin", type=float, default=None,
                    help="neighbour skin / d (default 0.1 with --liggghts, for both codes; else fbed's)")
    ap.add_argument("--no-append", action="store_true", help="print only; do not append to RESULTS.md")
    a = ap.parse_args(argv)
    from app.sim import runtime

    bed_kind = a.bed if a.bed != "auto" else ("settled" if a.liggghts else "lattice")
    if a.liggghts and bed_kind != "settled":
        ap.error("--liggghts compares from the settled bed only (the lattice's contacts round away in float32)")
    if a.liggghts:
        from liggghts_pour import available

        if not available():
            print("LIGGGHTS not found: apt-get update -qq && apt-get install -y liggghts", file=sys.stderr)
            return 2
    threads = 1 if a.liggghts else a.threads
    skin_d = a.skin if a.skin is not None else (0.1 if a.liggghts else 0.0)
    t_start = time.perf_counter()
    for precision in a.precision:
        arch = runtime.init(a.arch, precision, threads or None)
        if a.liggghts and arch != "cpu":
            ap.error("--liggghts runs on the CPU only (--arch cpu)")
        rows = []
        for n in a.sizes:
            if a.liggghts:
                rows.append(fair_size(n, precision, threads, arch, a.substeps, a.repeats, skin_d))
            else:
                rows.append(fbed_only(n, precision, threads, arch, a.substeps, a.repeats, bed_kind, skin_d))
        if a.liggghts:
            version = rows[0].pop("_version")
            for r in rows[1:]:
                r.pop("_version")
            title = (f"DEM throughput against LIGGGHTS {version} ({arch}, fbed {precision}, one thread / one "
                     f"core each; settled random bed poured by LIGGGHTS in a cylinder, Hertz-Mindlin + "
                     f"tangential history, e = {REST}, mu = {MU}, E = {E:g} Pa, dt = {DT:g} s, skin {skin_d:g} d; "
                     f"{a.repeats} interleaved pairs of {a.substeps} steps from the same state, medians)")
        else:
            title = (f"DEM throughput ({arch}, {precision}, threads {threads or 'all'}; Hertz-Mindlin + "
                     f"tangential history, {'touching-lattice' if bed_kind == 'lattice' else 'settled random'} "
                     f"bed in a cylinder, dt = {DT:g} s, median of {a.repeats} x {a.substeps} substeps "
                     "after 200 warm-up)")
        append_results(title, rows, arch, dry=a.no_append)
    print(f"total wall time {time.perf_counter() - t_start:.0f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
