"""The grain tracer's jump by grains routed along a flow: a matching that scales to a million grains.

matching.match_class pairs the grains that must change cell by a dense assignment (scipy's linear_sum_assignment):
its cost grows as the cube of those grains (448 s for the jumps of a 7,000-grain database), so above
engine.MATCH_MAX_GRAINS the jumps were stitched, which gives each grain its cell's mean tag and mixes twice as fast
(validation/rcfd/README.md, 00b). Here the grains of state s are instead carried to the cells of state j along
a flow, one cell at a time, and then paired with j's grains within each cell:

1. the flow: on the graph of face-neighbouring cells, the one of least sum f_e^2 / w_e for the grains' net
   outflow b = n_s - n_j of each cell (counts of one volume class), with conductance w_e the mean grain count of
   the edge's two cells in the two states plus a small floor (``FLOOR`` of the mean over occupied cells). It is
   w_e times the gradient of a potential, L_w phi = b (conjugate gradients with a multigrid preconditioner,
   potential.py): the linearised least-kinetic-energy
   (Wasserstein-2) displacement, which moves grains where grains are and goes round empty cells where it can.
   It runs downhill in phi, so it has no cycle;
2. rounded to whole grains: an integer flow with each edge's count the floor or the ceiling of its real flow and
   the same net outflows (it exists because the real flow does; found as a maximum flow, scipy's Dinic);
3. routed: in every cell the grains that leave are its own first (a grain keeps moving only where its cell sends
   out more than it held), so a shift of a column moves each of its grains one cell, not one grain the column's
   length; the arrivals that stay are those that came furthest. Cells are visited in the flow's topological
   levels, so a cell's arrivals are all known when it sends;
4. in every cell, the grains that end there are paired with j's grains at random (seeded): positions are known
   to a cell only.

Like the dense matching it is a permutation within each volume class: tags stay 0 or 1 and the tagged volume is
kept to round-off. It moves more grains than the least that must change cell (a column's shift moves all its
grains one cell), each a shorter way. On synthetic jumps of one size class its total squared distance was 4-9% under
the dense matching's (which keeps every cell's common grains in place), with three classes 14-27% over; it took
1/1.8-1/4.7 of its time at 3,400-7,000 grains (alternated), 3.3 s at 958,000 grains on 86,016 cells
(benchmarks/flow_matching.py; 2.2-2.3 s since the multigrid, benchmarks/flow_jump_ab.py). Against full runs:
validation/rcfd/README.md, 0000a and 0000c.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components, maximum_flow

from .potential import GridMultigrid, graph_laplacian, pcg

FLOOR = 1e-2  # the conductance's floor, as a share of the mean grain count over occupied cells
TOLERANCE = 1e-4  # [grains] how far an edge's rounded count may lie outside floor/ceiling of the solved flow


def ranked(cells: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(order, cell, rank): the grains sorted by cell, in random order within a cell (``rng``), their cells, and
    their rank within the cell."""
    order = shuffled_order(cells, rng)
    c = cells[order]
    return order, c, np.arange(c.size) - np.searchsorted(c, c, side="left")


def shuffled_order(keys: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """The order that sorts the non-negative integers ``keys``, ties in random order (``rng``): one argsort of
    key * N + a random permutation of 0..N-1 (distinct keys), 3.6x faster than a lexsort on (random float, key) at
    320,000 grains on 86,016 cells (26 against 91 ms, the random draws included; 15 interleaved pairs, AMD EPYC)."""
    n = keys.size
    return np.argsort(keys.astype(np.int64) * max(n, 1) + rng.permutation(n))


class FlowGraph:
    """The face-neighbour graph of a grid's cells that grains may occupy; ``edges`` (E, 2) flat indices; ``shape``:
    the grid's, when the n cells are a box (flat index (i * ny + j) * nz + k): the potentials are then solved with a
    multigrid preconditioner (potential.GridMultigrid), else with A's diagonal."""

    def __init__(self, n: int, edges: np.ndarray, shape: tuple | None = None):
        self.n = int(n)
        if shape is not None and int(np.prod(shape)) != self.n:
            raise ValueError(f"a grid of shape {tuple(shape)} has {int(np.prod(shape))} cells, not {self.n}")
        self.shape = None if shape is None else tuple(int(s) for s in shape)
        self.edges = np.asarray(edges, np.int64)
        e = self.edges
        adj = sp.csr_matrix((np.ones(2 * e.shape[0]), (np.r_[e[:, 0], e[:, 1]], np.r_[e[:, 1], e[:, 0]])),
                            shape=(self.n, self.n))
        self.components = connected_components(adj, directed=False)[1]

    def laplacian(self, density: np.ndarray) -> tuple[sp.csr_matrix, np.ndarray]:
        """(L, w): the weighted graph Laplacian of the flow (module text, step 1) and its edges' conductances w."""
        e = self.edges
        occupied = density[density > 0]
        w = 0.5 * (density[e[:, 0]] + density[e[:, 1]]) + FLOOR * (occupied.mean() if occupied.size else 1.0)
        W = sp.csr_matrix((np.r_[w, w], (np.r_[e[:, 0], e[:, 1]], np.r_[e[:, 1], e[:, 0]])), shape=(self.n, self.n))
        return graph_laplacian(W), w

    def potential_flows(self, B: np.ndarray, density: np.ndarray) -> list:
        """[(src, dst, f)] per column of ``B`` (cells, k): the flow of least sum f^2 / w with net outflow ``B[:, c]``
        per cell (module text, step 1), edges oriented downhill, f > 0 [grains]. One Laplacian for the k solves
        (potential.pcg)."""
        e = self.edges
        tot = np.stack([np.bincount(self.components, weights=b, minlength=self.n) for b in B.T])
        if np.abs(tot).max(initial=0.0) > 1e-9 * max(np.abs(B).sum(0).max(initial=0.0), 1.0):
            raise ValueError("the flow matching's problem failed: a part of the cells not joined to the rest by open "
                             "faces would have to gain or lose grains")
        lap, w = self.laplacian(density)
        mg = GridMultigrid(lap, self.shape) if self.shape is not None else None
        Phi = pcg(lap, B, 1e-12, 20 * self.n, "the flow matching's potential", precondition=mg)
        out = []
        for phi, b in zip(Phi.T, B.T):
            g = (phi[e[:, 0]] - phi[e[:, 1]]) * w
            keep = np.abs(g) > 1e-12 * max(np.abs(b).max(), 1.0)
            fwd = g[keep] > 0
            out.append((np.where(fwd, e[keep, 0], e[keep, 1]), np.where(fwd, e[keep, 1], e[keep, 0]), np.abs(g[keep])))
        return out


def integer_flow(n: int, src: np.ndarray, dst: np.ndarray, f: np.ndarray, supply: np.ndarray) -> np.ndarray:
    """Whole counts g on the edges src -> dst, each within floor(f - TOLERANCE) and ceil(f + TOLERANCE), with net
    outflow ``supply`` (integers) in every cell (module text, step 2). ValueError when there is none."""
    lo = np.maximum(np.floor(f - TOLERANCE), 0).astype(np.int64)
    hi = np.ceil(f + TOLERANCE).astype(np.int64)
    g = np.clip(np.rint(f).astype(np.int64), lo, hi)
    need = np.asarray(supply, np.int64) - (np.bincount(src, g, n) - np.bincount(dst, g, n)).round().astype(np.int64)
    if not need.any():
        return g
    up, down = hi - g, g - lo  # an edge's count may rise along src -> dst or fall (the arc dst -> src)
    S, T = n, n + 1
    pos, neg = np.nonzero(need > 0)[0], np.nonzero(need < 0)[0]
    ku, kd = np.nonzero(up > 0)[0], np.nonzero(down > 0)[0]
    rows = np.concatenate([src[ku], dst[kd], np.full(pos.size, S), neg])
    cols = np.concatenate([dst[ku], src[kd], pos, np.full(neg.size, T)])
    cap = np.concatenate([up[ku], down[kd], need[pos], -need[neg]]).astype(np.int32)
    res = maximum_flow(sp.csr_matrix((cap, (rows, cols)), shape=(n + 2, n + 2)), S, T, method="dinic")
    if res.flow_value != need[pos].sum():
        raise ValueError(f"the flow matching found no whole-grain flow ({res.flow_value} of {need[pos].sum()})")
    F = res.flow  # antisymmetric: F[src, dst] is the edge's net change over its up and down arcs
    g = g.copy()
    g[ku] += _entries(F, src[ku], dst[ku]).clip(0)
    g[kd] -= _entries(F, dst[kd], src[kd]).clip(0)
    return g


def _entries(F, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """F[rows[k], cols[k]] of a sparse matrix as int64 (0 where not stored), by a sorted key lookup: scipy's fancy
    indexing returns a matrix, or a sparse matrix for an empty index, depending on the version."""
    F = F.tocoo()
    F.sum_duplicates()  # (row-major sorted, one entry per position)
    keys = F.row.astype(np.int64) * F.shape[1] + F.col
    q = rows.astype(np.int64) * F.shape[1] + cols
    i = np.minimum(np.searchsorted(keys, q), max(keys.size - 1, 0))
    return np.where(keys[i] == q, F.data[i], 0).astype(np.int64) if keys.size else np.zeros(q.size, np.int64)


def dag_levels(n: int, src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """Each cell's level: the most edges on a path of the acyclic graph src -> dst that ends there (Kahn's, a
    level at a time); ValueError on a cycle."""
    indeg = np.bincount(dst, minlength=n)
    by_src = np.argsort(src, kind="stable")
    heads_by_src = dst[by_src]
    starts = np.searchsorted(src[by_src], np.arange(n + 1))
    level = np.zeros(n, np.int64)
    front, lv, seen = np.nonzero(indeg == 0)[0], 0, 0
    while front.size:
        level[front] = lv
        seen += front.size
        cnt = starts[front + 1] - starts[front]
        idx = np.repeat(starts[front] - np.cumsum(np.r_[0, cnt[:-1]]), cnt) + np.arange(cnt.sum())
        heads = heads_by_src[idx]
        np.subtract.at(indeg, heads, 1)
        front = np.unique(heads[indeg[heads] == 0])
        lv += 1
    if seen != n:
        raise ValueError("the flow has a cycle")
    return level


def class_flows(graph: FlowGraph, cfs: list, cts: list, density: np.ndarray) -> list:
    """The real flow (src, dst, f) of each volume class, its grains with cells ``cfs[c]`` in state s and ``cts[c]``
    in state j, or None where the two occupancies are equal; ``density``: the grain count per cell that weighs the
    flows (module text)."""
    n = graph.n
    b = [np.bincount(cf, minlength=n) - np.bincount(ct, minlength=n) for cf, ct in zip(cfs, cts)]
    moving = [k for k, bk in enumerate(b) if bk.any()]
    out = [None] * len(b)
    if moving:
        for k, flow in zip(moving, graph.potential_flows(np.stack([b[k] for k in moving], 1).astype(float), density)):
            out[k] = flow
    return out


def route_class(cf: np.ndarray, ct: np.ndarray, n: int, flow, rng: np.random.Generator) -> np.ndarray:
    """Grains of one volume class with cells ``cf`` in state s and ``ct`` in state j, on a grid of ``n`` cells:
    perm, grain g of j taking the tag of grain perm[g] of s, the grains routed along the real ``flow`` (src, dst,
    f) of class_flows (None: the occupancies are equal)."""
    ns, nj = np.bincount(cf, minlength=n), np.bincount(ct, minlength=n)
    final = cf.copy()
    if flow is not None:
        src, dst, f = flow
        g = integer_flow(n, src, dst, f, ns - nj)
        k = g > 0
        src, dst, g = src[k], dst[k], g[k]
        out = np.bincount(src, g, n).astype(np.int64)
        leave = np.minimum(out, ns)  # own grains first
        stay_in = np.bincount(dst, g, n).astype(np.int64) - (out - leave)  # arrivals that stay
        slot_from = np.repeat(src, g)
        o = shuffled_order(slot_from, rng)
        slot_to = np.repeat(dst, g)[o]  # each cell's outgoing grains' next cells, shuffled, cell by cell
        slot0 = np.searchsorted(slot_from[o], np.arange(n))
        of, c, r = ranked(cf, rng)
        go = r < leave[c]
        moving, at = of[go], slot_to[slot0[c[go]] + r[go]]
        hops = np.zeros(cf.size, np.int64)
        hops[moving] = 1
        level = dag_levels(n, src, dst)
        for lv in range(1, int(level.max(initial=0)) + 1):  # a cell's arrivals all come from lower levels
            here = level[at] == lv
            if not here.any():
                continue
            gm, gc = moving[here], at[here]
            moving, at = moving[~here], at[~here]
            o = np.lexsort((rng.random(gm.size), -hops[gm], gc))  # furthest come first: they stay
            gm, gc = gm[o], gc[o]
            rk = np.arange(gc.size) - np.searchsorted(gc, gc, side="left")
            stay = rk < stay_in[gc]
            final[gm[stay]] = gc[stay]
            gm, gc, rk = gm[~stay], gc[~stay], rk[~stay]
            hops[gm] += 1
            moving = np.concatenate([moving, gm])
            at = np.concatenate([at, slot_to[slot0[gc] + leave[gc] + rk - stay_in[gc]]])
        if moving.size:
            raise ValueError("the flow matching left grains unrouted")
    of, _, _ = ranked(final, rng)
    ot, _, _ = ranked(ct, rng)
    perm = np.empty(cf.size, np.int64)
    perm[ot] = of  # both sorted by (cell, rank), with the same count in every cell
    return perm
