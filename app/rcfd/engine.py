"""The machinery that analyses and paths share: a database's recurrence statistics, its shift operators and
grain volumes, the jump targets and stitches, and the transport of a tracer along a path.

Solids: with each grain's cell recorded (boundary/cells), the tracer rides on the recorded grains along each
sequence (transport.GrainTracer, ``solids="grains"``); at a jump the grains of the two states are matched one to
one by position, by a dense assignment (matching.GrainMatcher, ``jump="match"``, the default up to
MATCH_MAX_GRAINS grains) or routed along a flow (flowmatch, ``jump="flow"``, the default above), or the
cell volumes are stitched and the tag averaged over each cell (``jump="stitch"``); the indices along a sequence
come from the grains that change cell (sequence.SequenceIndex). The cell shifts (``solids="cells"``,
transport.SolidsTracer) average over a cell every frame. validation/rcfd/README.md measures them all against the
real grains.
"""
from __future__ import annotations

import dataclasses
import math
import pathlib
import time as wallclock

import h5py
import numpy as np

from . import forked
from . import paths as pathmod
from . import recurrence as rec
from .database import Database
from .flowmatch import FlowGraph
from .matching import GrainMatcher, grid_centres
from .sequence import SequenceIndex
from .stitch import LP_MAX_CELLS, Stitcher, face_edges
from .transport import GrainTracer, SolidsTracer, lacey_index, step_response

# 'auto' matches grains by the dense assignment up to here and routes them along a flow above: the dense assignment
# grows as the cube of the grains that change half cell (0.08-1.3 s a jump at 3,400 grains, 800-1,900 of them;
# validation/rcfd/README.md, 0a). On a 13,600-grain bed the flow's mixing error was half the stitch's, at about 1/60
# of its cost (separate runs); on the 3,400-grain bed the dense assignment's was the smallest of the three (0000a)
MATCH_MAX_GRAINS = 10_000
# the flow matching on half cells up to here, on the cells above: 958,000 grains took 58 s a jump on 64 x 64 x 168
# half cells and 3.3 s on 32 x 32 x 84 cells (2-core EPYC, benchmarks/flow_matching.py); 39-42 s and 2.2-2.3 s since
# the potentials' multigrid (benchmarks/flow_jump_ab.py)
FLOW_HALF_MAX_CELLS = 100_000
JUMPS = ("match", "flow", "stitch")
BED_EPS = 0.99  # cells whose time-mean void fraction is below this are the bed's (they enter R)


def bed_mask(db: Database) -> np.ndarray:
    return (db.open_volume > 0) & (db.eps.mean(0) < BED_EPS)


def plane_mean(db: Database, k: int) -> np.ndarray:
    """Open-volume-weighted mean eps of cell layer k at each boundary."""
    v = db.open_volume[:, :, k]
    return (db.eps[:, :, :, k] * v).sum((1, 2)) / max(v.sum(), 1e-300)


def statistics(db: Database) -> dict:
    """R, the spectra, D(tau), S(n): everything `analyze` reports, as arrays and numbers."""
    t_start = wallclock.perf_counter()
    mask = bed_mask(db)
    X = rec.state_matrix(db.eps, mask, db.open_volume * db.cell_volume)
    R, norm = rec.recurrence_matrix(X)
    t_R = wallclock.perf_counter() - t_start
    dt = db.frame_interval / int(db.attrs.get("lag", 1))  # the states' spacing (a lagged frame spans several)
    hbar = float(np.mean(db.bed_height))
    k_mid = int(np.clip(math.floor((0.5 * hbar - db.origin[2]) / db.h), 0, db.shape[2] - 1))
    mid = plane_mean(db, k_mid)
    sp_eps = rec.spectrum(mid, dt)
    sp_h = rec.spectrum(db.bed_height, dt)
    Dtau = rec.mean_distance_by_lag(R)
    lag = rec.first_recurrence(Dtau)
    period_frames = sp_eps["period"] / dt
    window = max(1, int(math.ceil(0.5 * period_frames))) if np.isfinite(period_frames) else max(1, db.n_states // 20)
    S = rec.similarity_curve(R, window)
    best = rec.best_recurrence(R, window)
    half = db.n_states // 2
    e = db.eps[:, mask]
    m1, m2, s1, s2 = e[:half].mean(0), e[half:].mean(0), e[:half].std(0), e[half:].std(0)
    return dict(R=R, norm=norm, mask=mask, mid=mid, k_mid=k_mid, sp_eps=sp_eps, sp_h=sp_h, Dtau=Dtau, lag=lag,
                window=window, S=S, best=best, R_seconds=t_R, halves={
                    "mean_rms_difference": float(np.sqrt(np.mean((m1 - m2) ** 2))),
                    "std_rms_difference": float(np.sqrt(np.mean((s1 - s2) ** 2))),
                    "std_mean": float(np.mean(0.5 * (s1 + s2)))})


def state_volumes(db: Database, ops) -> np.ndarray:
    """(B, n) grain volume per cell at each boundary in float64, from the shifts (column sums of the frame that
    starts there, row sums of the one that ends there)."""
    a = np.zeros((db.n_states, db.n_cells))
    seen = np.zeros(db.n_states, bool)
    for k in range(db.n_frames):
        P, a0 = ops[k]
        s = slice(int(db.offset[k]), int(db.offset[k + 1]))
        a[db.b0[k]] = a0
        if not seen[db.b1[k]]:
            a[db.b1[k]] = np.bincount(db.c1[s], weights=db.w[s], minlength=db.n_cells)
        seen[db.b0[k]] = seen[db.b1[k]] = True
    return a



class Engine:
    """Everything a set of paths shares: the operators, R, the jump targets, the stitches."""

    def __init__(self, db: Database, st: dict | None = None, params: pathmod.PathParams | None = None,
                 solids: str = "auto", jump_grid: str = "auto", jump: str = "auto", matchings="auto",
                 stitch_flow: str = "auto"):
        """``matchings``: the HDF5 store of the matched jumps (matching.GrainMatcher.load/save), 'auto' for
        RUN_DIR/rcfd/matchings.h5 beside the database, None for none; ``jump``: how the grain tracer crosses a jump,
        'match' (grains matched one to one by position, app.rcfd.matching; the default up to MATCH_MAX_GRAINS
        grains), 'flow' (grains routed one to one along a flow, app.rcfd.flowmatch; the default above) or 'stitch'
        (cell volumes stitched, then each grain takes its cell's mean tag; the cell tracer's only jump);
        ``jump_grid``: 'cells' locates the grains on the cells even where octants give the half cells, 'half' on the
        half cells even for a stitch too large for the min-cost flow; ``stitch_flow``: the stitch's flow
        (app.rcfd.stitch.FLOWS)."""
        t = wallclock.perf_counter()
        self.db = db
        if solids == "auto":
            solids = "grains" if db.cells is not None else "cells"
        if solids == "grains" and db.cells is None:
            raise ValueError(f"{db.path}: the grain tracer needs each grain's cell per boundary (record with "
                             "probes.rcfd_grain_cells = true), or use --solids cells")
        if solids not in ("grains", "cells"):
            raise ValueError(f"--solids must be 'grains' or 'cells', got {solids!r}")
        self.solids = solids
        if jump == "auto":
            jump = "stitch" if solids != "grains" else "match" if db.cells.shape[1] <= MATCH_MAX_GRAINS else "flow"
        if jump not in JUMPS or (jump in ("match", "flow") and solids != "grains"):
            raise ValueError(f"jump must be 'match' or 'flow' (grain tracer only) or 'stitch', got {jump!r}")
        self.jump = jump
        self.st = st or statistics(db)
        self.ops = [db.shift(k) for k in range(db.n_frames)]
        self.P = [op[0] for op in self.ops]
        self.a = state_volumes(db, self.ops)
        self.successor = db.successor()
        lag = int(db.attrs.get("lag", 1))
        if params is None:  # lengths in (lagged) frames from the recorded length; the window in boundaries
            params = pathmod.PathParams.default(max(3, (db.n_frames + lag - 1) // lag))
            period_states = self.st["sp_eps"]["period"] * lag / db.frame_interval
            if np.isfinite(period_states):
                params = dataclasses.replace(params, window=max(1, int(math.ceil(0.5 * period_states))))
        self.params = params
        self.targets = pathmod.jump_targets(self.st["R"], db.b0, self.successor, self.params)
        cells = (db.open_volume > 0) | (self.a.max(0) > 0).reshape(db.shape)
        self.stitcher = Stitcher(db.shape, cells, db.h, stitch_flow)
        # the grain tracer's jumps on half cells where the octants are recorded (a jump averages over its cells)
        # where the octants are recorded; a stitch only where its half-cell grid is small enough for the min-cost
        # flow (validated there), else on the cells (a million grains: 86,016 cells, not 688,128 half cells)
        self.half = self.solids == "grains" and db.octant is not None and jump_grid != "cells" and \
            (jump == "match" or jump_grid == "half" or 8 * db.n_cells <= (FLOW_HALF_MAX_CELLS if jump == "flow"
                                                                         else LP_MAX_CELLS))
        grains = int(db.attrs.get("grains", 0)) or 1
        self.grain_volume_mean = float(np.mean(db.grain_volume)) if db.grain_volume is not None else \
            float(self.a[0].sum()) / grains  # [m^3]: the cell tracer's grains per cell for Lacey's index
        self.seq = SequenceIndex(db.cells, db.grain_volume, db.n_cells, self.a) if self.solids == "grains" else None
        if self.half:
            self.fine = db.fine_cells(slice(None))
        # the grid of the grain tracer's jumps: each grain's cell per state, the grid's shape, spacing and open cells
        grid, shape, h, mask = (self.fine, db.fine_shape, 0.5 * db.h, cells.repeat(2, 0).repeat(2, 1).repeat(2, 2)) \
            if self.half else (db.cells, db.shape, db.h, cells)
        if self.jump in ("match", "flow"):
            graph = FlowGraph(int(np.prod(shape)), face_edges(shape, mask), shape) if self.jump == "flow" else None
            self.matcher = GrainMatcher(grid, grid_centres(shape, db.origin, h), db.grain_volume, graph=graph)
            if matchings == "auto":
                matchings = pathlib.Path(db.path).parent / "rcfd" / "matchings.h5"
            self.matchings_path = matchings
            self.matchings_loaded = self.matcher.load(matchings) if matchings is not None else 0
        elif self.half:
            nf = int(np.prod(shape))
            idx = (self.fine + nf * np.arange(db.n_states)[:, None]).ravel()
            self.a_fine = np.bincount(idx, weights=np.tile(db.grain_volume, db.n_states),
                                      minlength=nf * db.n_states).reshape(db.n_states, nf)
            self.fine_stitcher = Stitcher(shape, mask, h, stitch_flow)
        self.prep_seconds = wallclock.perf_counter() - t + self.st["R_seconds"]
        self.stitch_seconds = 0.0

    def prefetch_jumps(self, paths, workers: int | None = None, progress=None) -> int:
        """Build the matched jumps ``paths`` take (all but a jump at a path's start, which transport skips) before
        the transport, in parallel (matching.GrainMatcher.prefetch), storing them as they finish (``matchings``);
        their wall time counts as the jumps'. ``progress(done, total)`` after each store. How many were built."""
        if self.jump == "stitch":
            return 0
        t = wallclock.perf_counter()
        n = self.matcher.prefetch([(s_from, s_to) for p in paths for pos, s_from, s_to, _ in p.jumps if pos > 0],
                                  workers, store=self.matchings_path, progress=progress)
        self.stitch_seconds += wallclock.perf_counter() - t
        return n

    def transport_paths(self, paths, c0: np.ndarray, start_state: int, workers: int | None = None) -> list:
        """transport() of every path from ``start_state``, in path order: in ``workers`` forked processes (default
        one per core; forked.py) when no operator is built on the way (the grain tracer with matched jumps, built
        beforehand by prefetch_jumps), the same results as one by one; else one by one here (stitches are built
        and cached as the paths reach them)."""
        workers = min(len(paths), forked.cores() if workers is None else workers)
        if workers < 2 or not forked.can_fork() or self.jump == "stitch":  # (the cell tracer always stitches)
            return [self.transport(p, c0, start_state) for p in paths]
        out = [None] * len(paths)
        for k, res in forked.forked(self, "transport", [(p, c0, start_state) for p in paths], workers):
            out[k] = res
        return out

    def save_matchings(self) -> int:
        """Store the matched jumps computed so far (see ``matchings``): how many this engine has written in all
        (prefetch_jumps stores as it goes)."""
        if self.jump == "stitch" or getattr(self, "matchings_path", None) is None:
            return 0
        self.matcher.save(self.matchings_path)
        return self.matcher.stored

    def fluxes(self):
        """The frame-mean face fluxes of every frame, read once (float32)."""
        if getattr(self, "_fluxes", None) is None:
            if not self.db.has_flux:
                raise ValueError("the database holds no gas fluxes (recorded with probes.rcfd_fluxes = false)")
            with h5py.File(self.db.path, "r") as f:
                self._fluxes = [f[f"frame/flux_{a}"][: self.db.n_frames] for a in "xyz"]
        return self._fluxes

    def gas_transport(self, path: pathmod.Path, c_in: float = 1.0, scheme: str = "fct", first: int = 0,
                      count: int | None = None) -> dict:
        """A gas tracer fed at c_in through the inlet from the path's frame ``first`` on (a step input; ``count``
        frames, default to the path's end), on the recorded fluxes: the outlet's mixing-cup c after each frame (the
        step response F(t)) and the tracer balance (transport.step_response by ``scheme``, GasTracer's; at a jump
        eps switches state and c is kept)."""
        db, fl = self.db, self.fluxes()
        jumps = {pos: s_from for pos, s_from, _, _ in path.jumps if pos > first}
        eps = (lambda b: db.eps[b].astype(np.float64))
        stop = len(path.frames) if count is None else first + count
        frames = (([a[k].astype(np.float64) for a in fl], eps(db.b0[k]), eps(db.b1[k]),
                   eps(jumps[i]) if i in jumps else None)
                  for i, k in zip(range(first, stop), path.frames[first:stop]))
        t = wallclock.perf_counter()
        out = step_response(db.open_volume, db.h, frames, db.frame_interval, c_in, scheme=scheme)
        return {**out, "wall": wallclock.perf_counter() - t}

    def path(self, n_frames: int, start_state: int, seed: tuple) -> pathmod.Path:
        return pathmod.markov_path(n_frames, start_state, self.st["R"], self.db.b0, self.db.b1, self.successor,
                                   self.params, seed, self.targets)

    def transport(self, path: pathmod.Path, c0: np.ndarray, start_state: int, tau0: np.ndarray | None = None) -> dict:
        """Move the tracer along ``path``: concentration c0 per cell at the path's first state (laid on its grains),
        or, for the grain tracer, ``tau0`` per grain. The mixing index after each frame, the stitches, the
        bounds and the conservation."""
        db = self.db
        jumps = {pos: (s_from, s_to) for pos, s_from, s_to, _ in path.jumps}
        # the tag's concentration is laid onto the grains of the path's first frame (a path from the database's
        # last state starts with a jump: stitching the segregated start would mix it before any transport)
        first = int(db.b0[path.frames[0]])
        jumps.pop(0, None)
        if self.solids == "grains":
            return self._transport_grains(path, c0, tau0, jumps, first)
        tr = SolidsTracer(c0 * self.a[first], self.a[first])
        M, Lc = np.empty(len(path.frames) + 1), np.empty(len(path.frames) + 1)
        v = self.grain_volume_mean
        M[0], Lc[0] = tr.mixing_index(), lacey_index(tr.m, tr.m + tr.u, (tr.m + tr.u) / v)
        moved, t_stitch = [], 0.0
        t = wallclock.perf_counter()
        for i, k in enumerate(path.frames):
            if i in jumps:
                S, info, dt_s = self._stitch(*jumps[i])
                t_stitch += dt_s
                tr.apply(S)
                moved.append(info["moved_share"])
            tr.apply(self.P[k])
            M[i + 1], Lc[i + 1] = tr.mixing_index(), lacey_index(tr.m, tr.m + tr.u, (tr.m + tr.u) / v)
        wall = wallclock.perf_counter() - t - t_stitch
        self.stitch_seconds += t_stitch
        c = tr.concentration
        return {"M": M, "lacey": Lc, "moved": moved, "drift": tr.drift(), "c_min": float(c.min()),
                "c_max": float(c.max()), "m_min": float(min(tr.m.min(), tr.u.min())), "wall": wall}

    @property
    def jump_stitcher(self) -> Stitcher:
        """The stitcher stitched jumps use: on the half cells where ``half`` (the grain tracer only), else on the
        cells (a matching Engine with ``half`` builds none)."""
        return self.fine_stitcher if self.half else self.stitcher

    def _stitch(self, s_from: int, s_to: int):
        """(S, info, seconds spent building it: 0 when cached), with ``jump_stitcher``."""
        t = wallclock.perf_counter()
        st, a = self.jump_stitcher, (self.a_fine if self.half else self.a)
        fresh = (s_from, s_to) not in st.cache
        S, info = st.operator(a[s_from], a[s_to], key=(s_from, s_to))
        return S, info, (wallclock.perf_counter() - t) if fresh else 0.0

    def _grain_jump(self, tr: GrainTracer, s_from: int, s_to: int) -> tuple[dict, float]:
        """Carry the grain tracer across a jump (matched or stitched): (info, seconds spent building the operator:
        0 when cached)."""
        t = wallclock.perf_counter()
        if self.jump != "stitch":
            fresh = (s_from, s_to) not in self.matcher.cache
            perm, info = self.matcher.operator(s_from, s_to)
            dt_s = (wallclock.perf_counter() - t) if fresh else 0.0
            tr.permute(perm)
        else:
            S, info, dt_s = self._stitch(s_from, s_to)
            grid = self.fine if self.half else self.db.cells
            tr.jump(grid[s_from], grid[s_to], S)
        return info, dt_s

    def _transport_grains(self, path: pathmod.Path, c0, tau0, jumps: dict, first: int) -> dict:
        """The grain tracer along ``path``: the tagged volume per cell of each sequence from its movers
        (sequence.SequenceIndex) and its indices, a match or stitch at each jump; per jump, its change of the cell
        index and the share of the tagged volume that changed (index) cell."""
        db, seq = self.db, self.seq
        tr = GrainTracer(db.grain_volume, c0[db.cells[first]] if tau0 is None else tau0, db.n_cells)
        Ms, Ls, infos, last = [], [], [], None  # last: the tagged volume per cell at the latest state
        cuts = sorted(jumps) + [len(path.frames)]
        t_stitch = 0.0
        t = wallclock.perf_counter()
        start, s_prev = 0, first
        for end in cuts:  # every piece has frames: no jump at 0 (see transport), positions distinct and < end
            info = None
            if start in jumps:
                s_from, s_prev = jumps[start]
                info, dt_s = self._grain_jump(tr, s_from, s_prev)
                t_stitch += dt_s
            st = db.b1[path.frames[start:end]]
            m = seq.sequence(tr.vol * tr.tau, s_prev, st)  # row 0: at s_prev, after the jump if there is one
            M, Lc = seq.indices(m, np.concatenate([[s_prev], st]))
            if info is None:  # the path's first state
                Ms.append(M[:1])
                Ls.append(Lc[:1])
            else:
                infos.append({**info, "dM": float(M[0] - Ms[-1][-1]),
                              "tag_moved_share": 0.5 * float(np.abs(m[0] - last).sum()) / max(last.sum(), 1e-300)})
            Ms.append(M[1:])
            Ls.append(Lc[1:])
            last, s_prev, start = m[-1], int(st[-1]), end
        wall = wallclock.perf_counter() - t - t_stitch
        self.stitch_seconds += t_stitch
        mm, u = tr.volumes(db.cells[s_prev])
        c = np.divide(mm, mm + u, out=np.zeros_like(mm), where=mm + u > 0)
        return {"M": np.concatenate(Ms), "lacey": np.concatenate(Ls), "moved": [i["moved_share"] for i in infos],
                "jump_dM": [i["dM"] for i in infos], "tag_moved": [i["tag_moved_share"] for i in infos],
                "drift": tr.drift(), "c_min": float(c.min()), "c_max": float(c.max()),
                "m_min": float(min(tr.tau.min(), 1.0 - tr.tau.max())), "wall": wall}
