"""The pressure solver's operator assembled with scipy, independent of the Taichi code: the reference the
linear-solver tests and benchmarks/coarse_cycle_check.py measure a solution's residual against."""
import numpy as np
import scipy.sparse as sp


def cell_operator(shape, ts, periodic):
    """The cell-centred operator (A x)_c = sum over the faces f of c of T_f (x_c - x_nb(f)) of
    :class:`app.sim.gas.linsolve.MGPCG` as a scipy CSR matrix, for face transmissibilities ``ts`` (one array of
    face shape per axis) and ``periodic`` axes; a boundary face with T > 0 is a Dirichlet face with outside value
    0 (on its diagonal only)."""
    n = int(np.prod(shape))
    idx = np.arange(n).reshape(shape)
    rows, cols, vals = [], [], []
    diag = np.zeros(n)
    for a in range(3):
        t = ts[a]
        na = shape[a]
        # interior faces 1..na-1 join cells f-1 and f
        for f in range(1, na):
            tf = np.take(t, f, axis=a).ravel()
            i0 = np.take(idx, f - 1, axis=a).ravel()
            i1 = np.take(idx, f, axis=a).ravel()
            rows += [i0, i1]
            cols += [i1, i0]
            vals += [-tf, -tf]
            np.add.at(diag, i0, tf)
            np.add.at(diag, i1, tf)
        if periodic[a] and na > 1:
            tf = np.take(t, 0, axis=a).ravel()
            i0 = np.take(idx, na - 1, axis=a).ravel()
            i1 = np.take(idx, 0, axis=a).ravel()
            rows += [i0, i1]
            cols += [i1, i0]
            vals += [-tf, -tf]
            np.add.at(diag, i0, tf)
            np.add.at(diag, i1, tf)
        elif not periodic[a]:
            np.add.at(diag, np.take(idx, 0, axis=a).ravel(), np.take(t, 0, axis=a).ravel())
            np.add.at(diag, np.take(idx, na - 1, axis=a).ravel(), np.take(t, na, axis=a).ravel())
    A = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(n, n))
    return A + sp.diags(diag)
