"""Each drag law's U_mf for a uniform bed of the poppy seeds, at the packing fbed settles them into.

    python3 validation/mri/umf_uniform.py runs/prepared/mri_umf_prepare-*/bed.h5 [--radius 0.012]
    python3 validation/mri/umf_uniform.py runs/prepared/mri_umf_periodic_prepare-*/bed.h5 --box 0.024

Reads a settled bed (bed.h5): the bulk gas fraction between 0.2 and 0.8 of its height (the 95th percentile of
the grain heights) over the whole cross-section, the same in the annulus within one Sauter diameter of the wall
and in the core inside it (the narrow column's wall effect: looser packing at the wall), and the Sauter diameter
of its grains. For each law, U_mf is the superficial velocity at which the drag on a uniform bed at the bulk gas
fraction carries the buoyant weight: beta(eps, U / eps) U / eps^2 = (1 - eps)(rho_p - rho_g) g (the Sauter
diameter standing for the mixture, as in Ergun's equation). This is the law's own answer without the walls,
the grid and the bed's non-uniformity, to set beside the fluidization curve of presets/mri_umf.toml.
``--box W``: the bed of a laterally periodic box W wide (presets/mri_umf_periodic.toml), which has no wall:
its bulk over the whole section only.
Prints a markdown table. Imports app.sim.drag (Taichi), hence a script, not an analysis.
"""
from __future__ import annotations

import argparse
import pathlib
import sys

import h5py
import numpy as np
from scipy.optimize import brentq

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[2]))
from app.config.derived import grain_volume  # noqa: E402
from app.sim import drag  # noqa: E402

LAWS = ("koch_hill", "di_felice", "gidaspow", "beetstra")
RHO_P, RHO_G, MU, G = 1015.0, 1.2, 1.8e-5, 9.81


def band_voidage(x, r, r_lo, r_hi, z_lo, z_hi, axis=(0.0, 0.0)):
    """Gas fraction of the annulus r_lo <= radius < r_hi between heights z_lo and z_hi (grain volume by centre)."""
    rad = np.hypot(x[:, 0] - axis[0], x[:, 1] - axis[1])
    sel = (rad >= r_lo) & (rad < r_hi) & (x[:, 2] >= z_lo) & (x[:, 2] < z_hi)
    vol = np.sum(grain_volume(r[sel]))
    return 1.0 - vol / (np.pi * (r_hi ** 2 - r_lo ** 2) * (z_hi - z_lo))


def umf(law: str, eps: float, d: float) -> float:
    def excess(u):
        return float(drag.beta(law, eps, u / eps, d, RHO_G, MU)) * u / eps ** 2 - (1 - eps) * (RHO_P - RHO_G) * G

    return float(brentq(excess, 1e-4, 20.0))


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("bed")
    ap.add_argument("--radius", type=float, default=0.012, help="column radius [m]")
    ap.add_argument("--box", type=float, default=0.0, help="width [m] of a laterally periodic box (no wall)")
    a = ap.parse_args()
    with h5py.File(a.bed) as f:
        x = f["grains/position"][...].astype(float)
        r = f["grains/radius"][...].astype(float)
        alive = f["grains/alive"][...].astype(bool) if "grains/alive" in f else np.ones(len(r), bool)
    x, r = x[alive], r[alive]
    d32 = float(np.sum(r ** 3) / np.sum(r ** 2) * 2.0)
    h95 = float(np.quantile(x[:, 2], 0.95))
    z = (0.2 * h95, 0.8 * h95)
    if a.box > 0:
        sel = (x[:, 2] >= z[0]) & (x[:, 2] < z[1])
        eps = 1.0 - np.sum(grain_volume(r[sel])) / (a.box ** 2 * (z[1] - z[0]))
        print(f"grains {len(r)}, Sauter diameter {1e3 * d32:.4g} mm, bed height (z95) {1e3 * h95:.4g} mm, "
              f"gas fraction: bulk {eps:.4f} (periodic box, no wall)\n")
        print("| law | U_mf uniform bed at the bulk gas fraction [m/s] |\n|---|---|")
        for law in LAWS:
            print(f"| {law} | {umf(law, eps, d32):.4f} |")
        return 0
    R = a.radius
    eps = band_voidage(x, r, 0.0, R, *z)
    wall = band_voidage(x, r, R - d32, R, *z)
    core = band_voidage(x, r, 0.0, R - d32, *z)
    print(f"grains {len(r)}, Sauter diameter {1e3 * d32:.4g} mm, bed height (z95) {1e3 * h95:.4g} mm, "
          f"gas fraction: bulk {eps:.4f}, within one d of the wall {wall:.4f}, core {core:.4f}\n")
    print("| law | U_mf uniform bed at the bulk gas fraction [m/s] | at the core's [m/s] |\n|---|---|---|")
    for law in LAWS:
        print(f"| {law} | {umf(law, eps, d32):.4f} | {umf(law, core, d32):.4f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
