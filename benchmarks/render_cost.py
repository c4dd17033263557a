"""Rendering cost: milliseconds per frame (snapshot kernel, GGUI draw, read-back, panel and stamp)
against the DEM step it rides on, for beds of --sizes grains.

The scene is the DEM throughput bed (grains of 2 mm on a touching lattice in a cylinder,
Hertz-Mindlin with history). For each size: the median of --frames frames after two warm-up
frames, for the perspective view of every grain and for the slab view; and the median time of
a block of 20 DEM substeps. The share of the run is the frame time over (frame time + the DEM
time between frames), with the preset defaults of a frame every 10 ms of simulated time and
the substeps per 1 ms step given by --substeps-per-step (73 for presets/boyce.toml).

    python benchmarks/render_cost.py --arch cuda --sizes 260000 1000000

Appends a table to benchmarks/RESULTS.md.
"""
from __future__ import annotations

import argparse
import statistics
import time

from dem_throughput import bed, fbed_scene  # benchmarks/, this script's folder

from app.bench.common import append_results
from app.gui.render import Renderer, ViewSettings
from app.scene import build_simulation
from app.sim import runtime


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--arch", default="auto", choices=("auto", "cpu", "cuda"))
    ap.add_argument("--sizes", type=int, nargs="+", default=[20000])
    ap.add_argument("--frames", type=int, default=7)
    ap.add_argument("--width", type=int, default=1280)
    ap.add_argument("--height", type=int, default=720)
    ap.add_argument("--frame-interval-steps", type=int, default=10, help="fluid steps between frames")
    ap.add_argument("--substeps-per-step", type=int, default=73)
    ap.add_argument("--dry", action="store_true")
    a = ap.parse_args(argv)
    arch = runtime.init(a.arch, "float32")
    rows = []
    for n in a.sizes:
        pos, radius = bed(n)
        scene = fbed_scene(n, pos, radius, "float32", 0, arch)
        dem = build_simulation(scene).dem
        dem.set_grains(pos, radius=scene.initial["radius"])
        dem.advance(20)
        runtime.sync()
        t0 = time.perf_counter()
        for _ in range(3):
            dem.advance(20)
        runtime.sync()
        substep = (time.perf_counter() - t0) / 60
        for view in ("perspective", "slab"):
            r = Renderer(dem, None, scene.walls, scene.cfg.domain.lo, scene.cfg.domain.hi,
                         ViewSettings(width=a.width, height=a.height, view=view), title="bench")
            for _ in range(2):
                r.frame(0.0)
            times = []
            for _ in range(a.frames):
                t0 = time.perf_counter()
                r.frame(0.0)
                times.append(time.perf_counter() - t0)
            drawn = r.update_snapshot()
            r.close()
            frame = statistics.median(times)
            between = a.frame_interval_steps * a.substeps_per_step * substep
            rows.append({"grains": n, "view": view, "drawn": drawn, "size": f"{a.width}x{a.height}",
                         "frame ms": f"{1e3 * frame:.1f}", "DEM substep ms": f"{1e3 * substep:.3f}",
                         "DEM ms between frames": f"{1e3 * between:.0f}",
                         "render share": f"{100 * frame / (frame + between):.1f}%"})
            print(rows[-1], flush=True)
    append_results(f"Render cost ({arch}, frame every {a.frame_interval_steps} steps of "
                   f"{a.substeps_per_step} substeps)", rows, arch, dry=a.dry)


if __name__ == "__main__":
    main()
