"""Files a run writes: run.h5 (series and snapshots), checkpoints, bed.h5, summary.json.

Owns: the on-disk layout. Plain h5py/json; callers pass numpy arrays and dicts.

run.h5
  /series/<name>                1-D, one entry per series sample (``time`` in s first)
  /particles/<k>/{time,position,velocity,radius}   snapshot k (k = 0, 1, ...)
  /particle_id                  each grain's index (0 .. n-1), for run.xdmf
  attrs: fbed_version, fbed_code (app.provenance: the code that ran it), preset, units (JSON: name -> unit)
  /fields/<k>/{time,gas_velocity,pressure,void_fraction}  gas snapshot k: cell-centred
                                interstitial velocity (nx,ny,nz,3) [m/s], pressure [Pa], gas fraction [-]
checkpoint.h5 / bed.h5
  /grains/<array>               every changing DEM array (see DemSolver.state_arrays)
  /gas/<array>                  the gas solver's whole state (see FlowSolver.state_arrays)
  /particle_id                  each grain's index, for checkpoint.xdmf / bed.xdmf
  /parts/<name>/<array>         a recorder's own state at the checkpoint (checkpoint.h5 only; the rCFD probe's
                                open frame: RcfdRecorder.saved), so a resumed run records what the run would have
  attrs: time [s], step, config (the resolved TOML), fbed_version, fbed_code (the code that made the state)
  /grid/{points,hexahedra,open_volume}  the gas grid for run.xdmf (written once): cell corners [m],
                                cells as 8 corner indices (VTK order), open volume fraction of each cell [-]
Every write goes to a temporary file first and is renamed into place, so a crash
mid-write leaves the previous checkpoint intact. Before a write, the free space is checked against
what it needs; a full disk raises DiskFull (the temporary file removed), never a half-written file.
"""
from __future__ import annotations

import contextlib
import errno
import json
import math
import os
import shutil
import pathlib
import time as wallclock

import h5py
import numpy as np

from . import bedpack
from ..provenance import code_id

VERSION = "0.1.0"
#: a checkpoint's gas-group array of the adaptive fluid step: [pieces, peak, changes] (Simulation.gas_split ...)
SPLIT_KEY = "adaptive_split"

SERIES_UNITS = {
    "time": "s", "kinetic_energy": "J", "kinetic_energy_rotational": "J", "max_overlap": "1 (of diameter)",
    "max_speed": "m/s", "grains_alive": "1", "grains_removed": "1", "bed_height": "m", "wall_time": "s",
}


class DiskFull(Exception):
    """A write found too little free space (or the disk filled during it): nothing half-written is left."""

    def __init__(self, path, needed: int | None, free: int | None = None, written: int = 0):
        """``needed`` [bytes], or None where the writer cannot know it (an encoder's file): then ``written``, what
        the file held when the disk filled, is said instead."""
        self.path, self.needed, self.free = pathlib.Path(path), needed, free
        where = f"; {mb(free)} free on its disk" if free is not None else ""
        size = f"needed {mb(needed)}" if needed is not None else f"had {mb(written)} when the disk filled"
        super().__init__(f"the disk is full: writing {self.path.name} {size}{where}")


class FolderGone(Exception):
    """A write found its folder gone: removed or moved while the run wrote into it (nothing can be kept there)."""

    def __init__(self, path):
        self.path = pathlib.Path(path)
        super().__init__(f"the output folder {self.path.parent} is gone (removed or moved while the run wrote into "
                         f"it): {self.path.name} could not be written")


def mb(nbytes: int | float) -> str:
    return f"{nbytes / 1e6:.3g} MB" if nbytes >= 1e5 else f"{nbytes / 1e3:.3g} kB"


# room kept free beyond a write's own bytes: HDF5's metadata and b-trees, and the small files written after it
# (summary.json, run.xdmf), so a check that passes is not followed by a write that fails
SPACE_MARGIN = 1 << 20  # bytes


def free_bytes(path: pathlib.Path) -> int:
    p = pathlib.Path(path)
    while not p.exists() and p != p.parent:
        p = p.parent
    return shutil.disk_usage(p).free


def available_memory() -> float | None:
    """Memory the system can give a new process now [bytes] (Linux's MemAvailable), or None where unknown."""
    try:
        for line in pathlib.Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                return float(line.split()[1]) * 1024.0
    except OSError:
        pass
    return None


def check_space(path: pathlib.Path, needed: int) -> None:
    """Raise DiskFull unless the disk holding ``path`` has room for ``needed`` bytes and the margin."""
    free = free_bytes(path)
    if free < needed + SPACE_MARGIN:
        raise DiskFull(path, needed + SPACE_MARGIN, free)


def is_disk_full(err: BaseException) -> bool:
    """Whether an OSError (h5py's included: it puts errno 28 in its message) means no space left."""
    return isinstance(err, OSError) and (err.errno in (errno.ENOSPC, errno.EDQUOT)
                                         or "errno = 28" in str(err) or "No space left" in str(err))


def disk_full_text(err: BaseException) -> str | None:
    """What to tell of a full disk, from a :class:`DiskFull` or an OSError that means one (a write outside this
    module's guards: an analysis's table, a figure); None for any other error."""
    if isinstance(err, DiskFull):
        return str(err)
    if is_disk_full(err):
        name = getattr(err, "filename", None)
        return "the disk is full" + (f": writing {pathlib.Path(name).name}" if name else "")
    return None


@contextlib.contextmanager
def writing(path: pathlib.Path, nbytes: int, check: bool = True):
    """Guard a write of about ``nbytes`` into ``path`` (uncompressed: an upper bound): free space checked first
    (unless ``check`` is False: checked before), an ENOSPC from HDF5 turned into DiskFull."""
    if check:
        check_space(path, nbytes)
    try:
        yield
    except OSError as err:
        if is_disk_full(err):
            raise DiskFull(path, nbytes + SPACE_MARGIN, free_bytes(path)) from None
        raise


def grain_ids(n: int) -> np.ndarray:
    return np.arange(n, dtype=np.int32 if n < 2 ** 31 else np.int64)


def _nbytes(*groups) -> int:
    return sum(np.asarray(v).nbytes for arrays in groups if arrays for v in arrays.values())


def _atomic_write(path: pathlib.Path, fill, needed: int = 0) -> None:
    tmp = path.with_name(path.name + ".tmp")
    check_space(path, needed)
    try:
        with h5py.File(tmp, "w") as f:
            fill(f)
        os.replace(tmp, path)
    except OSError as err:
        tmp.unlink(missing_ok=True)
        if is_disk_full(err):
            raise DiskFull(path, needed, free_bytes(path)) from None
        if not path.parent.is_dir():
            raise FolderGone(path) from None
        raise
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def write_checkpoint(path: pathlib.Path, grains: dict | None, gas: dict | None, time: float, step: int,
                     config_text: str, parts: dict[str, dict] | None = None) -> None:
    """A checkpoint (or bed.h5): every array of the grains and/or the gas, time [s], step, resolved config, and
    ``parts``: name -> arrays of a recorder's own state (read back by :func:`read_parts`)."""
    parts = parts or {}

    def fill(f):
        named = [("grains", grains), ("gas", gas)] + [(f"parts/{k}", v) for k, v in parts.items()]
        for group, arrays in named:
            if arrays is None:
                continue
            g = f.create_group(group)
            for k, v in arrays.items():
                g.create_dataset(k, data=np.asarray(v))
        if grains is not None and "position" in grains:  # the grains' index, for checkpoint.xdmf
            f.create_dataset("particle_id", data=grain_ids(len(grains["position"])))
        f.attrs.update(time=time, step=step, config=config_text, fbed_version=VERSION, fbed_code=code_id())

    _atomic_write(pathlib.Path(path), fill, _nbytes(grains, gas, *parts.values()) + len(config_text))


def read_checkpoint(path: pathlib.Path) -> tuple[dict | None, dict | None, dict]:
    """(grain arrays or None, gas arrays or None, attributes) of a checkpoint (or a bed, packed or not)."""
    with h5py.File(path, "r") as f:
        if bedpack.is_packed(f):
            grains, meta = bedpack.read(f)
            return grains, None, meta
        grains = {k: f["grains"][k][...] for k in f["grains"]} if "grains" in f else None
        gas = {k: f["gas"][k][...] for k in f["gas"]} if "gas" in f else None
        meta = dict(f.attrs)
    return grains, gas, meta


def write_packed_bed(path: pathlib.Path, position, radius, time: float = 0.0, resolution: float = bedpack.RESOLUTION,
                     source: str = "", velocity=None, omega=None, speed_resolution: float = 0.0) -> dict:
    """A packed bed (app/io/bedpack.py: positions to the resolution [m], sizes exact, velocities and spins to the
    speed_resolution [m/s] where it is given), whole or not at all; returns its attrs (resolution, origin, grains)
    and ``bytes``, the file's size."""
    arrays, attrs = bedpack.pack(position, radius, resolution, velocity, omega, speed_resolution)
    attrs.update(time=time, source=source)
    path = pathlib.Path(path)
    _atomic_write(path, lambda f: bedpack.fill(f, arrays, attrs), sum(v.nbytes for v in arrays.values()))
    return {**attrs, "bytes": path.stat().st_size}


def read_parts(path: pathlib.Path) -> dict[str, dict]:
    """The recorders' parts of a checkpoint (name -> arrays; empty for one without them)."""
    with h5py.File(path, "r") as f:
        g = f.get("parts")
        return {} if g is None else {name: {k: g[name][k][...] for k in g[name]} for name in g}


def read_state(path: pathlib.Path) -> tuple[dict, dict]:
    """Grain arrays and attributes of a checkpoint or bed.h5."""
    grains, _, meta = read_checkpoint(path)
    return grains, meta


FRAME_GROUPS = ("slab", "planes", "porosity3d", "mri", "video")  # groups of appendable frames (probes, the video's)


# Series rows and probe frames are held in memory and written in batches: an HDF5 resize, write and flush per
# row cost ~5 ms (measured on this CPU: 16 series), a few percent of a million-grain GPU step. What is held is
# written when SERIES_BATCH rows or FRAME_BYTES of frames are pending, FLUSH_WALL seconds have passed, before
# every checkpoint (so a resumed run finds every row up to its checkpoint) and at close.
SERIES_BATCH = 256       # rows
FRAME_BYTES = 32 << 20   # bytes of pending probe frames
FLUSH_WALL = 10.0        # s of wall time


def _cut(group, n: int) -> None:
    """Cut every appendable dataset of a frame group to its first ``n`` rows."""
    for ds in group.values():
        if isinstance(ds, h5py.Dataset) and ds.maxshape and ds.maxshape[0] is None and ds.shape[0] > n:
            ds.resize((n,) + ds.shape[1:])


class RunFile:
    """Appends series rows, probe frames and snapshots to run.h5 (series and frames batched, see above)."""

    def __init__(self, path: pathlib.Path, preset: str, resume_time: float | None = None):
        self.path = pathlib.Path(path)
        mode = "a" if resume_time is not None and self.path.exists() else "w"
        self.f = h5py.File(self.path, mode)
        self.f.attrs.update(fbed_version=VERSION, fbed_code=code_id(), preset=preset, units=json.dumps(SERIES_UNITS))
        self.series = self.f.require_group("series")
        self.particles = self.f.require_group("particles")
        self._rows: list[dict] = []
        self._frames: dict[str, list] = {}
        self._frame_bytes = 0
        self._written = wallclock.perf_counter()
        self.failed = False  # a write failed: close() then only closes
        if resume_time is not None:
            self._truncate_after(resume_time)

    def _truncate_after(self, t: float) -> None:
        """Drop what a run wrote after its last checkpoint (it will be written again)."""
        if "time" in self.series:
            times = self.series["time"][...]
            keep = int(np.searchsorted(times, t + 1e-12, side="right"))
            for name in self.series:
                self.series[name].resize((keep,))
        for name in FRAME_GROUPS:  # appendable frame records (probes)
            for g in self._frame_groups(name):
                _cut(g, int(np.searchsorted(g["time"][...], t + 1e-12, side="right")))
        for group in (self.particles, self.f.get("fields")):
            if group is None:
                continue
            for k in list(group):
                if float(group[k]["time"][()]) > t + 1e-12:
                    del group[k]

    @contextlib.contextmanager
    def _writing(self, nbytes: int):
        """Guard one write of about ``nbytes`` (uncompressed: an upper bound): free space checked first, an
        ENOSPC from HDF5 turned into DiskFull (:func:`writing`), after which close() only closes."""
        with writing(self.path, nbytes):
            try:
                yield
            except OSError as err:
                self.failed = self.failed or is_disk_full(err)
                raise

    def append(self, row: dict) -> None:
        """One sample of every series in ``row``; a series first seen now is NaN for earlier samples."""
        self._rows.append({k: float(v) for k, v in row.items()})
        self._maybe_flush()

    def _maybe_flush(self) -> None:
        if (len(self._rows) >= SERIES_BATCH or self._frame_bytes >= FRAME_BYTES
                or wallclock.perf_counter() - self._written >= FLUSH_WALL):
            self.flush()

    def flush(self) -> None:
        """Write what is held (series rows, probe frames) and flush the file."""
        with self._writing(8 * 64 * len(self._rows) + self._frame_bytes):
            self._flush()

    def _flush(self) -> None:
        if self._rows:
            rows, self._rows = self._rows, []
            n = self.series["time"].shape[0] if "time" in self.series else 0
            names = list(dict.fromkeys([*self.series, *(k for r in rows for k in r)]))
            for name in names:
                if name not in self.series:
                    self.series.create_dataset(name, shape=(n,), maxshape=(None,), dtype="f8", chunks=(4096,),
                                               fillvalue=math.nan)
                ds = self.series[name]
                ds.resize((n + len(rows),))
                ds[n:] = np.array([r.get(name, math.nan) for r in rows])
        frames, self._frames, self._frame_bytes = self._frames, {}, 0
        for group, items in frames.items():
            self._write_frames(group, items)
        self.f.flush()
        self._written = wallclock.perf_counter()

    def snapshot(self, time: float, position, velocity, radius) -> int:
        with self._writing(4 * (7 * len(radius))):
            return self._snapshot(time, position, velocity, radius)

    def _snapshot(self, time: float, position, velocity, radius) -> int:
        if "particle_id" not in self.f:  # the grains' index, the same in every snapshot (run.xdmf's id)
            self.f.create_dataset("particle_id", data=grain_ids(len(radius)))
        k = len(self.particles)
        g = self.particles.create_group(str(k))
        try:
            g["time"] = time
            for name, arr in (("position", position), ("velocity", velocity), ("radius", radius)):
                g.create_dataset(name, data=np.asarray(arr, np.float32), compression="gzip", compression_opts=1)
            self.f.flush()
        except BaseException:  # no half-written snapshot is left in the file
            del self.particles[str(k)]
            raise
        return k

    def gas_fields(self, time: float, gas_velocity, pressure, void_fraction) -> int:
        with self._writing(4 * 5 * np.asarray(pressure).size):
            return self._gas_fields(time, gas_velocity, pressure, void_fraction)

    def _gas_fields(self, time: float, gas_velocity, pressure, void_fraction) -> int:
        fields = self.f.require_group("fields")
        k = len(fields)
        g = fields.create_group(str(k))
        try:
            g["time"] = time
            for name, arr in (("gas_velocity", gas_velocity), ("pressure", pressure),
                              ("void_fraction", void_fraction)):
                g.create_dataset(name, data=np.asarray(arr, np.float32), compression="gzip", compression_opts=1)
            self.f.flush()
        except BaseException:  # no half-written snapshot is left in the file
            del fields[str(k)]
            raise
        return k

    def _frame_groups(self, name: str):
        g = self.f.get(name)
        if g is None:
            return []
        if "time" in g:
            return [g]
        return [sub for sub in g.values() if isinstance(sub, h5py.Group) and "time" in sub]

    def frame(self, group: str, time: float, data, attrs: dict | None = None, dtype="f4",
              name: str = "porosity") -> None:
        """Append one frame (an array) to ``group``'s ``time`` and ``name`` datasets (created on first use, with
        ``attrs``)."""
        data = np.array(data, dtype)  # a copy: the caller's array may change before the batch is written
        self._frames.setdefault(group, []).append((time, data, attrs, name))
        self._frame_bytes += data.nbytes
        self._maybe_flush()

    def frame_count(self, group: str) -> int:
        """Frames ``group`` holds (those on disk and those still held)."""
        g = self.f.get(group)
        return (g["time"].shape[0] if g is not None and "time" in g else 0) + len(self._frames.get(group, ()))

    def keep_frames(self, group: str, n: int) -> None:
        """Drop all but the first ``n`` frames of ``group`` (on disk; none may be held)."""
        assert not self._frames.get(group), "keep_frames with frames still held"
        for g in self._frame_groups(group):
            _cut(g, n)

    def _write_frames(self, group: str, items: list) -> None:
        data, name = items[0][1], items[0][3]
        g = self.f.require_group(group)
        if "time" not in g:
            g.create_dataset("time", shape=(0,), maxshape=(None,), dtype="f8", chunks=(1024,))
            g.create_dataset(name, shape=(0,) + data.shape, maxshape=(None,) + data.shape, dtype=data.dtype,
                             chunks=(max(1, min(64, (1 << 20) // max(1, data.nbytes))),) + data.shape,
                             compression="gzip" if data.size > 4096 else None,
                             compression_opts=1 if data.size > 4096 else None)
            for k, v in (items[0][2] or {}).items():
                g.attrs[k] = v
        if g[name].shape[1:] != data.shape:  # h5py would cut (or pad) the frames there to the new shape, silently
            raise ValueError(f"{self.path}: /{group}/{name} holds frames of shape {g[name].shape[1:]}, not "
                             f"{data.shape}: a record's layout cannot change within a run")
        n, k = g["time"].shape[0], len(items)
        g["time"].resize((n + k,))
        g["time"][n:] = [item[0] for item in items]
        g[name].resize((n + k,) + data.shape)
        g[name][n:] = np.stack([item[1] for item in items])

    def put(self, name: str, data) -> None:
        """A fixed dataset (written once, e.g. a mask)."""
        with self._writing(np.asarray(data).nbytes):
            if name in self.f:
                del self.f[name]
            self.f.create_dataset(name, data=data)

    def grid(self, shape, h: float, origin, open_volume) -> None:
        """The gas grid, once, for run.xdmf: corner points, hexahedra (C order of the cell arrays: z fastest)
        and each cell's open volume fraction."""
        if "grid" in self.f:
            return
        nx, ny, nz = shape
        with self._writing(4 * (3 * (nx + 1) * (ny + 1) * (nz + 1) + 9 * nx * ny * nz)):
            ax = [origin[a] + h * np.arange(n + 1) for a, n in enumerate(shape)]
            X, Y, Z = np.meshgrid(*ax, indexing="ij")
            pts = np.stack([X.ravel(), Y.ravel(), Z.ravel()], axis=1).astype(np.float32)
            node = np.arange((nx + 1) * (ny + 1) * (nz + 1), dtype=np.int64).reshape(nx + 1, ny + 1, nz + 1)
            c = node[:-1, :-1, :-1]
            dx, dy, dz = (ny + 1) * (nz + 1), nz + 1, 1
            # VTK hexahedron: the bottom face (z low) counter-clockwise, then the top face
            hexes = np.stack([c, c + dx, c + dx + dy, c + dy, c + dz, c + dx + dz, c + dx + dy + dz, c + dy + dz],
                             axis=-1).reshape(-1, 8)
            g = self.f.create_group("grid")
            g.attrs.update(shape=np.asarray(shape), h=h, origin=np.asarray(origin, float))
            g.create_dataset("points", data=pts, compression="gzip", compression_opts=1)
            dt = np.int32 if hexes.max() < 2 ** 31 else np.int64
            g.create_dataset("hexahedra", data=hexes.astype(dt), compression="gzip", compression_opts=1)
            g.create_dataset("open_volume", data=np.asarray(open_volume, np.float32), compression="gzip",
                             compression_opts=1)
            self.f.flush()

    def close(self) -> None:
        """Write what is held and close; after a failed write (disk full) only close, as best it can."""
        if self.f:
            try:
                if not self.failed:
                    self.flush()
            finally:
                f, self.f = self.f, None
                try:
                    f.close()
                except Exception:  # noqa: BLE001 - a file that could not be written may not close cleanly
                    pass


def write_text(path: pathlib.Path, text: str) -> None:
    """A small text file, atomically (a temporary file renamed into place; removed when the disk is full)."""
    path = pathlib.Path(path)
    tmp = pathlib.Path(str(path) + ".tmp")
    try:
        tmp.write_text(text)
        os.replace(tmp, path)
    except OSError as err:
        tmp.unlink(missing_ok=True)
        if is_disk_full(err):
            raise DiskFull(path, len(text.encode()), free_bytes(path)) from None
        if not path.parent.is_dir():
            raise FolderGone(path) from None
        raise


def write_json(path: pathlib.Path, data: dict) -> None:
    write_text(path, json.dumps(data, indent=2, default=float) + "\n")


def read_series(path: pathlib.Path) -> dict:
    with h5py.File(path, "r") as f:
        return {k: f["series"][k][...] for k in f["series"]}
