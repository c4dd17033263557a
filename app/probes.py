"""Probes: void-fraction records taken while a coupled run steps, for the bubble analyses.

Owns: what [probes] asks for, sampled from the gas grid's void fraction (the deposited,
smoothed eps the gas solver sees) and appended to run.h5:
- ``/slab``: the central vertical x-z slab, eps averaged over the cell layers within
  ``slab_width`` / 2 of the mid-plane y (at least the one or two cells that straddle it);
  attrs ``h``, ``origin`` (x0, z0), ``y_cells`` (the layers averaged). Bubbles on it are what
  the MRI slice of Boyce et al. measured.
- ``/planes/z<height>``: horizontal planes, eps interpolated linearly between the two cell
  layers around each height; attrs ``z``, ``h``, ``origin`` (x0, y0), ``pair`` and ``level``
  (consecutive heights form (lower, upper) pairs, as the X-ray planes of Verma et al.);
  ``/planes/mask`` marks the vessel's open cells.
- ``/porosity3d``: the full 3-D eps; attrs ``h``, ``origin``.
- ``/mri``: the synthetic MRI, from the grains rather than the grid (``app.probes_mri``).
Cells outside the vessel hold eps = 1 on the grid; the masks say which cells count.
Plain numpy over the solver's host API: no Taichi here.
"""
from __future__ import annotations

import numpy as np

from .config.derived import plane_name


def slab_layers(ny: int, h: float, y0: float, y_mid: float, width: float) -> np.ndarray:
    """Indices of the y cell layers whose centres lie within width/2 of y_mid (at least the nearest one or two)."""
    centres = y0 + (np.arange(ny) + 0.5) * h
    sel = np.nonzero(np.abs(centres - y_mid) <= 0.5 * width + 1e-12)[0]
    if sel.size == 0:
        d = np.abs(centres - y_mid)
        sel = np.nonzero(d <= d.min() + 1e-9 * h)[0]  # one cell, or the two that straddle the mid-plane
    return sel


def plane_weights(nz: int, h: float, z0: float, z: float) -> tuple[int, int, float]:
    """(k0, k1, w): eps(z) = (1 - w) eps[..., k0] + w eps[..., k1] between cell centres (clamped)."""
    q = (z - z0) / h - 0.5
    k0 = int(np.clip(np.floor(q), 0, nz - 1))
    k1 = min(k0 + 1, nz - 1)
    w = float(np.clip(q - k0, 0.0, 1.0)) if k1 != k0 else 0.0
    return k0, k1, w


class Probes:
    """Sampling callbacks for a Simulation; ``attach(sim, runfile, guarded)`` adds those [probes] asks for."""

    def __init__(self, cfg, flow, walls_active: np.ndarray):
        self.cfg = cfg.probes
        self.config = cfg
        self.flow = flow
        d = cfg.domain
        self.h = cfg.gas.cell_size
        self.lo = np.asarray(d.lo, float)
        self.hi = np.asarray(d.hi, float)
        self.active = walls_active.astype(bool)
        nx, ny, nz = self.active.shape
        self.y_cells = slab_layers(ny, self.h, self.lo[1], 0.5 * (self.lo[1] + self.hi[1]), self.cfg.slab_width)
        self.planes = [(plane_name(z), z, plane_weights(nz, self.h, self.lo[2], z)) for z in sorted(self.cfg.planes)]

    def _eps(self) -> np.ndarray:
        return self.flow.fields.eps.to_numpy()

    def slab(self) -> np.ndarray:
        """(nx, nz) eps on the central slab (outside-vessel cells: 1)."""
        eps = self._eps()
        act = self.active[:, self.y_cells, :]
        e = np.where(act, eps[:, self.y_cells, :], 0.0).sum(1)
        n = act.sum(1)
        return np.where(n > 0, e / np.maximum(n, 1), 1.0)

    def plane(self, k0: int, k1: int, w: float, eps: np.ndarray | None = None) -> np.ndarray:
        eps = self._eps() if eps is None else eps
        return (1.0 - w) * eps[:, :, k0] + w * eps[:, :, k1]

    def attach(self, sim, runfile, guarded) -> None:
        c = self.cfg
        if c.slab_interval:
            attrs = {"h": self.h, "origin": (self.lo[0], self.lo[2]), "y_cells": self.y_cells,
                     "mask": self.active[:, self.y_cells, :].any(1).astype(np.uint8)}
            # attrs bound now: the name is reused below for the other records' attributes
            sim.add(guarded(lambda s, a=attrs: runfile.frame("slab", s.time, self.slab(), a)), c.slab_interval)
        if c.planes and c.planes_interval:
            k0 = self.planes[0][2][0]
            runfile.put("planes/mask", self.active[:, :, k0].astype(np.uint8))

            def record(s):
                eps = self._eps()
                for k, (name, z, (a, b, w)) in enumerate(self.planes):
                    pair = k // 2
                    lower = self.planes[2 * pair][1]
                    attrs = {"z": z, "h": self.h, "origin": (self.lo[0], self.lo[1]),
                             "pair": f"{100 * lower:g}cm", "level": "lower" if k % 2 == 0 else "upper"}
                    runfile.frame(f"planes/{name}", s.time, self.plane(a, b, w, eps), attrs)
            sim.add(guarded(record), c.planes_interval)
        if c.volume_interval:
            attrs = {"h": self.h, "origin": tuple(self.lo)}
            sim.add(guarded(lambda s, a=attrs: runfile.frame("porosity3d", s.time, self._eps(), a)), c.volume_interval)
        if c.mri_interval:  # the synthetic MRI bins the grains (app/probes_mri.py)
            from .probes_mri import MriProbe

            MriProbe(self.config).attach(sim, runfile, guarded)
