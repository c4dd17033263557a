"""rCFD's flow matching: grains routed along a flow at a jump (app/rcfd/flowmatch.py; synthetic, no Taichi)."""
import numpy as np
import pytest

from app.rcfd.flowmatch import FlowGraph, dag_levels, integer_flow
from app.rcfd.matching import GrainMatcher, grid_centres
from app.rcfd.stitch import face_edges
from app.rcfd.transport import GrainTracer

pytestmark = pytest.mark.unit


def _graph(shape, mask=None):
    """The graph as the engine builds it, with the grid's shape (the potentials' multigrid preconditioner)."""
    mask = np.ones(shape, bool) if mask is None else mask
    return FlowGraph(int(np.prod(shape)), face_edges(shape, mask), shape)


def _states(rng, g=900, shape=(8, 4, 10), B=4):
    """Grains in the lower 60% of a box; each later state moves 30% of the last one's grains one cell, and a
    block of them two cells up (a bubble's wake)."""
    n = int(np.prod(shape))
    ijk = np.stack([rng.integers(0, shape[0], g), rng.integers(0, shape[1], g), rng.integers(0, 6, g)], 1)
    out = []
    for _ in range(B):
        out.append((ijk[:, 0] * shape[1] + ijk[:, 1]) * shape[2] + ijk[:, 2])
        ijk = ijk.copy()
        mv = rng.random(g) < 0.3
        ijk[mv, rng.integers(0, 3)] += rng.choice([-1, 1], mv.sum())
        ijk[ijk[:, 0] < 3, 2] += 2 * (rng.random(int((ijk[:, 0] < 3).sum())) < 0.2)
        ijk = np.clip(ijk, 0, np.array(shape) - 1)
    return np.stack(out), n


def test_flow_matching_is_a_permutation_within_sizes_that_keeps_the_tag_exactly_and_reproduces():
    rng = np.random.default_rng(7)
    shape = (8, 4, 10)
    cells, n = _states(rng, shape=shape)
    vol = np.where(rng.random(cells.shape[1]) < 0.3, 2.0, 1.0)
    for v in (1.0, 2.0):  # state 2: state 1's cells dealt to other grains of each size (nothing needs to move)
        k = np.nonzero(vol == v)[0]
        cells[2, k] = cells[1, rng.permutation(k)]
    centres = grid_centres(shape, np.zeros(3), 1.0)
    m = GrainMatcher(cells, centres, vol, seed=4, graph=_graph(shape))
    tr = GrainTracer(vol, (rng.random(cells.shape[1]) < 0.4).astype(float), n)
    tagged0 = float(np.sum(tr.vol * tr.tau))
    for s, j in ((0, 1), (1, 3), (3, 0), (2, 0)):
        perm, info = m.operator(s, j)
        assert np.array_equal(np.sort(perm), np.arange(perm.size))
        assert np.array_equal(vol[perm], vol)  # within each size class
        tr.permute(perm)
        assert abs(np.sum(tr.vol * tr.tau) - tagged0) <= 1e-12 * tagged0
        assert set(np.unique(tr.tau)) <= {0.0, 1.0}  # a tag stays 0 or 1: nothing averaged
        least = sum(0.5 * np.abs(np.bincount(cells[s][vol == v], minlength=n)
                                 - np.bincount(cells[j][vol == v], minlength=n)).sum() * v for v in (1.0, 2.0))
        assert info["moved_volume"] >= least * (1 - 1e-12)  # a flow moves at least what must change cell
    for s, j in ((2, 2), (1, 2)):  # a self-jump, and a jump to the same occupancy: every grain stays in its cell
        perm, info = m.operator(s, j)
        assert info["moved_share"] == 0.0 and np.array_equal(cells[j], cells[s][perm])
    again = GrainMatcher(cells, centres, vol, seed=4, graph=_graph(shape))
    assert np.array_equal(again.operator(1, 3)[0], m.operator(1, 3)[0])  # reproducible from the seed
    other = GrainMatcher(cells, centres, vol, seed=5, graph=_graph(shape))
    assert not np.array_equal(other.operator(1, 3)[0], m.operator(1, 3)[0])
    assert again.fingerprint() != GrainMatcher(cells, centres, vol, seed=4).fingerprint()  # not the dense one's


def test_a_shifted_column_moves_every_grain_one_cell_not_one_grain_the_whole_way():
    """One grain in each of cells 0-4 of a row, then in cells 1-5: the flow matching moves each grain one cell
    (5 x 1^2 = 5 in squared distance); the dense assignment keeps cells 1-4 and moves one grain five cells (25).
    A shift, not a long jump: the tag pattern moves with the column, as the grains do."""
    shape = (6, 1, 1)
    cells = np.stack([np.arange(5), np.arange(1, 6)])
    centres = grid_centres(shape, np.zeros(3), 1.0)
    for graph, hops in ((_graph(shape), [1] * 5), (None, [5])):
        perm, info = GrainMatcher(cells, centres, np.ones(5), graph=graph).operator(0, 1)
        d = cells[1] - cells[0][perm]
        assert sorted(d[d != 0].tolist()) == hops
    tau = np.array([1.0, 1, 0, 0, 0])  # the lower two tagged: after the shift, cells 1-2 hold them
    perm, _ = GrainMatcher(cells, centres, np.ones(5), graph=_graph(shape)).operator(0, 1)
    assert np.array_equal(tau[perm], tau)


def test_the_flow_goes_round_an_empty_region_through_the_grains():
    """A U of occupied cells in a box (the middle columns empty above the floor row). Six grains' worth moves from
    the left arm to the right arm. The flow is weighed by the grains where they are, so it runs down the left arm,
    along the floor and up the right arm, shifting the floor's grains on (all six of them move), not straight
    across the empty middle, which the unweighted shortest route would take."""
    shape = (5, 1, 4)
    idx = np.arange(int(np.prod(shape))).reshape(shape)
    arm_l, arm_r, floor = idx[0, 0, 1:], idx[4, 0, 1:], idx[1:4, 0, 0]
    corners = [idx[0, 0, 0]] * 2 + [idx[4, 0, 0]] * 2
    s = np.concatenate([np.repeat(arm_l, 3), arm_r, np.repeat(floor, 2), corners])
    j = np.concatenate([arm_l, np.repeat(arm_r, 3), np.repeat(floor, 2), corners])
    cells = np.stack([s, j])
    perm, info = GrainMatcher(cells, grid_centres(shape, np.zeros(3), 1.0), np.ones(s.size),
                              graph=_graph(shape)).operator(0, 1)
    origin = cells[0][perm]  # the cell each grain of state j came from
    from_floor = np.isin(origin, floor)
    assert from_floor.sum() == 6 and np.all(cells[1][from_floor] != origin[from_floor])
    assert not np.any(np.isin(cells[1], idx[1:4, 0, 1:]))  # (and nothing ends in the empty middle)
    assert info["moved_share"] > 6 / s.size  # more grains move than the six that must: each a shorter way


def test_whole_grain_flow_keeps_every_net_outflow_and_rounds_each_edge_down_or_up():
    rng = np.random.default_rng(3)
    for trial in range(20):
        n = 30
        order = rng.permutation(n)  # a random acyclic graph: edges from earlier to later in ``order``
        a, b = rng.integers(0, n, (2, 120))
        keep = a != b
        a, b = a[keep], b[keep]
        rank = np.argsort(order)
        src, dst = np.where(rank[a] < rank[b], a, b), np.where(rank[a] < rank[b], b, a)
        e = np.unique(np.stack([src, dst], 1), axis=0)
        src, dst = e[:, 0], e[:, 1]
        f = rng.exponential(1.5, src.size) * (rng.random(src.size) < 0.8)
        # whole net outflows: move a fraction along a path so that every node's balance is an integer
        bal = np.bincount(src, f, n) - np.bincount(dst, f, n)
        frac = bal - np.round(bal)
        if np.abs(frac).max() > 1e-9:  # settle the fractions on the edges into the sink of the order
            last = order[-1]
            for v in range(n):
                if v != last and abs(frac[v]) > 1e-12:
                    src, dst = np.append(src, v), np.append(dst, last)
                    f = np.append(f, 1.0 - frac[v] if frac[v] > 0 else -frac[v])
            e, inv = np.unique(np.stack([src, dst], 1), axis=0, return_inverse=True)
            f = np.bincount(inv.ravel(), f)
            src, dst = e[:, 0], e[:, 1]
            bal = np.bincount(src, f, n) - np.bincount(dst, f, n)
        supply = np.round(bal).astype(np.int64)
        assert np.abs(bal - supply).max() < 1e-9
        g = integer_flow(n, src, dst, f, supply)
        assert np.array_equal(np.bincount(src, g, n) - np.bincount(dst, g, n), supply)
        assert np.all(g >= np.floor(f - 1e-4)) and np.all(g <= np.ceil(f + 1e-4))
        assert dag_levels(n, src[g > 0], dst[g > 0]).max() < n
    # every edge rounded down (none may fall) or up (none may rise) first: the correction has only one direction
    for f, want in ((0.4, 1), (1.6, 1), (0.6, 0)):
        supply = np.array([want, -want])
        assert integer_flow(2, np.array([0]), np.array([1]), np.array([f]), supply).tolist() == [want]


def test_a_closed_part_that_must_gain_grains_is_refused():
    shape = (4, 1, 1)
    mask = np.array([True, True, False, True]).reshape(shape)  # cell 3 joined to nothing
    cells = np.stack([np.array([0, 1, 3]), np.array([0, 1, 1])])
    m = GrainMatcher(cells, grid_centres(shape, np.zeros(3), 1.0), np.ones(3), graph=_graph(shape, mask))
    with pytest.raises(ValueError, match="not joined"):
        m.operator(0, 1)


def test_prefetched_matchings_from_forked_workers_equal_the_ones_computed_one_by_one():
    """GrainMatcher.prefetch builds the jumps in forked processes (run in a fresh interpreter without Taichi, as
    `fbed rcfd run` is): the same permutations and info as one by one, for the flow and the dense matching."""
    import subprocess
    import sys
    import textwrap

    code = textwrap.dedent("""
        import sys
        import numpy as np
        sys.path.insert(0, "tests")
        from test_rcfd_flowmatch import _graph, _states
        from app.rcfd.matching import GrainMatcher, grid_centres
        shape = (8, 4, 10)
        cells, n = _states(np.random.default_rng(9), shape=shape, B=6)
        vol = np.where(np.random.default_rng(1).random(cells.shape[1]) < 0.3, 2.0, 1.0)
        pairs = [(0, 3), (1, 4), (2, 5), (5, 0), (0, 3)]
        for graph in (_graph(shape), None):
            make = lambda: GrainMatcher(cells, grid_centres(shape, np.zeros(3), 1.0), vol, seed=3, graph=graph)
            one, par = make(), make()
            assert par.prefetch(pairs, workers=2) == 4 and "taichi" not in sys.modules
            assert par.fresh == set(pairs) and par.prefetch(pairs, workers=2) == 0
            for p in pairs:
                a, b = one.operator(*p), par.cache[p]
                assert np.array_equal(a[0], b[0]) and a[1] == b[1], p
        print("same")
    """)
    root = __import__("pathlib").Path(__file__).resolve().parents[1]
    r = subprocess.run([sys.executable, "-c", code], cwd=root, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0 and r.stdout.strip() == "same", r.stderr[-3000:]


def test_a_prefetch_killed_by_a_time_limit_keeps_the_matchings_it_stored(tmp_path):
    """A command cut off by a time limit (`timeout` signals the whole process group, the forked workers too) keeps
    the jumps it had built: the prefetch stores them as they finish. The child stores after every jump and is
    killed after the third: those three are in the store, and they are the permutations computed afresh."""
    import os
    import signal
    import subprocess
    import sys
    import textwrap

    code = textwrap.dedent("""
        import sys, time
        import numpy as np
        sys.path.insert(0, "tests")
        from test_rcfd_flowmatch import _graph, _states
        from app.rcfd.matching import GrainMatcher, grid_centres
        shape = (8, 4, 10)
        cells, n = _states(np.random.default_rng(9), shape=shape, B=8)
        m = GrainMatcher(cells, grid_centres(shape, np.zeros(3), 1.0), np.ones(cells.shape[1]), graph=_graph(shape))

        def progress(done, total):
            print(done, total, flush=True)
            if done == 3:
                time.sleep(120)  # the kill comes here
        m.prefetch([(s, (s + 3) % 8) for s in range(8)], workers=2, store=sys.argv[1], every=0.0, progress=progress)
        print("not killed", flush=True)
    """)
    root = __import__("pathlib").Path(__file__).resolve().parents[1]
    store = tmp_path / "matchings.h5"
    proc = subprocess.Popen([sys.executable, "-c", code, str(store)], cwd=root, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        lines = [proc.stdout.readline() for _ in range(3)]
        assert lines[-1].split() == ["3", "8"], (lines, proc.stderr.read()[-3000:] if proc.poll() else "")
        os.killpg(proc.pid, signal.SIGTERM)
        assert proc.wait(60) == -signal.SIGTERM
        shape = (8, 4, 10)
        cells, n = _states(np.random.default_rng(9), shape=shape, B=8)
        m = GrainMatcher(cells, grid_centres(shape, np.zeros(3), 1.0), np.ones(cells.shape[1]), graph=_graph(shape))
        assert m.load(store) == 3
        fresh = GrainMatcher(cells, grid_centres(shape, np.zeros(3), 1.0), np.ones(cells.shape[1]),
                             graph=_graph(shape))
        for key, (perm, info) in m.cache.items():
            assert np.array_equal(perm, fresh.operator(*key)[0]) and info == fresh.operator(*key)[1]
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)


def test_a_signal_that_comes_while_the_store_is_written_waits_for_the_write_to_end():
    import os
    import signal

    from app.rcfd.matching import _signals_held

    got = []
    old = signal.signal(signal.SIGTERM, lambda *a: got.append("signal"))
    try:
        with _signals_held():
            os.kill(os.getpid(), signal.SIGTERM)
            got.append("write finished")
        for _ in range(100):  # (a Python handler runs at the interpreter's next check)
            if len(got) == 2:
                break
        assert got == ["write finished", "signal"]
    finally:
        signal.signal(signal.SIGTERM, old)


def _singular_laplacian(rng, shape, round_=False):
    """A grid's weighted Laplacian with 10% of its cells closed (many separate parts), and with ``round_`` those
    outside a cylinder about z too (whole blocks of cells closed, as in a round vessel), conductances over three
    decades, as the grain-weighted flow's; right-hand sides consistent on every part, the third zero."""
    import scipy.sparse as sp

    from app.rcfd.potential import graph_laplacian

    mask = rng.random(shape) < 0.9
    if round_:
        i, j = np.indices(shape[:2]) + 0.5
        mask &= ((i - shape[0] / 2) ** 2 + (j - shape[1] / 2) ** 2 < (shape[0] / 2) ** 2)[:, :, None]
    e = face_edges(shape, mask)
    n = int(np.prod(shape))
    w = rng.uniform(0.01, 30.0, e.shape[0])
    L = graph_laplacian(sp.csr_matrix((np.r_[w, w], (np.r_[e[:, 0], e[:, 1]], np.r_[e[:, 1], e[:, 0]])), shape=(n, n)))
    comp = _graph(shape, mask).components
    B = rng.integers(-5, 6, (n, 3)).astype(float)
    B[L.diagonal() == 0] = 0.0
    for c in range(2):  # consistent: zero sum over every connected part
        B[:, c] -= (np.bincount(comp, B[:, c]) / np.bincount(comp))[comp] * (L.diagonal() > 0)
    B[:, 2] = 0.0
    return L, B, e


def test_pcg_solves_each_column_of_a_singular_consistent_laplacian_like_scipys_cg():
    """potential.pcg with A's diagonal (the stitch's potential): every column to its relative residual, the same
    solution as scipy's Jacobi-preconditioned cg from zero (both stay orthogonal to the constants), a row without
    a diagonal (a closed cell) left at 0, a zero column at 0, and a clear error when out of iterations."""
    import scipy.sparse as sp
    from scipy.sparse.linalg import cg

    from app.rcfd.potential import pcg

    L, B, _ = _singular_laplacian(np.random.default_rng(5), (6, 5, 7))
    n = L.shape[0]
    X = pcg(L, B, 1e-12, 20 * n, "test")
    assert X.shape == B.shape and np.all(X[L.diagonal() == 0] == 0.0) and np.all(X[:, 2] == 0.0)
    for c in range(2):
        assert np.linalg.norm(L @ X[:, c] - B[:, c]) <= 1e-12 * np.linalg.norm(B[:, c])
        ref = cg(L, B[:, c], rtol=1e-13, maxiter=20 * n, M=sp.diags(1.0 / np.maximum(L.diagonal(), 1e-300)))[0]
        assert np.abs(X[:, c] - ref).max() <= 1e-8 * np.abs(ref).max()
    with pytest.raises(ValueError, match="test did not converge in 3 iterations: hint"):
        pcg(L, B, 1e-12, 3, "test", ": hint")


@pytest.mark.parametrize("shape, round_", [((16, 12, 20), False), ((9, 7, 33), False), ((16, 16, 20), True)])
def test_the_multigrid_preconditioner_gives_the_same_flows_in_a_third_of_the_iterations(shape, round_):
    """potential.GridMultigrid (the flow matching's potentials on a box of cells): three levels of 2 x 2 x 2 blocks
    (odd sizes too) above a dense coarsest one. On a singular Laplacian with hundreds of separate parts, every
    column meets its relative residual, and the flows (the potential's differences over the edges: a solution is
    defined up to a constant per part) equal the Jacobi-preconditioned ones to 1e-9 of the largest. The Jacobi
    preconditioner needs iterations in proportion to the grid's length: 200, 173 and 196 here against 39, 41 and 41
    for the V-cycle (measured; 483 against 54 on the poppy bed's 32 x 32 x 84 cells). A cycle without its coarse
    correction took 122 and 106 on the first two, one without its second sweep (not symmetric) did not converge in
    2,000: a third is a bound that those fail and the cycle meets with room. The round vessel's corners close whole
    blocks of cells (zero rows on every level)."""
    from app.rcfd.potential import COARSEST, GridMultigrid, pcg

    L, B, e = _singular_laplacian(np.random.default_rng(5), shape, round_)
    n = L.shape[0]
    mg = GridMultigrid(L, shape)
    assert len(mg.levels) == 3 and mg.coarsest.shape[0] <= COARSEST
    jac, cyc = {}, {}
    X0 = pcg(L, B, 1e-12, 20 * n, "jacobi", stats=jac)
    X = pcg(L, B, 1e-12, 20 * n, "multigrid", precondition=mg, stats=cyc)
    assert np.all(X[:, 2] == 0.0)
    for c in range(2):
        assert np.linalg.norm(L @ X[:, c] - B[:, c]) <= 1e-12 * np.linalg.norm(B[:, c])
        g0, g = X0[e[:, 0], c] - X0[e[:, 1], c], X[e[:, 0], c] - X[e[:, 1], c]
        assert np.abs(g - g0).max() <= 1e-9 * np.abs(g0).max()
    assert 3 * cyc["iterations"] <= jac["iterations"], (cyc, jac)
    with pytest.raises(ValueError, match=r"a grid of shape \(2, 2, 2\) has 8 cells, not"):
        FlowGraph(n, e, (2, 2, 2))


def test_the_multigrid_converges_down_to_a_coarsest_level_of_one_cell(monkeypatch):
    """Merged down to one cell, the coarsest operator of a Laplacian is zero, but a Galerkin product leaves round-off
    there, whose pseudo-inverse is huge: conjugate gradients then did not converge in 3,000 iterations. The coarse
    operators are made exact Laplacians (zero row sums), so the cycle converges as with a larger coarsest level."""
    import app.rcfd.potential as potential

    shape = (16, 12, 20)
    L, B, _ = _singular_laplacian(np.random.default_rng(5), shape)
    monkeypatch.setattr(potential, "COARSEST", 1)
    mg = potential.GridMultigrid(L, shape)
    assert mg.coarsest.shape == (1, 1) and len(mg.levels) == 5
    stats = {}
    X = potential.pcg(L, B, 1e-12, 3000, "multigrid", precondition=mg, stats=stats)
    for c in range(2):
        assert np.linalg.norm(L @ X[:, c] - B[:, c]) <= 1e-12 * np.linalg.norm(B[:, c])
    assert stats["iterations"] <= 60, stats
