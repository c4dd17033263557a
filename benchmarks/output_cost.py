"""Output cost: milliseconds per step that run.h5's writers take with the Verma preset's records (every step
the 16 series; four 32 x 32 planes every 2 steps; the 32 x 32 x 115 3-D void fraction every 10 steps), for the
batched writer (app.io.store) and, with --compare REV, the writer of an earlier commit (its store.py from git).

Median of --repeats blocks of --steps steps after one warm-up block. Host-only (numpy and h5py): the same on a
GPU machine's host CPU, where it is part of the "callbacks" share of a run's wall time.

--gas also times the per-step gas reads on the Verma grid (32 x 32 x 115 cells in the 0.1 m cylinder, --arch):
copying the gas velocity and pressure to the host (pressure twice) with numpy reductions, as before, against
the device reductions (FlowSolver.gas_extremes, end_layer_pressures).

    python benchmarks/output_cost.py --compare 26dcc9c

Appends a table to benchmarks/RESULTS.md.
"""
from __future__ import annotations

import argparse
import importlib.util
import pathlib
import statistics
import subprocess
import tempfile
import time

import numpy as np

from app.bench.common import ROOT, append_results
from app.io import store as current_store

SERIES = ["time", "kinetic_energy", "kinetic_energy_rotational", "max_overlap", "max_speed", "grains_alive",
          "grains_removed", "bed_height", "gas_max_speed", "gas_cfl", "pressure_iterations", "pressure_residual",
          "divergence_residual", "clipped_cells", "pressure_drop", "wall_time"]


def load_store(rev: str | None):
    if rev is None:
        return current_store
    text = subprocess.run(["git", "show", f"{rev}:app/io/store.py"], cwd=ROOT, capture_output=True, text=True,
                          check=True).stdout
    path = pathlib.Path(tempfile.mkdtemp()) / f"store_{rev}.py"
    path.write_text(text)
    spec = importlib.util.spec_from_file_location(f"store_{rev}", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def block(store, steps: int, rng) -> float:
    """Wall seconds per step of ``steps`` steps of records into a fresh run.h5 (close included)."""
    plane = rng.random((32, 32)).astype(np.float32)
    volume = rng.random((32, 32, 115)).astype(np.float32)
    row = {k: 1.0 for k in SERIES}
    with tempfile.TemporaryDirectory() as d:
        rf = store.RunFile(pathlib.Path(d) / "run.h5", "bench")
        t0 = time.perf_counter()
        for i in range(steps):
            row["time"] = i * 1e-3
            rf.append(row)
            if i % 2 == 0:
                for z in range(4):
                    rf.frame(f"planes/z{z}", i * 1e-3, plane)
            if i % 10 == 0:
                rf.frame("porosity3d", i * 1e-3, volume)
        rf.close()
        return (time.perf_counter() - t0) / steps


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=1000)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--compare", default=None, help="git revision whose store.py to time as well")
    ap.add_argument("--dry", action="store_true", help="print, do not append to RESULTS.md")
    ap.add_argument("--gas", action="store_true", help="also time the per-step gas reads (Taichi)")
    ap.add_argument("--arch", default="cpu", choices=("cpu", "cuda"))
    a = ap.parse_args()
    rng = np.random.default_rng(0)
    rows = []
    for label, rev in [("batched (this commit)", None)] + ([(f"per write ({a.compare})", a.compare)] if a.compare else []):
        store = load_store(rev)
        block(store, a.steps // 4, rng)  # warm-up
        times = [block(store, a.steps, rng) for _ in range(a.repeats)]
        rows.append({"writer": label, "steps per block": a.steps, "median ms per step": f"{1e3 * statistics.median(times):.2f}",
                     "min": f"{1e3 * min(times):.2f}", "max": f"{1e3 * max(times):.2f}"})
    append_results("run.h5 output cost per step (Verma records)", rows, "cpu", dry=a.dry)
    if a.gas:
        append_results("per-step gas reads on the Verma grid", gas_reads(a.arch, a.repeats), a.arch, dry=a.dry)


def gas_reads(arch: str, repeats: int, calls: int = 200) -> list[dict]:
    from app.sim import gas as flow, runtime  # Taichi only for --gas: the writers' timing is host-only
    from app.sim.geometry import CylinderWall

    runtime.init(arch, "float32")
    cfg = flow.FlowConfig(shape=(32, 32, 115), h=0.003125, origin=(-0.05, -0.05, 0.0), rho=1.2, mu=1.8e-5,
                          gravity=(0, 0, -9.81), walls=(CylinderWall(center=(0.0, 0.0), radius=0.05),),
                          bcs={"bottom": flow.velocity_inlet((0, 0, 1.0)), "top": flow.pressure_outlet()})
    s = flow.FlowSolver(cfg)
    s.step(1e-3)
    vf = s.fields.vol_frac.to_numpy()
    bottom, top = vf[:, :, 0], vf[:, :, -1]

    def copies():
        u, p = s.cell_velocity(), s.pressure()
        float(np.sqrt((u ** 2).sum(-1)).max()), int((~np.isfinite(u)).sum() + (~np.isfinite(p)).sum())
        p = s.pressure()
        [float((p[:, :, k] * w).sum() / w.sum()) for k, w in ((0, bottom), (1, bottom), (-2, top), (-1, top))]

    def reductions():
        s.gas_extremes()
        s.end_layer_pressures()

    rows = []
    for label, fn in (("copies to the host + numpy (before)", copies), ("device reductions (now)", reductions)):
        fn()
        times = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            for _ in range(calls):
                fn()
            times.append((time.perf_counter() - t0) / calls)
        rows.append({"reads": label, "median ms per step": f"{1e3 * statistics.median(times):.3f}",
                     "min": f"{1e3 * min(times):.3f}", "max": f"{1e3 * max(times):.3f}"})
    return rows


if __name__ == "__main__":
    main()
