"""Potentials on a grid's cell graph, L phi = b with L a weighted graph Laplacian: preconditioned conjugate gradients
with no BLAS call in its iterations, and an aggregation multigrid V-cycle as the preconditioner on a box of cells.

Both the flow matching (flowmatch.FlowGraph.potential_flows, three right-hand sides a jump) and the stitch
(stitch.FlowStitch, with A's diagonal) solve such a system. A Jacobi preconditioner needs iterations in proportion
to the grid's length (the square root of the condition number): 483 on the poppy bed's 32 x 32 x 84 cells. The
V-cycle (2 x 2 x 2 blocks of cells merged per level, Galerkin coarse operators, one damped-Jacobi sweep before and
after, a pseudo-inverse on a coarsest level of at most COARSEST cells) needs 54, each about three times the cost
of a Jacobi one (benchmarks/flow_solve.py).
"""
from __future__ import annotations

from typing import Callable

import numpy as np
import scipy.sparse as sp

OMEGA = 0.67  # damping of the V-cycle's Jacobi sweeps (2/3: the usual choice for a 7-point Laplacian)
# [cells] the V-cycle's coarsest level at most, solved by a dense pseudo-inverse: small enough that OpenBLAS runs it
# on one thread (at 128 cells its threads, beside a busy core, made a 7,000-grain jump 1.4x slower than with the
# Jacobi preconditioner; 1.3x faster on one thread). 54 iterations on the poppy bed against 41 with up to 256 cells.
COARSEST = 32
RCOND = 1e-10  # eigenvalues of the coarsest operator under this share of its largest are its null space (round-off)


def _inverse_diagonal(A: sp.csr_matrix) -> np.ndarray:
    d = A.diagonal()
    return np.divide(1.0, d, out=np.zeros_like(d), where=d > 0)


def graph_laplacian(W: sp.spmatrix) -> sp.csr_matrix:
    """diag(W 1) - W of a symmetric matrix of weights W >= 0 between distinct cells (zero diagonal)."""
    return (sp.diags(np.asarray(W.sum(1)).ravel()) - W).tocsr()


def _laplacian(A: sp.csr_matrix) -> sp.csr_matrix:
    """A with its diagonal set to minus the sum of each row's other entries: a Galerkin operator P^T L P of a graph
    Laplacian L is one, but only to round-off, and a coarsest level of one cell would then hold that round-off, whose
    pseudo-inverse is huge (conjugate gradients then never converged)."""
    off = (A - sp.diags(A.diagonal())).tocsr()
    off.eliminate_zeros()
    return graph_laplacian(-off)


def _each_row(M: sp.csr_matrix, X: np.ndarray) -> np.ndarray:
    """M applied to every row of X (k, n): k sparse products (faster than one of M @ X.T here, and no BLAS)."""
    return np.stack([M @ x for x in X])


class GridMultigrid:
    """The V-cycle of a graph Laplacian ``A`` (zero row sums) on the cells of a box of ``shape`` (flat index
    (i * ny + j) * nz + k), as a preconditioner: ``self(R)`` for residuals R (k, n). Symmetric (the same sweep before
    and after the coarse correction) and positive semi-definite, as conjugate gradients need. Cells outside the
    graph (zero rows) may take any value: they join no edge."""

    def __init__(self, A: sp.csr_matrix, shape: tuple):
        self.levels = []  # (A, 1 / diagonal, restriction P^T, prolongation P) from the finest
        shape = tuple(int(s) for s in shape)
        while A.shape[0] > COARSEST and max(shape) > 1:
            coarse = tuple((s + 1) // 2 for s in shape)
            i, j, k = np.indices(shape).reshape(3, -1)
            block = ((i // 2) * coarse[1] + j // 2) * coarse[2] + k // 2
            P = sp.csr_matrix((np.ones(block.size), (np.arange(block.size), block)),
                              shape=(block.size, int(np.prod(coarse))))
            PT = P.T.tocsr()
            self.levels.append((A, _inverse_diagonal(A), PT, P))
            A, shape = _laplacian((PT @ A @ P).tocsr()), coarse
        self.coarsest = np.linalg.pinv(A.toarray(), rcond=RCOND, hermitian=True)

    def __call__(self, R: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """The V-cycle's approximation of A^+ R, R (k, n) (a new array: ``out`` is not used)."""
        return self._cycle(0, R)

    def _cycle(self, level: int, R: np.ndarray) -> np.ndarray:
        if level == len(self.levels):
            return np.einsum("ij,kj->ki", self.coarsest, R)  # (einsum: numpy's loops, not BLAS's threads)
        A, inv, PT, P = self.levels[level]
        X = OMEGA * inv * R
        X += _each_row(P, self._cycle(level + 1, _each_row(PT, R - _each_row(A, X))))
        X += OMEGA * inv * (R - _each_row(A, X))
        return X


def pcg(A: sp.csr_matrix, B: np.ndarray, rtol: float, maxiter: int, what: str, hint: str = "",
        precondition: Callable | None = None, stats: dict | None = None) -> np.ndarray:
    """X (n, k) with A X = B, A symmetric positive semi-definite, B (n, k) consistent: conjugate gradients, every
    column to ||r|| <= rtol ||b|| [2-norm], the k columns side by side. ``precondition(R, out)``: Z (k, n) for R
    (k, n), in ``out`` or new, a symmetric positive semi-definite operator (GridMultigrid); by default A's diagonal,
    rows without one left at 0.
    No BLAS call: the vector products are numpy's own loops, so it runs on one thread whatever else runs (scipy's cg
    takes BLAS's dot, whose threads, with a prefetch's worker on every core, made a solve up to 20x slower:
    validation/rcfd/README.md, 0000b). ``stats['iterations']``: how many it took. ValueError naming ``what`` (and
    ``hint``) if it has not converged in ``maxiter`` iterations."""
    B = np.ascontiguousarray(np.asarray(B, np.float64).reshape(A.shape[0], -1).T)  # (k, n): rows contiguous
    if precondition is None:
        inv = _inverse_diagonal(A)

        def precondition(R, out=None):
            return np.multiply(inv, R, out=out)

    def dots(U, V):
        return np.einsum("ij,ij->i", U, V)

    X, R, Q, T = np.zeros_like(B), B.copy(), np.empty_like(B), np.empty_like(B)
    Z = precondition(R, np.empty_like(B))
    P, rz = Z.copy(), dots(R, Z)
    target = rtol * np.sqrt(dots(B, B))
    for it in range(maxiter):  # (in place, the same operations in the same order as X += alpha * P etc.)
        live = np.sqrt(dots(R, R)) > target
        if not live.any():
            if stats is not None:
                stats["iterations"] = it
            return X.T
        for c in range(B.shape[0]):
            Q[c] = A @ P[c]
        pq = dots(P, Q)
        alpha = np.divide(rz, pq, out=np.zeros_like(rz), where=live & (pq > 0))[:, None]
        X += np.multiply(alpha, P, out=T)
        R -= np.multiply(alpha, Q, out=T)
        Z = precondition(R, Z)
        rz_new = dots(R, Z)
        beta = np.divide(rz_new, rz, out=np.zeros_like(rz), where=live & (rz > 0))[:, None]
        P *= beta
        P += Z
        rz = rz_new
    raise ValueError(f"{what} did not converge in {maxiter} iterations{hint}")
