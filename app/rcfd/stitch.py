"""The stitch at a jump: an operator S that turns one grain-volume distribution over the cells into another.

At a jump from state s to state j the carried volume (the grains' distribution a_s) must become a_j, the
distribution the next frames were recorded from. S moves volume between face neighbours along a flow f whose net
inflow is a_j - a_s in every cell, applied cell by cell in a topological order of the flow, each outflow carrying
its cell's current composition. So S is non-negative and column-stochastic (each origin's volume ends somewhere,
once): the tracer is kept to round-off and its concentration stays in [0, 1]. Each cell keeps a share ``stay`` of
its content (the volume it held and received) and sends the rest on, so S = diag(stay) (I - W)^-1 with W[d, s] the
share of s's content sent to d: unit lower-triangular in the topological order, solved by a sparse LU that makes no
fill (FlowStitch). Two flows make up the difference:

- ``"lp"``: the least volume x distance, a min-cost flow (scipy's HiGHS), whose optimal basic solution is a
  forest. Its cost grows faster than the cells: 0.13 s at 2,048 cells, 1.9 s at 10,752, 31 s at 36,288 (a blob
  emptied and a layer filled on a noisy bed, 2-core Xeon; validation/rcfd/README.md), so the 86,000 cells of the
  poppy-seed bed below 0.25 m are out of reach.
- ``"potential"``: the flow of least sum f^2, the gradient of a potential: L phi = -(a_j - a_s) with L the graph
  Laplacian (conjugate gradients, Jacobi preconditioned), f = phi_a - phi_b from a to b. It runs downhill in phi,
  so it has no cycle and the cells in decreasing phi are a topological order. On the cases above it moved 7-12% more volume x distance than ``"lp"``, and the tagged layer's mixing index
  rose 1-7% more, in 0.005 / 0.03 / 0.15 s, and 0.5 s at 86,016 cells. On rcfd_bubbling's 30 half-cell stitches:
  27% more volume x distance, 6% more index change per jump, the same mean index over 1 s (0.184) in 1/34 of the
  time (validation/rcfd/bench_stitch.py).
- ``"auto"``: ``"lp"`` up to LP_MAX_CELLS cells in the stitch graph, ``"potential"`` above.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.optimize import linprog
from scipy.sparse.csgraph import connected_components
from scipy.sparse.linalg import splu

from .flowmatch import dag_levels
from .potential import pcg

LP_MAX_CELLS = 20_000  # 'auto': the min-cost flow up to here (1.9 s at 10,752 cells, 31 s at 36,288)
FLOWS = ("auto", "lp", "potential")


def face_edges(shape: tuple, cells: np.ndarray) -> np.ndarray:
    """(E, 2) flat-index pairs of face-neighbouring cells that are both in ``cells`` (bool, shape)."""
    idx = np.arange(int(np.prod(shape))).reshape(shape)
    out = []
    for a in range(3):
        lo = [slice(None)] * 3
        hi = [slice(None)] * 3
        lo[a], hi[a] = slice(0, -1), slice(1, None)
        ok = cells[tuple(lo)] & cells[tuple(hi)]
        out.append(np.stack([idx[tuple(lo)][ok], idx[tuple(hi)][ok]], 1))
    return np.concatenate(out)


class FlowStitch:
    """S = diag(stay) (I - W)^-1 of an acyclic flow (see the module's text): ``S @ v`` for a volume per cell v.
    src -> dst carries f [m^3]; ``order`` lists the cells so that every flow runs from an earlier to a later one."""

    def __init__(self, a_from: np.ndarray, src: np.ndarray, dst: np.ndarray, f: np.ndarray, order: np.ndarray):
        n = a_from.size
        self.shape = (n, n)
        self.order = order
        content = a_from + np.bincount(dst, weights=f, minlength=n)  # what a cell holds before it sends
        out = np.bincount(src, weights=f, minlength=n)
        cap = np.where(out > content, content / np.maximum(out, 1e-300), 1.0)  # round-off: no overdraft
        share = f * cap[src] / np.maximum(content[src], 1e-300)  # of src's content, sent to dst
        self.stay = np.clip(1.0 - np.bincount(src, weights=share, minlength=n), 0.0, 1.0)
        rank = np.empty(n, np.int64)
        rank[order] = np.arange(n)
        W = sp.csc_matrix((share, (rank[dst], rank[src])), shape=(n, n))  # strictly lower in this order
        self._lu = splu((sp.identity(n, format="csc") - W).tocsc(), permc_spec="NATURAL", diag_pivot_thresh=0.0,
                        options={"SymmetricMode": True})  # no pivoting, no reordering: L = I - W, U = I

    def __matmul__(self, v: np.ndarray) -> np.ndarray:
        out = np.empty(self.shape[0])
        out[self.order] = self._lu.solve(np.asarray(v, np.float64)[self.order])  # each cell's content
        return out * self.stay


def topological_order(n: int, src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """The cells in an order in which every edge src -> dst runs forward: by level (flowmatch.dag_levels), in
    increasing index within a level; ValueError on a cycle."""
    return np.argsort(dag_levels(n, src, dst), kind="stable")


class Stitcher:
    """Stitch operators between grain-volume distributions over the cells of a graph (cached by key); ``flow``
    one of FLOWS (the module's text)."""

    def __init__(self, shape: tuple, cells: np.ndarray, h: float, flow: str = "auto"):
        if flow not in FLOWS:
            raise ValueError(f"the stitch's flow must be one of {', '.join(FLOWS)}, got {flow!r}")
        self.n = int(np.prod(shape))
        self.edges = face_edges(shape, cells)
        self.h = h
        e, E = self.edges, self.edges.shape[0]
        adj = sp.csr_matrix((np.ones(2 * E), (np.r_[e[:, 0], e[:, 1]], np.r_[e[:, 1], e[:, 0]])), shape=(self.n,) * 2)
        self.degree = np.asarray(adj.sum(1)).ravel()
        self.nodes = np.nonzero(self.degree > 0)[0]
        self.outside = self.degree == 0  # cells no open face joins: nothing can move there
        self.flow = flow if flow != "auto" else ("lp" if self.nodes.size <= LP_MAX_CELLS else "potential")
        if self.flow == "lp":
            # node-edge incidence: flow f_e >= 0 along (a -> b) and g_e >= 0 along (b -> a); net inflow = A [f, g]
            rows = np.concatenate([e[:, 1], e[:, 0], e[:, 0], e[:, 1]])
            cols = np.concatenate([np.arange(E), np.arange(E), E + np.arange(E), E + np.arange(E)])
            vals = np.concatenate([np.ones(E), -np.ones(E), np.ones(E), -np.ones(E)])
            self.A = sp.csr_matrix((vals, (rows, cols)), shape=(self.n, 2 * E))
        else:
            self.laplacian = (sp.diags(self.degree) - adj).tocsr()
            self.components = connected_components(adj, directed=False)[1]
        self.cache: dict = {}

    def operator(self, a_from: np.ndarray, a_to: np.ndarray, key=None):
        """(S, info): S column-stochastic, S a_from = a_to (to round-off for 'lp', to the solver's tolerance for
        'potential'); info: moved volume [m^3] and its share of the total, volume x distance [m^4], the flow used,
        fit_error (max |S a_from - a_to| over the largest cell's a_to)."""
        if key is not None and key in self.cache:
            return self.cache[key]
        a_from = np.asarray(a_from, np.float64)
        a_to = np.asarray(a_to, np.float64) * (a_from.sum() / a_to.sum())  # same total to round-off
        d = a_to - a_from
        scale = max(float(np.abs(d).max()), 1e-300)
        moved = 0.5 * float(np.abs(d).sum())
        if moved <= 1e-14 * a_from.sum():
            S, flux, fit = sp.identity(self.n, format="csr"), 0.0, 0.0
        elif np.abs(d[self.outside]).max(initial=0.0) > 1e-12 * scale:
            raise ValueError("grain volume in a cell outside the stitch graph")
        else:
            src, dst, f, order = self._lp(d, scale) if self.flow == "lp" else self._potential(d, scale)
            S, flux = FlowStitch(a_from, src, dst, f, order), float(f.sum())
            fit = float(np.abs(S @ a_from - a_to).max()) / max(float(a_to.max()), 1e-300)
        info = {"moved_volume": moved, "moved_share": moved / float(a_from.sum()), "volume_distance": flux * self.h,
                "flow": self.flow, "fit_error": fit}
        if key is not None:
            self.cache[key] = (S, info)
        return S, info

    def _lp(self, d: np.ndarray, scale: float) -> tuple:
        """The min-cost flow (src, dst, volume [m^3], a topological order of the cells)."""
        bd = d[self.nodes] / scale
        bd[np.argmax(np.abs(bd))] -= bd.sum()
        E = self.edges.shape[0]
        res = linprog(np.ones(2 * E), A_eq=self.A[self.nodes], b_eq=bd, bounds=(0, None), method="highs-ds")
        if res.status != 0:
            raise ValueError(f"the stitch's flow problem failed: {res.message}")
        E, e = self.edges.shape[0], self.edges
        f, g = res.x[:E], res.x[E:]
        fwd, back = f > 1e-12, g > 1e-12
        src, dst = np.concatenate([e[fwd, 0], e[back, 1]]), np.concatenate([e[fwd, 1], e[back, 0]])
        return src, dst, np.concatenate([f[fwd], g[back]]) * scale, topological_order(self.n, src, dst)

    def _potential(self, d: np.ndarray, scale: float) -> tuple:
        """The potential flow (src, dst, volume [m^3], the cells in decreasing potential: a topological order)."""
        b = -d / scale
        tot = np.bincount(self.components[self.nodes], weights=b[self.nodes])
        if np.abs(tot).max() > 1e-9 * np.abs(b).sum():
            raise ValueError("the stitch's flow problem failed: a part of the cells not joined to the rest by open "
                             "faces would have to gain or lose grain volume")
        size = np.bincount(self.components[self.nodes])
        mean = np.divide(tot, size, out=np.zeros_like(tot), where=size > 0)  # (labels of closed cells: no nodes)
        b[self.nodes] -= mean[self.components[self.nodes]]  # the round-off, so that each part's sum is zero
        phi = pcg(self.laplacian, b, 1e-14, 20 * self.n, "the stitch's potential", ": use flow 'lp'")[:, 0]
        e = self.edges
        g = (phi[e[:, 0]] - phi[e[:, 1]]) * scale
        fwd = g > 0
        f = np.abs(g)
        keep = f > 1e-14 * scale
        src, dst = np.where(fwd, e[:, 0], e[:, 1])[keep], np.where(fwd, e[:, 1], e[:, 0])[keep]
        return src, dst, f[keep], np.argsort(-phi, kind="stable")
