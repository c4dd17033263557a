"""Bed measures of a coupled run: the pressure drop across the bed and the bed's weight per area."""
from __future__ import annotations

import numpy as np

from ..io import store


class BedMeasures:
    """Bed-scale figures of a coupled run: pressure drop across the domain (gas hydrostatics removed),
    bed weight per area, and their time means."""

    def __init__(self, scene, flow, dem=None):
        self.flow = flow
        self.dem = dem
        g = scene.cfg.gas
        gz = abs(scene.cfg.domain.gravity[2])
        height = scene.flow.shape[2] * g.cell_size
        self.hydro = g.density * gz * height
        # open cross-section: the bottom layer's open volume fractions (the pressure drop's weights too)
        self.area = float(flow.fields.vol_frac.to_numpy()[:, :, 0].sum()) * g.cell_size ** 2
        self.weight_factor = gz * (1.0 - g.density / scene.cfg.particles.density)  # buoyant weight per kg
        self._initial_mass = float(np.sum(scene.derived.mass(2.0 * scene.initial["radius"])))

    @property
    def weight_per_area(self) -> float:
        """Buoyant weight of the grains still in the domain over the open cross-section [Pa]."""
        mass = self._initial_mass
        if self.dem is not None:
            mass = float(np.sum(self.dem.masses() * self.dem.read("alive")))
        return mass * self.weight_factor / self.area if self.area > 0 else float("nan")

    def pressure_drop(self) -> float:
        """Pressure at the bottom face of the domain minus the top face [Pa], gas weight removed: the
        open-area means of the first two (last two) cell layers, extrapolated half a cell to the face,
        so the grains in the lowest half cell count too."""
        return self.pressure_drop_of(*self.flow.end_layer_pressures())  # reduced on the device

    def pressure_drop_of(self, p0: float, p1: float, p_second_last: float, p_last: float) -> float:
        """``pressure_drop`` from the end layers' mean pressures [Pa] (as a diagnostics row holds them)."""
        pb = 1.5 * p0 - 0.5 * p1
        pt = 1.5 * p_last - 0.5 * p_second_last
        return pb - pt - self.hydro

    def summary(self, runfile, cfg) -> dict:
        series = store.read_series(runfile)
        t = series.get("time", np.zeros(0))
        wpa = self.weight_per_area
        if not t.size:  # stopped before its first row (the guard at the start): a KeyError traceback
            return {"bed_weight_per_area": wpa, "bed_area": self.area}
        t0 = cfg.output.average_from if cfg.output.average_from >= 0 else 0.5 * t[-1]
        sel = t >= t0 - 1e-12
        out = {"bed_weight_per_area": wpa, "bed_area": self.area, "average_from": float(t0)}
        if sel.any():
            dp = float(np.nanmean(series["pressure_drop"][sel]))
            out.update(mean_pressure_drop=dp, mean_bed_height=float(np.nanmean(series["bed_height"][sel])),
                       pressure_drop_over_weight=dp / wpa)
        return out
