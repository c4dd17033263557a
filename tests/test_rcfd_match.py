"""rCFD's matching jump, Lacey's index and the indices along a sequence from its movers (synthetic, no Taichi)."""
import math

import numpy as np
import pytest

from app.rcfd.matching import GrainMatcher, grid_centres
from app.rcfd.sequence import SequenceIndex
from app.rcfd.transport import GrainTracer, lacey_index, lacey_random_std, mixing_index

pytestmark = pytest.mark.unit


def test_lacey_index_is_zero_segregated_and_one_random_within_its_binomial_scatter():
    """Whole cells tagged: every sample pure, M_L = 0 exactly. Tags shuffled over the grains: E[M_L] = 1 exactly
    (the hypergeometric variance), the mean of 400 shuffles within 4 standard errors of 1, and their scatter within
    15% of lacey_random_std (binomial; the hypergeometric correction and the cells' covariance are O(1/cells))."""
    rng = np.random.default_rng(3)
    K = 200
    n = rng.integers(3, 15, K)
    cell = np.repeat(np.arange(K), n)
    T = int(0.4 * n.sum())
    m = np.zeros(K)
    total = 0
    for k in rng.permutation(K):  # whole cells, up to about T grains
        if total + n[k] <= T:
            m[k], total = n[k], total + n[k]
    assert lacey_index(m, n.astype(float), n) == pytest.approx(0.0, abs=1e-12)
    tags = np.zeros(n.sum())
    tags[:T] = 1.0
    L = np.array([lacey_index(np.bincount(cell, weights=rng.permutation(tags), minlength=K), n.astype(float), n)
                  for _ in range(400)])
    sd = lacey_random_std(n, T / n.sum())
    assert 0.005 < sd < 0.05  # a few grains per cell: the index of a random mixture scatters visibly
    assert abs(L.mean() - 1.0) <= 4 * sd / math.sqrt(L.size)
    assert L.std(ddof=1) == pytest.approx(sd, rel=0.15)
    # a cell index of the same random mixtures stays far below 1 with so few grains per cell; Lacey's does not
    mt = np.bincount(cell, weights=rng.permutation(tags), minlength=K)
    assert mixing_index(mt, n - mt) < 0.9


def _states(rng, g=600, shape=(6, 3, 8), B=4):
    n = int(np.prod(shape))
    cells = np.stack([rng.integers(0, n, g)])
    for _ in range(B - 1):  # each state: some grains move one cell along z from the last one
        c = cells[-1].copy()
        mv = rng.random(g) < 0.3
        c[mv] = np.clip(c[mv] + rng.choice([-1, 1], mv.sum()), 0, n - 1)
        cells = np.vstack([cells, c[None]])
    return cells, n


def test_matching_jump_is_a_permutation_that_conserves_the_tag_exactly_and_moves_the_least():
    rng = np.random.default_rng(11)
    shape = (6, 3, 8)
    cells, n = _states(rng, shape=shape)
    cells[2] = rng.integers(0, n, cells.shape[1])  # an unrelated state
    vol = np.where(rng.random(cells.shape[1]) < 0.3, 2.0, 1.0)  # two grain sizes, matched within each
    m = GrainMatcher(cells, grid_centres(shape, np.zeros(3), 1.0), vol, seed=4)
    tr = GrainTracer(vol, rng.random(cells.shape[1]), n)
    tagged0 = float(np.sum(tr.vol * tr.tau))
    for s, j in ((0, 1), (1, 2), (2, 3), (3, 3)):
        perm, info = m.operator(s, j)
        assert np.array_equal(np.sort(perm), np.arange(perm.size))
        assert np.array_equal(vol[perm], vol)
        tr.permute(perm)
        assert abs(np.sum(tr.vol * tr.tau) - tagged0) <= 1e-12 * tagged0
        assert tr.tau.min() >= 0.0 and tr.tau.max() <= 1.0
        least = sum(0.5 * np.abs(np.bincount(cells[s][vol == v], minlength=n)
                                 - np.bincount(cells[j][vol == v], minlength=n)).sum() * v for v in (1.0, 2.0))
        assert info["moved_volume"] == pytest.approx(least, rel=1e-12)  # only the grains that must change cell
    perm, info = m.operator(3, 3)
    assert info["moved_share"] == 0.0 and np.array_equal(cells[3][perm], cells[3])  # a self-jump stays in cells
    again = GrainMatcher(cells, grid_centres(shape, np.zeros(3), 1.0), vol, seed=4)
    assert np.array_equal(again.operator(1, 2)[0], m.operator(1, 2)[0])  # reproducible from the seed


def test_matching_sends_the_excess_to_the_nearest_deficit():
    """A row of cells: state 1 has one grain fewer in cells 0 and 5 and one more in cells 2 and 4. On squared
    distance the excess of cell 0 goes to cell 2 and that of cell 5 to cell 4 (4 + 1, not 16 + 9), and only
    those two grains change cell."""
    shape = (6, 1, 1)
    before = np.array([0, 0, 1, 3, 4, 5])
    after = np.array([0, 2, 1, 3, 4, 4])
    cells = np.stack([before, after])
    m = GrainMatcher(cells, grid_centres(shape, np.zeros(3), 1.0), np.ones(6))
    perm, info = m.operator(0, 1)
    moved = cells[1] != cells[0][perm]
    assert moved.sum() == 2 and info["moved_share"] == pytest.approx(2 / 6)
    assert sorted(zip(cells[0][perm][moved].tolist(), cells[1][moved].tolist())) == [(0, 2), (5, 4)]


def test_sequence_indices_from_movers_equal_the_direct_sums():
    rng = np.random.default_rng(2)
    cells, n = _states(rng, B=9)
    cells = np.insert(cells, 5, cells[4], axis=0)  # state 5 repeats 4: a transition without movers (a settled bed)
    vol = rng.uniform(0.5, 1.5, cells.shape[1])
    seq = SequenceIndex(cells, vol, n)
    w = vol * (rng.random(cells.shape[1]) < 0.4)
    for s_prev, states in ((0, np.arange(1, 10)), (3, np.arange(4, 7)), (4, np.array([5])), (2, np.array([5, 1, 7]))):
        m = seq.volumes(w, s_prev, states)
        direct = np.stack([np.bincount(cells[b], weights=w, minlength=n) for b in states])
        assert np.allclose(m, direct, rtol=0, atol=1e-12 * w.sum())
        assert np.array_equal(seq.sequence(w, s_prev, states)[0], seq.tagged(w, s_prev))
        M, L = seq.indices(m, states)
        b = np.stack([np.bincount(cells[s], weights=vol, minlength=n) for s in states])
        cnt = np.stack([np.bincount(cells[s], minlength=n) for s in states])
        assert np.allclose(M, [mixing_index(direct[i], b[i] - direct[i]) for i in range(len(states))], atol=1e-12)
        assert np.allclose(L, [lacey_index(direct[i], b[i], cnt[i]) for i in range(len(states))], atol=1e-12)


def test_stored_matchings_equal_the_direct_ones_and_are_not_reused_for_another_database(tmp_path):
    """A later run reuses the matchings the first stored (matching.GrainMatcher.save/load): bit for bit the ones it
    would compute, info included. A matcher on other cells, another seed or another grid finds none under its
    fingerprint and computes its own; a damaged store is ignored, not trusted."""
    rng = np.random.default_rng(5)
    shape = (6, 3, 8)
    cells, n = _states(rng, shape=shape)
    vol = np.where(rng.random(cells.shape[1]) < 0.3, 2.0, 1.0)
    centres = grid_centres(shape, np.zeros(3), 1.0)
    store = tmp_path / "rcfd" / "matchings.h5"
    first = GrainMatcher(cells, centres, vol, seed=2)
    pairs = ((0, 2), (1, 3), (3, 0))
    direct = {p: first.operator(*p) for p in pairs}
    assert first.save(store) == 3 and first.save(store) == 0  # nothing new the second time
    later = GrainMatcher(cells, centres, vol, seed=2)
    assert later.load(store) == 3 and not later.fresh
    for p in pairs:
        perm, info = later.cache[p]
        assert np.array_equal(perm, direct[p][0]) and perm.dtype == np.int64
        assert info == pytest.approx(direct[p][1], rel=1e-15)
    assert np.array_equal(later.operator(1, 2)[0], first.operator(1, 2)[0])  # a new pair computed as before
    other = cells.copy()
    other[1, 0] = (other[1, 0] + 1) % n  # one grain elsewhere in one state: another database
    for m in (GrainMatcher(other, centres, vol, seed=2), GrainMatcher(cells, centres, vol, seed=3),
              GrainMatcher(cells, centres + 0.5, vol, seed=2)):
        assert m.load(store) == 0 and not m.cache
    bad = tmp_path / "bad.h5"
    bad.write_bytes(b"not an HDF5 file")
    assert GrainMatcher(cells, centres, vol, seed=2).load(bad) == 0
    assert GrainMatcher(cells, centres, vol, seed=2).load(tmp_path / "missing.h5") == 0
