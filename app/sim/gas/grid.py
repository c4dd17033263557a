"""MAC grid of the gas and its cut cells, computed on the host from the vessel walls.

Owns: the description of the uniform staggered (MAC) grid (:class:`MacGrid`: shape, cell
size, origin, where each unknown sits) and the cut-cell geometry (:func:`cut_cells`):
the open fraction of every cell face (its *aperture*), the open volume fraction of every
cell, which cells take part in the pressure solve, and the wall clearance at every face
centre (used by the gas solver for no-slip ghost values).

Everything here is numpy; the gas solver copies the arrays into its grid bundle once (:mod:`.layout`).

Conventions
-----------
* Cell (i, j, k) spans ``origin + h*[i, i+1] x h*[j, j+1] x h*[k, k+1]`` [m].
* x-faces (normal x, carry u) have shape (nx+1, ny, nz) and sit at
  ``origin + h*(i, j+1/2, k+1/2)``; y-faces (nx, ny+1, nz) and z-faces (nx, ny, nz+1)
  likewise. Axis 2 (z) is vertical.
* Clearance (from :mod:`app.sim.geometry`) is positive on the open side (gas), negative
  inside wall material.

Cut-cell geometry (what the solver's accuracy rests on)
--------------------------------------------------------
* A face's aperture is the fraction of ``s x s`` sample points (cell-centred sub-grid of
  the face, ``s`` = ``samples``) whose clearance is >= 0. Faces whose centre is farther
  than one cell size from the wall are classified without sampling (the clearance is a
  distance, so it is 1-Lipschitz: such a face is wholly open or wholly closed). The
  aperture converges to the exact open fraction as O(1/s) per cut face; with the default
  s = 4 a face's open area is within ~1/8 of a face area, and the errors of neighbouring
  faces largely cancel in the total open area of a cross-section.
* A cell's volume fraction uses ``s^3`` sub-samples the same way.
* A cell is *active* (a gas cell, in the pressure solve) when its volume fraction is > 0
  and at least one of its faces is open; faces touching an inactive cell are closed
  (aperture 0), so no flux ever enters a cell that is not solved for.
"""
from __future__ import annotations

import dataclasses
from typing import Sequence

import numpy as np

from ..geometry import vessel_clearance

AXES = "xyz"


@dataclasses.dataclass(frozen=True)
class MacGrid:
    """Uniform staggered grid: ``shape`` cells of size ``h`` [m] starting at ``origin`` [m]."""

    shape: tuple[int, int, int]
    h: float
    origin: tuple[float, float, float] = (0.0, 0.0, 0.0)

    @property
    def extent(self) -> tuple[float, float, float]:
        """Domain size [m] along x, y, z."""
        return tuple(n * self.h for n in self.shape)

    def face_shape(self, axis: int) -> tuple[int, int, int]:
        s = list(self.shape)
        s[axis] += 1
        return tuple(s)

    def cell_centres(self) -> np.ndarray:
        """(nx, ny, nz, 3) cell-centre coordinates [m]."""
        return self._points([0.5, 0.5, 0.5], self.shape)

    def face_centres(self, axis: int) -> np.ndarray:
        """Face-centre coordinates [m] of the faces normal to ``axis``, shape face_shape(axis) + (3,)."""
        off = [0.5, 0.5, 0.5]
        off[axis] = 0.0
        return self._points(off, self.face_shape(axis))

    def _points(self, off, shape) -> np.ndarray:
        ax = [self.origin[a] + self.h * (np.arange(shape[a]) + off[a]) for a in range(3)]
        X, Y, Z = np.meshgrid(*ax, indexing="ij")
        return np.stack([X, Y, Z], axis=-1)


@dataclasses.dataclass(frozen=True, eq=False)
class CutCells:
    """Cut-cell geometry of a grid inside a vessel (all numpy arrays).

    ``apertures[a]``: open fraction [0, 1] of the faces normal to axis a (face_shape(a)).
    ``clearance[a]``: wall clearance [m] at those face centres (+inf without walls).
    ``volume``: open volume fraction [0, 1] of each cell; ``active``: bool, cell is solved.
    """

    apertures: tuple[np.ndarray, np.ndarray, np.ndarray]
    clearance: tuple[np.ndarray, np.ndarray, np.ndarray]
    volume: np.ndarray
    active: np.ndarray


def _sampled_fraction(walls, centres: np.ndarray, h: float, axes: Sequence[int], s: int,
                      points: int = 1 << 20) -> np.ndarray:
    """Fraction of s^len(axes) sub-points (spread over the square/cube of side h around each centre
    along ``axes``) with clearance >= 0. ``centres``: (N, 3). At most ``points`` sub-points at a time (25 MB
    of coordinates: 4,096 centres at once with s = 64 had asked for 26 GB, and the system killed the run)."""
    offs1 = (np.arange(s) + 0.5) / s - 0.5
    grids = np.meshgrid(*([offs1] * len(axes)), indexing="ij")
    offs = np.zeros((grids[0].size, 3))
    for n, a in enumerate(axes):
        offs[:, a] = grids[n].ravel() * h
    out = np.empty(len(centres))
    chunk = max(1, points // len(offs))
    for start in range(0, len(centres), chunk):
        c = centres[start:start + chunk]
        pts = c[:, None, :] + offs[None, :, :]
        cl = vessel_clearance(walls, pts)
        out[start:start + chunk] = np.mean(cl >= 0.0, axis=1)
    return out


def _fraction_field(walls, centres: np.ndarray, h: float, axes: Sequence[int], s: int):
    """Clearance at ``centres`` (..., 3) and the open fraction, sub-sampling only near the wall."""
    shape = centres.shape[:-1]
    flat = centres.reshape(-1, 3)
    cl = vessel_clearance(walls, flat)
    frac = (cl >= 0.0).astype(float)
    # a face/cell lies within sqrt(d)/2*h of its centre: farther than h from the wall it is all open
    # or all closed (the clearance is a distance, 1-Lipschitz)
    near = np.abs(cl) < h
    if np.any(near):
        frac[near] = _sampled_fraction(walls, flat[near], h, axes, s)
    return cl.reshape(shape), frac.reshape(shape)


def cut_cells(grid: MacGrid, walls: Sequence = (), samples: int = 4,
              periodic: Sequence[bool] = (False, False, False), min_volume: float = 0.0) -> CutCells:
    """Apertures, volume fractions, active cells and face clearances of ``grid`` inside ``walls``.

    Without walls every face is open and every cell active. ``samples`` (>= 1) sub-samples
    per face edge (s x s per face, s^3 per cell). Along a ``periodic`` axis the first and last
    faces are one face (joining the last and first cells): they get the smaller of the two
    sampled apertures. Cells whose open volume fraction is at most ``min_volume`` are closed
    (small-cell removal): a thin sliver between the wall and the grid has no resolved wall
    shear, so left open it is a frictionless bypass channel.
    """
    if samples < 1:
        raise ValueError(f"aperture samples must be >= 1, got {samples}")
    if not walls:
        aps = tuple(np.ones(grid.face_shape(a)) for a in range(3))
        cls = tuple(np.full(grid.face_shape(a), np.inf) for a in range(3))
        return CutCells(aps, cls, np.ones(grid.shape), np.ones(grid.shape, bool))
    h = grid.h
    aps, cls = [], []
    for a in range(3):
        tang = [b for b in range(3) if b != a]
        cl, fr = _fraction_field(walls, grid.face_centres(a), h, tang, samples)
        aps.append(fr)
        cls.append(cl)
    _, vol = _fraction_field(walls, grid.cell_centres(), h, (0, 1, 2), samples)
    active = vol > min_volume
    # a cell with open volume but every face closed is cut off from the rest of the gas
    for _ in range(2):
        any_open = np.zeros(grid.shape, bool)
        for a in range(3):
            ap = aps[a]
            lo = [slice(None)] * 3
            hi = [slice(None)] * 3
            lo[a] = slice(0, -1)
            hi[a] = slice(1, None)
            any_open |= ap[tuple(lo)] > 0
            any_open |= ap[tuple(hi)] > 0
        active &= any_open
        # close every face that touches an inactive cell (boundary faces see one cell)
        for a in range(3):
            ap = aps[a]
            pad = np.zeros([n + 2 if b == a else n for b, n in enumerate(grid.shape)], bool)
            sl = [slice(None)] * 3
            sl[a] = slice(1, -1)
            pad[tuple(sl)] = active
            lo = [slice(None)] * 3
            hi = [slice(None)] * 3
            lo[a] = slice(0, -1)
            hi[a] = slice(1, None)
            lo_act, hi_act = pad[tuple(lo)], pad[tuple(hi)]
            n = grid.shape[a]
            # interior faces need both cells active; boundary faces their one cell
            ok = lo_act & hi_act
            first = [slice(None)] * 3
            last = [slice(None)] * 3
            first[a] = 0
            last[a] = n
            if periodic[a]:
                both = lo_act[tuple(last)] & hi_act[tuple(first)]
                ok[tuple(first)] = both
                ok[tuple(last)] = both
                m = np.minimum(ap[tuple(first)], ap[tuple(last)])
                ap[tuple(first)] = m
                ap[tuple(last)] = m
            else:
                ok[tuple(first)] = hi_act[tuple(first)]
                ok[tuple(last)] = lo_act[tuple(last)]
            ap[~ok] = 0.0
    vol = np.where(active, vol, 0.0)
    return CutCells(tuple(aps), tuple(cls), vol, active)
