"""The synthetic MRI: the grains' volume in the central vertical slab, binned onto the MRI's pixels.

Owns: run.h5 ``/mri``, recorded every ``probes.mri_interval``. The MRI of the poppy-seed bed (seed 002,
Section 3.1) averaged the seeds' signal over a 10 mm thick vertical slice through the bed's axis on
pixels of 4 mm x 8 mm every 4 ms; the signal is the seeds' oil, so the image is the seeds' volume. Here
each grain contributes the exact part of its sphere that lies between the slab's two faces
(|y - y_axis| < slab_width / 2), all of it to the pixel that holds its centre (x, z); a pixel's solid
fraction is that volume over the pixel's open volume in the slab (the part of its dx x slab_width x dz
box inside the vessel). Recorded as void fraction (1 - solid), like ``/slab``, with attrs ``pixel``
(dx, dz), ``origin`` (x0, z0: the image's lower-left corner, z0 the floor), ``slab_width``,
``open_fraction`` (per pixel column) and ``mask`` (pixels at least half inside the vessel).

No Taichi here: the frame's binning runs on the device through the DEM's ``slab_volumes`` (one small array
read back a frame); ``MriImage.void`` is the same image in numpy from grains on the host, for analyses and tests.
"""
from __future__ import annotations

import math

import numpy as np

from .config.derived import mri_pixels


def slab_volume(dy: np.ndarray, r: np.ndarray, half: float) -> np.ndarray:
    """Volume [m^3] of spheres of radius r centred dy from a slab's mid-plane that lies within |y| < half."""
    t1 = np.maximum(-r, -half - dy)
    t2 = np.minimum(r, half - dy)
    v = math.pi * (r * r * (t2 - t1) - (t2 ** 3 - t1 ** 3) / 3.0)
    return np.where(t2 > t1, v, 0.0)


class MriImage:
    """The pixel grid of the synthetic MRI: (nx, nz) pixels of (dx, dz) from (x0, z0), the slab of
    width ``width`` about y = yc, and the vessel's open fraction of each pixel column."""

    def __init__(self, cfg):
        pr, d, v = cfg.probes, cfg.domain, cfg.vessel
        self.dx, self.dz = (float(a) for a in pr.mri_pixel)
        self.width = float(pr.slab_width)
        self.nx, self.nz, xc, self.yc, floor = mri_pixels(cfg)
        self.x0, self.z0 = xc - 0.5 * self.nx * self.dx, floor
        # open fraction of each column of the slab: 64 x 64 samples of (x, y) over its cross-section
        s = (np.arange(64) + 0.5) / 64
        xs = self.x0 + (np.arange(self.nx)[:, None] + s[None, :]) * self.dx
        ys = self.yc + (s - 0.5) * self.width
        if v.shape == "cylinder":
            inside = (xs[:, :, None] - xc) ** 2 + (ys[None, None, :] - self.yc) ** 2 < v.radius ** 2
        else:
            inside = np.broadcast_to(((xs >= d.lo[0]) & (xs <= d.hi[0]))[:, :, None], xs.shape + (64,))
        self.open_fraction = inside.mean((1, 2))
        self.mask = np.repeat((self.open_fraction >= 0.5)[:, None], self.nz, 1)

    def volumes(self, x: np.ndarray, r: np.ndarray) -> np.ndarray:
        """(nx, nz) grain volume [m^3] in the slab's pixels from grain centres x (n, 3) and radii r (n,), in numpy
        (the DEM's ``slab_volumes`` computes the same on the device)."""
        half = 0.5 * self.width
        dy = x[:, 1] - self.yc
        near = np.abs(dy) < half + r
        x, r, dy = x[near], r[near], dy[near]
        i = np.floor((x[:, 0] - self.x0) / self.dx).astype(np.int64)
        k = np.floor((x[:, 2] - self.z0) / self.dz).astype(np.int64)
        ok = (i >= 0) & (i < self.nx) & (k >= 0) & (k < self.nz)
        return np.bincount(i[ok] * self.nz + k[ok], weights=slab_volume(dy[ok], r[ok], half),
                           minlength=self.nx * self.nz).reshape(self.nx, self.nz)

    def void_of(self, vol: np.ndarray) -> np.ndarray:
        """(nx, nz) void fraction of the slab's pixels from their grain volume [m^3] (pixels outside the mask: 1)."""
        cell = self.dx * self.dz * self.width * np.maximum(self.open_fraction, 1e-12)[:, None]
        return np.where(self.mask, 1.0 - vol / cell, 1.0)

    def void(self, x: np.ndarray, r: np.ndarray) -> np.ndarray:
        """(nx, nz) void fraction of the slab's pixels from grain centres x (n, 3) and radii r (n,)."""
        return self.void_of(self.volumes(x, r))

    def attrs(self) -> dict:
        return {"pixel": (self.dx, self.dz), "origin": (self.x0, self.z0), "slab_width": self.width,
                "open_fraction": self.open_fraction, "mask": self.mask.astype(np.uint8)}


class MriProbe:
    """The /mri record's callback for a Simulation."""

    def __init__(self, cfg):
        self.image = MriImage(cfg)
        self.interval = cfg.probes.mri_interval

    def frame(self, sim) -> np.ndarray:
        """The image of the live grains, binned on the device (``DemSolver.slab_volumes``): one (nx, nz) array
        read back, where the grains themselves read back and binned in numpy (``MriImage.void``, the same image to
        rounding) took 52 ms a frame for 1e6 grains on one CPU thread (benchmarks/mri_frame_cost.py, 2026-12-06)."""
        im = self.image
        vol = sim.dem.slab_volumes(im.yc, 0.5 * im.width, (im.x0, im.z0), (im.dx, im.dz), (im.nx, im.nz))
        return im.void_of(vol)

    def attach(self, sim, runfile, guarded) -> None:
        attrs = self.image.attrs()
        sim.add(guarded(lambda s: runfile.frame("mri", s.time, self.frame(s), attrs)), self.interval)
