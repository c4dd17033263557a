"""What a bed run's outputs say: the figures of the accuracy bench's coupled bed (:mod:`.bed_cases`).

Owns: the bed's material and the inlet's ramp (glass beads of 3 mm in air, Wen-Yu drag), and the figures read
from a finished run's files or from a packing: the voidage of horizontal slices and of the bulk, the drag law's
U_mf at a voidage, the U_mf read off the fixed-bed part of the ramp, and over a window the bed height, the force
balance (pressure drop, the floor's force, the grains' momentum change), bubbles and the slug's gas pocket, and
the stepping cost. Plain numpy and h5py: nothing here runs a solver.
"""
from __future__ import annotations

import json
import math
import pathlib

import h5py
import numpy as np
from scipy.optimize import brentq

from ..analysis import bubbles
from ..analysis.verma import MAX_AREA_FRACTION
from ..config.derived import grain_mass
from ..config.schema import ContactConfig
from ..io import store
from ..sim import drag

DIAMETER, DENSITY = 3.0e-3, 2500.0   # [m], [kg/m^3]: glass; 3 mm for a DEM step a CPU core can afford
GAS_DENSITY, GAS_VISCOSITY = 1.2, 1.8e-5
GRAVITY = 9.81
DRAG = "wen_yu"
INLET_RAMP = 0.1                     # [s] the inlet rises linearly from 0 over this time (slow: a fixed-bed curve)
WARM_UP = 0.02                       # [s] steps left out of the cost (kernel compilation)
UMF_FIT = (0.3, 0.7)                 # fixed-bed points fitted, as fractions of the predicted U_mf


def voidage_profile(position: np.ndarray, radius: np.ndarray, area: float, dz: float, top: float):
    """Gas fraction in horizontal slices of thickness dz [m] from z = 0 to ``top`` [m], from the grains' exact
    sphere-slice volumes over ``area`` [m^2]; returns (slice centres [m], eps)."""
    edges = np.arange(0.0, top + dz, dz)
    r = radius[:, None]
    s = np.clip(edges[None, :] - position[:, 2:3], -r, r)          # each plane relative to each centre
    below = np.pi * (r * r * s - s ** 3 / 3.0 + 2.0 * r ** 3 / 3.0)  # grain volume below each plane
    return 0.5 * (edges[1:] + edges[:-1]), 1.0 - np.diff(below, axis=1).sum(0) / (area * dz)


def bulk_voidage(position: np.ndarray, radius: np.ndarray, area: float) -> float:
    """Gas fraction of the bed's bulk, between 0.2 and 0.8 of its height (the 95th percentile of the grain
    heights, as the bed-height diagnostic): away from the ordered layer on the floor and the loose surface."""
    h95 = float(np.quantile(position[:, 2], 0.95))
    zc, eps = voidage_profile(position, radius, area, 0.05 * h95, h95)
    return float(np.mean(eps[(zc > 0.2 * h95) & (zc < 0.8 * h95)]))


def predicted_umf(eps: float) -> float:
    """U_mf [m/s] the drag law predicts for a uniform bed of gas fraction ``eps``: the superficial velocity at
    which the drag per bed volume, beta(eps, U/eps) U / eps^2, carries the buoyant weight (1 - eps)(rho_p -
    rho_g) g."""
    def excess(u):
        beta = float(drag.beta(DRAG, eps, u / eps, DIAMETER, GAS_DENSITY, GAS_VISCOSITY))
        return beta * u / eps ** 2 - (1.0 - eps) * (DENSITY - GAS_DENSITY) * GRAVITY

    return float(brentq(excess, 1e-3, 20.0))


def fixed_bed_umf(series: dict, u_final: float, u_pred: float, weight: float, fluid_step: float,
                  bed_height: float, eps: float, domain_height: float) -> float:
    """U_mf [m/s] read off the ramp: dp = a U + b U^2 fitted to the fixed-bed points between UMF_FIT of the
    predicted U_mf and extended to the weight per area ``weight`` [Pa] (the classical reading: where the
    fixed-bed curve meets dp = W). The gas column's acceleration, rho_g dU/dt (H - H_bed + H_bed / eps), is
    taken off the pressure drop first (about 2% of it on this ramp)."""
    t = series["time"]
    ramp = np.clip((t - fluid_step) / INLET_RAMP, 0.0, 1.0)   # a record at t follows the step blown at t - step
    u = u_final * ramp
    accel = np.where((ramp > 0) & (ramp < 1), u_final / INLET_RAMP, 0.0)
    dp = series["pressure_drop"] - GAS_DENSITY * accel * (domain_height - bed_height + bed_height / eps)
    sel = (u >= UMF_FIT[0] * u_pred) & (u <= UMF_FIT[1] * u_pred)
    a, b = np.linalg.lstsq(np.column_stack([u[sel], u[sel] ** 2]), dp[sel], rcond=None)[0]
    return float((-a + math.sqrt(a * a + 4.0 * b * weight)) / (2.0 * b) if b > 0 else weight / a)


def _momentum(group) -> float:
    r, v = group["radius"][...].astype(float), group["velocity"][...].astype(float)
    return float(np.sum(grain_mass(r, DENSITY) * v[:, 2]))


def floor_force(group, youngs_modulus: float) -> float:
    """Upward force of the floor on the grains of a snapshot [N]: Hertz's elastic force of each grain's overlap
    with the floor (the floor as stiff as the grains: E* = E / (2 (1 - nu^2))). Damping is left out: it pushes
    while an impact compresses and pulls while it rebounds, and averages out over the window's many contacts."""
    nu = ContactConfig.__dataclass_fields__["poisson_ratio"].default
    r = group["radius"][...].astype(float)
    overlap = np.clip(r - group["position"][:, 2].astype(float), 0.0, None)
    return float(np.sum(4.0 / 3.0 * youngs_modulus / (2.0 * (1.0 - nu * nu)) * np.sqrt(r) * overlap ** 1.5))


def void_figures(frames: np.ndarray, times: np.ndarray, h: float, mask: np.ndarray, series: dict) -> dict:
    """From 3-D void-fraction frames (nt, nx, ny, nz): the mean equivalent diameter of the bubbles in the
    horizontal layers below the bed surface (Verma's rule: eps > 0.7, regions over half the cross-section
    dropped), their number, and the mean height of the gas pocket (the layers below the surface whose
    cross-section mean eps exceeds 0.7: the slug that lifts the bed)."""
    z = (np.arange(frames.shape[3]) + 0.5) * h
    surface = np.interp(times, series["time"], series["bed_height"])
    diameters, pockets = [], []
    for frame, top in zip(frames, surface):
        inside = z < top - h
        layer_eps = (frame * mask[:, :, None]).sum((0, 1)) / mask.sum()
        pockets.append(h * np.count_nonzero(inside & (layer_eps > bubbles.THRESHOLD)))
        diameters += [b["diameter"] for k in np.nonzero(inside)[0]
                      for b in bubbles.plane_bubbles(frame[:, :, k], h, mask=mask,
                                                     max_area=MAX_AREA_FRACTION * mask.sum() * h * h)]
    return {"bubble_diameter": float(np.mean(diameters)) if diameters else float("nan"), "bubbles": len(diameters),
            "gas_pocket_height": float(np.mean(pockets))}


def window_stats(run_dir: pathlib.Path, t0: float, t1: float, youngs_modulus: float) -> dict:
    """Over [t0, t1] [s] of a finished run: bed height (mean, std, peak); the pressure drop over the weight,
    raw and as the force balance (with the grains' momentum change and the floor's force); the largest
    overlap; bubbles and the gas pocket (``void_figures``)."""
    summary = json.loads((run_dir / "summary.json").read_text())
    series = store.read_series(run_dir / "run.h5")
    t = series["time"]
    sel = (t >= t0 - 1e-9) & (t <= t1 + 1e-9)
    height = series["bed_height"][sel]
    dp_mean = float(np.trapezoid(series["pressure_drop"][sel], t[sel]) / (t[sel][-1] - t[sel][0]))
    weight = summary["bed_weight_per_area"]
    with h5py.File(run_dir / "run.h5", "r") as f:
        snaps = sorted(((float(g["time"][()]), g) for g in f["particles"].values()), key=lambda s: s[0])
        snaps = [(ts, g) for ts, g in snaps if t0 - 1e-9 <= ts <= t1 + 1e-9]
        radius = snaps[0][1]["radius"][...].astype(float)
        change = _momentum(snaps[-1][1]) - _momentum(snaps[0][1])
        ts = np.array([ts for ts, _ in snaps])
        floor = float(np.trapezoid([floor_force(g, youngs_modulus) for _, g in snaps], ts) / (ts[-1] - ts[0]))
        vt = f["porosity3d"]["time"][...]
        pick = (vt >= t0 - 1e-9) & (vt <= t1 + 1e-9)
        frames = f["porosity3d"]["porosity"][pick]
        h = float(f["porosity3d"].attrs["h"])
        mask = f["planes"]["mask"][...].astype(bool)
    # mean(dp) A + floor = W + (change of the grains' vertical momentum) / T: the momentum term is the
    # slug's rise and fall, the floor's the grains raining out of the slug onto it (walls are frictionless)
    area = float(np.sum(grain_mass(radius, DENSITY))) * GRAVITY * (1 - GAS_DENSITY / DENSITY) / weight
    inertia = change / (area * (t1 - t0)) / weight
    floor_share = floor / area / weight
    return {"bed_height_mean": float(np.mean(height)), "bed_height_std": float(np.std(height)),
            "bed_height_max": float(np.max(height)), "dp_over_weight_raw": dp_mean / weight,
            "dp_over_weight": dp_mean / weight - inertia + floor_share, "momentum_over_weight": inertia,
            "floor_over_weight": floor_share, "max_overlap": float(np.max(series["max_overlap"][sel])),
            **void_figures(frames, vt[pick], h, mask, series), "substeps": summary.get("substeps_per_step"),
            "cost": stepping_cost(series), "grains_removed": summary.get("grains_removed", 0)}


def stepping_cost(series: dict, warm_up: float = WARM_UP) -> float:
    """Wall seconds of stepping per simulated second after ``warm_up`` [s] (compilation left out)."""
    t, wall = series["time"], series["wall_time"]
    i = int(np.searchsorted(t, t[0] + warm_up - 1e-12))
    return float((wall[-1] - wall[i]) / max(t[-1] - t[i], 1e-12))
