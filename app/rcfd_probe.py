"""The rCFD recording probe: frames of a coupled run written to rcfd.h5 beside run.h5.

From ``probes.rcfd_from`` on, every ``probes.rcfd_interval`` (a frame): the void fraction at the frame
boundaries, the gas face fluxes averaged over the frame (summed after every fluid step on the device by
the gas solver, FlowSolver.add_face_flux, and read once per frame), and the
grains' cell-to-cell volume shifts over the frame (each grain's cell by its centre at the frame's start
and end, weighted by its volume, summed per (c0, c1) pair), over the cells below ``probes.rcfd_z_max``
(a grain above it counts in the top layer). The layout is app/rcfd/database.py's. The frame interval
is checked against the field's own time scale sqrt(<g^2>/<dg/dt^2>) (g = eps - its mean, summed over the
recorded cells; <g^2> from the boundaries, dg/dt differenced over the fluid step that follows each
boundary): written to the file's attributes and logged when the frame is longer.

Cost: nothing read back in the fluid steps inside a frame; per frame, the void fraction twice (at the
boundary and one fluid step later), the flux sums and the counted grains' cells, octants and flags, computed on the
device (``DemSolver.tracked_cells``: 6 bytes a grain, not the 12-24 of a position, and no floors on the host). The
per-cell sums, the volume shifts and the writes run on a thread of their own, beside the next frame's steps. The
solvers are read through ``read_solvers`` only.
"""
from __future__ import annotations

import concurrent.futures
import json
import math
import pathlib
import time

import h5py
import numpy as np

from .config.derived import grain_volume, interval_steps
from .io import store
from .rcfd.database import parse_tag, recording_settings


#: HDF5 filters of the probe's compressed datasets: gzip at level 1 after the byte shuffle, as run.h5's fields
#: (app/io/store.py) are at level 1. With gzip's default level 4 and no shuffle, writing a million grains' cells and
#: octants was the largest part of the probe's host work at a boundary: that work took 332 ms a frame (grains
#: numbered at random; 276 in cell order), with these filters 211 (191), the files 4% smaller
#: (benchmarks/rcfd_frame_cost.py --h5, benchmarks/RESULTS.md).
H5_FILTERS = {"compression": "gzip", "compression_opts": 1, "shuffle": True}


# ---------------------------------------------------------------- adapter: the one place that reads the solvers
def read_solvers(sim, what: str):
    """What the probe reads from the gas solver and the DEM, by name:
    'geometry' -> (shape, h [m], origin [m], open volume fraction, apertures (3 face arrays));
    'eps' -> the gas void fraction (nx, ny, nz); 'add_flux' -> adds a step's face fluxes to the gas solver's
    device sums (returns a function of dt [s]); 'flux_sum' -> those sums [m^3] (3 face arrays), then cleared;
    'flux_peek' -> the same, not cleared; 'load_flux' -> sets them (a function of the 3 arrays);
    'alive' -> (n,) bool; 'track' -> the DEM's ``track(ids)``; 'cells' -> its ``tracked_cells(origin, h, shape,
    tag)`` (the tracked grains' cells, octants, alive and tag flags, computed on the device); 'radii' -> [m] (n,);
    'bed_height' -> [m]."""
    flow, dem = sim.flow, sim.dem
    if what == "geometry":
        return (tuple(flow.shape), float(flow.h), np.asarray(flow.config.grid.origin, float),
                np.asarray(flow.cut.volume, float), tuple(np.asarray(a, float) for a in flow.cut.apertures))
    if what == "eps":
        return flow.fields.eps.to_numpy()
    if what == "add_flux":
        return flow.add_face_flux
    if what == "flux_sum":
        return flow.face_flux_sum()
    if what == "flux_peek":
        return flow.face_flux_sum(clear=False)
    if what == "load_flux":
        return flow.load_face_flux_sum
    if what == "alive":
        return dem.read("alive").astype(bool)
    if what == "track":
        return dem.track
    if what == "cells":
        return dem.tracked_cells
    if what == "radii":
        return dem.radii()
    if what == "bed_height":
        return float(sim.diagnostics()["bed_height"])
    raise KeyError(what)


def shift_sums(c0: np.ndarray, c1: np.ndarray, vol: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """The frame's volume shifts: the distinct pairs (c0, c1) of the grains' cells at its start and end as keys
    c0 n + c1, ascending, and each pair's summed grain volume, added in grain order: exactly
    ``np.unique(c0 * n + c1, return_inverse=True)`` and ``np.bincount(inverse, weights=vol)``. Most grains end a
    frame in the cell they started it in: those pairs are summed by a bincount over the cells, and only the others go
    through np.unique's sort (1e6 grains: the sort took ~100 ms a frame on the CPU)."""
    stay = c0 == c1
    c_stay = c0[stay]
    present = np.bincount(c_stay, minlength=n) > 0
    w_stay = np.bincount(c_stay, weights=vol[stay], minlength=n)[present]
    diag = np.nonzero(present)[0].astype(np.int64)
    keys_move, inv = np.unique(c0[~stay].astype(np.int64) * n + c1[~stay], return_inverse=True)
    w_move = np.bincount(inv, weights=vol[~stay], minlength=keys_move.size)
    keys = np.concatenate([diag * n + diag, keys_move])
    order = np.argsort(keys, kind="stable")
    return keys[order], np.concatenate([w_stay, w_move])[order]


def face_eps(eps: np.ndarray, axis: int) -> np.ndarray:
    """eps on the faces normal to ``axis``: the mean of the two cells inside, the cell's own value on the
    domain faces (as the gas solver's boundary flux uses it). The recorded fluxes use the solver's own face
    gas fraction, on the device; this is its host-side formula (for checks)."""
    lo = np.take(eps, [0], axis=axis)
    hi = np.take(eps, [eps.shape[axis] - 1], axis=axis)
    ext = np.concatenate([lo, eps, hi], axis=axis)
    n = ext.shape[axis]
    return 0.5 * (np.take(ext, range(0, n - 1), axis=axis) + np.take(ext, range(1, n), axis=axis))


class RcfdRecorder:
    """Writes the frames; ``attach(sim, out_dir, guarded, resume_time, log, saved)``. ``saved(sim)`` is its part of a
    checkpoint: the frame open then and the time scale's sums, from which a resumed run goes on as the run did."""

    PART = "rcfd"  # the checkpoint's part (store.write_checkpoint's parts) that holds :meth:`saved`
    _SUMS = ("rate_sq", "rate_sq_frame", "flux_time")  # saved: the float sums [s^-2, s^-2, s], then the counts
    _COUNTS = ("samples", "rate_samples", "rate_samples_frame")

    def __init__(self, cfg, axis_xy):
        p = cfg.probes
        self.t0 = p.rcfd_from
        self.interval = p.rcfd_interval
        self.z_max = p.rcfd_z_max
        self.tag = p.rcfd_tag
        self.fluxes = p.rcfd_fluxes
        self.grain_cells = p.rcfd_grain_cells
        self.step = cfg.run.step
        self.settings = recording_settings(cfg)
        self.axis = np.asarray(axis_xy, float)
        self.f = None
        self.log = None
        self._tracking = None  # the counted grains the DEM tracks (track() once per list)
        self._writer = None  # the thread that appends to rcfd.h5 (_submit), and its boundary in flight
        self._pending = None

    # -- set-up
    def attach(self, sim, out_dir, guarded, resume_time, log, saved: dict | None = None) -> None:
        self.log = log
        self.spf = interval_steps(self.interval, self.step)
        self.s0 = int(math.ceil(self.t0 / self.step - 1e-9))
        shape, h, origin, vol, aps = read_solvers(sim, "geometry")
        nz = shape[2]
        if self.z_max > 0:
            nz = min(nz, max(1, int(math.ceil((self.z_max - origin[2]) / h - 1e-9))))
        self.shape = (shape[0], shape[1], nz)
        self.n = int(np.prod(self.shape))
        self.h, self.origin = h, origin
        self.path = pathlib.Path(out_dir) / "rcfd.h5"
        self._open(vol[:, :, :nz], resume_time)
        self._boundaries = int(self.f["boundary/time"].shape[0])  # kept here: the writer thread owns the file
        self._shifts = int(self.f["frame/offset"][-1])
        self.open_frame = None  # (start boundary index, start cells, step count at start)
        self.add_flux = read_solvers(sim, "add_flux") if self.fluxes else None
        self.flux_time = 0.0
        self.eps_sum = np.zeros(self.shape)
        self.eps_sq = np.zeros(self.shape)
        self.rate_sq = 0.0
        self.rate_sq_frame = 0.0
        self.samples = 0
        self.rate_samples = 0
        self.rate_samples_frame = 0
        self.prev_eps = None
        self.prev_boundary_eps = None
        self._flushed = time.perf_counter()
        if sim.step_count >= self.s0 and saved is not None and self._restore(saved, sim):
            pass  # resumed: the frame open at the checkpoint goes on, its sums and the time scale's as saved
        elif sim.step_count >= self.s0:  # resumed (from a checkpoint without the part), or continued, past the start
            times = self.f["boundary/time"][...]
            if times.size and abs(times[-1] - sim.time) < 1e-9 * max(1.0, sim.time) and self.counted is not None:
                # resumed on a frame boundary: its grains are the checkpoint's, so the frame goes on
                cells, self.last_octant, _, _ = self._cells(sim)
                self.open_frame, self.last_cells = (times.size - 1, cells), cells
                self.prev_boundary_eps = read_solvers(sim, "eps")[:, :, :nz].astype(np.float64)
                self.prev_eps = self.prev_boundary_eps
                if self.fluxes:
                    read_solvers(sim, "flux_sum")  # clears the device sums
            else:
                self(sim)
        sim.add(guarded(self), self.step, finish=self.finish)

    def _key(self, sim) -> np.ndarray:
        """What a saved part must match to be restored: the frames' start step and length, the recorded cells, the
        fluxes recorded or not, the boundaries and shifts in rcfd.h5 and the step (the checkpoint's)."""
        return np.array([self.s0, self.spf, *self.shape, int(self.fluxes), self._boundaries, self._shifts,
                         sim.step_count], np.int64)

    def saved(self, sim) -> dict:
        """This recorder's part of a checkpoint written now (after this step's call): rcfd.h5 written up to here (the
        writer thread drained, the file flushed), the open frame (its start boundary, the counted grains' cells and
        octants then, the flux sums so far on the device and their time), the time scale's sums, the void fraction
        the next rate sample differences from. Empty before the first frame."""
        if self.f is None or sim.step_count < self.s0:
            return {}
        self._drain()
        self.f.flush()
        out = {"key": self._key(sim), "sums": np.array([getattr(self, k) for k in self._SUMS], np.float64),
               "counts": np.array([getattr(self, k) for k in self._COUNTS], np.int64),
               "eps_sum": self.eps_sum, "eps_sq": self.eps_sq}
        for k in ("prev_eps", "prev_boundary_eps"):
            if getattr(self, k) is not None:
                out[k] = getattr(self, k)
        if self.open_frame is not None:
            out.update(open_boundary=np.int64(self.open_frame[0]), open_cells=self.open_frame[1],
                       last_octant=self.last_octant)
            if self.fluxes:
                out.update({f"flux_{'xyz'[a]}": q for a, q in enumerate(read_solvers(sim, "flux_peek"))})
        return out

    def _restore(self, saved: dict, sim) -> bool:
        """Go on from a checkpoint's part (:meth:`saved`) if it is this recording's at this step with rcfd.h5 as it
        was then; False (nothing changed) otherwise: then the frame open at the checkpoint is lost, as before."""
        if not np.array_equal(saved.get("key"), self._key(sim)):
            return False
        if "open_cells" in saved and (self.counted is None or saved["open_cells"].size != self.counted.size):
            return False
        for k, v in zip(self._SUMS, saved["sums"]):
            setattr(self, k, float(v))
        for k, v in zip(self._COUNTS, saved["counts"]):
            setattr(self, k, int(v))
        self.eps_sum, self.eps_sq = saved["eps_sum"], saved["eps_sq"]
        self.prev_eps, self.prev_boundary_eps = saved.get("prev_eps"), saved.get("prev_boundary_eps")
        if "open_cells" in saved:
            self.open_frame = (int(saved["open_boundary"]), saved["open_cells"])
            self.last_cells, self.last_octant = saved["open_cells"], saved["last_octant"]
            if self.fluxes:
                read_solvers(sim, "load_flux")(tuple(saved[f"flux_{a}"] for a in "xyz"))
        return True

    def _open(self, vol, resume_time) -> None:
        resume = resume_time is not None and self.path.exists()
        self.f = h5py.File(self.path, "a" if resume else "w")
        f = self.f
        if resume:
            self._truncate(resume_time)
            self.tagged_ids = f["grains_tagged"][...] if "grains_tagged" in f else None
            self.counted = f["grains_counted"][...] if "grains_counted" in f else None
            self.tagged = None
            self.vol = None
            self.last_cells = None
            return
        f.attrs.update(h=self.h, origin=self.origin, shape=self.shape, frame_interval=self.spf * self.step,
                       step=self.step, axis=self.axis, tag=self.tag, rcfd_from=self.t0,
                       settings=json.dumps(self.settings))
        f.create_dataset("geometry/open_volume", data=vol.astype(np.float32))
        n, sh = self.n, self.shape

        def app(name, shape, dtype, chunk=None):
            f.create_dataset(name, shape=(0,) + shape, maxshape=(None,) + shape, dtype=dtype,
                             chunks=chunk or ((max(1, min(64, (1 << 20) // max(1, 4 * int(np.prod(shape) or 1)))),)
                                              + shape), **(H5_FILTERS if np.prod(shape or (1,)) > 4096 else {}))

        app("boundary/time", (), "f8", (1024,))
        app("boundary/eps", sh, "f4")
        app("boundary/bed_height", (), "f8", (1024,))
        for k in ("solid", "tag_now", "tagged"):
            app(f"boundary/{k}", (n,), "f4")
        app("frame/b0", (), "i4", (1024,))
        app("frame/b1", (), "i4", (1024,))
        f.create_dataset("frame/offset", data=np.zeros(1, np.int64), maxshape=(None,), chunks=(1024,))
        app("shift/c0", (), "i4", (65536,))
        app("shift/c1", (), "i4", (65536,))
        app("shift/w", (), "f8", (65536,))
        if self.fluxes:
            fs = [(sh[0] + 1, sh[1], sh[2]), (sh[0], sh[1] + 1, sh[2]), (sh[0], sh[1], sh[2] + 1)]
            for a, s in zip("xyz", fs):
                app(f"frame/flux_{a}", s, "f4")
        self.tagged_ids = None
        self.counted = None
        self.tagged = None
        self.vol = None
        self.last_cells = None

    def _truncate(self, t: float) -> None:
        """Drop what was written after the checkpoint the run resumes from. The frame open then goes on from the
        checkpoint's part (:meth:`saved`); from a checkpoint without it that frame is lost, and the next one starts
        at the next frame boundary (its b0 then differs from the last frame's b1)."""
        f = self.f
        nb = int(np.searchsorted(f["boundary/time"][...], t + 1e-9, side="right"))
        for k in ("time", "eps", "bed_height", "solid", "tag_now", "tagged", "cells", "octant"):
            if f"boundary/{k}" not in f:
                continue
            ds = f[f"boundary/{k}"]
            ds.resize((nb,) + ds.shape[1:])
        nf = int(np.sum(f["frame/b1"][...] < nb))
        for k in ("b0", "b1") + (("flux_x", "flux_y", "flux_z") if "frame/flux_x" in f else ()):
            ds = f[f"frame/{k}"]
            ds.resize((nf,) + ds.shape[1:])
        f["frame/offset"].resize((nf + 1,))
        ns = int(f["frame/offset"][nf])
        for k in ("c0", "c1", "w"):
            f[f"shift/{k}"].resize((ns,))

    @staticmethod
    def _append(ds, data) -> None:
        """Append one item (shape ds.shape[1:]) or, to a 1-D dataset, an array of items."""
        data = np.asarray(data)
        if data.shape == ds.shape[1:]:
            data = data[None]
        n = ds.shape[0]
        ds.resize((n + data.shape[0],) + ds.shape[1:])
        ds[n:] = data

    def cells_and_octants(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Each point's cell (flat index, clipped to the recorded cells) and which eighth of it the point is in
        (bits x, y, z: 4, 2, 1), from one floor on the half-cells: a half-cell index q2 clipped to [0, 2 n - 1]
        gives the cell as q2 // 2, the same as floor((x - origin) / h) clipped to [0, n - 1] (dividing by h / 2 is
        dividing by h and doubling, exactly in floating point), and the octant bit as q2 & 1. The probe takes these
        from the device (:meth:`_cells`, the same floors in ``app/sim/dem/cells.py``); this host form is their
        reference (tests, benchmarks/rcfd_frame_cost.py)."""
        q = np.floor((x - self.origin) / (0.5 * self.h)).astype(np.int64)
        for a in range(3):
            np.clip(q[:, a], 0, 2 * self.shape[a] - 1, out=q[:, a])
        c = q >> 1
        cells = (c[:, 0] * self.shape[1] + c[:, 1]) * self.shape[2] + c[:, 2]
        return cells, (((q[:, 0] & 1) << 2) | ((q[:, 1] & 1) << 1) | (q[:, 2] & 1)).astype(np.uint8)

    # -- every fluid step
    def __call__(self, sim) -> None:
        s = sim.step_count
        if s < self.s0:
            return
        if self.open_frame is not None and self.fluxes:
            self.add_flux(self.step)  # on the device: nothing read back
            self.flux_time += self.step
        phase = (s - self.s0) % self.spf
        if phase == 0:
            eps = read_solvers(sim, "eps")[:, :, :self.shape[2]].astype(np.float64)
            if self.spf == 1 and self.prev_eps is not None:  # frames of one fluid step: every step is a sample
                self._taylor(eps, boundary=False)
            self._taylor(eps, boundary=True)
            self._boundary(sim, eps)
        elif phase == 1 and self.prev_eps is not None:  # one fluid step after a boundary: the rate sample
            self._taylor(read_solvers(sim, "eps")[:, :, :self.shape[2]].astype(np.float64), boundary=False)

    def _taylor(self, eps: np.ndarray, boundary: bool) -> None:
        """<g^2> from the boundaries' eps; <dg/dt^2> from the change over the fluid step after each boundary."""
        if boundary:
            self.samples += 1
            self.eps_sum += eps
            self.eps_sq += eps * eps
        else:
            self.rate_sq += float(np.sum(((eps - self.prev_eps) / self.step) ** 2))
            self.rate_samples += 1
        self.prev_eps = eps

    def volumes(self, sim) -> np.ndarray:
        """The counted grains' volumes [m^3]: the radii read once (they do not change in a run), not every frame."""
        if self.vol is None:
            self.vol = grain_volume(read_solvers(sim, "radii")[self.counted])
        return self.vol

    def _cells(self, sim) -> tuple:
        """The counted grains' (cells, octants, alive, in the tag's region now), from the device: the floors of
        :meth:`cells_and_octants` and the tag expression computed there, 6 bytes a grain read back instead of
        the positions (a million grains on one CPU thread: 27 ms a frame against 68 for the read and numpy)."""
        if self._tracking is not self.counted:
            read_solvers(sim, "track")(self.counted)
            self._tracking = self.counted
        return read_solvers(sim, "cells")(self.origin, self.h, self.shape, parse_tag(self.tag))

    def _boundary(self, sim, eps: np.ndarray) -> None:
        """A frame boundary: everything read from the solvers here; the per-cell sums, the volume shifts and the
        appends to rcfd.h5 are handed to the writer thread (:meth:`_submit`)."""
        if self.counted is None:  # the grains counted from the first boundary on
            self.counted = np.nonzero(read_solvers(sim, "alive"))[0]
        cells, octant, alive, now = self._cells(sim)
        first = None
        if self.tagged_ids is None:
            self.tagged_ids = self.counted[now]
            first = (self.counted, self.tagged_ids, self.volumes(sim) if self.grain_cells else None)
        ids = self.counted
        if self.last_cells is not None:  # a grain that left the domain stays in its last cell
            gone = ~alive
            cells[gone] = self.last_cells[gone]
            octant[gone] = self.last_octant[gone]
        vol = self.volumes(sim)
        if self.tagged is None:  # which counted grains are tagged: fixed from the first boundary on
            self.tagged = np.isin(ids, self.tagged_ids)
        b = self._boundaries
        self._boundaries += 1
        rows = [("boundary/time", sim.time), ("boundary/eps", eps.astype(np.float32)),
                ("boundary/bed_height", read_solvers(sim, "bed_height"))]
        if self.grain_cells:
            rows += [("boundary/cells", cells.astype(np.int32)), ("boundary/octant", octant)]
        to_sum = dict(cells=cells, now=now, tagged=self.tagged, vol=vol, open_frame=self.open_frame, b=b)  # for _sums
        if self.fluxes:
            sums = read_solvers(sim, "flux_sum")  # read once per frame, and cleared
            if self.open_frame is not None:
                nz = self.shape[2]
                for a in range(3):
                    q = sums[a][:, :, :nz + 1 if a == 2 else nz] / max(self.flux_time, 1e-300)
                    rows.append((f"frame/flux_{'xyz'[a]}", q.astype(np.float32)))
            self.flux_time = 0.0
        self._submit(first, rows, to_sum)
        self.open_frame = (b, cells)
        self.last_cells, self.last_octant = cells, octant
        if self.prev_boundary_eps is not None:
            self.rate_sq_frame += float(np.sum(((eps - self.prev_boundary_eps) / (self.spf * self.step)) ** 2))
            self.rate_samples_frame += 1
        self.prev_boundary_eps = eps

    # -- the writer thread: rcfd.h5's appends overlap the next frame's stepping
    def _submit(self, first, rows, to_sum) -> None:
        """Hand a boundary's appends, and its per-cell sums and volume shifts to compute (:meth:`_sums`), to the
        writer thread, after the last boundary's are written (at most one boundary in flight; an error there, e.g. a
        full disk, is raised here, one boundary later, or at finish). h5py lets other threads run while HDF5
        compresses and writes, and numpy's sorts and most of its array passes release the GIL too, so that work
        overlaps the next frame's steps where the host waits outside Python; where the steps hold the GIL (a Taichi
        kernel call does, on the CPU) it only moves off the boundary (benchmarks/rcfd_frame_cost.py --h5 --steps)."""
        self._drain()
        nbytes = sum(np.asarray(v).nbytes for _, v in rows) + (0 if first is None else sum(
            np.asarray(v).nbytes for v in first if v is not None))
        nbytes += 12 * self.n + (0 if to_sum["open_frame"] is None else 16 * to_sum["cells"].size)  # <= a shift a grain
        store.check_space(self.path, nbytes)  # as every writer of the run: a full disk is a clean stop
        if self._writer is None:
            self._writer = concurrent.futures.ThreadPoolExecutor(max_workers=1, thread_name_prefix="rcfd-h5")
        self._pending = self._writer.submit(self._write, first, rows, to_sum, nbytes)

    def _sums(self, cells, now, tagged, vol, open_frame, b) -> list:
        """On the writer thread: the boundary's per-cell volumes (all counted grains, those in the tag's region now,
        the tagged ones) and, closing the open frame, its volume shifts (:func:`shift_sums`) with the frame's rows.
        The running shift count is this thread's alone once the probe is attached."""
        rows = []
        for name, sel in (("solid", None), ("tag_now", now), ("tagged", tagged)):
            w = vol if sel is None else vol * sel
            rows.append((f"boundary/{name}", np.bincount(cells, weights=w, minlength=self.n).astype(np.float32)))
        if open_frame is not None:
            b_start, c_start = open_frame
            keys, w = shift_sums(c_start, cells, vol, self.n)
            self._shifts += keys.size
            rows += [("shift/c0", (keys // self.n).astype(np.int32)), ("shift/c1", (keys % self.n).astype(np.int32)),
                     ("shift/w", w), ("frame/b0", b_start), ("frame/b1", b), ("frame/offset", self._shifts)]
        return rows

    def _drain(self) -> None:
        """Wait for the writer thread's boundary in flight; its error, if any, is raised here (a full disk as the
        run's :class:`~app.io.store.DiskFull`, which stops it cleanly with its last good checkpoint)."""
        pending, self._pending = self._pending, None
        if pending is not None:
            pending.result()

    def _write(self, first, rows, to_sum, nbytes) -> None:
        f = self.f
        rows = rows + self._sums(**to_sum)
        with store.writing(self.path, nbytes, check=False):  # its space checked by _submit
            if first is not None:
                counted, tagged_ids, vol = first
                f.create_dataset("grains_counted", data=counted)
                f.create_dataset("grains_tagged", data=tagged_ids)
                f.attrs["grains"] = int(counted.size)
                if vol is not None:
                    n = int(counted.size)
                    f.create_dataset("grains_volume", data=vol)
                    f.create_dataset("boundary/cells", shape=(0, n), maxshape=(None, n), dtype="i4",
                                     chunks=(max(1, min(64, (1 << 20) // (4 * n))), n), **H5_FILTERS)
                    f.create_dataset("boundary/octant", shape=(0, n), maxshape=(None, n), dtype="u1",
                                     chunks=(max(1, min(64, (1 << 20) // n)), n), **H5_FILTERS)
            for name, data in rows:
                self._append(f[name], data)
            now_wall = time.perf_counter()
            if now_wall - self._flushed > 10.0:  # a crash loses at most ~10 s of frames
                f.flush()
                self._flushed = now_wall

    def frame_check(self) -> dict:
        """The Taylor time scale of eps from the samples so far, at the fluid step and at the frame interval."""
        n = max(self.samples, 1)
        var = float(np.sum(self.eps_sq / n - (self.eps_sum / n) ** 2))
        lam = math.sqrt(var / (self.rate_sq / self.rate_samples)) if self.rate_samples and self.rate_sq > 0 \
            else float("inf")
        lam_f = math.sqrt(var / (self.rate_sq_frame / self.rate_samples_frame)) \
            if self.rate_samples_frame and self.rate_sq_frame > 0 else float("inf")
        dt_f = self.spf * self.step
        ok = dt_f <= lam
        msg = "ok" if ok else (f"the frame interval {dt_f:g} s is longer than the void fraction's Taylor time "
                               f"{lam:.3g} s (sqrt(<g^2>/<dg/dt^2>)): frames do not resolve the field's changes; "
                               "lower probes.rcfd_interval")
        return {"taylor_time": lam, "taylor_time_frame": lam_f, "taylor_samples": self.samples, "frame_check": msg}

    def finish(self, sim, reason) -> None:
        if self.f is None:
            return
        try:
            self._drain()  # the last boundary's appends (an error in them is raised here, the file still closed)
            if self.samples > 1:
                chk = self.frame_check()
                self.f.attrs.update(chk)
                if chk["frame_check"] != "ok" and self.log:
                    self.log(f"fbed: rcfd: {chk['frame_check']}")
        finally:
            if self._writer is not None:
                self._writer.shutdown(wait=True)
                self._writer = None
            self.f.close()
            self.f = None
