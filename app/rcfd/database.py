"""The rcfd.h5 database: its layout, a reader, and the tag expressions.

rcfd.h5 (written by app/rcfd_probe.py beside run.h5; every array over the recorded region,
the gas grid's cells with z below ``probes.rcfd_z_max``, shape (nx, ny, nz) and flat index
c = (i * ny + j) * nz + k):
  /geometry/open_volume (nx, ny, nz)  open volume fraction of each cell [-] (0 outside the vessel)
  /boundary/time (B,)                 frame boundaries [s]
  /boundary/eps (B, nx, ny, nz) f4    gas void fraction at each boundary [-] (the deposited field the gas sees)
  /boundary/bed_height (B,)           the DEM's bed height (95th percentile of grain heights) [m]
  /boundary/solid (B, n) f4           grain volume per cell by grain centre [m^3]
  /boundary/tag_now (B, n) f4         volume of the grains that satisfy the tag expression now [m^3]
  /boundary/tagged (B, n) f4          volume of the grains tagged at the first boundary [m^3]
  /grains_counted, /grains_volume     the grains counted (DEM indices) and their volumes [m^3]
  /boundary/cells (B, grains) i4      each counted grain's cell (probes.rcfd_grain_cells): the grain tracer
                                      rides on it (transport.GrainTracer), operators over ``lag`` frames are
                                      built from it (load(..., lag))
  /boundary/octant (B, grains) u1     the eighth of its cell each grain is in (bits x, y, z: 4, 2, 1): the
                                      grain tracer's jumps stitch on this half-cell grid
  /frame/b0, /frame/b1 (N,) i4        the boundaries a frame starts and ends at (b1 = b0 + 1; a resume from a checkpoint
                                      without the probe's part loses the frame open then: a gap)
  /frame/offset (N+1,) i8             frame k's shift triplets are shift/*[offset[k]:offset[k+1]]
  /shift/c0, /shift/c1 i4, /shift/w f8   grain volume [m^3] that went from cell c0 to cell c1 in the frame
  /frame/flux_x|y|z (N, faces...) f4  gas volume flux through each face, eps_f u_f a_f h^2, averaged over the
                                      frame [m^3/s] (x faces (nx+1, ny, nz), y (nx, ny+1, nz), z (nx, ny, nz+1))
  attrs: h [m], origin [m] (x0, y0, z0), shape, frame_interval [s], step [s], axis [m] (x, y of the vessel axis),
         tag, grains, taylor_time [s] (sqrt(<g^2>/<dg/dt^2>) at the fluid step), taylor_time_frame [s]
         (the same differenced at the frame interval), taylor_samples, frame_check ('ok' or a warning),
         settings (JSON: the [probes] rcfd_* values it was recorded with, RECORDING_KEYS)
Grains count from the first boundary on, all of them to the end: a grain that leaves the domain stays in
the cell it was last seen in, so every frame's shift conserves the grain volume exactly.
"""
from __future__ import annotations

import dataclasses
import pathlib
import re

import h5py
import numpy as np
import scipy.sparse as sp

from ..config.derived import RCFD_MIN_FRAMES

#: the [probes] keys a recording is made with, kept in rcfd.h5's ``settings`` attribute: a resume that changed one
#: would append frames of another kind to the file (app/resume.check_recording refuses that)
RECORDING_KEYS = ("rcfd_from", "rcfd_interval", "rcfd_z_max", "rcfd_tag", "rcfd_grain_cells", "rcfd_fluxes")


def recording_settings(cfg) -> dict:
    """The values of :data:`RECORDING_KEYS` in a config (SI units, as in the preset)."""
    return {k: getattr(cfg.probes, k) for k in RECORDING_KEYS}

_TAG = re.compile(r"^\s*([xyz])\s*(<=|>=|<|>)\s*([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)\s*$")


def parse_tag(expr: str) -> tuple[int, str, float]:
    """``'x<0'`` -> (axis, op, value); raises ValueError naming the expected form."""
    m = _TAG.match(expr or "")
    if not m:
        raise ValueError(f"tag {expr!r} is not of the form AXIS OP VALUE (e.g. 'x<0', 'z>=0.03'; AXIS x, y or z, "
                         "OP <, <=, > or >=, VALUE in m)")
    return "xyz".index(m.group(1)), m.group(2), float(m.group(3))


def tag_mask(expr: str, points: np.ndarray) -> np.ndarray:
    """Which of ``points`` (n, 3) [m] satisfy the tag expression."""
    axis, op, value = parse_tag(expr)
    v = np.asarray(points)[:, axis]
    return {"<": v < value, "<=": v <= value, ">": v > value, ">=": v >= value}[op]


def shift_operator(c0: np.ndarray, c1: np.ndarray, w: np.ndarray, n: int) -> tuple[sp.csr_matrix, np.ndarray]:
    """(P, a): P[c1, c0] = w / a[c0], the share of cell c0's grain volume a[c0] that ends in c1; a cell that holds
    no grains keeps whatever it is given (P's column there is the unit vector), so every column sums to one."""
    w = np.asarray(w, np.float64)
    a = np.bincount(c0, weights=w, minlength=n)
    empty = np.nonzero(a <= 0)[0]
    vals = np.concatenate([w / a[c0], np.ones(empty.size)])
    rows = np.concatenate([c1, empty])
    cols = np.concatenate([c0, empty])
    return sp.csr_matrix((vals, (rows, cols)), shape=(n, n)), a


@dataclasses.dataclass
class Database:
    """An rcfd.h5 read into memory (the boundary fields as float32, shifts as float64)."""

    path: pathlib.Path
    h: float
    origin: np.ndarray
    shape: tuple
    frame_interval: float
    axis: np.ndarray
    tag: str
    attrs: dict
    open_volume: np.ndarray
    time: np.ndarray           # (B,)
    eps: np.ndarray            # (B, nx, ny, nz)
    bed_height: np.ndarray     # (B,)
    solid: np.ndarray          # (B, n)
    tag_now: np.ndarray        # (B, n)
    tagged: np.ndarray         # (B, n)
    b0: np.ndarray             # (N,)
    b1: np.ndarray
    offset: np.ndarray
    c0: np.ndarray
    c1: np.ndarray
    w: np.ndarray
    has_flux: bool
    cells: np.ndarray | None = None         # (B, grains) each counted grain's cell (boundary/cells), if recorded
    grain_volume: np.ndarray | None = None  # (grains,) [m^3]
    tagged_grains: np.ndarray | None = None  # (grains,) bool: tagged at the first boundary
    octant: np.ndarray | None = None         # (B, grains) u1: the eighth of its cell each grain is in

    @property
    def fine_shape(self) -> tuple:
        """The half-cell grid: each cell split in two along every axis."""
        return tuple(2 * s for s in self.shape)

    def fine_cells(self, b) -> np.ndarray:
        """Each counted grain's half-cell at boundary (or boundaries) ``b`` (flat index on fine_shape)."""
        c, o = self.cells[b], self.octant[b].astype(np.int64)
        i, j, k = np.unravel_index(c, self.shape)
        fs = self.fine_shape
        return ((2 * i + (o >> 2 & 1)) * fs[1] + 2 * j + (o >> 1 & 1)) * fs[2] + 2 * k + (o & 1)

    @property
    def n_cells(self) -> int:
        return int(np.prod(self.shape))

    @property
    def n_frames(self) -> int:
        return int(self.b0.size)

    @property
    def n_states(self) -> int:
        return int(self.time.size)

    @property
    def cell_volume(self) -> float:
        return self.h ** 3

    def shift(self, k: int) -> tuple[sp.csr_matrix, np.ndarray]:
        """Frame k's shift operator P_k and the grain volume per cell at its start (see shift_operator)."""
        s = slice(int(self.offset[k]), int(self.offset[k + 1]))
        return shift_operator(self.c0[s], self.c1[s], self.w[s], self.n_cells)

    def successor(self) -> np.ndarray:
        """For each frame, the frame that starts where it ends (-1 at the end of a recorded stretch)."""
        start = self.frame_starting_at()
        return np.where(self.b1 < self.n_states, start[np.minimum(self.b1, self.n_states - 1)], -1)

    def frame_starting_at(self) -> np.ndarray:
        """For each boundary (state), the frame that starts there (-1: none)."""
        out = np.full(self.n_states, -1, np.int64)
        out[self.b0] = np.arange(self.n_frames)
        return out

    def cell_centres(self) -> np.ndarray:
        """(nx, ny, nz, 3) cell centres [m]."""
        idx = np.indices(self.shape).transpose(1, 2, 3, 0)
        return self.origin + (idx + 0.5) * self.h

    def flux(self, k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        with h5py.File(self.path, "r") as f:
            return tuple(f[f"frame/flux_{a}"][k].astype(np.float64) for a in "xyz")


def load(path, lag: int = 1) -> Database:
    """Read rcfd.h5 (or the rcfd.h5 in a run folder). With ``lag`` > 1 a frame spans ``lag`` recorded frames:
    its shift is built from each grain's cell at its two ends (boundary/cells), so grain motion that reverses
    within it does not count as dispersion; frames overlap (one starts at every boundary), and a path strides
    ``lag`` boundaries per frame. Gas fluxes are used at lag 1 only."""
    p = pathlib.Path(path)
    if p.is_dir():
        p = p / "rcfd.h5"
    if not p.exists():
        raise FileNotFoundError(f"{p}: no rcfd.h5 (record one with probes.rcfd_from >= 0)")
    with h5py.File(p, "r") as f:
        a = dict(f.attrs)
        nb = f["boundary/time"].shape[0]
        nfr = f["frame/b0"].shape[0]
        # a frame whose end boundary or shifts were not written (a run stopped mid-write) is dropped
        b1 = f["frame/b1"][...]
        nfr = min(nfr, f["frame/offset"].shape[0] - 1)
        while nfr and b1[nfr - 1] >= nb:
            nfr -= 1
        off = f["frame/offset"][: nfr + 1].astype(np.int64)
        db = Database(
            path=p, h=float(a["h"]), origin=np.asarray(a["origin"], float), shape=tuple(int(s) for s in a["shape"]),
            frame_interval=float(a["frame_interval"]), axis=np.asarray(a["axis"], float), tag=str(a["tag"]),
            attrs=a, open_volume=f["geometry/open_volume"][...].astype(np.float64),
            time=f["boundary/time"][...], eps=f["boundary/eps"][...], bed_height=f["boundary/bed_height"][...],
            solid=f["boundary/solid"][...], tag_now=f["boundary/tag_now"][...], tagged=f["boundary/tagged"][...],
            b0=f["frame/b0"][:nfr].astype(np.int64), b1=b1[:nfr].astype(np.int64), offset=off,
            c0=f["shift/c0"][: off[-1]].astype(np.int64), c1=f["shift/c1"][: off[-1]].astype(np.int64),
            w=f["shift/w"][: off[-1]].astype(np.float64), has_flux="frame/flux_x" in f)
        if "boundary/cells" in f and f["boundary/cells"].shape[0] >= nb:
            db.cells = f["boundary/cells"][:nb].astype(np.int64)
            db.grain_volume = f["grains_volume"][...].astype(np.float64)
            db.tagged_grains = np.isin(f["grains_counted"][...], f["grains_tagged"][...])
            if "boundary/octant" in f and f["boundary/octant"].shape[0] >= nb:
                db.octant = f["boundary/octant"][:nb]
    if lag > 1:
        db = _lagged(db, int(lag))
    if db.n_frames < RCFD_MIN_FRAMES:
        raise ValueError(f"{p}: {db.n_frames} frames recorded; rCFD needs at least {RCFD_MIN_FRAMES} (record "
                         "longer, or from earlier: probes.rcfd_from)")
    return db


def _lagged(db: Database, lag: int) -> Database:
    if db.cells is None:
        raise ValueError(f"{db.path}: --lag needs each grain's cell per boundary (record with "
                         "probes.rcfd_grain_cells = true)")
    cells, vol = db.cells, db.grain_volume
    succ = db.successor()
    b0, b1, off, c0s, c1s, ws = [], [], [0], [], [], []
    n = db.n_cells
    for k in range(db.n_frames):
        j, ok = k, True
        for _ in range(lag - 1):
            j = succ[j]
            if j < 0:
                ok = False
                break
        if not ok:
            continue
        s0, s1 = int(db.b0[k]), int(db.b1[j])
        pair = cells[s0] * n + cells[s1]
        keys, inv = np.unique(pair, return_inverse=True)
        b0.append(s0), b1.append(s1)
        c0s.append(keys // n), c1s.append(keys % n), ws.append(np.bincount(inv, weights=vol))
        off.append(off[-1] + keys.size)
    if len(b0) < RCFD_MIN_FRAMES:  # 1000 on 24 recorded frames: numpy's "need at least one array to concatenate"
        raise ValueError(f"{db.path}: --lag {lag} leaves {len(b0)} frames of {lag} recorded frames from the "
                         f"{db.n_frames} recorded; rCFD needs at least {RCFD_MIN_FRAMES}: give a smaller --lag")
    return dataclasses.replace(db, b0=np.asarray(b0, np.int64), b1=np.asarray(b1, np.int64),
                               offset=np.asarray(off, np.int64), c0=np.concatenate(c0s).astype(np.int64),
                               c1=np.concatenate(c1s).astype(np.int64), w=np.concatenate(ws),
                               frame_interval=db.frame_interval * lag, has_flux=False,
                               attrs={**db.attrs, "lag": lag})

