"""One synthetic-MRI frame (app/probes_mri.py) of a million-grain bed: the grains read back and binned in numpy (the
probe before 2026-12-06) against the binning on the device (``DemSolver.slab_volumes``, one small image read back).

The poppy-seed bed's geometry (presets/mri_poppy.toml: the 96 mm cylinder, a 10 mm slab, 2 x 4 mm pixels... as
the preset sets them) with ``--n`` grains of the three size classes at random in its lower 0.2 m; both paths give
the same image to rounding (checked here). Medians of ``--repeats`` frames, alternated.

    python3 benchmarks/mri_frame_cost.py --arch cpu --n 1000000
"""
from __future__ import annotations

import argparse
import pathlib
import sys

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

from app.bench.common import alternated_ms, append_results  # noqa: E402


def host_frame(dem, im):
    """The probe's frame before: positions, radii and flags read back, the slab's grains picked, numpy."""
    x = dem.read("position")
    r = np.asarray(dem.radii(), np.float64)
    near = dem.read("alive").astype(bool)
    near &= np.abs(x[:, 1] - im.yc) < 0.5 * im.width + r + 1e-6
    return im.volumes(x[near].astype(np.float64), r[near])


def poppy_dem(cfg, n: int, z_top: float, rng):
    """A DEM of ``n`` grains of the poppy preset's three classes (``cfg``, presets/mri_poppy.toml) placed at random
    in its cylinder (within 0.95 of its cross-section) between z = 2 mm and ``z_top`` [m], drawn from ``rng``."""
    from app.scene import Scene
    from app.sim.dem import DemSolver

    radius = cfg.vessel.radius
    rho = radius * np.sqrt(rng.uniform(0.0, 0.95, n))
    phi = rng.uniform(0.0, 2 * np.pi, n)
    pos = np.column_stack([rho * np.cos(phi), rho * np.sin(phi), rng.uniform(0.002, z_top, n)])
    r = 0.5 * rng.choice(np.asarray(cfg.particles.diameters), n)
    dem = DemSolver(Scene(cfg, "mri_poppy.toml", initial={"position": pos, "radius": r}).model)
    dem.set_grains(pos, radius=r)
    return dem


def device_frame(dem, im):
    return dem.slab_volumes(im.yc, 0.5 * im.width, (im.x0, im.z0), (im.dx, im.dz), (im.nx, im.nz))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--arch", default="cpu", choices=("cpu", "cuda"))
    ap.add_argument("--n", type=int, default=1000000)
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--no-append", action="store_true")
    a = ap.parse_args(argv)
    from app.config import load
    from app.probes_mri import MriImage
    from app.sim import runtime

    arch = runtime.init(a.arch, "float32")
    cfg = load(ROOT / "presets" / "mri_poppy.toml")
    im = MriImage(cfg)
    dem = poppy_dem(cfg, a.n, 0.2, np.random.default_rng(1))
    same = np.allclose(host_frame(dem, im), device_frame(dem, im), rtol=1e-9, atol=0.0)
    ms = alternated_ms({"host": lambda: host_frame(dem, im), "device": lambda: device_frame(dem, im)}, a.repeats)
    host, dev = ms["host"], ms["device"]
    row = {"N": a.n, "pixels": f"{im.nx} x {im.nz}", "host ms/frame": f"{host:.1f}", "device ms/frame": f"{dev:.2f}",
           "host / device": f"{host / dev:.0f}", "same image": "yes" if same else "NO"}
    print(row, flush=True)
    append_results(f"Synthetic MRI frame, grains read back and binned in numpy against binned on the device "
                   f"({arch}, float32; the poppy-seed cylinder and slab, random grains of its three classes; median of "
                   f"{a.repeats})", [row], arch, dry=a.no_append)
    return 0 if same else 1


if __name__ == "__main__":
    sys.exit(main())
