"""The grain tracer's mixing indices along a recorded sequence, from the grains that change cell.

Between jumps the tag rides on the recorded grains (transport.GrainTracer), so the tagged volume per cell at each
state of a sequence is a sum over grains. Summing all grains at every state costs O(grains) per frame; most grains
stay in their cell from one boundary to the next (94% in rcfd_bubbling's 5 ms frames), so here the tagged volume of
the sequence's first state is summed once and each later state adds the grains that arrived and takes off those
that left (the movers of every boundary-to-boundary transition, precomputed once per database). The indices then
use per-state constants (grain volume and count per cell, their sums), also precomputed:

- the cell index M = 1 - sum |m - cbar b| / (2 cbar (1 - cbar) sum b) (transport.mixing_index);
- Lacey's index (transport.lacey_index), with sum n (m / b - p)^2 = sum (n / b^2) m^2 - 2 p sum (n / b) m + p^2 N.

The result equals the direct sums to round-off (tests/test_rcfd.py). A sequence whose states are not consecutive
boundaries (a lagged database, a resumed recording's gap) is summed directly.
"""
from __future__ import annotations

import numpy as np


def _runs_on(states: np.ndarray, first: int) -> bool:
    """Whether ``states`` are first, first + 1, ... (consecutive boundaries)."""
    return states[0] == first and states[-1] == first + states.size - 1 and \
        np.array_equal(states, first + np.arange(states.size))


class SequenceIndex:
    """Per-database data for the indices along sequences: the movers of each transition b -> b + 1 (CSR), and per
    state the grain volume b and count n per cell with their sums."""

    def __init__(self, cells: np.ndarray, volume: np.ndarray, n_cells: int, solid: np.ndarray | None = None):
        """cells (B, grains) each grain's cell per state; volume (grains,) [m^3]; solid (B, n_cells) [m^3] if known
        (else summed from the grains)."""
        self.cells = cells
        self.vol = np.asarray(volume, np.float64)
        self.n = int(n_cells)
        B = cells.shape[0]
        ch = cells[1:] != cells[:-1]
        t, g = np.nonzero(ch)  # row-major: sorted by transition
        self.mv_off = np.concatenate([[0], np.cumsum(ch.sum(1))]).astype(np.int64)
        self.mv_g = g.astype(np.int64)
        # each move's cell as a flat index into (transitions, cells): transition t's row t (offset per sequence)
        self.mv_from = t.astype(np.int64) * self.n + cells[t, g]
        self.mv_to = t.astype(np.int64) * self.n + cells[t + 1, g]
        idx = (cells + self.n * np.arange(B)[:, None]).ravel()
        counts = np.bincount(idx, minlength=B * self.n).reshape(B, self.n).astype(np.float64)
        b = solid if solid is not None else \
            np.bincount(idx, weights=np.tile(self.vol, B), minlength=B * self.n).reshape(B, self.n)
        self.b = np.asarray(b, np.float64)
        inv = np.divide(1.0, self.b, out=np.zeros_like(self.b), where=(self.b > 0) & (counts > 0))
        self.wl, self.wq = counts * inv, counts * inv * inv
        self.N, self.K = counts.sum(1), (counts > 0).sum(1)
        self.btot = self.b.sum(1)
        self.mover_share = float(self.mv_g.size / max(1, (B - 1) * cells.shape[1]))

    def tagged(self, w: np.ndarray, state: int) -> np.ndarray:
        """Tagged volume per cell at ``state`` for per-grain tagged volumes w = vol * tau."""
        return np.bincount(self.cells[state], weights=w, minlength=self.n)

    def volumes(self, w: np.ndarray, s_prev: int, states: np.ndarray) -> np.ndarray:
        """(L, n) tagged volume per cell at ``states`` (the boundaries after each frame of a sequence that starts at
        boundary ``s_prev``) for per-grain tagged volumes w, which do not change along the sequence."""
        return self.sequence(w, s_prev, states)[1:]

    def sequence(self, w: np.ndarray, s_prev: int, states: np.ndarray) -> np.ndarray:
        """(L + 1, n): the tagged volume per cell at ``s_prev`` (row 0) and at each of ``states`` (as ``volumes``)."""
        L, n = states.size, self.n
        if L and _runs_on(states, s_prev + 1):
            lo, hi = self.mv_off[s_prev], self.mv_off[s_prev + L]
            off = (s_prev - 1) * n  # transition s_prev + t lands in row t + 1
            wm = w[self.mv_g[lo:hi]]
            # (astype: bincount of no moves returns integers, which would truncate the volumes set below)
            m = np.bincount(self.mv_to[lo:hi] - off, weights=wm, minlength=(L + 1) * n).astype(np.float64, copy=False)
            m -= np.bincount(self.mv_from[lo:hi] - off, weights=wm, minlength=(L + 1) * n)
            m = m.reshape(L + 1, n)  # row t + 1: the arrivals less the departures of transition s_prev + t
            m[0] = self.tagged(w, s_prev)
            for i in range(1, L + 1):  # the running sum down the rows, row by row: 2x np.cumsum(m, 0) here
                np.add(m[i], m[i - 1], out=m[i])
            return m
        idx = (self.cells[np.concatenate([[s_prev], states])] + n * np.arange(L + 1)[:, None]).ravel()
        return np.bincount(idx, weights=np.tile(w, L + 1), minlength=(L + 1) * n).reshape(L + 1, n)

    def indices(self, m: np.ndarray, states: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(cell index M, Lacey index) at each row of m (L, n), the tagged volume per cell at ``states``."""
        L = states.size
        rows = slice(int(states[0]), int(states[0]) + L) if L > 1 and _runs_on(states, states[0]) else states
        # (consecutive states: views of the per-state rows, not copies)
        b, wq, wl = self.b[rows], self.wq[rows], self.wl[rows]
        btot, N, K = self.btot[rows], self.N[rows], self.K[rows]
        p = m.sum(1) / btot
        ok = (p > 0) & (p < 1)
        t = np.multiply(b, p[:, None])  # one scratch array for |m - p b| and then m^2
        np.subtract(m, t, out=t)
        np.abs(t, out=t)
        dev = t.sum(1)
        np.multiply(m, m, out=t)
        with np.errstate(invalid="ignore", divide="ignore"):
            M = 1.0 - dev / (2.0 * p * (1.0 - p) * btot)
            s2 = (np.einsum("ij,ij->i", wq, t) - 2.0 * p * np.einsum("ij,ij->i", wl, m) + p * p * N) / N
            s0 = p * (1.0 - p)
            lacey = (s0 - s2) / (s0 - s0 * (K - 1) / (N - 1))
        return np.where(ok, M, np.nan), np.where(ok & (K > 1), lacey, np.nan)
