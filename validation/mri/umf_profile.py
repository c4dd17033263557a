"""A fixed bed's pressure drop from a drag law integrated over the bed's own gas-fraction profile, at layers of a
chosen thickness: how much the averaging scale alone lowers the law's pressure drop.

    python3 validation/mri/umf_profile.py runs/mri_umf_periodic-sweep/case-000/bed.h5 --box 0.024 \\
        --law koch_hill --velocity 0.1 --layers 0.25e-3 1e-3 3e-3

Reads a settled bed (bed.h5) of a laterally periodic box W wide (no wall: every layer spans the whole section).
Each layer's gas fraction is exact (each sphere's volume between the layer's two heights, spherical caps); the
law's pressure gradient beta(eps, U / eps) U / eps^2 (the convention of umf_uniform.py) is integrated over the
layers and divided by the buoyant weight of the same layers. Layers of the gas grid's cell size show what the
grid sees. Prints one line per layer thickness. Imports app.sim.drag (Taichi), hence a script.
"""
from __future__ import annotations

import argparse
import pathlib
import sys

import h5py
import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[2]))
from umf_uniform import G, MU, RHO_G, RHO_P  # noqa: E402
from app.sim import drag  # noqa: E402


def layer_gas_fraction(x: np.ndarray, r: np.ndarray, area: float, edges: np.ndarray) -> np.ndarray:
    """Gas fraction of each layer between consecutive ``edges`` [m] over a section of ``area`` [m^2]."""
    def below(z):  # each sphere's volume under height z
        t = np.clip(z - x[:, 2], -r, r)
        return np.pi * (r ** 2 * (t + r) - (t ** 3 + r ** 3) / 3)
    cum = np.array([np.sum(below(z)) for z in edges])
    return 1.0 - np.diff(cum) / (area * np.diff(edges))


def pressure_drop_over_weight(eps: np.ndarray, law: str, u: float, d: float) -> float:
    """The law's pressure drop over the buoyant weight, both summed over the layers holding grains."""
    sel = eps < 0.999
    e = eps[sel]
    grad = np.array([float(drag.beta(law, ei, u / ei, d, RHO_G, MU)) * u / ei ** 2 for ei in e])
    return float(np.sum(grad) / np.sum((1 - e) * (RHO_P - RHO_G) * G))


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("bed")
    ap.add_argument("--box", type=float, required=True, help="width [m] of the laterally periodic box")
    ap.add_argument("--law", default="koch_hill")
    ap.add_argument("--velocity", type=float, default=0.1, help="superficial gas velocity [m/s]")
    ap.add_argument("--layers", type=float, nargs="+", default=[0.25e-3, 1e-3, 3e-3], help="thicknesses [m]")
    a = ap.parse_args()
    with h5py.File(a.bed) as f:
        x = f["grains/position"][...].astype(float)
        r = f["grains/radius"][...].astype(float)
    d32 = float(np.sum(r ** 3) / np.sum(r ** 2) * 2.0)
    top = float(x[:, 2].max() + r.max())
    for dz in a.layers:
        edges = np.arange(0.0, top + dz, dz)
        eps = layer_gas_fraction(x, r, a.box ** 2, edges)
        print(f"layers of {1e3 * dz:.3g} mm: {a.law} at {a.velocity:g} m/s gives dp / W = "
              f"{pressure_drop_over_weight(eps, a.law, a.velocity, d32):.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
