"""Generic bubble tools on porosity (void-fraction) fields. SI units throughout.

Geometry convention: a 2-D field ``eps2d`` of shape (n0, n1) is cell-centred on a uniform grid
of cell size ``h``; cell (i, j) covers [i h, (i+1) h] x [j h, (j+1) h] measured from the corner
of the first cell (the plane's "origin cell corner"), so its centre is ((i+0.5) h, (j+0.5) h).
Every position returned here is relative to that corner.

A bubble is a connected region (4-connectivity, ``scipy.ndimage.label``'s default) where the
porosity, bilinearly interpolated onto a ``factor``-times finer grid (``refine_plane``), exceeds
``threshold`` (0.7 in Verma et al. 2014). Its area is the number of fine sub-cells times
(h/factor)^2 and its equivalent diameter sqrt(4 A / pi).

Cells outside the vessel (``mask`` False) never belong to a bubble. Before interpolation their
values are replaced by the value of the nearest inside cell, so that the porosity of ~1 that a
simulator reports outside a cylinder cannot leak into the inside sub-cells next to the wall.
"""
from __future__ import annotations

import math

import numpy as np
from scipy import ndimage

from .correlations import G, UEX_VERMA, darton, werther  # noqa: F401  (bubbles.darton etc., as before)

#: Verma et al. (2014) bubble threshold on porosity.
THRESHOLD = 0.7
#: Sub-grid refinement factor (linear interpolation, 4x as in Verma et al. 2014).
FACTOR = 4
#: Regions smaller than MIN_AREA_CELLS * h^2 are dropped (seed 000's rule).
MIN_AREA_CELLS = 2.0


# --------------------------------------------------------------------------------------------
# refinement and detection
# --------------------------------------------------------------------------------------------
def _linear_weights(n: int, factor: int):
    """Indices and weights to interpolate n cell-centred samples onto n*factor sub-cell centres.

    Sub-cell k (0 <= k < n*factor) has its centre at ((k + 0.5) / factor) cells from the
    corner, i.e. at u = (k + 0.5) / factor - 0.5 in the index space of the cell centres.
    Points within half a cell of the border (u < 0 or u > n-1) take the border value.
    """
    u = (np.arange(n * factor) + 0.5) / factor - 0.5
    if n == 1:
        z = np.zeros(n * factor, dtype=np.intp)
        return z, z, np.zeros(n * factor)
    i0 = np.clip(np.floor(u).astype(np.intp), 0, n - 2)
    w = np.clip(u - i0, 0.0, 1.0)
    return i0, i0 + 1, w


def refine_plane(eps2d, factor: int = FACTOR) -> np.ndarray:
    """Bilinear up-sampling of a cell-centred 2-D field by an integer ``factor``.

    Input shape (n0, n1), output shape (n0*factor, n1*factor). Output sample (I, J) is the
    centre of sub-cell (I, J) of size h/factor, at ((I+0.5) h/factor, (J+0.5) h/factor) from the
    origin corner; its value is the bilinear interpolation between the four surrounding cell
    centres ((i+0.5) h, (j+0.5) h). In the outer half-cell band, beyond the outermost cell
    centres, the border value is used (constant extrapolation). This keeps the cell-centred
    geometry: the fine grid covers exactly the same rectangle as the coarse one, so the area of
    a thresholded region converges to the area of the 0-contour of the interpolant as
    ``factor`` grows (identical to ``scipy.ndimage.zoom(eps2d, factor, order=1,
    mode='nearest', grid_mode=True)``).
    """
    eps = np.asarray(eps2d, dtype=float)
    if eps.ndim != 2:
        raise ValueError(f"refine_plane expects a 2-D field, got shape {eps.shape}")
    factor = int(factor)
    if factor < 1:
        raise ValueError("factor must be a positive integer")
    if factor == 1:
        return eps.copy()
    a0, b0, w0 = _linear_weights(eps.shape[0], factor)
    a1, b1, w1 = _linear_weights(eps.shape[1], factor)
    rows = eps[a0, :] * (1.0 - w0)[:, None] + eps[b0, :] * w0[:, None]
    return rows[:, a1] * (1.0 - w1)[None, :] + rows[:, b1] * w1[None, :]


def _check_mask(mask, shape):
    if mask is None:
        return None
    m = np.asarray(mask).astype(bool)
    if m.shape != tuple(shape):
        raise ValueError(f"mask shape {m.shape} does not match field shape {tuple(shape)}")
    return m


def _fill_outside(eps: np.ndarray, mask: np.ndarray | None) -> np.ndarray:
    """Replace cells outside ``mask`` by the value of the nearest inside cell."""
    if mask is None or mask.all() or not mask.any():
        return eps
    idx = ndimage.distance_transform_edt(~mask, return_distances=False, return_indices=True)
    return eps[tuple(idx)]


def bubble_phase(eps2d, threshold: float = THRESHOLD, factor: int = FACTOR, mask=None) -> np.ndarray:
    """Boolean fine grid (shape (n0*factor, n1*factor)): refined porosity > threshold, inside mask.

    NaN cells count as not-bubble.
    """
    eps = np.asarray(eps2d, dtype=float)
    m = _check_mask(mask, eps.shape)
    fine = refine_plane(_fill_outside(eps, m), factor) > threshold
    if m is not None:
        fine &= np.repeat(np.repeat(m, factor, axis=0), factor, axis=1)
    return fine


def _region_stats(labels: np.ndarray, n: int, dx: float):
    """Per-label (1..n) sub-cell count, centroid and second moments, vectorised."""
    lab = labels.ravel()
    i, j = np.indices(labels.shape)
    x = (i.ravel() + 0.5) * dx
    y = (j.ravel() + 0.5) * dx
    cnt = np.bincount(lab, minlength=n + 1)[1:].astype(float)
    sx = np.bincount(lab, weights=x, minlength=n + 1)[1:]
    sy = np.bincount(lab, weights=y, minlength=n + 1)[1:]
    sxx = np.bincount(lab, weights=x * x, minlength=n + 1)[1:]
    syy = np.bincount(lab, weights=y * y, minlength=n + 1)[1:]
    sxy = np.bincount(lab, weights=x * y, minlength=n + 1)[1:]
    cx, cy = sx / cnt, sy / cnt
    # central second moments of the union of square sub-cells (dx^2/12: each sub-cell's own)
    vxx = sxx / cnt - cx * cx + dx * dx / 12.0
    vyy = syy / cnt - cy * cy + dx * dx / 12.0
    vxy = sxy / cnt - cx * cy
    return cnt, cx, cy, vxx, vyy, vxy


def _aspect_from_moments(vxx, vyy, vxy):
    """Major/minor axis ratio (>= 1) of the ellipse with the same second moments."""
    tr = 0.5 * (vxx + vyy)
    det = np.sqrt(np.maximum(0.25 * (vxx - vyy) ** 2 + vxy * vxy, 0.0))
    lmax, lmin = tr + det, np.maximum(tr - det, 1e-300)
    return np.sqrt(lmax / lmin)


def plane_bubbles(eps2d, h: float, threshold: float = THRESHOLD, factor: int = FACTOR,
                  min_area: float | None = None, mask=None, max_area: float | None = None) -> list[dict]:
    """Bubbles in a horizontal porosity plane.

    Parameters
    ----------
    eps2d : (nx, ny) array, cell-centred porosity.
    h : cell size [m].
    threshold : porosity above which a (refined) point belongs to a bubble.
    factor : sub-grid refinement (``refine_plane``).
    min_area : regions smaller than this [m^2] are dropped; default 2 h^2.
    mask : optional bool (nx, ny), True = inside the vessel; outside cells are never bubble.
    max_area : optional [m^2]; larger regions are dropped (e.g. a plane above the bed surface,
        where the whole cross-section is "bubble").

    Returns
    -------
    list of dicts, one per kept region, in label order, with
    ``area`` [m^2], ``diameter`` = sqrt(4 A / pi) [m], ``centroid`` (x, y) [m] from the origin
    corner of cell (0, 0), ``aspect`` = major/minor axis ratio (>= 1) of the ellipse with the
    region's second moments.
    """
    if min_area is None:
        min_area = MIN_AREA_CELLS * h * h
    fine = bubble_phase(eps2d, threshold, factor, mask)
    labels, n = ndimage.label(fine)
    if n == 0:
        return []
    dx = h / factor
    cnt, cx, cy, vxx, vyy, vxy = _region_stats(labels, n, dx)
    area = cnt * dx * dx
    aspect = _aspect_from_moments(vxx, vyy, vxy)
    out = []
    for k in range(n):
        if area[k] < min_area or (max_area is not None and area[k] > max_area):
            continue
        out.append({"area": float(area[k]),
                    "diameter": float(math.sqrt(4.0 * area[k] / math.pi)),
                    "centroid": (float(cx[k]), float(cy[k])),
                    "aspect": float(aspect[k])})
    return out


def slab_bubble(eps2d, h: float, threshold: float = THRESHOLD, factor: int = FACTOR,
                seed=None, mask=None) -> dict | None:
    """The bubble in a VERTICAL porosity plane (shape (nx, nz), axis 1 is height).

    Picks the largest connected region above ``threshold`` (after ``refine_plane``), or, when
    ``seed`` = (x, z) [m] is given, the region containing that point (None if the point is not
    inside a region). Returns None when there is no region.

    Returned dict (lengths in m, positions from the origin corner of cell (0, 0)):
    ``area`` [m^2], ``diameter`` = sqrt(4 A / pi), ``centroid`` (x, z), ``width`` (horizontal
    extent), ``height`` (vertical extent), ``aspect`` = height / width, ``bottom`` and ``top``
    (z of the lowest and highest sub-cell edges of the region).
    """
    fine = bubble_phase(eps2d, threshold, factor, mask)
    labels, n = ndimage.label(fine)
    if n == 0:
        return None
    dx = h / factor
    cnt, cx, cz, _, _, _ = _region_stats(labels, n, dx)
    if seed is None:
        k = int(np.argmax(cnt))
    else:
        i, j = int(math.floor(seed[0] / dx)), int(math.floor(seed[1] / dx))
        if not (0 <= i < labels.shape[0] and 0 <= j < labels.shape[1]) or labels[i, j] == 0:
            return None
        k = int(labels[i, j]) - 1
    sl = ndimage.find_objects(labels, max_label=k + 1)[k]
    width = (sl[0].stop - sl[0].start) * dx
    height = (sl[1].stop - sl[1].start) * dx
    area = cnt[k] * dx * dx
    return {"area": float(area),
            "diameter": float(math.sqrt(4.0 * area / math.pi)),
            "centroid": (float(cx[k]), float(cz[k])),
            "width": float(width),
            "height": float(height),
            "aspect": float(height / width),
            "bottom": float(sl[1].start * dx),
            "top": float(sl[1].stop * dx)}


# --------------------------------------------------------------------------------------------
# statistics over frames
# --------------------------------------------------------------------------------------------
def _as_frames(frames) -> np.ndarray:
    a = np.asarray(frames)
    if a.ndim == 2:
        a = a[None]
    if a.ndim != 3:
        raise ValueError(f"expected frames of shape (nt, nx, ny), got {a.shape}")
    return a


def bubble_diameters(frames, h: float, threshold: float = THRESHOLD, factor: int = FACTOR,
                     min_area: float | None = None, mask=None, max_area: float | None = None) -> np.ndarray:
    """Equivalent diameters [m] of every bubble in every frame (frames: (nt, nx, ny))."""
    d = [b["diameter"] for f in _as_frames(frames)
         for b in plane_bubbles(f, h, threshold, factor, min_area, mask, max_area)]
    return np.asarray(d, dtype=float)


def equivalent_diameter(frames, h: float, threshold: float = THRESHOLD, factor: int = FACTOR,
                        min_area: float | None = None, mask=None,
                        max_area: float | None = None) -> tuple[float, int]:
    """Number-average equivalent diameter over all bubbles of all frames.

    frames: (nt, nx, ny) porosity of one horizontal plane. Returns (mean diameter [m], number
    of bubbles); (nan, 0) if none. Other arguments as in ``plane_bubbles``.
    """
    d = bubble_diameters(frames, h, threshold, factor, min_area, mask, max_area)
    return (float(d.mean()) if d.size else float("nan")), int(d.size)


def diameter_profile(frames3d, h: float, z_centres, threshold: float = THRESHOLD, factor: int = FACTOR,
                     min_area: float | None = None, mask=None, max_area: float | None = None):
    """Equivalent diameter against height from 3-D frames.

    frames3d: (nt, nx, ny, nz); every horizontal layer k (height ``z_centres[k]`` [m]) is
    analysed as a plane with ``equivalent_diameter``. Returns (z [m], mean diameter [m] (nan
    where no bubble), count) arrays of length nz.
    """
    a = np.asarray(frames3d)
    if a.ndim == 3:
        a = a[None]
    if a.ndim != 4:
        raise ValueError(f"expected frames of shape (nt, nx, ny, nz), got {a.shape}")
    z = np.asarray(z_centres, dtype=float)
    if z.shape != (a.shape[3],):
        raise ValueError(f"z_centres has shape {z.shape}, expected ({a.shape[3]},)")
    mean = np.full(z.shape, np.nan)
    count = np.zeros(z.shape, dtype=int)
    for k in range(a.shape[3]):
        mean[k], count[k] = equivalent_diameter(a[:, :, :, k], h, threshold, factor, min_area, mask, max_area)
    return z, mean, count


def track_bubbles(frames3d, times, h: float, threshold: float = THRESHOLD, mask=None,
                  min_cells: int = 8, max_growth: float = 0.3) -> dict:
    """Bubbles followed through 3-D porosity frames; a check on the plane-pair rise velocities.

    A bubble is a connected region (6-connectivity) of cells with porosity above ``threshold``,
    inside ``mask`` ((nx, ny) or (nx, ny, nz)); regions reaching the top layer are open to the
    freeboard and dropped, as are regions of fewer than ``min_cells`` cells. Its height is the
    centroid of its cells weighted by (porosity - threshold). A bubble of one frame is the same
    bubble in the next when each is the other's largest overlap and the volume changes by less
    than ``max_growth`` (coalescences, splits and eruptions are left out). The frames must be
    close enough in time that a bubble overlaps its former self (it rises less than its height).

    frames3d: (nt, nx, ny, nz) on cells of size h [m], layer k centred at (k + 0.5) h above the
    frames' origin; times: (nt,) [s]. Returns a dict of arrays, one entry per matched pair of
    frames: ``time`` [s] and ``z`` [m above the origin] at the midpoint, ``velocity`` [m/s] (rise
    of the centroid over the frame interval) and ``diameter`` [m] (sphere of the mean volume).
    """
    a = np.asarray(frames3d)
    if a.ndim != 4:
        raise ValueError(f"expected frames of shape (nt, nx, ny, nz), got {a.shape}")
    t = np.asarray(times, dtype=float)
    if t.shape != (a.shape[0],):
        raise ValueError(f"times has shape {t.shape}, expected ({a.shape[0]},)")
    inside = np.ones(a.shape[1:], bool)
    if mask is not None:
        mk = np.asarray(mask).astype(bool)
        if mk.shape == a.shape[1:3]:
            mk = np.broadcast_to(mk[:, :, None], a.shape[1:])
        inside = _check_mask(mk, a.shape[1:])
    zc = (np.arange(a.shape[3]) + 0.5) * h

    def regions(eps):
        lab, n = ndimage.label((eps > threshold) & inside)
        idx = np.arange(1, n + 1)
        vol = np.bincount(lab.ravel(), minlength=n + 1)[1:]
        drop = np.zeros(n + 1, bool)
        drop[np.unique(lab[:, :, -1])] = True  # open to the freeboard
        drop[1:] |= vol < min_cells
        lab[drop[lab]] = 0
        w = np.where(lab > 0, eps - threshold, 0.0)
        wsum = ndimage.sum(w, lab, idx)
        zcen = ndimage.sum(w * zc[None, None, :], lab, idx) / np.where(wsum > 0, wsum, 1.0)
        return lab, vol, zcen

    rows = []
    prev = regions(a[0])
    for n in range(1, a.shape[0]):
        cur = regions(a[n])
        (la, va, za), (lb, vb, zb) = prev, cur
        both = (la > 0) & (lb > 0)
        if both.any():
            nb = int(lb.max()) + 1
            code, cnt = np.unique(la[both].astype(np.int64) * nb + lb[both], return_counts=True)
            pa, pb = code // nb, code % nb
            order = np.argsort(-cnt, kind="stable")  # largest overlaps first
            best_a, best_b = {}, {}
            for r in order:
                best_a.setdefault(int(pa[r]), int(pb[r]))
                best_b.setdefault(int(pb[r]), int(pa[r]))
            dt = t[n] - t[n - 1]
            for ia, ib in best_a.items():
                if best_b[ib] != ia:
                    continue
                v1, v2 = va[ia - 1], vb[ib - 1]
                if abs(v2 / v1 - 1.0) >= max_growth:
                    continue
                rows.append((0.5 * (t[n] + t[n - 1]), 0.5 * (za[ia - 1] + zb[ib - 1]),
                             (zb[ib - 1] - za[ia - 1]) / dt, (3.0 * (v1 + v2) * h ** 3 / math.pi) ** (1.0 / 3.0)))
        prev = cur
    r = np.asarray(rows, dtype=float).reshape(-1, 4)
    return {"time": r[:, 0], "z": r[:, 1], "velocity": r[:, 2], "diameter": r[:, 3]}


def porosity_pdf(values, bin: float = 0.04, range: tuple[float, float] = (0.0, 1.0)):  # noqa: A002
    """Probability density of porosity values with bins of width ``bin`` over ``range``.

    NaNs are dropped and values are clipped into ``range`` (a porosity of exactly 1 falls in the
    last bin). Returns (bin centres, density) with sum(density) * bin == 1 (when any value).
    """
    lo, hi = float(range[0]), float(range[1])
    nb = max(1, int(math.ceil((hi - lo) / bin - 1e-9)))
    edges = lo + bin * np.arange(nb + 1)
    v = np.asarray(values, dtype=float).ravel()
    v = np.clip(v[np.isfinite(v)], lo, edges[-1])
    centres = 0.5 * (edges[1:] + edges[:-1])
    if v.size == 0:
        return centres, np.zeros(nb)
    dens, _ = np.histogram(v, bins=edges, density=True)
    return centres, dens
