"""The packed bed (`fbed pack`, app/io/bedpack.py): bytes a grain against resolution, and what a restart from it costs.

Part 1 (always): a million-grain bed of the poppy study's three classes, grains uniform in its 96 mm x 130 mm
column (a packing's gaps are no smaller: the code space per grain is the same), packed at each --resolutions:
bytes a grain and MB for --grains grains, the largest position error, pack and unpack time. Float32 positions
under gzip (the earlier packer's form) beside them.

Part 2 (--bed BED.h5 --preset PRESET [--set ...]): a settled bed restarted DEM-only from itself (every grain's
state: position, velocity, spin, radius), from float32 positions and radii, and from each packed resolution; each
restart runs --duration s (`fbed run PRESET --set particles.initial_state=...`), and its series give the
kinetic-energy peak [J] and end, the largest speed [m/s] and the bed height's change [m].

Part 3 (--moving BED.h5 --moving-preset PRESET [--moving-set ...]): a fluidized bed restarted, gas on, from every
grain's state, from packs that keep velocities and spins at each --speed-resolutions (positions at the largest
--resolutions), and from a pack without them (a bed at rest); each restart runs --duration s, and the rows give
the pack's bytes a grain, the kinetic energy at the start and its mean, and how far the bed height strays from the
full state's restart (the gas starts afresh in all: a run from particles.initial_state has no gas state).

    python benchmarks/bed_pack.py
    python benchmarks/bed_pack.py --bed runs/prep/bed.h5 --preset presets/mri_poppy_prepare.toml \\
        --set vessel.radius=0.012 --set "domain.lo=[-0.012,-0.012,0.0]" --set "domain.hi=[0.012,0.012,0.15]"
"""
from __future__ import annotations

import argparse
import os
import pathlib
import subprocess
import sys
import tempfile
import time

import h5py
import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from app.bench.common import append_results  # noqa: E402
from app.io import store  # noqa: E402

CLASSES = np.array([0.919e-3, 1.050e-3, 1.269e-3]) / 2  # m: the poppy seeds' radii


def sizes(n: int, resolutions, d: pathlib.Path) -> list[dict]:
    rng = np.random.default_rng(1)
    r = np.sqrt(rng.random(n)) * 0.048
    th = rng.random(n) * 2 * np.pi
    x = np.stack([r * np.cos(th), r * np.sin(th), rng.random(n) * 0.13], 1).astype(np.float32)
    rad = rng.choice(CLASSES.astype(np.float32), n)
    rows = []
    with h5py.File(d / "f32.h5", "w") as f:
        f.create_dataset("position", data=x, compression="gzip", compression_opts=6, shuffle=True)
        f.create_dataset("radius", data=rad, compression="gzip", compression_opts=6, shuffle=True)
    b = (d / "f32.h5").stat().st_size
    rows.append({"form": "float32 positions, gzip 6 + shuffle", "resolution [m]": "-",
                 "B a grain": f"{b / n:.2f}", f"MB for {n} grains": f"{b / 1e6:.2f}", "largest error [m]": "-",
                 "pack [s]": "-", "unpack [s]": "-"})
    for res in resolutions:
        t0 = time.perf_counter()
        info = store.write_packed_bed(d / "p.h5", x, rad, resolution=res)
        t1 = time.perf_counter()
        back, _, meta = store.read_checkpoint(d / "p.h5")
        t2 = time.perf_counter()
        q = np.rint((x - meta["origin"]) / meta["resolution"]).astype(np.int64)
        qb = np.rint((back["position"] - meta["origin"]) / meta["resolution"]).astype(np.int64)
        i = np.lexsort((*q.T[::-1], rad))
        j = np.lexsort((*qb.T[::-1], back["radius"].astype(np.float32)))
        err = float(np.abs(x[i].astype(np.float64) - back["position"][j]).max())
        rows.append({"form": "fbed pack", "resolution [m]": f"{info['resolution']:.3g}",
                     "B a grain": f"{info['bytes'] / n:.2f}", f"MB for {n} grains": f"{info['bytes'] / 1e6:.2f}",
                     "largest error [m]": f"{err:.3g}", "pack [s]": f"{t1 - t0:.2f}", "unpack [s]": f"{t2 - t1:.2f}"})
    return rows


def _run_from(path, preset: str, sets: list[str], duration: float, out: pathlib.Path) -> dict:
    cmd = [sys.executable, "-m", "app", "run", preset, "--arch", "cpu", "--out", str(out),
           "--set", f'particles.initial_state="{path}"', "--set", f"run.duration={duration}",
           "--set", "output.series_interval=1e-3", "--set", "output.average_from=0.0"] + \
        [a for s in sets for a in ("--set", s)]
    r = subprocess.run(cmd, capture_output=True, text=True, env=dict(os.environ, PYTHONPATH=str(ROOT)))
    if r.returncode:
        sys.exit(f"{path}: {r.stderr[-2000:]}")
    return store.read_series(out / "run.h5")


def restarts(bed: pathlib.Path, preset: str, sets: list[str], duration: float, resolutions,
             d: pathlib.Path) -> list[dict]:
    grains, _, _ = store.read_checkpoint(bed)
    alive = grains["alive"].astype(bool) if "alive" in grains else np.ones(len(grains["radius"]), bool)
    with h5py.File(d / "f32.h5", "w") as f:
        f.create_dataset("grains/position", data=grains["position"][alive].astype(np.float32))
        f.create_dataset("grains/radius", data=grains["radius"][alive].astype(np.float32))
    starts = [("every grain's state", bed), ("float32 positions and radii", d / "f32.h5")]
    for res in resolutions:
        store.write_packed_bed(d / f"p{res:g}.h5", grains["position"][alive], grains["radius"][alive], resolution=res)
        starts.append((f"fbed pack, {res:g} m", d / f"p{res:g}.h5"))
    rows = []
    for name, path in starts:
        s = _run_from(path, preset, ["particles.bed_height=0.0", "guard.interval=1e-3"] + sets, duration,
                      d / f"run{len(rows)}")
        rows.append({"restart from": name, "kinetic energy peak [J]": f"{s['kinetic_energy'].max():.3g}",
                     "at the end [J]": f"{s['kinetic_energy'][-1]:.3g}", "largest speed [m/s]":
                     f"{s['max_speed'].max():.3g}", "bed height change [m]":
                     f"{s['bed_height'][-1] - s['bed_height'][0]:.2g}"})
    return rows


def moving_restarts(bed: pathlib.Path, preset: str, sets: list[str], duration: float, resolution: float,
                    speed_resolutions, d: pathlib.Path) -> list[dict]:
    grains, _, _ = store.read_checkpoint(bed)
    alive = grains["alive"].astype(bool) if "alive" in grains else np.ones(len(grains["radius"]), bool)
    x, r, v, w = (grains[k][alive] for k in ("position", "radius", "velocity", "omega"))
    starts = [("every grain's state", bed, None)]
    for q in list(speed_resolutions) + [0.0]:
        info = store.write_packed_bed(d / f"m{q:g}.h5", x, r, resolution=resolution, velocity=v, omega=w,
                                      speed_resolution=q)
        what = f"fbed pack, speeds to {q:g} m/s" if q else "fbed pack, no speeds (at rest)"
        starts.append((what, d / f"m{q:g}.h5", info["bytes"] / len(r)))
    rows, ref = [], None
    for name, path, per_grain in starts:
        s = _run_from(path, preset, sets, duration, d / f"moving{len(rows)}")
        ref = s if ref is None else ref
        rows.append({"restart from": name, "B a grain": f"{per_grain:.2f}" if per_grain else "-",
                     "kinetic energy at the start [J]": f"{s['kinetic_energy'][0]:.4g}",
                     "its mean over the run [J]": f"{s['kinetic_energy'].mean():.4g}",
                     "bed height off the full state's, largest [m]":
                     f"{np.abs(s['bed_height'] - ref['bed_height']).max():.2g}"})
    return rows


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--grains", type=int, default=958000)
    ap.add_argument("--resolutions", type=float, nargs="+", default=[1e-7, 5e-7, 1e-6, 2e-6])
    ap.add_argument("--bed", type=pathlib.Path, help="a settled bed.h5 for the restarts (part 2)")
    ap.add_argument("--preset", help="the preset the restarts run (DEM only: its gas off)")
    ap.add_argument("--set", dest="sets", action="append", default=[], help="an override of the restarts' preset")
    ap.add_argument("--duration", type=float, default=0.03, help="each restart's simulated time [s]")
    ap.add_argument("--moving", type=pathlib.Path, help="a fluidized bed.h5 for the moving restarts (part 3)")
    ap.add_argument("--moving-preset", help="the preset the moving restarts run (gas on)")
    ap.add_argument("--moving-set", dest="moving_sets", action="append", default=[],
                    help="an override of the moving restarts' preset")
    ap.add_argument("--speed-resolutions", type=float, nargs="+", default=[1e-3, 3e-3, 1e-2])
    ap.add_argument("--dry", action="store_true", help="print, do not append to RESULTS.md")
    a = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        d = pathlib.Path(tmp)
        if not a.moving:
            append_results(f"Packed bed: size against resolution ({a.grains} grains of the poppy study's classes, "
                           "uniform in its 96 mm x 130 mm column; numpy and h5py)", sizes(a.grains, a.resolutions, d),
                           "cpu", a.dry)
        if a.bed:
            append_results(f"Packed bed: a settled bed restarted from it ({a.bed.name}, {a.preset} with "
                           f"{' '.join(a.sets) or 'no overrides'}; {a.duration:g} s DEM only, cpu)",
                           restarts(a.bed, a.preset, a.sets, a.duration, a.resolutions, d), "cpu", a.dry)
        if a.moving:
            res = max(a.resolutions)
            append_results(f"Packed bed: a fluidized bed restarted from it ({a.moving.name}, {a.moving_preset} with "
                           f"{' '.join(a.moving_sets) or 'no overrides'}; positions to {res:g} m; {a.duration:g} s, "
                           "gas on, cpu)", moving_restarts(a.moving, a.moving_preset, a.moving_sets, a.duration, res,
                                                           a.speed_resolutions, d), "cpu", a.dry)
    return 0


if __name__ == "__main__":
    sys.exit(main())
