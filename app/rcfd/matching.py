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

Step 2 is the cost: a dense assignment of ~1000 grains takes 0.1-1.3 s. The matching of a pair (s, j) depends only
on the two states' grid cells, the grains' volumes and the seed, and a database has at most one jump target per
state, so a database needs at most as many matchings as it has states, whatever the tag, seed, horizon or number of
paths. ``GrainMatcher.load``/``save`` keep them in an HDF5 store (by default RUN_DIR/rcfd/matchings.h5, written by
`fbed rcfd run` as they are built), under a fingerprint of everything they depend on: a later run on the same
database reuses them bit for bit, a re-recorded database or another grid or seed gets a new group.
(Measured and rejected, validation/rcfd/README.md: pairing the rest within coarser blocks first raises the squared
distance moved by 10-200%; a sparse assignment (min_weight_full_bipartite_matching) on the pairs within 8 half
cells is infeasible for a quarter of the jumps, up to 3% costlier and 1.6-2.5x faster; integer or perturbed costs
do not speed up linear_sum_assignment.)
"""
from __future__ import annotations

import hashlib
import pathlib
import signal
import threading
import time
from contextlib import contextmanager

import h5py
import numpy as np
from scipy.optimize import linear_sum_assignment

from . import forked
from .flowmatch import FLOOR, FlowGraph, class_flows, ranked, route_class

MATCH_VERSION = 2  # bumped whenever match_class changes what it computes (a stored matching is then not reused;
#                   2: the random order within a cell drawn as a permutation, flowmatch.ranked)
FLOW_VERSION = 3  # the same for flowmatch's flow and routing (2: the three classes' potentials solved together;
#                  3: ranked's permutation, and the potentials' multigrid preconditioner on a box of cells)
SAVE_EVERY = 30.0  # [s] between the saves of a prefetch's finished matchings (what a killed command keeps)
MAX_CLASSES = 16  # distinct grain volumes a matching handles (a polydisperse bed has a continuum: stitch instead)


def match_class(cf: np.ndarray, ct: np.ndarray, centres: np.ndarray, rng: np.random.Generator) -> tuple:
    """Grains with cells ``cf`` in state s and ``ct`` in state j (same grains' volume class): (perm, residual)
    with grain g of j taking the tag of grain perm[g] of s; residual: the indices in j of grains matched across
    cells."""
    n = centres.shape[0]
    of, cfs, rf = ranked(cf, rng)
    ot, cts, rt = ranked(ct, rng)
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
    """Permutations between the grains of two states by position on a grid, cached per (s, j): by the dense
    assignment (match_class) or, given the grid's ``graph``, by grains routed along a flow (flowmatch.route_class)."""

    def __init__(self, cells: np.ndarray, centres: np.ndarray, volume: np.ndarray, seed: int = 0,
                 graph: FlowGraph | None = None):
        """cells (B, grains): each grain's grid cell per state; centres (cells, 3) [m]; volume (grains,) [m^3];
        graph: the grid's face-neighbour graph, for the flow matching."""
        self.cells = cells
        self.graph = graph
        self.centres = np.asarray(centres, np.float64)
        self.vol = np.asarray(volume, np.float64)
        classes, self.cls = np.unique(self.vol, return_inverse=True)
        if classes.size > MAX_CLASSES:
            raise ValueError(f"{classes.size} distinct grain volumes: the matching jump pairs grains of equal "
                             f"volume (at most {MAX_CLASSES} classes); use the stitch (jump='stitch')")
        self.members = [np.nonzero(self.cls == k)[0] for k in range(classes.size)]
        self.seed = int(seed)
        self.cache: dict = {}
        self.fresh: set = set()  # the pairs computed here (not loaded) and not saved yet: what save() writes
        self.stored = 0  # how many save() has written, in all

    def fingerprint(self) -> str:
        """A digest of everything a matching depends on: the algorithm's version, the seed, every state's cells, the
        grid's centres and the grains' volumes."""
        h = hashlib.sha1(f"match v{MATCH_VERSION} seed {self.seed}".encode())
        arrays = [np.ascontiguousarray(self.cells, np.int64), self.centres, self.vol]
        if self.graph is not None:
            h.update(f"flow v{FLOW_VERSION} floor {FLOOR} grid {self.graph.shape}".encode())
            arrays.append(self.graph.edges)
        for a in arrays:
            h.update(str(a.shape).encode())
            h.update(np.ascontiguousarray(a).tobytes())
        return h.hexdigest()

    def load(self, path) -> int:
        """Read the matchings stored for this fingerprint at ``path`` (HDF5) into the cache: how many (0 when the
        file or the group is missing or unreadable)."""
        path = pathlib.Path(path)
        if not path.exists():
            return 0
        try:
            with h5py.File(path, "r") as f:
                g = f.get(self.fingerprint())
                if g is None:
                    return 0
                for name, ds in g.items():
                    s, j = (int(x) for x in name.split("_"))
                    info = {k: float(v) for k, v in ds.attrs.items()}
                    self.cache.setdefault((s, j), (ds[()].astype(np.int64), info))
                return len(g)
        except (OSError, ValueError):  # a damaged or foreign file: compute afresh (save() will not fix it)
            return 0

    def save(self, path) -> int:
        """Append the matchings computed since construction to the store at ``path``: how many (0 where it cannot be
        written, e.g. a read-only run folder: the matchings are then only computed again)."""
        new = sorted(k for k in self.fresh if k in self.cache)
        if not new:
            return 0
        path = pathlib.Path(path)
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            with _signals_held(), h5py.File(path, "a") as f:
                g = f.require_group(self.fingerprint())
                for s, j in new:
                    name = f"{s}_{j}"
                    if name in g:
                        continue
                    perm, info = self.cache[(s, j)]
                    ds = g.create_dataset(name, data=perm.astype(np.int32 if perm.size < 2**31 else np.int64),
                                          compression="gzip")
                    for k, v in info.items():
                        ds.attrs[k] = v
        except (OSError, ValueError):
            return 0
        self.fresh.difference_update(new)
        self.stored += len(new)
        return len(new)

    def prefetch(self, pairs, workers: int | None = None, store=None, every: float = SAVE_EVERY, progress=None) -> int:
        """Compute the matchings of ``pairs`` (s, j) not cached yet, in ``workers`` forked processes (default: one per
        CPU; the states are shared, not copied), and cache them: the same permutations as one by one, each seeded by
        its pair. One process where fork is missing or Taichi is loaded (its threads are not forked). With a
        ``store`` (HDF5 path) the finished ones are saved every ``every`` seconds [s] and at the end, so a command
        that is killed keeps what it built; ``progress(done, total)`` is called after each of those saves. How many
        were computed."""
        todo = sorted({(int(s), int(j)) for s, j in pairs} - set(self.cache))
        workers = min(len(todo), forked.cores() if workers is None else workers)
        last, done = time.monotonic(), 0

        def finished(key, res):
            nonlocal last, done
            self.cache[key] = res
            self.fresh.add(key)
            done += 1
            if store is not None and time.monotonic() - last >= every:
                self.save(store)
                last = time.monotonic()
                if progress is not None:
                    progress(done, len(todo))

        if workers < 2 or not forked.can_fork():
            for key in todo:
                finished(key, self.operator(*key))
        else:
            for k, res in forked.forked(self, "operator", todo, workers):
                finished(todo[k], res)
        if store is not None:
            self.save(store)
        return len(todo)

    def operator(self, s_from: int, s_to: int) -> tuple[np.ndarray, dict]:
        """(perm, info): tau_new = tau[perm]; info: the grain volume matched across grid cells and its share of the
        total (the dense assignment's is the least any jump moves, 0.5 sum |a_s - a_j| / sum a; a flow's is more,
        each a shorter way), and the RMS distance it moves [m]."""
        key = (int(s_from), int(s_to))
        if key in self.cache:
            return self.cache[key]
        rng = np.random.default_rng([self.seed, *key])
        perm = np.empty(self.vol.size, np.int64)
        moved = []
        cf, ct = self.cells[s_from], self.cells[s_to]
        if self.graph is not None:
            n = self.graph.n
            density = 0.5 * (np.bincount(cf, minlength=n) + np.bincount(ct, minlength=n))
            flows = class_flows(self.graph, [cf[idx] for idx in self.members], [ct[idx] for idx in self.members],
                                density)
        for k, idx in enumerate(self.members):
            if self.graph is None:
                p, res = match_class(cf[idx], ct[idx], self.centres, rng)
            else:
                p = route_class(cf[idx], ct[idx], n, flows[k], rng)
                res = np.nonzero(ct[idx] != cf[idx][p])[0]
            perm[idx] = idx[p]
            moved.append(idx[res])
        moved = np.concatenate(moved)
        d = self.centres[self.cells[s_to][moved]] - self.centres[self.cells[s_from][perm[moved]]]
        info = {"moved_volume": float(self.vol[moved].sum()), "moved_share": float(self.vol[moved].sum() / self.vol.sum()),
                "rms_distance": float(np.sqrt(np.mean(np.sum(d * d, 1)))) if moved.size else 0.0}
        self.cache[key] = (perm, info)
        self.fresh.add(key)
        return perm, info


@contextmanager
def _signals_held():
    """SIGINT and SIGTERM held back while the store is written and raised after it: a command stopped by a time
    limit ends between two saves, not inside one, so the HDF5 file it leaves is whole. (A handler that notes the
    signal, not a signal mask: any of the process's threads may take a signal sent to it. Only the main thread can
    set handlers; SIGKILL cannot be held.)"""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    got = []
    old = {s: signal.signal(s, lambda signum, frame: got.append(signum)) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    finally:
        for s, handler in old.items():
            signal.signal(s, signal.SIG_DFL if handler is None else handler)
        if got:
            signal.raise_signal(got[0])


def grid_centres(shape: tuple, origin: np.ndarray, h: float) -> np.ndarray:
    """(cells, 3) centres [m] of a grid of spacing h from ``origin``, flat index (i * ny + j) * nz + k."""
    idx = np.indices(shape).reshape(3, -1).T
    return np.asarray(origin, np.float64) + (idx + 0.5) * h
