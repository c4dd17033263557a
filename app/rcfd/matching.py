"""The grain tracer's jump by matching grains: state s's grains handed onto state j's grains one to one.

At a jump from state s to the most similar state j, the recorded grains of j are other grains than those of s.
The cell stitch (transport.Stitcher + GrainTracer.jump) moves volume between cells and then gives every grain of
j its cell's mean tag: it averages the tag over a cell at each jump, the rCFD's remaining over-mixing
(validation/rcfd/README.md). Here instead each grain of state j takes the tag of one grain of state s, the one
matched to it by position: a permutation, so nothing is averaged, a tag of 0 or 1 stays 0 or 1, and

- the tagged volume sum(vol * tau) is kept exactly (the same products summed in another order: to round-off)
  when matched grains have the same volume -- grains are matched within classes of equal volume;
- tau stays in [0, 1] (its values are only moved).

Positions are known to a grid cell (the half cells where the probe records octants). The matching is optimal
for a metric cost in two steps:
1. in every grid cell, min(n_s, n_j) grains of s are paired with grains of j in the same cell (at random, seeded
   by the pair (s, j): which grain within a cell is unknown). For a metric cost some optimal matching keeps this
   common part in place;
2. the rest (each cell's excess in s against its deficit in j: 0.5 sum |n_s - n_j| grains, the least that must
   change cell) by scipy's linear_sum_assignment on the squared distance of their cells' centres, which prefers
   many short moves to a few long ones.
"""
from __future__ import annotations

import numpy as np
from scipy.optimize import linear_sum_assignment

MAX_CLASSES = 16  # distinct grain volumes a matching handles (a polydisperse bed has a continuum: stitch instead)


def _ranked(cells: np.ndarray, key: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(order, cell, rank): the grains sorted by cell then ``key``, their cells, and their rank within the cell."""
    order = np.lexsort((key, cells))
    c = cells[order]
    first = np.searchsorted(c, c, side="left")
    return order, c, np.arange(c.size) - first


def match_class(cf: np.ndarray, ct: np.ndarray, centres: np.ndarray, rng: np.random.Generator) -> tuple:
    """Grains with cells ``cf`` in state s and ``ct`` in state j (same grains' volume class): (perm, residual)
    with grain g of j taking the tag of grain perm[g] of s; residual: the indices in j of grains matched across
    cells."""
    n = centres.shape[0]
    of, cfs, rf = _ranked(cf, rng.random(cf.size), n)
    ot, cts, rt = _ranked(ct, rng.random(ct.size), n)
    common = np.minimum(np.bincount(cf, minlength=n), np.bincount(ct, minlength=n))
    keep_f, keep_t = rf < common[cfs], rt < common[cts]
    perm = np.empty(cf.size, np.int64)
    perm[ot[keep_t]] = of[keep_f]  # both sorted by (cell, rank): the kept ones pair in order
    res_f, res_t = of[~keep_f], ot[~keep_t]
    if res_t.size:
        res_f = res_f[rng.permutation(res_f.size)]  # ties of the lattice broken at random
        res_t = res_t[rng.permutation(res_t.size)]
        d = centres[cf[res_f]][:, None, :] - centres[ct[res_t]][None, :, :]
        rows, cols = linear_sum_assignment(np.einsum("ijk,ijk->ij", d, d))
        perm[res_t[cols]] = res_f[rows]
    return perm, res_t


class GrainMatcher:
    """Permutations between the grains of two states by position on a grid, cached per (s, j)."""

    def __init__(self, cells: np.ndarray, centres: np.ndarray, volume: np.ndarray, seed: int = 0):
        """cells (B, grains): each grain's grid cell per state; centres (cells, 3) [m]; volume (grains,) [m^3]."""
        self.cells = cells
        self.centres = np.asarray(centres, np.float64)
        self.vol = np.asarray(volume, np.float64)
        classes, self.cls = np.unique(self.vol, return_inverse=True)
        if classes.size > MAX_CLASSES:
            raise ValueError(f"{classes.size} distinct grain volumes: the matching jump pairs grains of equal "
                             f"volume (at most {MAX_CLASSES} classes); use the stitch (jump='stitch')")
        self.members = [np.nonzero(self.cls == k)[0] for k in range(classes.size)]
        self.seed = int(seed)
        self.cache: dict = {}

    def operator(self, s_from: int, s_to: int) -> tuple[np.ndarray, dict]:
        """(perm, info): tau_new = tau[perm]; info: the grain volume matched across grid cells (its share of the
        total: the least any jump moves, 0.5 sum |a_s - a_j| / sum a) and the RMS distance it moves [m]."""
        key = (int(s_from), int(s_to))
        if key in self.cache:
            return self.cache[key]
        rng = np.random.default_rng([self.seed, *key])
        perm = np.empty(self.vol.size, np.int64)
        moved = []
        for idx in self.members:
            p, res = match_class(self.cells[s_from][idx], self.cells[s_to][idx], self.centres, rng)
            perm[idx] = idx[p]
            moved.append(idx[res])
        moved = np.concatenate(moved)
        d = self.centres[self.cells[s_to][moved]] - self.centres[self.cells[s_from][perm[moved]]]
        info = {"moved_volume": float(self.vol[moved].sum()), "moved_share": float(self.vol[moved].sum() / self.vol.sum()),
                "rms_distance": float(np.sqrt(np.mean(np.sum(d * d, 1)))) if moved.size else 0.0}
        self.cache[key] = (perm, info)
        return perm, info


def grid_centres(shape: tuple, origin: np.ndarray, h: float) -> np.ndarray:
    """(cells, 3) centres [m] of a grid of spacing h from ``origin``, flat index (i * ny + j) * nz + k."""
    idx = np.indices(shape).reshape(3, -1).T
    return np.asarray(origin, np.float64) + (idx + 0.5) * h
